"""What the shaping loop needs from a tunnel, real or simulated, and the data it returns.

The simulator (``wind_shaper.sim``) and the hardware bridge (the ROS node graph) both satisfy
``Tunnel``, so the loop code is the same for both.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .errors import SweepError
from .geometry import TunnelGeometry


def path_at(times, positions, when) -> np.ndarray:
    """A path sampled at ``times`` (n,) [s] as ``positions`` (n, 2) [m], read at ``when`` (K,)
    [s]: linear between samples, held at the ends."""
    return np.column_stack([np.interp(when, times, positions[:, k]) for k in range(2)])


@dataclass(frozen=True)
class Sweep:
    """One sweep of the force plate at fixed fan commands.

    positions: (M, 2) plate centre [m, tunnel frame]; forces: (M,) vertical force on the plate
    [N]; times: (M,) [s] since the sweep started; pwm: (n_fans,) commands in force during the
    sweep [fraction 0..1].
    """

    positions: np.ndarray
    forces: np.ndarray
    times: np.ndarray
    pwm: np.ndarray

    def __post_init__(self):
        pos = np.asarray(self.positions, dtype=float)
        frc = np.asarray(self.forces, dtype=float)
        tim = np.asarray(self.times, dtype=float)
        pwm = np.asarray(self.pwm, dtype=float)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise SweepError(f'sweep positions must be (M, 2); got {pos.shape}')
        if frc.shape != (len(pos),) or tim.shape != (len(pos),):
            raise SweepError(f'sweep has {len(pos)} positions but forces {frc.shape} and '
                             f'times {tim.shape}: every sample needs a position, force and time')
        for name, arr in (('positions', pos), ('forces', frc), ('times', tim), ('pwm', pwm)):
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return len(self.forces)

    def finite(self) -> 'Sweep':
        """The samples whose position and force are finite (NaN/inf dropped)."""
        ok = np.all(np.isfinite(self.positions), axis=1) & np.isfinite(self.forces)
        return Sweep(self.positions[ok], self.forces[ok], self.times[ok], self.pwm)

    @property
    def duration_s(self) -> float:
        """Plate time of the sweep [s]: first to last sample plus one sample period."""
        if len(self.times) < 2:
            return 0.0
        return float(self.times[-1] - self.times[0] + np.median(np.diff(self.times)))

    @staticmethod
    def concatenate(parts) -> 'Sweep':
        """The samples of consecutive parts of one sweep at the same commands, in order."""
        parts = list(parts)
        if not parts:
            raise SweepError('no sweep parts to join')
        return Sweep(np.vstack([p.positions for p in parts]), np.concatenate([p.forces for p in parts]),
                     np.concatenate([p.times for p in parts]), parts[0].pwm)

    def positions_at(self, when) -> np.ndarray:
        """The plate's path (K, 2) [m] at times ``when`` (K,) [s], linear between samples and
        held at the sweep's ends."""
        return path_at(self.times, self.positions, when)

    def to_measurements(self) -> 'Measurements':
        return Measurements(np.tile(self.pwm, (len(self), 1)), self.positions, self.forces)


@dataclass(frozen=True)
class Measurements:
    """Force samples at known commands, pooled from sweeps or calibration.

    pwm: (M, n_fans) commands [fraction]; positions: (M, 2) [m]; forces: (M,) [N].
    """

    pwm: np.ndarray
    positions: np.ndarray
    forces: np.ndarray

    def __post_init__(self):
        pwm = np.atleast_2d(np.asarray(self.pwm, dtype=float))
        pos = np.asarray(self.positions, dtype=float).reshape(-1, 2)
        frc = np.asarray(self.forces, dtype=float).ravel()
        if not (len(pwm) == len(pos) == len(frc)):
            raise SweepError(f'measurements disagree in length: pwm {len(pwm)}, positions '
                             f'{len(pos)}, forces {len(frc)}')
        object.__setattr__(self, 'pwm', pwm)
        object.__setattr__(self, 'positions', pos)
        object.__setattr__(self, 'forces', frc)

    def __len__(self) -> int:
        return len(self.forces)

    @staticmethod
    def concatenate(parts) -> 'Measurements':
        parts = list(parts)
        if not parts:
            raise SweepError('no measurements to pool')
        return Measurements(np.vstack([p.pwm for p in parts]),
                            np.vstack([p.positions for p in parts]),
                            np.concatenate([p.forces for p in parts]))


@runtime_checkable
class Tunnel(Protocol):
    """A tunnel the loop can drive: set commands, sweep the plate, hold the plate still."""

    geometry: TunnelGeometry

    def apply(self, pwm: np.ndarray) -> np.ndarray:
        """Command the fans [fraction 0..1 per fan]; returns what was really applied."""

    def sweep(self, n_samples: int = 1000) -> Sweep:
        """Move the plate along a path over the operating area and record force and pose."""

    def measure_at(self, positions: np.ndarray, samples_per_point: int = 20) -> np.ndarray:
        """Hold the plate at each position (K, 2) [m] and return the mean force (K,) [N]."""
