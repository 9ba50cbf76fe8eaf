"""Reports: a self-contained HTML page and a Markdown page with PNG plots, and a JSON summary.

``Report`` collects sections (text, tables, figures) and writes ``<out>/report.html`` (images
embedded, one file to mail around), ``<out>/report.md`` (images beside it as PNG files) and
``<out>/summary.json``. The plotting functions draw the workbench's figures on matplotlib's Agg
backend: residual maps with the fans drawn, residual against each fan's command, against radius
and angle, measured against predicted, the candidate ranking, before/after maps and the closed
loop's tracking error per iteration.
"""
from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402

from ..core.geometry import TunnelGeometry  # noqa: E402
from ..report.run_report import draw_fans  # noqa: E402

__all__ = ['Report', 'plot_residual_map', 'plot_residual_maps', 'plot_fan_curves',
           'plot_radial_angular', 'plot_measured_vs_model', 'plot_ranking', 'plot_closed_loop',
           'residual_sections']


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f'{type(obj).__name__} is not JSON serialisable')


class Report:
    """Sections of a report, written by ``write(out_dir)``."""

    def __init__(self, title: str):
        self.title = title
        self.sections: list[tuple] = []
        self.summary: dict = {}

    def text(self, text: str, heading: str | None = None):
        self.sections.append(('text', heading, text))

    def bullets(self, items, heading: str | None = None):
        self.sections.append(('bullets', heading, list(items)))

    def table(self, header, rows, heading: str | None = None):
        self.sections.append(('table', heading, (list(header), [list(r) for r in rows])))

    def figure(self, name: str, fig, caption: str = '', heading: str | None = None):
        """Add a matplotlib figure, saved as ``<name>.png``."""
        self.sections.append(('figure', heading, (name, fig, caption)))

    def write(self, out_dir) -> Path:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        md = [f'# {self.title}', '']
        body = [f'<h1>{html.escape(self.title)}</h1>']
        for kind, heading, content in self.sections:
            if heading:
                md += [f'## {heading}', '']
                body.append(f'<h2>{html.escape(heading)}</h2>')
            if kind == 'text':
                md += [content, '']
                body += [f'<p>{html.escape(p)}</p>' for p in content.split('\n\n')]
            elif kind == 'bullets':
                md += [f'- {b}' for b in content] + ['']
                body.append('<ul>' + ''.join(f'<li>{html.escape(str(b))}</li>' for b in content) + '</ul>')
            elif kind == 'table':
                header, rows = content
                md += ['| ' + ' | '.join(map(str, header)) + ' |', '|' + '---|' * len(header)]
                md += ['| ' + ' | '.join(str(c).replace('|', '/') for c in r) + ' |' for r in rows] + ['']
                body.append('<table><tr>' + ''.join(f'<th>{html.escape(str(h))}</th>' for h in header)
                            + '</tr>' + ''.join('<tr>' + ''.join(f'<td>{html.escape(str(c))}</td>' for c in r)
                                                + '</tr>' for r in rows) + '</table>')
            elif kind == 'figure':
                name, fig, caption = content
                path = out / f'{name}.png'
                fig.savefig(path, dpi=90)
                plt.close(fig)
                md += [f'![{caption or name}]({name}.png)', '']
                if caption:
                    md += [f'*{caption}*', '']
                data = base64.b64encode(path.read_bytes()).decode()
                body.append(f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(name)}">'
                            f'<figcaption>{html.escape(caption)}</figcaption></figure>')
        (out / 'report.md').write_text('\n'.join(md))
        style = ('body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}'
                 'table{border-collapse:collapse;font-size:0.85em}td,th{border:1px solid #ccc;'
                 'padding:3px 6px;text-align:left}img{max-width:100%}figcaption{font-style:italic}')
        (out / 'report.html').write_text(
            f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>{html.escape(self.title)}</title>'
            f'<style>{style}</style></head><body>{"".join(body)}</body></html>')
        (out / 'summary.json').write_text(json.dumps(self.summary, indent=1, default=_json_default))
        return out


# -- plots ----------------------------------------------------------------------------------------

def plot_residual_map(analysis, geometry: TunnelGeometry, axes, title: str = '', vmax=None):
    """The GP-smoothed residual (measured - model) [N] on ``axes[0]`` and its standard
    deviation on ``axes[1]``, fans drawn."""
    tri = mtri.Triangulation(analysis.grid[:, 0], analysis.grid[:, 1])
    vmax = vmax or max(float(np.max(np.abs(analysis.map_mean))), 1e-3)
    cs = axes[0].tricontourf(tri, analysis.map_mean, levels=np.linspace(-vmax, vmax, 21),
                             cmap='RdBu_r', extend='both')
    plt.colorbar(cs, ax=axes[0], label='measured - model [N]')
    draw_fans(axes[0], geometry)
    axes[0].set_title(f'{title} residual (RMSE {analysis.rmse:.3f} N)', fontsize=9)
    cs = axes[1].tricontourf(tri, analysis.map_std, levels=21, cmap='Greys')
    plt.colorbar(cs, ax=axes[1], label='std of the smoothed residual [N]')
    draw_fans(axes[1], geometry)
    axes[1].set_title('its uncertainty (GP standard deviation)', fontsize=9)


def plot_discrepancy(fit, commands: np.ndarray, geometry: TunnelGeometry):
    """What lies outside the library (``discrepancy.DiscrepancyFit``): the discrepancy at the
    sweeps' mean command [N], the share of it each command feature carries, and, when computed,
    the map of its fixed-fraction reading [% of the local force]; fans drawn."""
    from .discrepancy import disc_grid
    grid = disc_grid(geometry.sweep_radius, 0.02)
    tri = mtri.Triangulation(grid[:, 0], grid[:, 1])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    value = fit.value(np.mean(commands, axis=0), grid)
    vmax = max(float(np.max(np.abs(value))), 1e-3)
    cs = axes[0].tricontourf(tri, value, levels=np.linspace(-vmax, vmax, 21), cmap='RdBu_r', extend='both')
    plt.colorbar(cs, ax=axes[0], label='measured - model [N]')
    draw_fans(axes[0], geometry)
    axes[0].set_title('discrepancy at the sweeps\' mean command', fontsize=9)
    names = sorted(fit.shares, key=fit.shares.get)
    axes[1].barh(names, [100 * fit.shares[n] for n in names], color='tab:gray')
    axes[1].set_xlabel('share of the discrepancy [%]')
    axes[1].set_title('what it scales with', fontsize=9)
    if fit.fraction_map is not None:
        grid_g, g = fit.fraction_map
        gmax = max(float(np.max(np.abs(100 * g))), 1e-3)
        cs = axes[2].tricontourf(mtri.Triangulation(grid_g[:, 0], grid_g[:, 1]), 100 * g,
                                 levels=np.linspace(-gmax, gmax, 21), cmap='RdBu_r', extend='both')
        plt.colorbar(cs, ax=axes[2], label='measured / model - 1 [%]')
        draw_fans(axes[2], geometry)
        axes[2].set_title(f'as a fixed fraction of the local force (explains '
                          f'{100 * fit.readings.get("fraction", {}).get("r2", 0):.0f} %)', fontsize=9)
    else:
        axes[2].axis('off')
    fig.tight_layout()
    return fig


def plot_residual_maps(analyses: dict, geometry: TunnelGeometry):
    """One row per analysis (e.g. before / after), a shared colour scale."""
    vmax = max(float(np.max(np.abs(a.map_mean))) for a in analyses.values()) or 1e-3
    fig, axes = plt.subplots(len(analyses), 2, figsize=(11, 4.3 * len(analyses)), squeeze=False)
    for row, (label, a) in enumerate(analyses.items()):
        plot_residual_map(a, geometry, axes[row], label, vmax)
    fig.tight_layout()
    return fig


def plot_fan_curves(analysis, geometry: TunnelGeometry):
    """Mean residual near each fan (within 10 cm of its hub) against that fan's command."""
    names = list(analysis.fan_curves)
    cols = min(4, len(names))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False, sharey=True)
    for ax, name in zip(axes.ravel(), names):
        c, m, s = analysis.fan_curves[name]
        ok = np.isfinite(m)
        ax.errorbar(100 * c[ok], m[ok], yerr=np.nan_to_num(s[ok]), fmt='o-', ms=3)
        ax.axhline(0, color='gray', lw=0.8)
        ax.set_title(f'{name} (explains {100 * analysis.fan_r2.get(name, 0):.0f} %)', fontsize=9)
        ax.set_xlabel(f'{name} command [%]', fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel('residual near the fan [N]', fontsize=8)
    for ax in axes.ravel()[len(names):]:
        ax.axis('off')
    fig.tight_layout()
    return fig


def plot_radial_angular(analysis):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4))
    c, m, s = analysis.radial
    a1.errorbar(c, m, yerr=np.nan_to_num(s), fmt='o-')
    a1.axhline(0, color='gray', lw=0.8)
    a1.set_xlabel('radius r [m]')
    a1.set_ylabel('mean residual [N]')
    a1.set_title(f'against radius ({100 * analysis.radial_eta2:.0f} % of the variance)', fontsize=9)
    c, m, s = analysis.angular
    a2.errorbar(np.degrees(c), m, yerr=np.nan_to_num(s), fmt='o-')
    a2.axhline(0, color='gray', lw=0.8)
    a2.set_xlabel('angle from +x [deg]')
    a2.set_title(f'against angle, after the radial mean ({100 * analysis.angular_eta2:.0f} %)', fontsize=9)
    fig.tight_layout()
    return fig


def plot_measured_vs_model(pred, y, per_sweep: dict):
    """Measured against predicted force, and the RMSE of each sweep."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))
    a1.plot(pred, y, '.', ms=2, alpha=0.4)
    lo, hi = float(min(pred.min(), y.min())), float(max(pred.max(), y.max()))
    a1.plot([lo, hi], [lo, hi], 'k--', lw=0.8)
    a1.set_xlabel('model [N]')
    a1.set_ylabel('measured [N]')
    labels = list(per_sweep)
    a2.bar(range(len(labels)), [per_sweep[k].rmse for k in labels])
    a2.set_xticks(range(len(labels)), labels, rotation=60, fontsize=7)
    a2.set_ylabel('RMSE per sweep [N]')
    fig.tight_layout()
    return fig


def plot_ranking(trials, baseline_rmse: float, top: int = 12):
    """Held-out model error with each candidate, in the ranking's order (training BIC, refined
    candidates first), against the model without."""
    trials = list(trials)[:top]
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(trials) + 1.2))
    y = np.arange(len(trials))[::-1]
    colors = ['tab:green' if t.passed else ('tab:blue' if t.stage == 'refined' else 'tab:gray') for t in trials]
    ax.barh(y, [t.heldout_rmse for t in trials], color=colors)
    ax.axvline(baseline_rmse, color='k', ls='--', lw=1, label='without any candidate')
    ax.set_yticks(y, [t.candidate.name for t in trials], fontsize=8)
    ax.set_xlabel('held-out model error [N] (green: reported; blue: refitted; grey: screened)')
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_closed_loop(comparison):
    """True-field RMSE to the target per iteration for each model (median over seeds)."""
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    for label, e in comparison.errors.items():
        k = np.arange(e.shape[1])
        ax.plot(k, np.median(e, axis=0), 'o-', label=label)
    ax.set_yscale('log')
    ax.set_xlabel('iteration k')
    ax.set_ylabel('true-field RMSE to target [N]')
    ax.set_title(f'closed loop: {comparison.target}', fontsize=9)
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def residual_sections(report: Report, analyses: dict, geometry: TunnelGeometry, key: str) -> None:
    """The report's sections on where a model fails: the residual maps of every analysis
    (``{label: residuals.ResidualAnalysis}``), then the last one's residual against each fan's
    command and against radius and angle, and its structure in words. ``key`` prefixes the
    figures' file names."""
    report.figure(f'{key}_maps', plot_residual_maps(analyses, geometry),
                  'GP-smoothed residual (measured - model) over the tunnel, fans drawn; right: its '
                  'standard deviation', heading='Where the model fails')
    last = list(analyses.values())[-1]
    report.figure(f'{key}_fans', plot_fan_curves(last, geometry),
                  'residual near each fan against that fan\'s command (share of the residual variance '
                  'each fan\'s command explains)')
    report.figure(f'{key}_radial', plot_radial_angular(last), 'residual against radius and angle')
    report.bullets(last.describe(), heading='Structure of the residual')
