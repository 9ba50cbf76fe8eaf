"""Unmodelled effects on the measurement rather than the flow: the plate's drag law and a
motion capture out of step with the force sensor. Registered, with the others, by
``wind_shaper.sim.unmodelled_effects``.

Forces [N], times [s], positions [m, tunnel frame].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..core.tunnel import path_at
from .effects import HiddenEffect

__all__ = ['DragLaw', 'MocapLatency']


@dataclass(frozen=True)
class DragLaw(HiddenEffect):
    """The plate's drag coefficient falls as the air speeds up (its Reynolds number grows), so
    the force it takes up grows more slowly than the flow's dynamic pressure. With F the force
    a plate of constant drag coefficient would take up [N],

        F' = F (max(|F|, floor) / force_ref)^(-exponent / 2)

    (Cd ~ Re^-exponent, Re ~ speed ~ sqrt(F)); F' = F at ``force_ref``. It acts on the local
    force, whichever fans make it: not on one fan's thrust curve, not on where jets land."""

    exponent: float = 0.25
    force_ref: float = 2.0
    floor: float = 0.05
    name: ClassVar[str] = 'drag_law'
    bounds: ClassVar = {'exponent': (0.0, 0.8), 'force_ref': (0.1, 50.0), 'floor': (0.001, 1.0)}

    def reading(self, force, geometry):
        if self.exponent == 0:
            return force
        size = np.maximum(np.abs(force), self.floor) / self.force_ref
        return force * size ** (-0.5 * self.exponent)


@dataclass(frozen=True)
class MocapLatency(HiddenEffect):
    """Motion capture and the force sensor are out of step: each force sample is recorded with
    the plate's position ``lag`` [s] earlier (the path is held at its start before that). The
    field is unchanged; a sweep's force map is smeared and shifted along the plate's own path,
    which no term of position and commands can describe."""

    lag: float = 0.04
    name: ClassVar[str] = 'mocap_latency'
    bounds: ClassVar = {'lag': (0.0, 0.5)}

    def recorded(self, positions, dt):
        if self.lag == 0 or len(positions) < 2:
            return positions
        t = np.arange(len(positions)) * dt
        return path_at(t, positions, t - self.lag)
