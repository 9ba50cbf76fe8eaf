"""Measurement noise of the simulated tunnel: turbulence on the force, motion-capture jitter.

A measured force is F = F_true * (1 + relative * xi_m) + absolute * xi_a [N], where xi_m and
xi_a are independent zero-mean unit-variance series, each a mix of white noise and an AR(1)
process of correlation time ``correlation_time`` [s] (turbulent gusts last ~0.1 s, so
neighbouring 50 Hz samples are correlated). The mocap position adds N(0, position_sd) [m] per
axis; ``dropout`` is the fraction of samples the mocap loses (position NaN).

Optional kinds, off by default (the field estimator's noise model is not built around them, so
they test it on noise it was not designed for; sweeps and ``measure_at``, not the live stream):
``gusts: two_scale`` splits the correlated share evenly between AR(1) series of
``correlation_time`` and of ``slow_time`` [s]; ``gusts: von_karman`` makes the correlated share
broadband turbulence, a von Karman spectrum S(f) ~ (1 + (f / f0)^2)^(-5/6) with f0 = 1 / (2 pi
slow_time) (eddies up to an integral time ``slow_time`` [s], a -5/3 inertial range above them: no
single correlation time describes it); ``tails`` > 2 makes the white share Student-t with
that many degrees of freedom (heavy-tailed turbulence, still unit variance); ``exponent`` != 1
makes the turbulence sd relative * force_ref * (F / force_ref)^exponent [N]; ``drift`` [N] adds
a slow zero drift of the sensor: a random walk reaching sd ``drift`` after 20 s.
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
    gusts: str = 'ar1'
    slow_time: float = 1.0
    tails: float = 0.0
    exponent: float = 1.0
    force_ref: float = 2.5
    drift: float = 0.0

    def __post_init__(self):
        if self.gusts not in ('ar1', 'two_scale', 'von_karman'):
            raise ConfigError(f'noise gusts must be ar1, two_scale or von_karman; got {self.gusts!r}')
        if not (self.tails == 0 or self.tails > 2):
            raise ConfigError(f'noise tails must be 0 (Gaussian) or > 2 degrees of freedom; got {self.tails}')
        if not (self.exponent > 0 and self.force_ref > 0):
            raise ConfigError(f'noise exponent and force_ref must be > 0; got {self.exponent}, {self.force_ref}')
        for key in ('relative', 'absolute', 'correlation_time', 'position_sd', 'slow_time', 'drift'):
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
            return cls(**{k: (str(v) if k == 'gusts' else float(v)) for k, v in dict(cfg or {}).items()})
        except (TypeError, ValueError) as exc:
            raise ConfigError(f'bad noise config: {exc}; keys are relative, absolute, '
                              f'correlation_time, correlated_fraction, position_sd, dropout, gusts, '
                              f'slow_time, tails, exponent, force_ref, drift') from None

    # -- draws -----------------------------------------------------------------------------------
    def unit_series(self, n: int, dt: float, rng: np.random.Generator, width: int = 1) -> np.ndarray:
        """(n, width) zero-mean unit-variance noise along axis 0 (time step ``dt`` [s]): a
        stationary AR(1) share ``correlated_fraction`` plus white noise."""
        white = rng.standard_normal((n, width))
        if self.tails:
            white = rng.standard_t(self.tails, (n, width)) * np.sqrt((self.tails - 2) / self.tails)
        if self.correlated_fraction == 0 or self.correlation_time == 0:
            return white
        if self.gusts == 'von_karman':
            ar = self._von_karman(n, dt, self.slow_time, rng, width)
        else:
            ar = self._ar1(n, dt, self.correlation_time, rng, width)
        if self.gusts == 'two_scale':
            ar = np.sqrt(0.5) * (ar + self._ar1(n, dt, self.slow_time, rng, width))
        f = self.correlated_fraction
        return np.sqrt(f) * ar + np.sqrt(1 - f) * white

    @staticmethod
    def _ar1(n, dt, tau, rng, width):
        """(n, width) stationary unit-variance AR(1) of correlation time tau [s]."""
        phi = float(np.exp(-dt / tau)) if tau > 0 else 0.0
        start = rng.standard_normal((1, width))  # stationary initial state
        return lfilter([np.sqrt(1 - phi * phi)], [1.0, -phi], rng.standard_normal((n, width)),
                       axis=0, zi=phi * start)[0]

    @staticmethod
    def _von_karman(n, dt, integral_time, rng, width):
        """(n, width) unit-variance Gaussian series with a von Karman spectrum (spectral synthesis
        on a record twice as long, so that its circular wrap stays out of the n samples)."""
        m = 2 * n
        f = np.fft.rfftfreq(m, dt)
        amplitude = (1.0 + (2.0 * np.pi * integral_time * f) ** 2) ** (-5.0 / 12.0)
        amplitude[0] = 0.0                               # zero mean
        spectrum = (rng.standard_normal((len(f), width)) + 1j * rng.standard_normal((len(f), width)))
        series = np.fft.irfft(spectrum * amplitude[:, None], n=m, axis=0)[:n]
        expected = np.sqrt(2.0 * np.sum(amplitude ** 2) - amplitude[-1] ** 2) / m * np.sqrt(2.0)
        return series / expected

    def forces(self, true: np.ndarray, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Noisy forces for a true force array (n,) or (n, k) along time axis 0 [N]."""
        true = np.asarray(true, dtype=float)
        if self.relative == 0 and self.absolute == 0 and self.drift == 0:
            return true.copy()
        shape = true.shape
        t2 = true.reshape(shape[0], -1)
        xi_m = self.unit_series(shape[0], dt, rng, t2.shape[1])
        xi_a = self.unit_series(shape[0], dt, rng, t2.shape[1])
        if self.exponent == 1:
            out = t2 * (1 + self.relative * xi_m) + self.absolute * xi_a
        else:
            out = t2 + self._scale(t2) * self.relative * xi_m + self.absolute * xi_a
        if self.drift:
            steps = rng.standard_normal(t2.shape) * self.drift * np.sqrt(dt / 20.0)
            out += np.cumsum(steps, axis=0)
        return out.reshape(shape)

    def _scale(self, true):
        """What the relative turbulence multiplies [N]: the force, or force_ref (F/force_ref)^exponent."""
        if self.exponent == 1:
            return true
        return np.sign(true) * self.force_ref * (np.abs(true) / self.force_ref) ** self.exponent

    def sd(self, true) -> np.ndarray:
        """Per-sample noise sd [N] for true forces [N] (the drift excluded)."""
        true = np.asarray(true, dtype=float)
        return np.sqrt((self.relative * self._scale(true)) ** 2 + self.absolute ** 2)

    def positions(self, positions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Mocap readings of true positions (n, 2) [m]: jitter plus dropouts (NaN)."""
        out = np.array(positions, dtype=float)
        if self.position_sd > 0:
            out += self.position_sd * rng.standard_normal(out.shape)
        if self.dropout > 0:
            out[rng.random(len(out)) < self.dropout] = np.nan
        return out
