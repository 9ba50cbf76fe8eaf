"""How long to sweep: until the field estimate is good enough for the next step (``SweepLength``).

The paper sweeps 1000 samples (20 s) every iteration whatever the estimate needs. Here the plate
sweeps on in chunks and the field is estimated after each one past a hard minimum; the sweep ends
as soon as every key point has been passed (coverage 1.0 at the estimator's ``max_gap``) and the
GP's posterior standard deviation, as an RMS over the key points, is below ``std_max``. That
threshold is tied to the update's stopping rule: ``std_factor`` x its noise floor, the error a
sweep is taken to resolve at best; estimating finer than that buys the next step nothing. The
RMS, not the largest std, because the update and the stopping rule see the estimate's noise as
mean(std^2) over the key points: where the turbulence grows with the force, the few key points
under the strongest jets would otherwise hold every sweep to its longest for a gain the step
never sees. No key point may exceed ``worst_factor`` x the threshold (a spot the plate barely
passed). ``samples_per_sweep`` stays the longest a sweep may last.

Samples are counted at the tunnel's sample rate (the rig: 50 Hz, so 50 samples = 1 s of plate
time); forces and standard deviations [N].
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping

import numpy as np

from ..core.config import take_section
from ..core.errors import ConfigError, SweepError
from ..estimation import Coverage
from .region import SweepRegion


@dataclass(frozen=True)
class SweepProgress:
    """Where a sweep stands: samples so far, share of key points passed [0..1], the largest
    posterior std at a key point and its RMS over the key points [N] (NaN before an estimate),
    and whether it may end."""

    n_samples: int
    coverage: float
    std_max: float
    enough: bool
    std_rms: float = float('nan')

    def text(self) -> str:
        std = ('-' if not np.isfinite(self.std_max) else
               f'{self.std_rms:.3f} N RMS, largest {self.std_max:.3f} N')
        return f'{self.n_samples} samples, coverage {100 * self.coverage:.0f} %, std {std}'


@dataclass(frozen=True)
class SweepLength:
    """adaptive: end a sweep early when the estimate is good enough (False: always the full
    ``samples_per_sweep``); min_samples: never fewer (keeps coverage honest: a plate that
    lingers near the key points must still cross the area); chunk_samples: estimate again after
    every this many samples; std_factor: the largest RMS over the key points of the posterior
    std, as a multiple of the stopping rule's noise floor [N]; worst_factor: no key point's std
    above this many times that threshold."""

    adaptive: bool = True
    min_samples: int = 300
    chunk_samples: int = 50
    std_factor: float = 1.2
    worst_factor: float = 2.0
    #: an interim estimate reuses the hyperparameters fitted at the sweep's first estimate
    #: until the sweep has grown to this many times the samples they were fitted on (then
    #: they are fitted again): one or two fits per sweep instead of one per chunk
    refit_growth: float = 1.5
    #: a run fits the hyperparameters on the first sweep and again every this many sweeps; the
    #: sweeps between reuse the last fit (the tunnel's turbulence, a share of the force, does not
    #: change from one sweep to the next), which keeps an iteration's estimates cheap
    refit_sweeps: int = 4
    #: where to sweep after the first iteration: a ``control.region.SweepRegion`` section
    region: Mapping | None = None

    def __post_init__(self):
        if not (isinstance(self.min_samples, int) and self.min_samples >= 10):
            raise ConfigError(f'shaping.sweep.min_samples must be a whole number >= 10; got '
                              f'{self.min_samples!r}')
        if not (isinstance(self.chunk_samples, int) and self.chunk_samples >= 1):
            raise ConfigError(f'shaping.sweep.chunk_samples must be a whole number >= 1; got '
                              f'{self.chunk_samples!r}')
        if not (isinstance(self.refit_sweeps, int) and self.refit_sweeps >= 1):
            raise ConfigError(f'shaping.sweep.refit_sweeps must be a whole number >= 1; got '
                              f'{self.refit_sweeps!r}')
        if not (isinstance(self.refit_growth, (int, float)) and self.refit_growth >= 1):
            raise ConfigError(f'shaping.sweep.refit_growth must be >= 1; got {self.refit_growth!r}')
        if not self.std_factor > 0:
            raise ConfigError(f'shaping.sweep.std_factor must be > 0; got {self.std_factor!r}')
        if not (isinstance(self.worst_factor, (int, float)) and self.worst_factor >= 1):
            raise ConfigError(f'shaping.sweep.worst_factor must be >= 1 (a multiple of the RMS '
                              f'threshold); got {self.worst_factor!r}')
        if self.region is not None and not isinstance(self.region, (Mapping, SweepRegion)):
            raise ConfigError(f'shaping.sweep.region must be a section (enabled, change_error, '
                              f'min_share, max_share, reach); got {self.region!r}')
        self.region_policy  # validates the region section

    @property
    def region_policy(self) -> SweepRegion:
        """The region section as a ``SweepRegion`` (off unless it says ``enabled: true``; only
        an adaptive sweep can keep to a region)."""
        if isinstance(self.region, SweepRegion):
            return self.region
        return take_section(SweepRegion, self.region, 'shaping.sweep.region')

    def std_max(self, rule) -> float:
        """The threshold [N] for ``rule`` (its stopping rule's floor; 0.05 N without one)."""
        stopping = getattr(rule, 'stopping', None)
        floor = getattr(stopping, 'floor', 0.05) if stopping is not None else 0.05
        return self.std_factor * float(floor)

    def good_enough(self, std, threshold: float) -> tuple[float, float, bool]:
        """(RMS over the key points, largest, enough) of a field estimate's std (N,) [N]
        against ``threshold`` (``std_max``) [N]."""
        std = np.asarray(std, dtype=float)
        if std.size == 0 or not np.all(np.isfinite(std)):
            return float('nan'), float('nan'), False
        rms, worst = float(np.sqrt(np.mean(std ** 2))), float(np.max(std))
        return rms, worst, bool(rms <= threshold and worst <= self.worst_factor * threshold)


class SweepMonitor:
    """Follows one sweep as its samples arrive: coverage of the key points, and (past the
    minimum, at full coverage) the estimate's std. ``add(positions)`` then ``check()``.

    plan: a ``control.region.RegionPlan`` when only its region is swept: coverage counts its
    needed key points, the minimum shrinks with its share, and the estimate is fused with what
    it carries over."""

    def __init__(self, policy: SweepLength, estimator, key_points, std_max: float, plan=None,
                 reuse=None):
        self.policy, self.estimator, self.plan = policy, estimator, plan
        self.key_points = np.asarray(key_points, dtype=float)
        self.std_max = float(std_max)
        watched = self.key_points if plan is None else self.key_points[plan.needed]
        self.coverage = Coverage(watched, estimator.max_gap)
        self.min_samples = (policy.min_samples if plan is None
                            else max(policy.chunk_samples, int(np.ceil(policy.min_samples * plan.share))))
        self.n = 0
        self.estimate = None
        self.consistency = float('nan')  # a region sweep's check of its carried values
        self.fitted = None   # (the estimate whose hyperparameters interim estimates reuse, its sweep's length)
        #: an earlier sweep's estimate whose hyperparameters every estimate of this sweep reuses
        self.reuse = reuse
        #: samples the last estimate was made from, and the count before which another one is
        #: unlikely to be good enough (``check``)
        self.estimated_at = 0
        self.next_check = 0

    def add(self, positions) -> None:
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        self.coverage.add(positions)
        self.n += len(positions)

    def estimate_now(self, sweep):
        """The field from ``sweep`` (fused with the plan's carried values); SweepError as the
        estimator raises it."""
        reuse = self.reuse
        if reuse is None and self.fitted is not None and len(sweep) < self.policy.refit_growth * self.fitted[1]:
            reuse = self.fitted[0]
        if self.plan is None:
            estimate = self.estimator.estimate(sweep, self.key_points, reuse=reuse)
        else:
            estimate, self.consistency = fused_estimate(self.estimator, sweep, self.key_points,
                                                        self.plan, reuse=reuse)
        if reuse is None:
            self.fitted = (estimate, len(sweep))
        return estimate

    def check(self, sweep) -> SweepProgress:
        """Progress after the samples of ``sweep`` (everything so far); estimates the field when
        the minimum is reached and every key point is passed."""
        if self.n < max(self.min_samples, self.next_check) or self.coverage.share < 1.0:
            last = (float('nan'),) * 2 if self.estimate is None else \
                self.policy.good_enough(self.estimate.std, self.std_max)[:2]
            return SweepProgress(self.n, self.coverage.share, last[1], False, last[0])
        try:
            self.estimate = self.estimate_now(sweep)
        except SweepError:
            return SweepProgress(self.n, self.coverage.share, float('nan'), False)
        self.estimated_at = len(sweep)
        rms, worst, enough = self.policy.good_enough(self.estimate.std, self.std_max)
        if not enough and np.isfinite(rms) and rms > self.std_max:
            # the std falls about as 1 / sqrt(samples): skip the estimates that cannot be good
            # enough yet (80 % of the predicted count, as gusts and uneven coverage slow it)
            self.next_check = int(0.8 * self.n * (rms / self.std_max) ** 2)
        return SweepProgress(self.n, self.coverage.share, worst, enough, rms)

    def final_estimate(self, sweep):
        """The estimate of the whole of ``sweep`` (the one ``check`` just made if it saw all of
        it)."""
        if self.estimate is not None and self.estimated_at == len(sweep):
            return self.estimate
        return self.estimate_now(sweep)


def fused_estimate(estimator, sweep, key_points, plan, reuse=None):
    """A region sweep's field estimate: the GP on ``sweep`` (only the plan's needed key points
    must be passed) fused at every key point with what the plan carries over; returns it and
    the plan's ``consistency`` with the fresh estimate. reuse: as ``FieldEstimator.estimate``."""
    fresh = estimator.estimate(sweep, key_points, required=plan.needed, reuse=reuse)
    mean, std = plan.fuse(fresh.mean, fresh.std)
    return replace(fresh, mean=mean, std=std), plan.consistency(fresh.mean, fresh.std)


__all__ = ['SweepLength', 'SweepMonitor', 'SweepProgress', 'fused_estimate']
