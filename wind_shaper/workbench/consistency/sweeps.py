"""Does a value hold across sweeps? The check before an effect is named.

A term that only patches an unexplained residual can lower the error on average and still be the
wrong physics: a fan "gain" that compensates a blocked patch of the straightener comes out
different in every sweep, because the patch does not follow that fan's command. A real effect
has one value whatever the commands. ``check_across_sweeps`` therefore

1. refits the candidate's own parameters sweep by sweep (the rest of the model held), on the
   sweeps where the effect changes the prediction at all (its *signal*: the RMS difference
   between the model with the effect and the model before it was added [N]);
2. scores each sweep's value against the pooled one, z = |value - pooled| / sigma, with sigma
   the sweep's standard error and ``tolerance`` x the effect's size (|pooled - null| over the
   whole parameter, or |pooled| without a null value) added in quadrature (what the rest of the model gets slightly wrong in one sweep);
3. counts the held-out sweeps on which the model with the effect predicts better than without.

It passes when at most ``max_disagree`` of the informative training sweeps disagree (z >
``max_z``), the spread as a whole is not beyond chance (chi-square of the z's, p >= ``min_p``),
and the effect helps on at least ``min_heldout_share`` of the informative held-out sweeps.
Forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from ...model import Term, param_slices, term_label
from ..data import FitData
from ..fitting import fit_model

__all__ = ['SweepCheck', 'check_across_sweeps', 'judge_spread']


@dataclass
class SweepCheck:
    """The per-sweep check of one candidate (see the module docstring).

    names: the term's parameter elements; pooled, null: their pooled and no-effect values (NaN:
    none); size: the effect's size per element (see ``_term_elements``);
    values, stds: (S, P) refitted per training sweep (NaN where the sweep is not informative);
    signal: (S,) the effect's signal per training sweep [N]; informative, disagree: (S,) masks;
    heldout_better, heldout_informative: (H,) masks over the held-out sweeps."""

    names: list
    pooled: np.ndarray
    null: np.ndarray
    values: np.ndarray
    stds: np.ndarray
    signal: np.ndarray
    informative: np.ndarray
    disagree: np.ndarray
    heldout_better: np.ndarray
    heldout_informative: np.ndarray
    p_value: float = 1.0
    size: np.ndarray | None = None
    passed: bool = False
    reasons: list = field(default_factory=list)
    too_few: bool = False       # too few training sweeps show it to check it (more data would)
    spread: bool = False        # it does not hold across the sweeps (a patch of something else)
    heldout_short: bool = False  # it improves too few of the held-out sweeps it touches
    beside: 'BesideCheck | None' = None  # the check again beside a discrepancy model, if run

    def spread_text(self) -> str:
        """'its gain runs from 0.62 to 0.91 across the sweeps' for the parameter that disagrees
        most (relative to the effect's size)."""
        if not self.informative.any():
            return ''
        v = self.values[self.informative]
        size = np.maximum(self.size if self.size is not None else np.abs(self.pooled), 1e-12)
        spread = (np.nanmax(v, 0) - np.nanmin(v, 0)) / size
        if np.isfinite(self.null).any():  # the magnitude parameters (see check_across_sweeps)
            spread = np.where(np.isfinite(self.null), spread, -np.inf)
        worst = int(np.nanargmax(spread))
        lo, hi = np.nanmin(v[:, worst]), np.nanmax(v[:, worst])
        name = _short(self.names[worst])
        return f'its {name} runs from {lo:.3g} to {hi:.3g} across the sweeps'

    def to_json(self) -> dict:
        def clean(a):
            return np.where(np.isfinite(a), np.round(np.asarray(a, float), 5), None).tolist()
        return {'parameters': list(self.names), 'pooled': clean(self.pooled),
                'null': clean(self.null), 'per_sweep': clean(self.values),
                'per_sweep_std': clean(self.stds), 'signal_N': clean(self.signal),
                'informative': self.informative.tolist(), 'disagree': self.disagree.tolist(),
                'heldout_better': self.heldout_better.tolist(),
                'heldout_informative': self.heldout_informative.tolist(),
                'p_value': float(self.p_value), 'passed': bool(self.passed), 'reasons': list(self.reasons),
                'beside_discrepancy': self.beside.to_json() if self.beside is not None else None}


def _term_elements(model: Term, label: str, null: dict):
    """The term's slice of ``model.theta``, and per element of it: the no-effect value (NaN for
    a parameter without one) and the effect's size, |pooled - null| over the whole parameter
    (a shift's length, not one coordinate), or |pooled| where there is no null value."""
    for node, sl in param_slices(model):
        if term_label(node) == label:
            break
    else:
        raise ValueError(f'no term {label} in the model')
    pooled = model.theta[sl]
    null_values, size = np.full(len(pooled), np.nan), np.zeros(len(pooled))
    i = 0
    for h in node._free():
        part = slice(i, i + h.size)
        if h.name in null:
            null_values[part] = np.broadcast_to(np.asarray(null[h.name], float), (h.size,))
            size[part] = np.linalg.norm(pooled[part] - null_values[part])
        else:
            size[part] = np.linalg.norm(pooled[part])
        i += h.size
    return sl, null_values, size


def _magnitude(null_values: np.ndarray) -> np.ndarray:
    """Which elements carry the effect's magnitude: those with a no-effect value (a gain, a
    shift), not those that only shape it (an elongation's direction); all of a term without
    any null value."""
    finite = np.isfinite(null_values)
    return finite if finite.any() else np.ones(len(null_values), bool)


def _short(name: str) -> str:
    """A parameter element's own name, without the path of terms it sits in."""
    return name.split('.')[-1].split('__')[-1]


def _signal(with_effect: Term, without: Term, data: FitData) -> np.ndarray:
    """RMS difference [N] of the two models' predictions per sweep (sorted sweep ids)."""
    diff = with_effect(data.U, data.Z) - without(data.U, data.Z)
    return np.array([np.sqrt(np.mean(diff[data.sweep == s] ** 2)) for s in np.unique(data.sweep)])


def _shows_effect(signal: np.ndarray, min_signal: float) -> np.ndarray:
    """The sweeps whose signal [N] is at least ``min_signal`` and a quarter of the median."""
    return signal >= max(min_signal, 0.25 * float(np.median(signal)))


def judge_spread(z: np.ndarray, informative: np.ndarray, dof: int, *, max_z: float = 3.0,
                 max_disagree: float = 0.25, min_p: float = 1e-3) -> tuple[np.ndarray, float, bool]:
    """The rule that decides whether a value holds across sweeps, from the z-scores (S, P) of
    each sweep's values against the value they should share (0 where a sweep is not
    informative): (disagree (S,), chi-square p-value on ``dof`` degrees of freedom, holds). It
    holds when at most ``max_disagree`` of the informative sweeps have a z above ``max_z`` and
    the spread as a whole is not beyond chance (p >= ``min_p``)."""
    disagree = informative & np.any(z > max_z, axis=1)
    n_inf = int(informative.sum())
    p_value = float(chi2.sf(float(np.sum(z ** 2)), dof)) if n_inf > 1 else 1.0
    return disagree, p_value, not (disagree.sum() > max_disagree * n_inf or p_value < min_p)


def check_across_sweeps(model: Term, label: str, null: dict, train: FitData, heldout,
                        previous: Term, *, tolerance: float = 0.1, max_z: float = 3.0,
                        max_disagree: float = 0.25, min_p: float = 1e-3,
                        min_heldout_share: float = 2 / 3, min_signal: float = 0.02,
                        min_sweeps: int = 3, max_nfev: int = 20) -> SweepCheck:
    """Check the term ``label`` of ``model`` (fitted on ``train``) sweep by sweep; ``heldout``
    is the diagnosis's ``HeldOut``, ``previous`` the model before the term was added."""
    sl, null_values, size = _term_elements(model, label, null)
    names = list(model.theta_names[sl])
    pooled = model.theta[sl]

    sweeps = np.unique(train.sweep)
    signal = _signal(model, previous, train)
    informative = _shows_effect(signal, min_signal)
    values = np.full((len(sweeps), len(names)), np.nan)
    stds = np.full_like(values, np.nan)
    free = np.zeros(len(model.theta), bool)
    free[sl] = True
    for i, s in enumerate(sweeps):
        if not informative[i]:
            continue
        fit = fit_model(model, train.subset(train.sweep == s), free=free, max_nfev=max_nfev)
        values[i], stds[i] = fit.theta, fit.theta_std
    # a sweep's error: its standard error, plus a tolerance for what the rest of the model gets
    # slightly wrong in that sweep (a fraction of the effect's size)
    sigma = np.sqrt(np.nan_to_num(stds, nan=np.inf) ** 2 + (tolerance * size) ** 2)
    z = np.where(informative[:, None], np.abs(values - pooled) / sigma, 0.0)
    # The effect's magnitude is what must hold: the parameters with a no-effect value (a gain,
    # a shift), not those that only shape it (an elongation's direction, undefined near no
    # elongation); a term without any null value is checked on all of its parameters.
    magnitude = _magnitude(null_values)
    z = z[:, magnitude]
    n_inf = int(informative.sum())
    disagree, p_value, holds = judge_spread(z, informative, max((n_inf - 1) * int(magnitude.sum()), 1),
                                            max_z=max_z, max_disagree=max_disagree, min_p=min_p)

    # held-out sweeps: does the effect help on most of those it touches?
    data = heldout.data
    pred_new, pred_old = model(data.U, data.Z), previous(data.U, data.Z)
    h_sweeps = np.unique(data.sweep)
    h_signal = _signal(model, previous, data)
    h_informative = _shows_effect(h_signal, min_signal)
    better = np.array([np.mean((pred_new[data.sweep == s] - data.y[data.sweep == s]) ** 2)
                       < np.mean((pred_old[data.sweep == s] - data.y[data.sweep == s]) ** 2)
                       for s in h_sweeps])

    check = SweepCheck(names, pooled, null_values, values, stds, signal, informative, disagree,
                       better, h_informative, p_value=p_value, size=size)
    check.too_few = n_inf < min_sweeps
    check.spread = not check.too_few and not holds
    if check.too_few:
        check.reasons.append(f'only {n_inf} training sweep(s) show the effect: too few to check that '
                             f'it holds across sweeps (needs {min_sweeps}); record more sweeps')
    elif check.spread:
        check.reasons.append(f'it does not hold across sweeps: {check.spread_text()} '
                             f'({int(disagree.sum())} of {n_inf} sweeps disagree with the pooled fit by '
                             f'more than {max_z:g} standard errors; chance of so much spread {p_value:.1g})')
    n_held = int(h_informative.sum())
    n_better = int((better & h_informative).sum())
    check.heldout_short = bool(n_held and n_better < min_heldout_share * n_held)
    if check.heldout_short:
        check.reasons.append(f'it improves only {n_better} of the {n_held} held-out sweeps it touches')
    check.passed = not check.reasons
    return check
