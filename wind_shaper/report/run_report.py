"""A run's report folder: PNG plots like the paper's figures and a JSON of every iteration.

Writes (into ``out_dir``): ``run.json`` (settings, target, model, every iteration),
``sweeps.npz`` (raw sweep samples per iteration), ``field_maps.png`` (measured field vs target
at iterations 0, 1 and last), ``error.png`` (error per iteration), ``pwm.png`` (PWM per fan).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402

from ..core.geometry import TunnelGeometry  # noqa: E402
from ..control import IterationRecord  # noqa: E402


def draw_fans(ax, geometry: TunnelGeometry, labels: bool = True):
    """Fan hubs as circles (dashed when disabled) with their names, on axes in metres."""
    for fan in geometry.fans.fans:
        ax.add_patch(plt.Circle((fan.x, fan.y), 0.06, fill=False, lw=1.2,
                                ls='-' if fan.enabled else '--', color='k'))
        if labels and geometry.fans.n_fans <= 40:
            ax.text(fan.x, fan.y, fan.name, ha='center', va='center', fontsize=7)
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')


def plot_field_maps(records: Sequence[IterationRecord], geometry: TunnelGeometry, path):
    """Estimated field, target and their difference at iterations 0, 1 and last [N]."""
    picks = sorted({0, min(1, len(records) - 1), len(records) - 1})
    kp = geometry.key_points
    tri = mtri.Triangulation(kp[:, 0], kp[:, 1])
    target = records[0].target
    lo = min(target.min(), min(r.estimate.mean.min() for r in records))
    hi = max(target.max(), max(r.estimate.mean.max() for r in records))
    levels = np.linspace(lo, hi, 21)
    err_max = max(np.abs(records[k].estimate.mean - target).max() for k in picks) or 1.0
    fig, axes = plt.subplots(len(picks), 3, figsize=(12, 3.6 * len(picks)), squeeze=False)
    for row, k in enumerate(picks):
        rec = records[k]
        panels = ((rec.estimate.mean, f'measured field, iteration {rec.k}', levels, 'viridis'),
                  (target, 'target', levels, 'viridis'),
                  (rec.estimate.mean - target, f'measured - target (RMSE {np.sqrt(rec.error):.3f} N)',
                   np.linspace(-err_max, err_max, 21), 'RdBu_r'))
        for ax, (values, title, lv, cmap) in zip(axes[row], panels):
            cs = ax.tricontourf(tri, values, levels=lv, cmap=cmap, extend='both')
            fig.colorbar(cs, ax=ax, label='force [N]')
            draw_fans(ax, geometry)
            ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_error(records: Sequence[IterationRecord], path):
    """RMSE per iteration [N]: from the GP estimate and, on a simulator, from the true field."""
    ks = [r.k for r in records]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(ks, [np.sqrt(r.error) for r in records], 'o-', label='estimated (GP at key points)')
    if all(r.true_error is not None for r in records):
        ax.plot(ks, [np.sqrt(r.true_error) for r in records], 's--', label='true field (simulator)')
    ax.set_yscale('log')
    ax.set_xlabel('iteration k')
    ax.set_ylabel('RMSE to target [N]')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_pwm(records: Sequence[IterationRecord], geometry: TunnelGeometry, path, u_max=None):
    """PWM per fan per iteration [% of full PWM], one line per fan (like the paper's figure)."""
    ks = [r.k for r in records]
    P = np.array([r.pwm for r in records]) * 100.0
    fig, ax = plt.subplots(figsize=(6, 3.5))
    if geometry.fans.n_fans <= 40:
        for j, name in enumerate(geometry.fans.names):
            ax.plot(ks, P[:, j], 'o-', ms=3, label=name)
        ax.legend(ncol=4, fontsize=7)
    else:
        ax.plot(ks, P, lw=0.5, alpha=0.4)
    if u_max is not None:
        ax.axhline(u_max * 100, color='gray', ls=':', lw=1)
    ax.set_xlabel('iteration k')
    ax.set_ylabel('PWM [%]')
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(out_dir, records: Sequence[IterationRecord], geometry: TunnelGeometry,
                 meta: dict, u_max=None) -> Path:
    """Write JSON, raw sweeps and the three PNGs; returns the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**meta,
           'fans': list(geometry.fans.names),
           'enabled': geometry.fans.enabled.tolist(),
           'key_points_m': np.round(geometry.key_points, 6).tolist(),
           'iterations': [r.to_json() for r in records]}
    (out / 'run.json').write_text(json.dumps(doc, indent=1))
    np.savez_compressed(out / 'sweeps.npz', **{
        f'k{r.k:03d}_{name}': getattr(r.sweep, name)
        for r in records for name in ('positions', 'forces', 'times', 'pwm')})
    plot_field_maps(records, geometry, out / 'field_maps.png')
    plot_error(records, out / 'error.png')
    plot_pwm(records, geometry, out / 'pwm.png', u_max)
    return out
