"""Faults in time: effects that change as the recording goes on, not with where the plate is.

Every other effect gives the same force at the same commands and place whenever it is measured;
these two do not, and no term of position and commands can describe them:

* ``SensorZeroDrift``: the force sensor's zero moves over the recording (a strain-gauge sensor
  warming up, a cable pulling): a slow linear drift, optionally with a random walk on top;
* ``UnsettledFans``: the fans reach a new command through a first-order lag, and each sweep
  starts before they have settled, so its first seconds read the previous commands.

They act through the plant's time hooks (``HiddenEffect.sensor_zero`` and ``.running``): the
plant keeps a recording clock [s] that each sweep advances by its own length, and the commands
in force before the last change. Held-plate measurements (``measure_at``, the commissioning
batch) and ``true_field`` do not see them: they are faults of a recording, not of the flow.
Forces [N], times [s], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .effects import HiddenEffect, register_effects

__all__ = ['SensorZeroDrift', 'UnsettledFans', 'TIME_FAULTS']


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


#: The faults in time (sensing), written for the time checks of the diagnosis.
TIME_FAULTS = (SensorZeroDrift, UnsettledFans)

register_effects(*TIME_FAULTS)
