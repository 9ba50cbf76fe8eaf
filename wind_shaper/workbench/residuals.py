"""Where the model fails: the residual r = measured - model, mapped and taken apart.

``analyse_residuals(model, data, geometry)`` returns a ``ResidualAnalysis``:

* a map of the residual over the tunnel, smoothed by Gaussian-process regression, with its
  standard deviation (where the smoothing is unsure) on a grid [m];
* the residual against each fan's command near that fan, and how much of the residual each
  fan's command explains (R^2 of r on U_j w_j(z), U_j^2 w_j(z), w_j the fan's Gaussian
  footprint): a residual that follows one fan's command points at that fan;
* the residual against radius and against angle (binned means), and the share of its
  variance each explains (eta^2): a radial pattern points at the wall or the footprints' shape,
  an angular one at swirl or a lopsided fan;
* which fans' neighbourhoods (nearest hub) and which rings carry the squared error;
* whether the map is a tilt (a plane across the tunnel, with its direction), and what the
  residual at its peak follows from sweep to sweep: one fan's command, the total thrust, the
  CW/CCW balance, or no command at all.

``describe()`` puts the structure in plain words for the "no candidate explains the residual"
verdict. Positions [m, tunnel frame], forces [N], commands [fraction].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..estimation import GaussianProcessField
from ..core.geometry import TunnelGeometry
from ..model import Term
from .data import FitData

__all__ = ['ResidualAnalysis', 'analyse_residuals', 'disc_grid']


def _eta2(values: np.ndarray, groups: np.ndarray) -> float:
    """Share of the variance of ``values`` explained by group means (eta squared)."""
    if len(values) < 3:
        return 0.0
    total = float(np.sum((values - values.mean()) ** 2))
    if total <= 0:
        return 0.0
    means = np.zeros(groups.max() + 1)
    counts = np.bincount(groups, minlength=len(means))
    np.add.at(means, groups, values)
    means = means / np.maximum(counts, 1)
    return float(np.sum(counts * (means - values.mean()) ** 2) / total)


def _binned(x, r, edges):
    idx = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    centres = 0.5 * (edges[1:] + edges[:-1])
    mean = np.full(len(centres), np.nan)
    sem = np.full(len(centres), np.nan)
    count = np.bincount(idx, minlength=len(centres))
    for k in range(len(centres)):
        v = r[idx == k]
        if len(v):
            mean[k] = v.mean()
            sem[k] = v.std() / np.sqrt(len(v)) if len(v) > 1 else np.nan
    return centres, mean, sem, count, idx


@dataclass
class ResidualAnalysis:
    """See the module docstring. Arrays: grid (G, 2) [m], map_mean / map_std (G,) [N];
    fan_curves {fan: (command centres, mean residual, sem)}; fan_r2 {fan: R^2}; radial / angular
    (centres, mean, sem); radial_eta2, angular_eta2, smooth_share [-]; fan_share, ring_share
    {name: share of the squared error}; rmse [N]."""

    rmse: float
    bias: float
    grid: np.ndarray
    map_mean: np.ndarray
    map_std: np.ndarray
    smooth_share: float
    fan_curves: dict
    fan_r2: dict
    radial: tuple
    radial_eta2: float
    angular: tuple
    angular_eta2: float
    fan_share: dict
    ring_share: dict
    positions: np.ndarray = field(repr=False, default=None)
    residuals: np.ndarray = field(repr=False, default=None)
    peak_follows: str = ''

    def top_fans(self, k: int = 2) -> list[tuple[str, float]]:
        return sorted(self.fan_r2.items(), key=lambda kv: -kv[1])[:k]

    def peak(self):
        """(position (2,) [m], smoothed residual there [N]) where the map is largest for its
        uncertainty."""
        score = np.abs(self.map_mean) / np.maximum(self.map_std, 1e-6)
        k = int(np.argmax(score))
        return self.grid[k], float(self.map_mean[k])

    def tilt(self):
        """(direction [deg from +x] in which the residual grows, its slope [N per 10 cm], share
        of the smoothed map's variance a plane explains), or None for a flat map."""
        m = self.map_mean - self.map_mean.mean()
        if float(m @ m) <= 0 or self.positions is None:
            return None
        # the share from the smoothed map (is it a plane?), the slope from the samples (the map
        # flattens towards the edge, where the smoothing has no data beyond)
        X = np.column_stack([np.ones(len(self.grid)), self.grid])
        coef, *_ = np.linalg.lstsq(X, self.map_mean, rcond=None)
        fit = X @ coef - self.map_mean.mean()
        P = np.column_stack([np.ones(len(self.positions)), self.positions])
        (_, gx, gy), *_ = np.linalg.lstsq(P, self.residuals, rcond=None)
        return (float(np.degrees(np.arctan2(gy, gx))), float(0.1 * np.hypot(gx, gy)),
                float((fit @ fit) / (m @ m)))

    def describe(self) -> list[str]:
        """The residual's structure in plain sentences, strongest first."""
        out = []
        where, value = self.peak()
        out.append(f'the smoothed residual is largest at ({where[0]:+.2f}, {where[1]:+.2f}) m, where the '
                   f'model is {"low" if value > 0 else "high"} by {abs(value):.2f} N'
                   + (f'; there it follows {self.peak_follows}' if self.peak_follows else ''))
        (fan, r2), = self.top_fans(1) or [('', 0.0)]
        if r2 >= 0.15:
            centres, mean, _ = self.fan_curves[fan]
            ok = np.isfinite(mean)
            slope = np.polyfit(centres[ok], mean[ok], 1)[0] if ok.sum() >= 2 else 0.0
            sense = 'grows' if slope > 0 else 'falls'
            out.append(f'the residual follows fan {fan}\'s command: near {fan} it {sense} with its PWM '
                       f'(fan {fan}\'s command explains {100 * r2:.0f} % of the residual variance)')
        if self.radial_eta2 >= 0.15:
            c, m, _ = self.radial
            k = int(np.nanargmax(np.abs(m)))
            out.append(f'it has a radial pattern ({100 * self.radial_eta2:.0f} % of its variance): '
                       f'strongest at r = {c[k]:.2f} m, where the model is {"low" if m[k] > 0 else "high"} '
                       f'by {abs(m[k]):.2f} N on average')
        tilt = self.tilt()
        if tilt is not None and tilt[2] >= 0.5:
            direction, per_10cm, share = tilt
            out.append(f'it tilts across the tunnel ({100 * share:.0f} % of the smoothed map is a plane): '
                       f'the model is increasingly low towards {direction:.0f} deg from +x, by '
                       f'{per_10cm:.2f} N per 10 cm')
        if self.angular_eta2 >= 0.15:
            c, m, _ = self.angular
            k = int(np.nanargmax(np.abs(m)))
            out.append(f'it has an angular pattern ({100 * self.angular_eta2:.0f} % of its variance): '
                       f'strongest towards {np.degrees(c[k]):.0f} deg from +x')
        worst = max(self.fan_share.items(), key=lambda kv: kv[1])
        out.append(f'the neighbourhood of fan {worst[0]} carries {100 * worst[1]:.0f} % of the squared '
                   f'error; by ring: ' + ', '.join(f'{k} {100 * v:.0f} %' for k, v in self.ring_share.items()))
        if abs(self.bias) > 0.3 * self.rmse:
            out.append(f'on average the model is {"low" if self.bias > 0 else "high"} by {abs(self.bias):.2f} N')
        out.append(f'{100 * self.smooth_share:.0f} % of the residual variance is smooth over the tunnel '
                   f'(the rest is turbulence)')
        return out

    def to_json(self) -> dict:
        def arr(a):
            return np.round(np.asarray(a, float), 5).tolist()
        return {'rmse_N': self.rmse, 'bias_N': self.bias, 'smooth_share': self.smooth_share,
                'fan_r2': {k: round(v, 4) for k, v in self.fan_r2.items()},
                'radial': {'r_m': arr(self.radial[0]), 'mean_N': arr(self.radial[1]),
                           'eta2': self.radial_eta2},
                'angular': {'angle_rad': arr(self.angular[0]), 'mean_N': arr(self.angular[1]),
                            'eta2': self.angular_eta2},
                'fan_share': {k: round(v, 4) for k, v in self.fan_share.items()},
                'ring_share': {k: round(v, 4) for k, v in self.ring_share.items()},
                'structure': self.describe()}


def disc_grid(radius: float, step: float) -> np.ndarray:
    """Points of a square grid of ``step`` [m] within ``radius`` [m] of the axis, (G, 2)."""
    ticks = np.arange(-radius, radius + 1e-9, step)
    xx, yy = np.meshgrid(ticks, ticks)
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    return pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius + 1e-9]


def analyse_residuals(model: Term, data: FitData, geometry: TunnelGeometry, *,
                      grid_step: float = 0.02, length_scale: float = 0.05,
                      noise_sd: float | None = None, max_gp_points: int = 1500,
                      seed: int = 0) -> ResidualAnalysis:
    """Analyse the residual of ``model`` on ``data`` (cell means or raw samples).

    length_scale [m]: the residual map's GP length scale; noise_sd [N]: the residual's noise
    (default: half its standard deviation); at most ``max_gp_points`` points (random, fixed
    ``seed``) feed the GP."""
    fans = geometry.fans
    r = data.y - model(data.U, data.Z)
    Z = data.Z
    rmse = float(np.sqrt(np.mean(r ** 2)))
    # -- map
    rng = np.random.default_rng(seed)
    pick = np.arange(len(r)) if len(r) <= max_gp_points else np.sort(rng.choice(len(r), max_gp_points, replace=False))
    noise = float(noise_sd) if noise_sd is not None else 0.5 * float(np.std(r))
    gp = GaussianProcessField(length_scale=length_scale, noise_std=max(noise, 1e-3))
    gp.fit(Z[pick], r[pick])
    grid = disc_grid(geometry.sweep_radius, grid_step)
    mean, std = gp.predict(grid, return_std=True)
    at_samples = gp.predict(Z[pick])
    smooth = float(np.var(at_samples) / np.var(r[pick])) if np.var(r[pick]) > 0 else 0.0
    # -- per fan: residual vs command near the fan, and R^2 of r on fan-local command features
    fan_curves, fan_r2 = {}, {}
    sigma = 0.12
    edges = np.linspace(0.0, 1.0, 9)
    rc = r - r.mean()
    sst = float(rc @ rc) or 1.0
    for j, fan in enumerate(fans.fans):
        if not fan.enabled:
            continue
        d2 = np.sum((Z - fans.positions[j]) ** 2, axis=1)
        w = np.exp(-d2 / sigma ** 2)
        u = data.U[:, j]
        X = np.column_stack([np.ones(len(r)), u * w, u * u * w, w])
        coef, *_ = np.linalg.lstsq(X, r, rcond=None)
        fit = X @ coef
        base = X[:, :1] @ np.linalg.lstsq(X[:, :1], r, rcond=None)[0]
        fan_r2[fan.name] = float(max(0.0, (np.sum((r - base) ** 2) - np.sum((r - fit) ** 2)) / sst))
        near = d2 < 0.1 ** 2
        if near.any():
            c, m, s, _, _ = _binned(u[near], r[near], edges)
        else:
            c, m, s = 0.5 * (edges[1:] + edges[:-1]), np.full(8, np.nan), np.full(8, np.nan)
        fan_curves[fan.name] = (c, m, s)
    # -- radius and angle
    rad = np.hypot(Z[:, 0], Z[:, 1])
    redges = np.linspace(0.0, geometry.sweep_radius + 1e-9, 13)
    rcent, rmean, rsem, _, ridx = _binned(rad, r, redges)
    radial_eta2 = _eta2(r, ridx)
    ang = np.arctan2(Z[:, 1], Z[:, 0])
    aedges = np.linspace(-np.pi, np.pi, 13)
    after_radial = r - np.nan_to_num(rmean)[ridx]
    acent, amean, asem, _, aidx = _binned(ang[rad > 0.05], after_radial[rad > 0.05], aedges)
    angular_eta2 = _eta2(after_radial[rad > 0.05], aidx) if (rad > 0.05).sum() > 3 else 0.0
    # -- who carries the squared error
    hubs = fans.positions
    nearest = np.argmin(((Z[:, None, :] - hubs[None]) ** 2).sum(axis=2), axis=1)
    sq = r ** 2
    total = float(sq.sum()) or 1.0
    fan_share = {fans.names[j]: float(sq[nearest == j].sum() / total) for j in range(fans.n_fans)}
    rings = {'r < 0.10 m': rad < 0.10, '0.10-0.20 m': (rad >= 0.10) & (rad < 0.20),
             '0.20-0.30 m': (rad >= 0.20) & (rad < 0.30), 'r >= 0.30 m': rad >= 0.30}
    ring_share = {k: float(sq[m].sum() / total) for k, m in rings.items()}
    out = ResidualAnalysis(rmse, float(r.mean()), grid, mean, std, smooth, fan_curves, fan_r2,
                           (rcent, rmean, rsem), radial_eta2, (acent, amean, asem), angular_eta2,
                           fan_share, ring_share, Z, r)
    out.peak_follows = _what_it_follows(out.peak()[0], data, r, fans)
    return out


def _what_it_follows(where, data: FitData, r, fans, radius: float = 0.06) -> str:
    """Which command the residual near ``where`` follows best, sweep by sweep: one fan's, or
    all fans' together (sum of U^2, thrust growing about as U^2). Needs at least 5 sweeps."""
    near = np.sum((data.Z - where) ** 2, axis=1) < radius ** 2
    sweeps = np.unique(data.sweep[near])
    if len(sweeps) < 5:
        return ''
    res = np.array([r[near & (data.sweep == k)].mean() for k in sweeps])
    cmd = np.array([data.U[near & (data.sweep == k)][0] for k in sweeps])
    rn = res - res.mean()
    sst = float(rn @ rn)
    if sst <= 0:
        return ''
    best = ('', 0.0)
    options = [(f"fan {fans.names[j]}'s command", cmd[:, j]) for j in range(fans.n_fans) if fans.enabled[j]]
    thrust = cmd[:, fans.enabled] ** 2  # thrust grows about as U^2
    options.append(('the total thrust of all fans (sum of U^2)', thrust.sum(axis=1)))
    total = np.maximum(thrust.sum(axis=1), 1e-9)
    options.append(('the CW/CCW balance ((T_ccw - T_cw) / T, as swirl would)',
                    thrust @ fans.spin_sign[fans.enabled] / total))
    for label, x in options:
        xc = x - x.mean()
        if float(xc @ xc) <= 0:
            continue
        r2 = float((xc @ rn) ** 2 / (xc @ xc) / sst)
        if r2 > best[1]:
            best = (label, r2)
    if best[1] >= 0.5:
        return f'{best[0]} (R² {best[1]:.2f} over {len(sweeps)} sweeps)'
    if abs(res.mean()) > 2.5 * res.std():
        return f'no command: it stays about {res.mean():+.2f} N in every one of {len(sweeps)} sweeps'
    return ''
