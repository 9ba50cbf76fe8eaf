"""A formula for what the library does not explain: sparse regression of the residual.

``fit_formula(model, data, geometry)`` writes the residual r = measured - model as a short sum
of spatial modes times command features (``wind_shaper.model.FieldFormula``):

* modes: uniform, x/R, y/R (a tilt), r^2/R^2 (a bowl), the two quadrupoles, and a bump over
  each enabled fan's hub;
* features: 1, the total thrust T = mean U^2, the CW/CCW balance B, and each fan's own U^2
  (paired only with the bump over that fan).

The terms are chosen by sequential thresholded least squares (SINDy's STLSQ, from pysindy) on
standardised columns, for a ladder of thresholds; of the formulas whose error in predicting
left-out training sweeps is within one standard error (over the sweeps) of the best, the one with
the fewest terms is kept (sweeps are the independent units), refitted on all training cells. It is offered when it has at most
``max_terms`` terms, holds across the training sweeps (one amplitude in each, ``_amplitudes``)
and lowers the held-out model error by at least ``min_gain``: then an
effect of simple form has been found, written out, with no physical name attached.
Positions [m], forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import TunnelGeometry
from ..model import MODE_NAMES, FieldFormula, Term, command_features
from .consistency import judge_spread
from .data import FitData
from .wording import error_text

__all__ = ['FormulaFit', 'fit_formula', 'formula_text']

_GLOBAL_MODES = tuple(MODE_NAMES)
_GLOBAL_FEATURES = ('one', 'thrust', 'balance')


@dataclass
class FormulaFit:
    """term: the fitted ``FieldFormula`` (only the chosen terms); threshold: STLSQ's, on
    standardised columns; cv_rmse [N]: predicting left-out training sweeps; heldout_before /
    heldout_after [N]: the held-out model error without and with it (set by ``judge``)."""

    term: FieldFormula
    threshold: float
    cv_rmse: float
    n_terms: int
    heldout_before: float = float('nan')
    heldout_after: float = float('nan')
    offered: bool = False
    holds: bool = False          # one amplitude in every training sweep that shows it
    amplitudes: tuple = ()       # per informative training sweep, the formula's fitted scale

    def judge(self, model: Term, heldout, *, min_gain: float = 0.2, max_terms: int = 4) -> 'FormulaFit':
        """Set the held-out errors and ``offered``: few terms, the held-out drop, and the
        amplitude check across the training sweeps."""
        self.heldout_before = float(heldout.evaluate(model)['model_rmse'])
        self.heldout_after = float(heldout.evaluate(model + self.term)['model_rmse'])
        self.offered = bool(0 < self.n_terms <= max_terms and self.holds
                            and self.heldout_after <= (1 - min_gain) * self.heldout_before)
        return self

    def to_json(self) -> dict:
        return {'formula': self.term.formula(), 'terms': self.n_terms, 'threshold': self.threshold,
                'holds_across_sweeps': self.holds, 'amplitudes': [round(a, 3) for a in self.amplitudes],
                'cv_rmse_N': round(self.cv_rmse, 5), 'offered': self.offered,
                'heldout_model_rmse_N': {'without': round(self.heldout_before, 5),
                                         'with': round(self.heldout_after, 5)},
                'term': self.term.to_dict()}


def _library(geometry: TunnelGeometry):
    """[(mode, feature)] pairs of the regression, in column order."""
    fans = [f.name for f in geometry.fans.fans if f.enabled]
    pairs = [(m, f) for m in _GLOBAL_MODES for f in _GLOBAL_FEATURES]
    for name in fans:
        pairs += [(f'bump:{name}', 'one'), (f'bump:{name}', 'thrust'), (f'bump:{name}', f'fan:{name}')]
    return pairs


def _columns(pairs, data: FitData, geometry: TunnelGeometry, radius: float, bump_width: float):
    modes = sorted({m for m, _ in pairs}, key=[m for m, _ in pairs].index)
    feats = sorted({f for _, f in pairs}, key=[f for _, f in pairs].index)
    probe = FieldFormula(geometry.fans, modes, feats, np.zeros((len(modes), len(feats))),
                         radius=radius, bump_width=bump_width)
    rho = probe.modes(data.Z)
    phi, _ = command_features(geometry.fans, feats, data.U)
    return np.column_stack([rho[:, modes.index(m)] * phi[:, feats.index(f)] for m, f in pairs])


def _stlsq(X, y, threshold, alpha):
    import warnings

    import pysindy  # imported here: it takes seconds and only this needs it
    opt = pysindy.STLSQ(threshold=threshold, alpha=alpha, max_iter=30)
    with warnings.catch_warnings():  # "eliminated all coefficients" is an answer here, not a fault
        warnings.simplefilter('ignore', UserWarning)
        opt.fit(X, y[:, None])
    return np.asarray(opt.coef_, float).ravel()


def _refit(X, y, support, alpha):
    w = np.zeros(X.shape[1])
    if support.any():
        A = X[:, support]
        w[support] = np.linalg.solve(A.T @ A + alpha * np.eye(support.sum()), A.T @ y)
    return w


def _amplitudes(pred: np.ndarray, r: np.ndarray, sweep: np.ndarray, *, min_signal: float = 0.02,
                tolerance: float = 0.1, max_z: float = 3.0, max_disagree: float = 0.25,
                min_p: float = 1e-3) -> tuple[bool, tuple]:
    """Does the formula hold across sweeps? Per training sweep where it predicts at least
    ``min_signal`` [N] RMS, the scale a_s that fits it to that sweep's residual (1 for a real
    effect, whatever the commands; a patch of another effect needs a different scale in each
    sweep). z = |a_s - 1| / sqrt(se^2 + tolerance^2); it holds when at least 3 sweeps show it, at
    most ``max_disagree`` of them have z > ``max_z`` and the chi-square of the z's is not beyond
    chance (p >= ``min_p``): the rule of the check of named effects (``consistency.judge_spread``),
    with one degree of freedom per sweep (the amplitude is compared with 1, not with a pooled fit)."""
    amps, zs = [], []
    for s in np.unique(sweep):
        rows = sweep == s
        p, y = pred[rows], r[rows]
        if len(p) < 5 or float(np.sqrt(np.mean(p * p))) < min_signal:
            continue
        a = float(p @ y) / float(p @ p)
        resid = y - a * p
        se = float(np.sqrt(resid @ resid / max(len(y) - 1, 1) / (p @ p)))
        amps.append(a)
        zs.append(abs(a - 1.0) / np.hypot(se, tolerance))
    zs = np.asarray(zs)
    if len(zs) < 3:
        return False, tuple(amps)
    _, _, holds = judge_spread(zs[:, None], np.ones(len(zs), bool), len(zs), max_z=max_z,
                               max_disagree=max_disagree, min_p=min_p)
    return bool(holds), tuple(amps)


def fit_formula(model: Term, data: FitData, geometry: TunnelGeometry, *,
                thresholds=(0.02, 0.04, 0.07, 0.1, 0.15, 0.25), alpha: float = 1e-3,
                bump_width: float = 0.08) -> FormulaFit:
    """Sparse formula for the residual of ``model`` on ``data`` (training cells); see the
    module docstring. thresholds: STLSQ's, on columns scaled to unit RMS and a residual scaled
    to unit RMS (a term must carry at least that share of the residual's scale)."""
    radius = geometry.sweep_radius
    pairs = _library(geometry)
    r = data.y - model(data.U, data.Z)
    X = _columns(pairs, data, geometry, radius, bump_width)
    scale = np.sqrt(np.mean(X ** 2, axis=0))
    keep = scale > 1e-9
    Xs = np.where(keep, X / np.where(keep, scale, 1.0), 0.0)
    r_scale = float(np.sqrt(np.mean(r ** 2))) or 1.0
    ys = r / r_scale
    sweeps = np.unique(data.sweep)
    tried = []
    for th in thresholds:
        support = np.abs(_stlsq(Xs, ys, th, alpha)) > 0
        per_sweep = []
        for s in sweeps:  # the support chosen on all cells; its weights refitted without sweep s
            out = data.sweep == s
            w = _refit(Xs[~out], ys[~out], support, alpha)
            e = ys[out] - Xs[out] @ w
            per_sweep.append(float(e @ e))
        tried.append((float(np.sum(per_sweep)), th, support, np.asarray(per_sweep)))
    # the one-standard-error rule: the sparsest formula whose left-out error is within one
    # standard error (over sweeps) of the best's; a term that helps less is noise or misfit
    low = min(tried, key=lambda t: t[0])
    se = float(np.std(low[3] - np.mean(low[3]), ddof=1) * np.sqrt(len(sweeps))) if len(sweeps) > 1 else 0.0
    ok = [t for t in tried if t[0] <= low[0] + se]
    best = min(ok, key=lambda t: (int(t[2].sum()), t[0]))[:3]
    sse, th, support = best
    w = _refit(Xs, ys, support, alpha) * r_scale / np.where(keep, scale, 1.0)
    chosen = [(pairs[i], w[i]) for i in np.flatnonzero(support)]
    modes = list(dict.fromkeys(m for (m, _), _ in chosen)) or ['uniform']
    feats = list(dict.fromkeys(f for (_, f), _ in chosen)) or ['one']
    W = np.zeros((len(modes), len(feats)))
    for (m, f), v in chosen:
        W[modes.index(m), feats.index(f)] = v
    term = FieldFormula(geometry.fans, modes, feats, W, radius=radius, bump_width=bump_width,
                        note='sparse formula fitted to the residual by the diagnosis')
    out = FormulaFit(term, float(th), float(r_scale * np.sqrt(sse / len(r))), len(chosen))
    if chosen:
        out.holds, out.amplitudes = _amplitudes(term(data.U, data.Z), r, data.sweep)
    return out


def formula_text(fit: FormulaFit, floor: float = 0.0) -> str:
    """The verdict's sentence on the formula (empty when it is not offered); ``floor`` [N]:
    the smallest held-out model error the noise resolves (``wording.error_text``)."""
    if not fit.offered:
        return ''
    return (f'A short formula fits it (sparse regression over spatial modes x command features): '
            f'residual = {fit.term.formula()}, with R = {fit.term.radius:.2f} m, T = mean U^2 (the total '
            f'thrust), B = the CCW minus the CW fans\' mean U^2, bumps {100 * fit.term.bump_width:.0f} cm '
            f'wide; it lowers the held-out model error from {error_text(fit.heldout_before, floor)} to '
            f'{error_text(fit.heldout_after, floor).removeprefix("at ")}. That is an effect of simple form the library does not name; '
            f'`wind-shaper model add --effect formula` adds it.')
