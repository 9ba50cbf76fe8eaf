"""Measurement noise of the simulated tunnel: turbulence on the force, motion-capture jitter.

A measured force is F = F_true * (1 + relative * xi_m) + absolute * xi_a [N], where xi_m and
xi_a are independent zero-mean unit-variance series, each a mix of white noise and an AR(1)
process of correlation time ``correlation_time`` [s] (turbulent gusts last ~0.1 s, so
neighbouring 50 Hz samples are correlated). The mocap position adds N(0, position_sd) [m] per
axis; ``dropout`` is the fraction of samples the mocap loses (position NaN).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.signal import lfilter

from ..core.errors import ConfigError


@dataclass(frozen=True)
class NoiseModel:
    """Noise levels. relative: sd of the multiplicative turbulence [fraction of the force];
    absolute: sd of the additive noise [N]; correlation_time [s]; correlated_fraction: share
    of each noise variance that is AR(1) (the rest is white); position_sd: mocap noise [m];
    dropout: fraction 0..1 of sweep samples with a lost (NaN) position."""

    relative: float = 0.04
    absolute: float = 0.03
    correlation_time: float = 0.1
    correlated_fraction: float = 0.5
    position_sd: float = 0.0005
    dropout: float = 0.0

    def __post_init__(self):
        for key in ('relative', 'absolute', 'correlation_time', 'position_sd'):
            if not (np.isfinite(getattr(self, key)) and getattr(self, key) >= 0):
                raise ConfigError(f'noise {key} must be finite and >= 0; got {getattr(self, key)}')
        for key in ('correlated_fraction', 'dropout'):
            if not 0 <= getattr(self, key) <= 1:
                raise ConfigError(f'noise {key} must be in [0, 1]; got {getattr(self, key)}')

    @classmethod
    def zero(cls) -> 'NoiseModel':
        """No noise at all: measurements equal the true field at the true positions."""
        return cls(relative=0.0, absolute=0.0, position_sd=0.0)

    @classmethod
    def from_config(cls, cfg: Mapping | None) -> 'NoiseModel':
        """A mapping of the fields above (missing keys keep their defaults); ``'zero'`` for none."""
        if cfg in ('zero', 'none', False):
            return cls.zero()
        try:
            return cls(**{k: float(v) for k, v in dict(cfg or {}).items()})
        except TypeError as exc:
            raise ConfigError(f'bad noise config: {exc}; keys are relative, absolute, '
                              f'correlation_time, correlated_fraction, position_sd, dropout') from None

    # -- draws -----------------------------------------------------------------------------------
    def unit_series(self, n: int, dt: float, rng: np.random.Generator, width: int = 1) -> np.ndarray:
        """(n, width) zero-mean unit-variance noise along axis 0 (time step ``dt`` [s]): a
        stationary AR(1) share ``correlated_fraction`` plus white noise."""
        white = rng.standard_normal((n, width))
        if self.correlated_fraction == 0 or self.correlation_time == 0:
            return white
        phi = float(np.exp(-dt / self.correlation_time))
        start = rng.standard_normal((1, width))  # stationary initial state
        ar = lfilter([np.sqrt(1 - phi * phi)], [1.0, -phi], rng.standard_normal((n, width)),
                     axis=0, zi=phi * start)[0]
        f = self.correlated_fraction
        return np.sqrt(f) * ar + np.sqrt(1 - f) * white

    def forces(self, true: np.ndarray, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Noisy forces for a true force array (n,) or (n, k) along time axis 0 [N]."""
        true = np.asarray(true, dtype=float)
        if self.relative == 0 and self.absolute == 0:
            return true.copy()
        shape = true.shape
        t2 = true.reshape(shape[0], -1)
        xi_m = self.unit_series(shape[0], dt, rng, t2.shape[1])
        xi_a = self.unit_series(shape[0], dt, rng, t2.shape[1])
        return (t2 * (1 + self.relative * xi_m) + self.absolute * xi_a).reshape(shape)

    def sd(self, true) -> np.ndarray:
        """Per-sample noise sd [N] for true forces [N]."""
        true = np.asarray(true, dtype=float)
        return np.sqrt((self.relative * true) ** 2 + self.absolute ** 2)

    def positions(self, positions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Mocap readings of true positions (n, 2) [m]: jitter plus dropouts (NaN)."""
        out = np.array(positions, dtype=float)
        if self.position_sd > 0:
            out += self.position_sd * rng.standard_normal(out.shape)
        if self.dropout > 0:
            out[rng.random(len(out)) < self.dropout] = np.nan
        return out
