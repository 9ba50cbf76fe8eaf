"""Sweep only the region a step changed (``SweepRegion``, ``plan_region``, ``RegionPlan``).

After an update the field moves mostly near the fans whose commands moved. Where the model
predicts little change, the last estimate still holds: carried over with the model's predicted
change, its std grown by the model's error in that change,

    carried = mean_prev + (model(U_next) - model(U_prev)),
    carried_std = sqrt(std_prev^2 + (change_error * |model(U_next) - model(U_prev)|)^2).

Only key points whose carried std exceeds the sweep's target std (``SweepLength.std_max``, the
std a fresh sweep would be swept down to) are *needed*: the plate sweeps the region around them,
and the new estimate is the inverse-variance fusion of the fresh GP estimate (large std far from
the swept region) and the carried one, at every key point. A carried value's std never shrinks,
so a key point skipped now is swept once its std has grown past the target. Each region sweep
also checks the carried values against the fresh ones where it swept (``consistency``); a
model whose predicted changes miss by more than their stated error gets a larger change error
for the next plan (``change_error_after``), so less is carried over.

Forces and standard deviations [N]; positions [m, tunnel frame]; commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.area import SweepArea
from ..core.errors import ConfigError


@dataclass(frozen=True)
class SweepRegion:
    """enabled: sweep only the needed region after the first iteration (False: every sweep
    covers the whole area); change_error: the model's predicted change of the field is trusted
    to within this fraction of itself (0.5: a change of 0.1 N is known to +-0.05 N);
    min_share: sweep at least this share of the key points (a patch around the one with the
    largest carried std), so no sweep is skipped whole and the stalest part is refreshed; max_share: when more than this share is needed, sweep
    the whole area (a region path saves little then); reach: the region is every position
    within this distance [m] of a needed key point (above the estimator's max_gap, so the plate
    passes each needed key point closely enough)."""

    enabled: bool = False
    change_error: float = 0.5
    min_share: float = 0.2
    max_share: float = 0.75
    reach: float = 0.10

    def __post_init__(self):
        if not isinstance(self.enabled, bool):
            raise ConfigError(f'shaping.sweep.region.enabled must be true or false; got {self.enabled!r}')
        if not (isinstance(self.change_error, (int, float)) and self.change_error >= 0):
            raise ConfigError(f'shaping.sweep.region.change_error must be >= 0 (a fraction of the '
                              f'predicted change); got {self.change_error!r}')
        if not (0 < self.min_share <= self.max_share <= 1):
            raise ConfigError(f'shaping.sweep.region needs 0 < min_share <= max_share <= 1; got '
                              f'min_share {self.min_share!r}, max_share {self.max_share!r}')
        if not self.reach > 0:
            raise ConfigError(f'shaping.sweep.region.reach must be > 0 m; got {self.reach!r}')


@dataclass(frozen=True)
class RegionPlan:
    """Where to sweep and what is carried over. needed: (N,) key points to sweep; carried_mean,
    carried_std: (N,) the last estimate moved by the model's predicted change [N]; area: where
    to sweep (within ``reach`` of a needed key point); change_error: the fraction of the
    predicted change taken as its error in carried_std."""

    needed: np.ndarray
    carried_mean: np.ndarray
    carried_std: np.ndarray
    area: SweepArea
    change_error: float = float('nan')

    @property
    def share(self) -> float:
        return float(np.mean(self.needed))

    def fuse(self, fresh_mean, fresh_std) -> tuple[np.ndarray, np.ndarray]:
        """Inverse-variance fusion of a fresh estimate from the region's sweep with the carried
        one, at every key point: (mean, std) (N,) [N]. Far from the swept region the fresh GP
        reverts to its prior (a large std) and the carried value wins; near it, the fresh one."""
        m1, s1 = np.asarray(fresh_mean, float), np.maximum(np.asarray(fresh_std, float), 1e-9)
        m2, s2 = self.carried_mean, np.maximum(self.carried_std, 1e-9)
        w1, w2 = 1.0 / s1 ** 2, 1.0 / s2 ** 2
        return (w1 * m1 + w2 * m2) / (w1 + w2), 1.0 / np.sqrt(w1 + w2)

    def consistency(self, fresh_mean, fresh_std) -> float:
        """How well the carried values agree with the fresh estimate where the region was swept
        (the key points whose fresh std is below the carried one): the mean of
        (fresh - carried)^2 / (fresh_std^2 + carried_std^2). About 1 when the model predicts
        the change within its stated error; well above 1 when it does not. NaN if no such point."""
        fm, fs = np.asarray(fresh_mean, float), np.asarray(fresh_std, float)
        sure = self.needed & (fs < self.carried_std)
        if not sure.any():
            return float('nan')
        z2 = (fm - self.carried_mean) ** 2 / (fs ** 2 + self.carried_std ** 2)
        return float(np.mean(z2[sure]))

    def to_json(self) -> dict:
        return {'share': round(self.share, 4), 'needed': [int(i) for i in np.nonzero(self.needed)[0]],
                'reach_m': self.area.reach, 'change_error': self.change_error,
                'carried_std_max_N': float(np.max(self.carried_std[~self.needed]))
                if (~self.needed).any() else None}

    def text(self) -> str:
        n, N = int(self.needed.sum()), len(self.needed)
        return (f'sweeping {n} of {N} key points (the region the step changed: {self.area.text()}); '
                f'the other {N - n} carried over with the model\'s predicted change')


def carry_over(model, U_prev, U_next, key_points, mean_prev, std_prev, change_error: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """The last estimate (mean_prev, std_prev at ``key_points``, measured at ``U_prev``) moved
    to commands ``U_next`` by the model's predicted change; its std grows by ``change_error`` x
    the change. Returns (mean, std) (N,) [N]."""
    kp = np.asarray(key_points, dtype=float)
    change = np.asarray(model(np.asarray(U_next, float), kp), float) - \
        np.asarray(model(np.asarray(U_prev, float), kp), float)
    std = np.sqrt(np.asarray(std_prev, float) ** 2 + (change_error * change) ** 2)
    return np.asarray(mean_prev, float) + change, std


def change_error_after(policy: SweepRegion, consistency: float) -> float:
    """The change error for the next plan after a region sweep whose carried values met the
    fresh ones with ``consistency`` (``RegionPlan.consistency``): the policy's, grown by
    sqrt(consistency) when the model's predicted change proved worse than stated (a model
    that does not match the tunnel soon has every key point swept again)."""
    if not np.isfinite(consistency) or consistency <= 1.0:
        return float(policy.change_error)
    return float(policy.change_error * np.sqrt(consistency))


def plan_region(policy: SweepRegion, model, key_points, U_prev, U_next, mean_prev, std_prev,
                std_max: float, change_error: float | None = None) -> RegionPlan | None:
    """The region to sweep at ``U_next`` after an estimate (mean_prev, std_prev) at ``U_prev``,
    or None to sweep the whole area (policy off, or more than ``max_share`` needed). Needed:
    key points whose carried std exceeds ``std_max`` [N]; at least ``min_share`` of them (a
    patch around the largest carried std). change_error: instead of the policy's (see
    ``change_error_after``)."""
    if not policy.enabled:
        return None
    kp = np.asarray(key_points, dtype=float)
    kappa = float(policy.change_error if change_error is None else change_error)
    mean, std = carry_over(model, U_prev, U_next, kp, mean_prev, std_prev, kappa)
    needed = std > std_max
    least = int(np.ceil(policy.min_share * len(kp)))
    if needed.sum() < least:
        # refresh the stalest patch: the key points nearest the one with the largest carried
        # std (a compact patch, which a plate sweeps quickly; scattered points would not be)
        seed = kp[int(np.argmax(np.where(needed, -np.inf, std)))]
        near = np.argsort(np.linalg.norm(kp - seed, axis=1), kind='stable')
        for i in near[~needed[near]][:least - int(needed.sum())]:
            needed[i] = True
    if needed.mean() > policy.max_share:
        return None
    return RegionPlan(needed, mean, std, SweepArea(kp[needed], policy.reach), kappa)


def next_region(sweep_length, rule, model, key_points, last, U) -> RegionPlan | None:
    """The region plan for the sweep at commands ``U`` (n_fans,) after the iteration ``last``
    (anything with ``U``, ``mean``, ``std`` and ``info``, as ``control.update.PastIteration``;
    None before the first): None for the whole area. sweep_length: a ``SweepLength`` (its
    region section and target std, for ``rule``'s noise floor); the change error grows after
    a region sweep whose carried values proved worse than stated."""
    if sweep_length is None or not sweep_length.adaptive or last is None or last.std is None:
        return None
    policy = sweep_length.region_policy
    kappa = change_error_after(policy, dict(last.info or {}).get('region', {}).get('consistency', float('nan')))
    return plan_region(policy, model, key_points, last.U, U, last.mean, last.std,
                       sweep_length.std_max(rule), kappa)


def region_record(plan: RegionPlan | None, consistency: float) -> dict:
    """What an iteration's info says of its region sweep ({} for a whole sweep)."""
    if plan is None:
        return {}
    return {**plan.to_json(), 'consistency': consistency, 'text': plan.text()}


__all__ = ['SweepRegion', 'RegionPlan', 'carry_over', 'change_error_after', 'next_region',
           'plan_region', 'region_record']
