"""Suggested experiments: the next sweeps' commands that teach the diagnosis the most.

After a diagnosis, two questions are open, and each has a classical optimal-design answer on the
models' predictions at the key points (a sweep measures the field there: its samples spread over
the key points, each with the measurement noise ``noise_sd`` [N] of the diagnosis):

* **separate** the leading hypotheses (the current model and the best refined candidates of the
  last step): a sweep at commands U tells hypotheses i and j apart by
  d_ij(U) = sum_k (f_i(U, z_k) - f_j(U, z_k))^2 / noise_sd^2, the expected rise of the
  log-likelihood ratio (T-optimality, Atkinson & Fedorov; noise_sd here is that of the mean
  of the samples a sweep leaves per key point). Sweeps are picked greedily to
  maximise sum_ij log(1 + D_ij), D_ij the separation accumulated over the picked sweeps, so a
  pair already told apart counts less and the next sweep goes after the pairs still confused;
* **shrink** the uncertainty of the fitted parameters (the final model's free ones): the
  information of the recorded cells I_0 = J0' W J0 / noise_sd^2 (W: samples per cell) grows by
  J(U)' J(U) / noise_sd^2 per sweep (per-key-point noise as above);
  sweeps are picked greedily to maximise log det I (D-optimality), the Jacobians by central
  differences in the parameters.

* **explore**: when the diagnosis found nothing, no hypothesis is there to aim at; the sweeps are
  a Latin hypercube (every fan's commands spread evenly over the range, independent of the
  others), the one of many farthest from the sweeps already recorded.

``goal='auto'`` explores when nothing was found, separates when a finding has a runner-up within
10 of its BIC, and shrinks otherwise. The candidates are random commands within [u_min, u_max]
(each enabled fan also off at times, the design's 0), scored all at once. The result is an
``experiment.Design`` that `wind-shaper collect --design FILE` runs. Commands [fraction],
forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import TunnelGeometry
from ..experiment import Design, check_design, design_commands
from ..model import Term
from .diagnose import Diagnosis
from .errors import FitError

__all__ = ['Suggestion', 'suggest_sweeps', 'separation', 'information_gain', 'GOALS']

GOALS = ('auto', 'separate', 'shrink', 'explore')
#: A runner-up within this BIC of the best refined candidate leaves the diagnosis unsure.
UNSURE_DBIC = 10.0


@dataclass(frozen=True)
class Suggestion:
    """design: the suggested sweeps; goal: 'separate' or 'shrink'; hypotheses: the names of the
    models separated; value_before / value_after: the criterion before and after the sweeps
    (separate: the smallest pairwise separation in noise units; shrink: each parameter's 1-sigma
    error [its unit], by name); per_sweep: what each sweep adds (text, for the report)."""

    design: Design
    goal: str
    hypotheses: tuple
    value_before: dict
    value_after: dict
    per_sweep: tuple = field(default=())

    def outcome_text(self) -> str:
        """What the sweeps are expected to do, in words."""
        n = len(self.design)
        if self.goal == 'explore':
            return (f'{n} sweep(s) at commands as far as possible from the sweeps recorded (no effect '
                    f'was found: new operating points give the diagnosis most to go on)')
        if self.goal == 'separate':
            return (f'{n} sweep(s) chosen to tell apart {", ".join(self.hypotheses)}: the closest '
                    f'pair is expected to differ by {self.value_after["min_separation"]:.1f} in '
                    f'units of the noise (log-likelihood ratio) after them')
        shrink = [self.value_after[k] / self.value_before[k] for k in self.value_before
                  if self.value_before[k] > 0]
        return (f'{n} sweep(s) chosen to pin the fitted parameters down: their standard errors '
                f'are expected to fall to {100 * np.median(shrink):.0f} % of today\'s (median over '
                f'{len(shrink)} parameters; best {100 * min(shrink):.0f} %)' if shrink else
                f'{n} sweep(s) chosen to pin the fitted parameters down')

    def summary(self) -> dict:
        return {'goal': self.goal, 'expected': self.outcome_text(), 'hypotheses': list(self.hypotheses),
                'before': self.value_before, 'after': self.value_after,
                'commands': np.round(self.design.commands, 4).tolist(),
                'labels': list(self.design.labels), 'per_sweep': list(self.per_sweep)}


def _pool(geometry: TunnelGeometry, u_min: float, u_max: float, n: int, rng) -> np.ndarray:
    """n random command vectors: each enabled fan uniform in [u_min, u_max], off (0) in one of
    eight draws; disabled fans 0."""
    enabled = np.asarray(geometry.fans.enabled, bool)
    U = rng.uniform(u_min, u_max, (n, len(enabled)))
    U[rng.random(U.shape) < 0.125] = 0.0
    return U * enabled


def _predict(model: Term, U: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """(len(U), len(Z)) predictions of ``model`` at every command vector and key point [N]."""
    M, N = len(U), len(Z)
    return model(np.repeat(U, N, axis=0), np.tile(Z, (M, 1))).reshape(M, N)


def separation(models, U: np.ndarray, Z: np.ndarray, noise_sd: float) -> np.ndarray:
    """(len(U), P) separation of each of the P model pairs by one sweep at each command vector
    (see the module docstring) [dimensionless]."""
    F = [_predict(m, U, Z) for m in models]
    pairs = [(i, j) for i in range(len(F)) for j in range(i + 1, len(F))]
    return np.stack([np.sum((F[i] - F[j]) ** 2, axis=1) / noise_sd ** 2 for i, j in pairs], axis=1)


def _jacobian(model: Term, mask: np.ndarray, U: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """(rows, k) derivatives of the prediction at rows (U, Z) by the parameters picked by mask
    (central differences, steps relative to each value and its bounds)."""
    theta = np.asarray(model.theta, float)
    lo, hi = np.asarray(model.bounds, float).T
    cols = []
    for i in np.flatnonzero(mask):
        h = 1e-4 * max(abs(theta[i]), 1e-2)
        up, dn = theta.copy(), theta.copy()
        up[i], dn[i] = min(theta[i] + h, hi[i]), max(theta[i] - h, lo[i])
        cols.append((model.with_theta(up)(U, Z) - model.with_theta(dn)(U, Z)) / (up[i] - dn[i]))
    return np.stack(cols, axis=1)


def information_gain(model: Term, mask: np.ndarray, U: np.ndarray, Z: np.ndarray, noise_sd: float
                     ) -> np.ndarray:
    """(len(U), k, k) information each sweep at one of the command vectors U adds about the
    parameters picked by mask."""
    M, N = len(U), len(Z)
    J = _jacobian(model, mask, np.repeat(U, N, axis=0), np.tile(Z, (M, 1))).reshape(M, N, -1)
    return np.einsum('mnk,mnl->mkl', J, J) / noise_sd ** 2


def _too_close(U: np.ndarray, picked: list, distance: float) -> np.ndarray:
    """Which rows of U lie within ``distance`` of a picked vector in every fan."""
    if not picked:
        return np.zeros(len(U), bool)
    P = np.asarray(picked)
    return np.any(np.max(np.abs(U[:, None, :] - P[None, :, :]), axis=2) < distance, axis=1)


def _hypotheses(d: Diagnosis, n: int):
    """(names, models) to separate: the model the diagnosis' last step started from ('no further
    effect') and the best refined candidates of that step, each fitted on the training sweeps."""
    if not d.rankings_:
        raise FitError('the diagnosis ranked no candidate: there is nothing to separate (use the '
                       'goal shrink)')
    step = len(d.rankings_) - 1
    base = d.baseline_.model if step == 0 else d.selected_[step - 1].model
    refined = sorted((t for t in d.rankings_[step] if t.stage == 'refined'), key=lambda t: t.bic)
    rivals = refined[:max(n - 1, 1)]
    if not rivals:
        raise FitError('the diagnosis refined no candidate to separate from the model: use the '
                       'goal shrink')
    return (['no further effect'] + [t.candidate.name for t in rivals],
            [base] + [t.model for t in rivals])


def _unsure(d: Diagnosis) -> bool:
    if d.verdict_ != 'found':
        return True
    last = [t for t in (d.rankings_[-1] if d.rankings_ else []) if t.stage == 'refined']
    bics = sorted(t.bic for t in last)
    return len(bics) >= 2 and bics[1] - bics[0] < UNSURE_DBIC


def suggest_sweeps(d: Diagnosis, n_sweeps: int, u_min: float, u_max: float, *, goal: str = 'auto',
                   n_hypotheses: int = 4, pool: int = 400, min_distance: float = 0.1,
                   seed: int = 0) -> Suggestion:
    """The ``n_sweeps`` commands that best serve ``goal`` after the fitted diagnosis ``d`` (see
    the module docstring), within [u_min, u_max] (0 = off allowed), as a checked Design. No two
    suggestions lie closer than ``min_distance`` of the range in every fan, so that a model error
    at one operating point does not decide alone."""
    if goal not in GOALS:
        raise ValueError(f'goal must be one of {GOALS}; got {goal!r}')
    if n_sweeps < 1:
        raise ValueError(f'suggest at least one sweep; got {n_sweeps}')
    geometry = d.geometry_
    Z = geometry.key_points
    rng = np.random.default_rng(seed)
    U = _pool(geometry, u_min, u_max, pool, rng)
    # a sweep spreads its samples over the area: each key point stands for the samples per
    # sweep of the recorded data over the number of key points (the noise is per sample)
    data = d.train_
    samples_per_sweep = float(data.count.sum()) / max(len(np.unique(data.sweep)), 1)
    noise = float(d.noise_sd_) / np.sqrt(samples_per_sweep / len(Z))
    if goal == 'auto':
        refined = any(t.stage == 'refined' for r in d.rankings_ for t in r)
        goal = ('explore' if d.verdict_ != 'found' else
                'separate' if _unsure(d) and refined else 'shrink')
    picked, notes = [], []
    if goal == 'explore':
        # Latin hypercubes spread every fan's commands evenly (what lets the diagnosis tell the
        # fans' effects apart); of many, the one farthest from the sweeps already recorded
        recorded = np.vstack([d.train_sweeps_.commands, d.test_sweeps_.commands])
        enabled = np.asarray(geometry.fans.enabled, bool)
        scale = max(u_max - u_min, 1e-9)
        best_gap, best = -1.0, None
        gap_before = None
        for k in range(max(pool // max(n_sweeps, 1), 20)):
            cand = design_commands(len(enabled), n_sweeps, low=u_min, high=u_max,
                                   seed=seed * 100003 + k, enabled=enabled)
            gaps = np.min(np.linalg.norm((cand[:, None, enabled] - recorded[None, :, enabled]) / scale,
                                         axis=2), axis=1)
            gap_before = float(np.min(gaps)) if gap_before is None else gap_before
            if np.min(gaps) > best_gap:
                best_gap, best = float(np.min(gaps)), cand
        picked = list(best)
        notes = [f'a Latin hypercube {best_gap:.2f} of the range from the nearest recorded sweep']
        names = ['(no hypothesis yet: new operating points)']
        value_before, value_after = {'nearest_gap': gap_before}, {'nearest_gap': best_gap}
    elif goal == 'separate':
        names, models = _hypotheses(d, n_hypotheses)
        S = separation(models, U, Z, noise)          # (pool, pairs)
        total = np.zeros(S.shape[1])
        before = float(total.min())
        for _ in range(n_sweeps):
            score = np.sum(np.log1p(total[None, :] + S), axis=1)
            score[_too_close(U, picked, min_distance * (u_max - u_min))] = -np.inf
            best = int(np.argmax(score))
            picked.append(U[best])
            total = total + S[best]
            notes.append(f'smallest pair separation {np.min(total):.1f} (noise units)')
        value_before, value_after = {'min_separation': before}, {'min_separation': float(total.min())}
    else:
        fit = d.final_
        mask = np.asarray(fit.mask, bool)
        names = [n for n, m in zip(fit.model.theta_names, mask) if m]
        J0 = _jacobian(fit.model, mask, data.U, data.Z)
        info = (J0 * data.count[:, None]).T @ J0 / float(d.noise_sd_) ** 2 + 1e-12 * np.eye(len(names))
        G = information_gain(fit.model, mask, U, Z, noise)
        std_before = np.sqrt(np.diag(np.linalg.pinv(info)))
        for _ in range(n_sweeps):
            _, logdet = np.linalg.slogdet(info[None, :, :] + G)
            logdet[_too_close(U, picked, min_distance * (u_max - u_min))] = -np.inf
            best = int(np.argmax(logdet))
            picked.append(U[best])
            info = info + G[best]
            notes.append(f'log det information {logdet[best]:.1f}')
        std_after = np.sqrt(np.diag(np.linalg.pinv(info)))
        value_before = {n: float(s) for n, s in zip(names, std_before)}
        value_after = {n: float(s) for n, s in zip(names, std_after)}
        names = [repr(fit.model)]
    labels = [f'suggested {i + 1}' for i in range(len(picked))]
    design = check_design(list(geometry.fans.names), np.array(picked), labels, geometry.fans,
                          u_min, u_max, f'suggested by the diagnosis ({goal})')
    return Suggestion(design, goal, tuple(names), value_before, value_after, tuple(notes))
