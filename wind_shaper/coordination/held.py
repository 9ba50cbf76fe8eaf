"""The paper's held-plate calibration batch as a guided procedure on a rig, without ROS.

``held_points`` lists the batch (``model.CalibrationPlan``): each enabled fan alone at every
level of ``plan.levels`` with the plate over its hub, then at ``plan.spread_level`` with the
plate at each offset around the hub (+-x, +-y). A point farther from the axis than the sweeps
take the plate (``sweep_radius``) is left out: the plate would reach into the tunnel wall. ``Stillness`` judges from the mocap poses whether the plate is where it
should be and still, which the coordinator waits for before it records a point.
Positions [m, tunnel frame]; commands [fraction 0..1, the tunnel's fan order]; times [s].
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ['HeldPoint', 'held_points', 'Stillness']


@dataclass(frozen=True)
class HeldPoint:
    """One point of the batch: ``label`` (unique, e.g. 'LM1 35 % over the hub'), commands ``pwm``
    (n_fans,), plate position (x, y)."""

    label: str
    pwm: tuple
    x: float
    y: float


def held_points(geometry, plan) -> tuple[list[HeldPoint], int]:
    """(the batch's points in the order to hold them, how many were left out as outside the
    tunnel)."""
    fans = geometry.fans
    limit = float(geometry.sweep_radius) + 1e-9
    points, outside = [], 0
    for j in np.flatnonzero(fans.enabled):
        name, hub = fans.names[j], np.asarray(fans.positions[j], float)
        for level in plan.levels:
            U = np.zeros(fans.n_fans)
            U[j] = level
            points.append(HeldPoint(f"{name} {100 * level:.0f} % over the hub", tuple(map(float, U)),
                                    float(hub[0]), float(hub[1])))
        U = np.zeros(fans.n_fans)
        U[j] = plan.spread_level
        for s in plan.offsets:
            for d, word in (((1, 0), '+x'), ((-1, 0), '-x'), ((0, 1), '+y'), ((0, -1), '-y')):
                p = hub + s * np.asarray(d, float)
                if np.hypot(*p) > limit:
                    outside += 1
                    continue
                points.append(HeldPoint(f'{name} {100 * plan.spread_level:.0f} %, {100 * s:.0f} cm '
                                        f'{word} of the hub', tuple(map(float, U)), float(p[0]), float(p[1])))
    return points, outside


class Stillness:
    """The plate's recent poses, and whether it is held at a target. ``add(t, x, y)`` takes each
    pose [s, m]; ``verdict(x, y, tolerance, still_s)`` is '' when every pose of the last
    ``still_s`` seconds lies within ``tolerance`` [m] of (x, y) and they spread less than
    tolerance / 2 (the plate is still), else what is wrong, in words."""

    def __init__(self, keep_s: float = 5.0):
        self.keep_s = float(keep_s)
        self._poses: deque = deque()

    def clear(self) -> None:
        self._poses.clear()

    def add(self, t: float, x: float, y: float) -> None:
        if np.isfinite(x) and np.isfinite(y):
            self._poses.append((float(t), float(x), float(y)))
        while self._poses and self._poses[0][0] < t - self.keep_s:
            self._poses.popleft()

    def verdict(self, x: float, y: float, tolerance: float, still_s: float) -> str:
        if not self._poses:
            return 'no plate pose yet (is the mocap tracking the plate?)'
        last = self._poses[-1][0]
        recent = np.array([p[1:] for p in self._poses if p[0] >= last - still_s])
        span = self._poses[-1][0] - self._poses[0][0]
        off = float(np.max(np.hypot(recent[:, 0] - x, recent[:, 1] - y)))
        if off > tolerance:
            here = recent[-1]
            return (f'the plate is {100 * float(np.hypot(here[0] - x, here[1] - y)):.1f} cm from the '
                    f'point (at ({here[0]:+.3f}, {here[1]:+.3f}) m; tolerance {100 * tolerance:.1f} cm)')
        if span < still_s:
            return f'holding still for {still_s:g} s'
        spread = float(np.max(np.ptp(recent, axis=0)))
        if spread > 0.5 * tolerance:
            return f'the plate moves ({100 * spread:.1f} cm in {still_s:g} s): hold it still'
        return ''
