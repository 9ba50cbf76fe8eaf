"""What lies outside the library: a discrepancy model of the residual, and its description.

``fit_discrepancy(model, data, geometry)`` fits ``wind_shaper.model.Discrepancy`` to the
residual r = measured - model on training cells: Gaussian bumps on a grid times command
features (a fixed pattern, the total thrust, the CW/CCW balance, each fan's thrust near that
fan). It is the weight-space form of a Gaussian process over position and command features:
every feature group has its own prior variance, and the variances, the noise and the bumps'
width are chosen by the marginal likelihood (evidence; MacKay's fixed-point updates), so a
group the data do not need is switched off rather than fitted to noise.

``describe_discrepancy`` says in words what the fitted discrepancy looks like: how it scales
(the share of its energy over the sweeps' commands that each feature carries) and the spatial
pattern of each main part (uniform, a tilt with its direction, radial: centre, ring or wall, a
region near a fan, a strip), and how large. Positions [m], forces [N].
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from ..core.geometry import TunnelGeometry
from ..model import CommandScale, Discrepancy, Product, Term, command_features, feature_words
from .data import FitData
from .residuals import disc_grid
from .wording import error_text

#: What Kennedy and O'Hagan's scale of the model follows (``CommandScale``): a fixed share of
#: the field, and one that grows with the total thrust (a shared supply or inlet that sags as
#: the flow grows, a drift of the air's density).
SCALE_FEATURES = ('one', 'thrust')

__all__ = ['SCALE_FEATURES', 'DiscrepancyFit', 'fit_discrepancy', 'discrepancy_basis', 'describe_discrepancy',
           'describe_map', 'disc_grid', 'describe_outside', 'outside_text']


@dataclass
class DiscrepancyFit:
    """term: the fitted ``Discrepancy``; log_evidence: of the chosen width; noise_sd [N]: the
    cell-level noise the evidence chose; shares {feature: share of the discrepancy's energy};
    words: the description, sentence by sentence."""

    term: Discrepancy
    log_evidence: float
    noise_sd: float
    shares: dict
    words: list = field(default_factory=list)
    cv_rmse: float = float('nan')      # [N] predicting left-out training sweeps
    train_rms: float = float('nan')    # [N] the residual it was fitted to
    heldout_before: float = float('nan')  # [N] held-out model error without it
    heldout_after: float = float('nan')   # [N] and with it
    readings: dict = field(default_factory=dict)  # the physical readings tried, with their R^2
    fraction_map: tuple | None = None  # (grid (G, 2) [m], g (G,)): the fixed-fraction reading's map
    # Kennedy and O'Hagan's scale of the model, when fitted with one: the share s(U) of the
    # model's own field (``base``, the model the residual was taken from) the tunnel adds
    scale: CommandScale | None = None
    base: Term | None = None
    # set by the diagnosis (``rest``): the smallest held-out model error the noise lets the
    # sweeps resolve [N] (smaller reads "at the noise level"), one sample's noise [N], and
    # whether the model error it describes is smaller than that noise
    error_floor: float = 0.0
    sample_noise: float = float('nan')
    below_noise: bool = False

    def added_to(self, model: Term) -> Term:
        """``model`` with the discrepancy: model + term, and with a scale model x (1 + s(U)) +
        term (no free parameters added: a refit moves the model's own only)."""
        if self.scale is None:
            return model + self.term
        return Product(model, self.scale.plus_one()) + self.term

    def value(self, U, Z) -> np.ndarray:
        """The discrepancy at commands U and points Z (M, 2) [m]: term, plus base x s(U) [N]."""
        out = self.term(U, Z)
        if self.scale is not None:
            out = out + self.base(U, Z) * self.scale(U, Z)
        return out

    @property
    def offered(self) -> bool:
        """Whether it is a term worth adding: it lowers the held-out model error >= 20 %."""
        return bool(self.heldout_after <= 0.8 * self.heldout_before)

    def to_json(self) -> dict:
        return {'width_m': self.term.width, 'bumps': len(self.term.centres),
                'features': list(self.term.features), 'noise_sd_N': round(self.noise_sd, 5),
                'log_evidence': round(self.log_evidence, 2), 'cv_rmse_N': round(self.cv_rmse, 5),
                'train_residual_rms_N': round(self.train_rms, 5), 'below_noise': self.below_noise,
                'heldout_model_rmse_N': {'without': round(self.heldout_before, 5),
                                         'with': round(self.heldout_after, 5)},
                'offered': bool(self.offered), 'readings': self.readings,
                'shares': {k: round(v, 4) for k, v in self.shares.items()}, 'words': list(self.words),
                'term': self.term.to_dict(),
                'scale': self.scale.to_dict() if self.scale is not None else None}


def _evidence_fit(Phi: np.ndarray, r: np.ndarray, groups: np.ndarray, n_iter: int = 30):
    """Bayesian linear regression with one prior precision per column group, chosen with the
    noise precision by evidence maximisation. Returns (mean weights, log evidence, noise sd, prior precisions per group)."""
    n, p = Phi.shape
    G = Phi.T @ Phi
    b = Phi.T @ r
    n_groups = int(groups.max()) + 1
    var_r = max(float(np.var(r)), 1e-12)
    alpha = np.full(n_groups, 1.0 / var_r)
    beta = 4.0 / var_r
    for _ in range(n_iter):
        A = beta * G
        A[np.diag_indices(p)] += alpha[groups]
        cf = cho_factor(A)
        m = beta * cho_solve(cf, b)
        S_diag = np.diag(cho_solve(cf, np.eye(p)))
        gamma = 1.0 - alpha[groups] * S_diag
        resid = r - Phi @ m
        sse = float(resid @ resid)
        new_alpha = alpha.copy()
        for g in range(n_groups):
            sel = groups == g
            mm = float(m[sel] @ m[sel])
            new_alpha[g] = min(max(float(gamma[sel].sum()), 1e-6) / max(mm, 1e-30), 1e12)
        new_beta = max(n - float(gamma.sum()), 1.0) / max(sse, 1e-30)
        converged = (np.all(np.abs(np.log(new_alpha / alpha)) < 1e-2)
                     and abs(np.log(new_beta / beta)) < 1e-2)
        alpha, beta = new_alpha, new_beta
        if converged:
            break
    A = beta * G
    A[np.diag_indices(p)] += alpha[groups]
    cf = cho_factor(A)
    m = beta * cho_solve(cf, b)
    resid = r - Phi @ m
    logdet = 2.0 * float(np.sum(np.log(np.diag(cf[0]))))
    log_ev = 0.5 * (float(np.sum(np.log(alpha[groups]))) + n * np.log(beta) - beta * float(resid @ resid)
                    - float(m @ (alpha[groups] * m)) - logdet - n * np.log(2 * np.pi))
    return m, float(log_ev), float(1.0 / np.sqrt(beta)), alpha


def _leave_sweep_out(Phi, r, groups, sweep, m_alpha_beta) -> float:
    """Mean squared error [N^2] of predicting each sweep's cells from the others' (the prior
    variances and noise held as the evidence chose them)."""
    alpha, beta = m_alpha_beta
    p = Phi.shape[1]
    A = beta * (Phi.T @ Phi)
    A[np.diag_indices(p)] += alpha[groups]
    b = Phi.T @ r
    sse = 0.0
    for s in np.unique(sweep):
        rows = sweep == s
        Ps, rs = Phi[rows], r[rows]
        m = beta * cho_solve(cho_factor(A - beta * (Ps.T @ Ps)), b - Ps.T @ rs)
        e = rs - Ps @ m
        sse += float(e @ e)
    return sse / len(r)


def _design(data: FitData, geometry: TunnelGeometry, width: float, spacing: float, names: list,
            n_global: int, fan_radius: float):
    """Columns (n, p) of bumps x features, their prior groups and (bump, feature) index."""
    fans = geometry.fans
    phi, _ = command_features(fans, names, data.U)
    centres = disc_grid(geometry.sweep_radius + 0.5 * width, spacing * width)
    rho = np.exp(-0.5 * np.sum((data.Z[:, None, :] - centres[None]) ** 2, axis=2) / width ** 2)
    cols, groups, index = [], [], []
    for f, name in enumerate(names):
        if name.startswith('fan:'):
            hub = fans.positions[fans.names.index(name[4:])]
            keep = np.flatnonzero(np.hypot(*(centres - hub).T) <= fan_radius)
            group = n_global  # every fan's part shares one prior variance
        else:
            keep = np.arange(len(centres))
            group = f
        cols.append(rho[:, keep] * phi[:, f:f + 1])
        groups += [group] * len(keep)
        index += [(k, f) for k in keep]
    return centres, np.hstack(cols), np.asarray(groups), index


def _scale_columns(fans, scale_features, field: np.ndarray, U: np.ndarray) -> np.ndarray:
    """Columns (n, F) of Kennedy and O'Hagan's scale: the model's force ``field`` (n,) [N]
    times each of ``scale_features`` at the commands U."""
    if not scale_features:
        return np.zeros((len(field), 0))
    return field[:, None] * command_features(fans, scale_features, U)[0]


def _with_group(Phi: np.ndarray, groups: np.ndarray, cols: np.ndarray):
    """(Phi, groups) with ``cols`` appended as one more prior group."""
    return np.hstack([Phi, cols]), np.concatenate([groups, np.full(cols.shape[1], groups.max() + 1)])


def fit_discrepancy(model: Term, data: FitData, geometry: TunnelGeometry, *,
                    widths=(0.06, 0.10), spacing: float = 1.25, fan_radius: float = 0.15,
                    features=('one', 'thrust', 'balance'), per_fan=(False, True),
                    note: str = '', scale_features=()) -> DiscrepancyFit:
    """Fit a ``Discrepancy`` to the residual of ``model`` on ``data`` (training cells).

    Tried: every bump width in ``widths`` [m] (on a square grid of ``spacing`` x width), with
    the whole-tunnel ``features`` only and with each enabled fan's thrust added as a feature
    (bumps within ``fan_radius`` [m] of its hub only), as ``per_fan`` lists. For each, the
    prior variances and the noise are chosen by the evidence; among them the one that predicts
    left-out sweeps best is kept (sweeps are the independent units: a part fitted to one
    sweep's turbulence or to one operating point does not carry over). With ``scale_features``
    (e.g. ``SCALE_FEATURES``) each is also tried with Kennedy and O'Hagan's scale of the model,
    a share of the model's own field that follows those features (one prior group); when that
    predicts left-out sweeps better it is kept as ``scale`` (a ``CommandScale``; ``added_to``
    puts both in a model). BLAS runs on one thread
    here: on matrices this small more threads only contend (a fit on an idle 2-core machine
    0.67 s -> 0.14 s; on a loaded one up to 30 s -> 0.2 s)."""
    from threadpoolctl import threadpool_limits
    with threadpool_limits(1, user_api='blas'):  # small matrices: threads only contend
        return _fit_discrepancy(model, data, geometry, widths, spacing, fan_radius, features,
                                per_fan, note, tuple(scale_features))


def _fit_discrepancy(model, data, geometry, widths, spacing, fan_radius, features, per_fan, note,
                     scale_features):
    fans = geometry.fans
    field_ = model(data.U, data.Z)
    r = data.y - field_
    scale_cols = _scale_columns(fans, scale_features, field_, data.U)
    best = None
    for with_fans, width, scaled in itertools.product(per_fan, widths,
                                                      (False, True) if scale_features else (False,)):
        names = list(features) + ([f'fan:{f.name}' for f in fans.fans if f.enabled] if with_fans else [])
        centres, Phi, groups, index = _design(data, geometry, width, spacing, names, len(features),
                                              fan_radius)
        if scaled:
            Phi, groups = _with_group(Phi, groups, scale_cols)
        m, log_ev, noise, alpha = _evidence_fit(Phi, r, groups)
        cv = _leave_sweep_out(Phi, r, groups, data.sweep, (alpha, 1.0 / noise ** 2))
        if best is None or cv < best[0]:
            W = np.zeros((len(centres), len(names)))
            for (k, f), w in zip(index, m):
                W[k, f] = w
            scale = CommandScale(fans, scale_features, m[len(index):]) if scaled else None
            best = (cv, Discrepancy(fans, centres, width, names, W, note=note), log_ev, noise, scale)
    cv, term, log_ev, noise, scale = best
    out = DiscrepancyFit(term, log_ev, noise, {}, scale=scale, base=model if scale is not None else None)
    out.cv_rmse = float(np.sqrt(cv))
    out.train_rms = float(np.sqrt(np.mean(r ** 2)))
    return out


def discrepancy_basis(data: FitData, geometry: TunnelGeometry, residual: np.ndarray, *,
                      widths=(0.06, 0.10), spacing: float = 1.25, fan_radius: float = 0.15,
                      features=('one', 'thrust', 'balance'), field: np.ndarray | None = None,
                      scale_features=SCALE_FEATURES):
    """The discrepancy's columns on ``data`` (bumps x the whole-tunnel ``features`` and every
    enabled fan's thrust near that fan), at the bump width [m] whose evidence for ``residual``
    [N] is highest, as a prior for other fits: (Phi (n, p), the prior precision of each column
    [1/N^2], the noise sd [N] the evidence chose). With ``field`` (n,) [N], the model's force on
    ``data``, Kennedy and O'Hagan's scale of the model, let follow the whole-tunnel
    ``scale_features`` (columns field x feature, one prior group: a shared supply or inlet
    that gives every fan less as the total flow grows, a drift of the air's density), is
    added."""
    from threadpoolctl import threadpool_limits
    names = list(features) + [f'fan:{f.name}' for f in geometry.fans.fans if f.enabled]
    scale_cols = _scale_columns(geometry.fans, scale_features, field, data.U) if field is not None else None
    best = None
    with threadpool_limits(1, user_api='blas'):  # small matrices: threads only contend
        for width in widths:
            _, Phi, groups, _ = _design(data, geometry, width, spacing, names, len(features), fan_radius)
            if scale_cols is not None:
                Phi, groups = _with_group(Phi, groups, scale_cols)
            _, log_ev, noise, alpha = _evidence_fit(Phi, residual, groups)
            if best is None or log_ev > best[0]:
                best = (log_ev, Phi, alpha[groups], noise)
    return best[1], best[2], best[3]


def _shares(fit: DiscrepancyFit, commands: np.ndarray, grid: np.ndarray):
    """({part: share of the energy}, the parts (S, G, P) [N], their names) over the commands
    (S, n_fans) on the grid: each command feature's part of the bumps, and 'scale' (the model's
    own field x s(U)) when fitted."""
    parts = np.stack([fit.term.parts(u, grid) for u in commands])
    names = list(fit.term.features)
    if fit.scale is not None:
        scaled = np.stack([fit.base(u, grid) * fit.scale(u, grid) for u in commands])
        parts = np.concatenate([parts, scaled[:, :, None]], axis=2)
        names.append('scale')
    energy = np.mean(parts ** 2, axis=(0, 1))
    total = float(energy.sum()) or 1.0
    return {f: float(e / total) for f, e in zip(names, energy)}, parts, names


def _scale_words(scale: CommandScale) -> str:
    """How the model's own field is scaled, in words: the share s(U) at low total thrust and
    with every fan at full PWM, and what that reads as."""
    w = dict(zip(scale.features, scale.weights[0]))
    low, full = w.get('one', 0.0), w.get('one', 0.0) + w.get('thrust', 0.0)
    if full - low < -0.03:
        reading = ('every fan gives less as the total flow grows: a starved inlet, or a shared '
                   'supply that sags under the load')
    elif full - low > 0.03:
        reading = 'every fan gives more as the total flow grows, whatever fan it is'
    else:
        reading = 'a fixed share of the whole field: the air\'s density, or the thrust calibration off'
    return (f'the model\'s own field scaled, {100 * low:+.0f} % of its force at a low total thrust and '
            f'{100 * full:+.0f} % with every fan at full PWM: {reading}')


def describe_map(values: np.ndarray, grid: np.ndarray, geometry: TunnelGeometry,
                 unit: str = 'N') -> str:
    """The spatial pattern of a map (G,) on the grid (G, 2) [m] in words, with where the model
    is low (positive: measured above the model) or high and by how much. unit: 'N' (a force) or
    '%' (a share of the local force)."""
    def amount(v):
        return f'{abs(v):.2f} N' if unit == 'N' else f'{abs(v):.0f} % of the local force'
    fans = geometry.fans
    ms = float(np.mean(values ** 2))
    if ms <= 0:
        return 'flat'
    peak = int(np.argmax(np.abs(values)))
    vmax = float(values[peak])
    side = 'low' if vmax > 0 else 'high'
    mean = float(values.mean())
    if mean * mean >= 0.8 * ms:
        return f'about uniform over the tunnel (the model is {"low" if mean > 0 else "high"} by about {amount(mean)})'
    centred = values - mean
    var = float(centred @ centred)
    X = np.column_stack([np.ones(len(grid)), grid])
    coef, *_ = np.linalg.lstsq(X, values, rcond=None)
    plane = X @ coef - mean
    if var > 0 and float(plane @ plane) >= 0.7 * var:
        direction = np.degrees(np.arctan2(coef[2], coef[1]))
        return (f'a tilt across the tunnel: the model is increasingly low towards {direction:.0f} deg '
                f'from +x, by {amount(0.1 * np.hypot(coef[1], coef[2]))} per 10 cm')
    rad = np.hypot(grid[:, 0], grid[:, 1])
    edges = np.linspace(0.0, rad.max() + 1e-9, 9)
    idx = np.clip(np.digitize(rad, edges) - 1, 0, len(edges) - 2)
    counts = np.bincount(idx, minlength=len(edges) - 1)
    bin_mean = np.bincount(idx, weights=values, minlength=len(edges) - 1) / np.maximum(counts, 1)
    between = float(np.sum(counts * (bin_mean - mean) ** 2))
    if var > 0 and between >= 0.7 * var:
        k = int(np.argmax(np.abs(bin_mean - mean)))
        rk = 0.5 * (edges[k] + edges[k + 1])
        where = ('at the centre' if k == 0 else 'at the edge, next to the wall' if k >= len(counts) - 2
                 else f'on a ring at r = {rk:.2f} m')
        return (f'radial, strongest {where} (the model is {"low" if bin_mean[k] > mean else "high"} there '
                f'by {amount(bin_mean[k])})')
    region = (np.sign(values) == np.sign(vmax)) & (np.abs(values) >= 0.5 * abs(vmax))
    share = region.mean()
    where = grid[peak]
    hubs = fans.positions[fans.enabled]
    names = [f.name for f in fans.fans if f.enabled]
    d = np.hypot(*(hubs - where).T)
    order = np.argsort(d)
    spacing = float(np.min([np.hypot(*(hubs[i] - hubs[j])) for i in range(len(hubs))
                            for j in range(i)])) if len(hubs) > 1 else 0.2
    if d[order[0]] <= 0.35 * spacing:
        near = f'over fan {names[order[0]]}'
    elif len(order) > 1 and d[order[1]] <= 0.75 * spacing:
        near = f'between fans {names[order[0]]} and {names[order[1]]}'
    elif np.hypot(*where) >= geometry.sweep_radius - 0.05:
        near = 'at the edge'
    else:
        near = f'near fan {names[order[0]]}'
    if share <= 0.35:
        pts = grid[region]
        w = np.abs(values[region])
        c = np.average(pts, axis=0, weights=w)
        cov = np.cov((pts - c).T, aweights=w) if len(pts) > 2 else np.eye(2) * 1e-4
        lam, vec = np.linalg.eigh(cov)
        lam = np.maximum(lam, 1e-8)
        # +-2 sd of the weighted spread is the region's extent; nothing in the tunnel is wider
        # than the tunnel, and a region that spans most of it is no patch
        extent = 2 * geometry.wall_radius
        long_, wide = min(4 * np.sqrt(lam[1]), extent), min(4 * np.sqrt(lam[0]), extent)
        angle = (np.degrees(np.arctan2(vec[1, 1], vec[0, 1])) + 90) % 180 - 90
        if long_ >= 0.75 * extent:
            shape = (f'a region across most of the tunnel (about {100 * long_:.0f} cm of its '
                     f'{100 * extent:.0f} cm)')
        elif long_ >= 2.5 * wide:
            shape = (f'a strip along {angle:.0f} deg from +x, about {100 * long_:.0f} cm long and '
                     f'{100 * wide:.0f} cm wide')
        else:
            shape = f'a patch about {100 * long_:.0f} cm across'
        return (f'local: {shape}, centred at ({c[0]:+.2f}, {c[1]:+.2f}) m {near} (the model is {side} '
                f'there by up to {amount(vmax)})')
    return (f'spread over the tunnel, largest at ({where[0]:+.2f}, {where[1]:+.2f}) m {near} (the model '
            f'is {side} there by {amount(vmax)})')


def _as_displacement(D: np.ndarray, model: Term, commands, grid, step: float = 0.005):
    """(R^2, (dx, dy) [m]): how well D (S, G) is the model's field displaced by one (dx, dy),
    D ~ Phi(z - d) - Phi(z) ~ -d . grad Phi."""
    rows_x, rows_y = [], []
    for u in commands:
        ex, ey = np.array([step, 0.0]), np.array([0.0, step])
        rows_x.append(-(model(u, grid + ex) - model(u, grid - ex)) / (2 * step))
        rows_y.append(-(model(u, grid + ey) - model(u, grid - ey)) / (2 * step))
    X = np.column_stack([np.ravel(rows_x), np.ravel(rows_y)])
    y = D.ravel()
    d, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ d
    return 1.0 - float(e @ e) / max(float(y @ y), 1e-30), d


def _as_fraction(D: np.ndarray, model: Term, commands, grid):
    """(R^2, g (G,)): how well D (S, G) is a fixed fraction g(z) of the model's local force
    (a patch that lets through a fixed share of the flow: D = g Phi)."""
    F = np.stack([model(u, grid) for u in commands])
    g = np.sum(D * F, axis=0) / np.maximum(np.sum(F * F, axis=0), 1e-12)
    e = D - g * F
    return 1.0 - float(np.sum(e * e)) / max(float(np.sum(D * D)), 1e-30), g


def describe_discrepancy(fit: DiscrepancyFit, commands: np.ndarray, geometry: TunnelGeometry,
                         *, model: Term | None = None, min_share: float = 0.2,
                         min_r2: float = 0.6) -> list[str]:
    """Fill ``fit.shares`` and ``fit.words`` for the sweeps' commands (S, n_fans); returns the
    words. A part is described when it carries at least ``min_share`` of the energy; the fans'
    own parts together when they do. With the ``model`` the residual was taken from, two
    physical readings are tried first: the field displaced as a whole (a draft, a frame offset),
    and a fixed fraction of the local force (a blocked or leaking patch); each is stated when it
    explains at least ``min_r2`` of the discrepancy over the sweeps."""
    grid = disc_grid(geometry.sweep_radius, 0.02)
    shares, parts, features = _shares(fit, commands, grid)
    fit.shares = shares
    fan_share = sum(v for k, v in shares.items() if k.startswith('fan:'))
    words = []
    total = parts.sum(axis=2)
    rms = float(np.sqrt(np.mean(total ** 2)))
    words.append(f'It is {rms:.3f} N RMS over the sweeps\' commands.')
    fit.readings = {}
    if model is not None and rms > 0:
        r2_shift, d = _as_displacement(total, model, commands, grid)
        r2_frac, g = _as_fraction(total, model, commands, grid)
        fit.fraction_map = (grid, g)
        fit.readings = {'displacement': {'r2': round(r2_shift, 4), 'shift_m': np.round(d, 4).tolist()},
                        'fraction': {'r2': round(r2_frac, 4)}}
        if r2_shift >= min_r2 and r2_shift >= r2_frac:
            words.append(f'It looks like the whole field displaced by {100 * np.hypot(*d):.1f} cm towards '
                         f'{np.degrees(np.arctan2(d[1], d[0])):.0f} deg from +x (dx {100 * d[0]:+.1f} cm, '
                         f'dy {100 * d[1]:+.1f} cm; this explains {100 * r2_shift:.0f} % of it): a draft '
                         f'across the tunnel, or the motion capture frame off the tunnel\'s.')
        elif r2_frac >= min_r2 and shares.get('one', 0.0) < 0.3:  # a fixed part is no fraction
            pattern = describe_map(100 * g, grid, geometry, unit='%')
            words.append(f'It looks like a fixed fraction of the local force ({100 * r2_frac:.0f} % of it '
                         f'is): {pattern}; a patch of the straightener that passes more or less of the '
                         f'flow (blocked, damaged, a leak), or something in the flow\'s way.')
    ranked = sorted(((v, k) for k, v in shares.items() if not k.startswith('fan:')), reverse=True)
    for v, k in ranked:
        if v < min_share:
            continue
        if k == 'scale':
            words.append(f'{100 * v:.0f} % of it is {_scale_words(fit.scale)}.')
            continue
        f = features.index(k)
        typical = float(np.median(np.abs(parts[:, :, f]).max(axis=1)))
        strongest = int(np.argmax(np.abs(parts[:, :, f]).max(axis=1)))
        pattern = describe_map(parts[strongest, :, f], grid, geometry)
        words.append(f'{100 * v:.0f} % of it {feature_words(k)}: {pattern}'
                     + (f'; typical peak {typical:.2f} N' if k != 'one' else '') + '.')
    if fan_share >= min_share:
        per_fan = sorted(((v, k) for k, v in shares.items() if k.startswith('fan:')), reverse=True)
        top = ', '.join(f'{k[4:]} {100 * v:.0f} %' for v, k in per_fan[:3] if v >= 0.02)
        v, k = per_fan[0]
        f = features.index(k)
        strongest = int(np.argmax(np.abs(parts[:, :, f]).max(axis=1)))
        words.append(f'{100 * fan_share:.0f} % of it follows single fans\' commands near those fans '
                     f'({top}); the largest part, with fan {k[4:]}: '
                     f'{describe_map(parts[strongest, :, f], grid, geometry)}.')
    fit.words = words
    return words


def describe_outside(model: Term, train: FitData, heldout, commands: np.ndarray,
                     geometry: TunnelGeometry) -> DiscrepancyFit:
    """The discrepancy of ``model`` fitted on the training cells, judged on the held-out sweeps
    (``metrics.HeldOut``: ``heldout_before`` / ``heldout_after`` [N], the model error without
    and with it) and described over the sweeps' ``commands``."""
    fit = fit_discrepancy(model, train, geometry, note='fitted to the residual by the diagnosis',
                          scale_features=SCALE_FEATURES)
    fit.heldout_before = float(heldout.evaluate(model)['model_rmse'])
    fit.heldout_after = float(heldout.evaluate(fit.added_to(model))['model_rmse'])
    describe_discrepancy(fit, commands, geometry, model=model)
    return fit


def outside_text(fit: DiscrepancyFit) -> str:
    """The verdict's paragraph on what the library does not explain."""
    head = ('What the residual looks like (a discrepancy model: a Gaussian process over position and '
            'the fans\' commands, fitted to the training sweeps\' residual; it names no physics): '
            + ' '.join(fit.words))
    if fit.below_noise:
        head = (f'Below the noise: the model error left ({error_text(fit.heldout_before, fit.error_floor)}) '
                f'is smaller than one sample\'s noise ({fit.sample_noise:.3f} N), though the held-out '
                f'sweeps resolve it; read what follows as a faint pattern, not a finding. ' + head)
    before = error_text(fit.heldout_before, fit.error_floor)
    after = error_text(fit.heldout_after, fit.error_floor)
    if fit.offered:
        tail = (f' Added to the model it lowers the held-out model error from {before} to '
                f'{after.removeprefix("at ")}, so it is a stable pattern of position and command: `wind-shaper model '
                f'add --effect discrepancy` (or --from-diagnosis with this summary.json) adds it as a '
                f'term, and the loop then shapes with it while the physics is still unknown.')
    else:
        tail = (f' It does not carry over to the held-out sweeps (model error {before} -> '
                f'{after}): the residual is not a stable pattern of position and these command '
                f'features, so it is not offered as a term.')
    return head + tail
