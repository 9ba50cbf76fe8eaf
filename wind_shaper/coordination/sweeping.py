"""How the coordinator sweeps the plate, without ROS: where and how long, how it watches a
sweep, and when a sweep is good enough to end early.

``sweep_span`` turns a region plan (``control.region.RegionPlan``, or None for the whole area)
into the sweep's length and the region the sweep service is asked to cover. ``watch_sweep``
asks the field estimator how far the sweep is every ``sweep_check_s`` while the plate moves,
and with ``shaping.sweep.adaptive`` returns as soon as ``SweepJudge`` finds the estimate good
enough. It awaits a ``waits`` object (the node's ``ros.waiting.Waits``: ``wait``,
``remaining``, ``raise_for``, ``ending``) and the sweep motion's future (anything with
``done()``), so tests drive it with plain asyncio.

Positions [m, tunnel frame]; times [s]; std [N]; coverage [0..1] (share of key points passed).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Awaitable, Callable

import numpy as np

from ..control.region import RegionPlan
from ..estimation import coverage_share
from .iteration import IterationStopped


def required(plan: RegionPlan | None) -> list[bool]:
    """EstimateField's ``required`` flags for a region sweep (empty: every key point)."""
    return [] if plan is None else [bool(v) for v in plan.needed]


@dataclass(frozen=True)
class SweepSpan:
    """One sweep's length ``duration_s`` [s], where it goes in words, and the region the sweep
    service is asked to cover (discs at ``region_x``, ``region_y`` [m] of reach
    ``region_reach`` [m]; no centres: the whole area)."""

    duration_s: float
    where: str
    region_x: tuple = ()
    region_y: tuple = ()
    region_reach: float = 0.0


def sweep_span(plan: RegionPlan | None, duration_s: float, sweep_min_s: float,
               sweep_radius: float) -> SweepSpan:
    """The sweep over the whole area for ``duration_s`` [s], or over ``plan``'s region: the
    region's share of the disc of ``sweep_radius`` [m] sets the time, with room to spare, never
    below ``sweep_min_s`` nor above ``duration_s``."""
    if plan is None:
        return SweepSpan(duration_s, 'the whole area')
    share = plan.area.disc_share(sweep_radius)
    duration = min(duration_s, max(sweep_min_s, 1.5 * share * duration_s))
    return SweepSpan(duration, f'the region {plan.area.text()} ({int(plan.needed.sum())} key points)',
                     tuple(float(v) for v in plan.area.centres[:, 0]),
                     tuple(float(v) for v in plan.area.centres[:, 1]), plan.area.reach)


def peek_figures(positions: np.ndarray | None, success: bool, mean, std, key_points: np.ndarray,
                 radius: float, plan: RegionPlan | None = None) -> tuple[float, float, float]:
    """(coverage [0..1] or NaN, largest std [N] or NaN, RMS of the std over the key points [N] or
    NaN) of a sweep so far, from the plate
    ``positions`` (n, 2) the estimator holds (None: none yet) and its peek estimate (``success``,
    ``mean``, ``std`` at every key point). A region sweep counts its own key points and judges
    the std fused with what it carries over. ``radius`` [m]: how near a key point counts as
    passed."""
    kp = key_points if plan is None else key_points[plan.needed]
    coverage = math.nan
    if positions is not None:
        coverage = coverage_share(positions, kp, radius)
    if not (success and len(std)):
        return coverage, math.nan, math.nan
    std = np.asarray(std, dtype=float)
    if plan is not None:
        std = plan.fuse(np.asarray(mean, dtype=float), std)[1]
    return coverage, float(np.max(std)), float(np.sqrt(np.mean(std ** 2)))


@dataclass(frozen=True)
class SweepJudge:
    """Whether a sweep may end early: ``adaptive`` on, at least ``min_s`` [s] swept, every key
    point passed, the RMS of the std over the key points at most ``std_max`` [N] and no key
    point's std above ``worst_factor`` x ``std_max`` (``control.sweep_length.SweepLength``)."""

    adaptive: bool
    min_s: float
    std_max: float
    worst_factor: float = 2.0

    def verdict(self, k: int, elapsed_s: float, coverage: float, max_std: float,
                rms_std: float | None = None) -> str:
        """'' while the sweep must go on, else what to log as it ends (``rms_std`` None: the
        largest std stands for it)."""
        rms = max_std if rms_std is None else rms_std
        if not (self.adaptive and elapsed_s >= self.min_s and coverage >= 1.0
                and rms <= self.std_max and max_std <= self.worst_factor * self.std_max):
            return ''
        return (f'iteration {k}: the estimate is good enough after {elapsed_s:.1f} s (coverage '
                f'{100 * coverage:.0f} %, std {rms:.3f} N RMS <= {self.std_max:.3f} N, largest '
                f'{max_std:.3f} N): ending the sweep')


async def watch_sweep(waits, motion, duration_s: float, check_s: float,
                      peek: Callable[[], Awaitable[tuple[float, float]]],
                      report: Callable[[float, float], None], enough: Callable[..., str],
                      *, warn: Callable[[str], None], info: Callable[[str], None],
                      clock: Callable[[], float] = time.monotonic) -> bool:
    """Ask ``peek()`` for (coverage, largest std, further figures such as the std's RMS) every
    ``check_s`` [s] and ``report`` the first two, until ``motion`` (the sweep service's future,
    or None for an operator) ends or ``duration_s`` [s] passes (False); True as soon as
    ``enough(elapsed_s, coverage, max_std, *further)`` returns a message (which goes to ``info``). A peek that fails is warned about and the sweep
    goes on, unless a cancel or the deadline ends it; a cancel raises through ``waits``."""
    t0 = clock()
    while True:
        elapsed = clock() - t0
        if motion is not None and motion.done():
            return False
        if elapsed + check_s >= duration_s:   # no check left before the end
            reason = await waits.wait(motion, waits.remaining(duration_s - elapsed))
            if reason == 'cancelled':
                waits.raise_for(reason, '')
            return False
        reason = await waits.wait(motion, waits.remaining(check_s))
        if reason == 'cancelled':
            waits.raise_for(reason, '')
        if motion is not None and motion.done():
            return False
        try:
            coverage, max_std, *further = await peek()
        except IterationStopped as exc:
            if waits.ending():   # a cancel or the procedure's deadline ends it here
                raise
            warn(f'no sweep progress from the field_estimator ({exc}); the sweep goes on')
            continue
        report(coverage, max_std)
        message = enough(clock() - t0, coverage, max_std, *further)
        if message:
            info(message)
            return True


def discarded_text(problem: str, stays: str) -> str:
    """Why a sweep is discarded: the fans' ``problem`` during it, and what stays (``stays``)."""
    return (f'sweep discarded: {problem} (fan_output restarted, the autopilot link dropped, or an '
            f'emergency stop?); {stays}')


__all__ = ['SweepJudge', 'SweepSpan', 'discarded_text', 'peek_figures', 'required', 'sweep_span',
           'watch_sweep']
