"""Unmodelled effects on the measurement rather than the flow: the plate's drag law and a
motion capture out of step with the force sensor; and the faults in time, which change as the
recording goes on rather than with where the plate is: the force sensor's zero drifting
(``SensorZeroDrift``) and fans that had not settled when a sweep began (``UnsettledFans``).
Registered, with the others, by ``wind_shaper.sim.unmodelled_effects``.

The faults in time act through the plant's time hooks (``HiddenEffect.sensor_zero`` and
``.running``): the plant keeps a recording clock [s] that each sweep advances by its own length,
and the commands in force before the last change. Held-plate measurements (``measure_at``, the
commissioning batch) and ``true_field`` do not see them: they are faults of a recording, not of
the flow.

Forces [N], times [s], positions [m, tunnel frame].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..core.tunnel import path_at
from .effects import HiddenEffect

__all__ = ['DragLaw', 'MocapLatency', 'SensorZeroDrift', 'UnsettledFans']


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


@dataclass(frozen=True)
class SensorZeroDrift(HiddenEffect):
    """The force sensor's zero moves with recording time t [s] (the plant's clock: the sweeps'
    plate time laid end to end):

        zero(t) = rate * t + walk * W(t)      [N]

    W a standard Wiener process fixed by ``walk_seed`` (so every sweep of one tunnel sees one
    path). The default, 0.002 N/s, is 0.04 N per 20 s sweep: 0.44 N between the first and the
    last sweep of twelve. Every recorded force carries the zero of its own moment, with the fans
    on or off."""

    rate: float = 0.002
    walk: float = 0.0
    walk_seed: int = 0
    name: ClassVar[str] = 'sensor_zero_drift'
    bounds: ClassVar = {'rate': (-0.1, 0.1), 'walk': (0.0, 0.5), 'walk_seed': (0, 2 ** 31)}

    def sensor_zero(self, clock):
        clock = np.asarray(clock, float)
        zero = self.rate * clock
        if self.walk > 0 and len(clock):
            zero = zero + self.walk * _wiener(clock, int(self.walk_seed))
        return zero


def _wiener(t: np.ndarray, seed: int, step: float = 0.5) -> np.ndarray:
    """A standard Wiener process at times ``t`` [s] (>= 0), on a fixed ``step`` [s] grid
    linearly interpolated; the grid's draws come in one order, so a longer recording extends
    the same path."""
    n = int(np.ceil(max(float(np.max(t)), 0.0) / step)) + 2
    steps = np.random.default_rng(seed).standard_normal(n) * np.sqrt(step)
    path = np.concatenate([[0.0], np.cumsum(steps)])
    return np.interp(t, step * np.arange(len(path)), path)


@dataclass(frozen=True)
class UnsettledFans(HiddenEffect):
    """Each fan follows its command through a first-order lag of time constant ``tau`` [s]
    (the rotor's inertia against the ESC's torque), and the recording starts ``wait`` [s] after
    the command changed: during a sweep, at time s [s] since the change,

        u(s) = u_new + (u_old - u_new) exp(-s / tau).

    The default, 1.5 s and no wait, leaves 13 % of the old command after 3 s. Sweeps at the
    same commands as the one before are not affected."""

    tau: float = 1.5
    wait: float = 0.0
    name: ClassVar[str] = 'unsettled_fans'
    bounds: ClassVar = {'tau': (0.0, 20.0), 'wait': (0.0, 60.0)}

    def running(self, previous, commanded, since):
        if self.tau == 0:
            return None
        left = np.exp(-(np.asarray(since, float) + self.wait) / self.tau)
        return commanded[None, :] + (previous - commanded)[None, :] * left[:, None]
