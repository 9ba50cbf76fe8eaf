"""Is what the model leaves on the held-out sweeps more than the measurement noise? A test.

A model that is right leaves held-out residuals r = measured - model that are the noise alone,
so their mean square over the held-out samples is the noise variance sigma^2 up to chance. The
statistic is the ratio

    T = mean(r^2) / sigma^2

and under "the residual is noise" n_eff T follows a chi-square law with n_eff degrees of freedom
(sigma given: ``--noise-sd``), or T an F(n_eff, m) law when sigma^2 was estimated from the
sweeps' revisits with m effective degrees of freedom (m = 2 / (relative standard error of the
noise variance)^2, from ``metrics.HeldOut.resolution``). The model explains the sweeps to the
noise level when T is below the law's 95th percentile (``level``).

n_eff: turbulence lasts longer than one sample (gusts of ~0.1 s at 50 Hz), so neighbouring
samples are not independent. The noise's autocorrelation at lag k is read off the residual's
semivariogram, rho_k = 1 - gamma_k / sigma^2 with gamma_k = mean((r_{t+k} - r_t)^2) / 2 within
each sweep: a model error changes little over a few samples (the plate moves millimetres), so
gamma_k at short lags is the noise's, whatever the model misses. The mean of r^2 then has the
variance of n / (1 + 2 sum_k rho_k^2) independent squares (Bartlett's formula for squares of a
Gaussian series), so n_eff = n / (1 + 2 sum_k rho_k^2), summed over lags 1..``max_lag`` until
rho_k falls below 0.05.

``floor`` [N] is the smallest model error the test can tell from none, sigma sqrt(bound - 1):
a smaller one is printed "at the noise level", never 0.000 N. Forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

__all__ = ['NoiseFloor', 'noise_floor_test', 'effective_samples']


@dataclass(frozen=True)
class NoiseFloor:
    """ratio: mean(r^2) / sigma^2 on the held-out samples; bound: its ``level`` percentile when
    the residual is noise; n: samples, n_eff: effectively independent ones; noise_df: the noise
    variance's degrees of freedom (inf when given); noise_sd [N]; within: ratio <= bound;
    floor [N]: the smallest model error the test resolves."""

    ratio: float
    bound: float
    n: int
    n_eff: float
    noise_df: float
    noise_sd: float
    level: float = 0.95

    @property
    def within(self) -> bool:
        return bool(self.ratio <= self.bound)

    @property
    def floor(self) -> float:
        return float(self.noise_sd * np.sqrt(max(self.bound - 1.0, 0.0)))

    def law(self) -> str:
        if np.isfinite(self.noise_df):
            return f'F({self.n_eff:.0f}, {self.noise_df:.0f})'
        return f'chi-square({self.n_eff:.0f}) / {self.n_eff:.0f}'

    def text(self) -> str:
        """The test in words, for the verdict."""
        verdict = 'within' if self.within else 'above'
        return (f'the held-out residual\'s mean square is {self.ratio:.2f} x the noise variance, '
                f'{verdict} the {100 * self.level:.0f} % bound {self.bound:.2f} for noise alone '
                f'({self.law()}: {self.n} samples, {self.n_eff:.0f} effectively independent)')

    def to_json(self) -> dict:
        return {'ratio': round(self.ratio, 4), 'bound': round(self.bound, 4), 'n': self.n,
                'n_eff': round(self.n_eff, 1),
                'noise_df': None if not np.isfinite(self.noise_df) else round(self.noise_df, 1),
                'level': self.level, 'within': self.within, 'floor_N': round(self.floor, 5)}


def effective_samples(residual: np.ndarray, sweep: np.ndarray, noise_var: float,
                      max_lag: int = 50) -> float:
    """n / (1 + 2 sum_k rho_k^2) for the residual (M,) in time order within each sweep (M,),
    rho_k from its semivariogram against the noise variance (see the module docstring)."""
    n = len(residual)
    if n < 3 or noise_var <= 0:
        return float(max(n, 1))
    starts = np.flatnonzero(np.r_[True, sweep[1:] != sweep[:-1]])
    bounds = list(zip(starts, np.r_[starts[1:], n]))
    total = 0.0
    for k in range(1, max_lag + 1):
        diffs = [residual[a + k:b] - residual[a:b - k] for a, b in bounds if b - a > k]
        if not diffs:
            break
        d = np.concatenate(diffs)
        rho = 1.0 - 0.5 * float(np.mean(d * d)) / noise_var
        if rho < 0.05:
            break
        total += min(rho, 1.0) ** 2
    return float(np.clip(n / (1.0 + 2.0 * total), min(len(bounds), n), n))


def noise_floor_test(residual: np.ndarray, sweep: np.ndarray, noise_sd: float, *,
                     resolution: float = float('nan'), level: float = 0.95) -> NoiseFloor:
    """The test of the held-out ``residual`` (M,) [N] (raw samples, time order within each
    ``sweep`` (M,)) against the noise ``noise_sd`` [N]; ``resolution`` [N]: the noise estimate's
    (``metrics.HeldOut.resolution``: two standard errors of the noise variance, sqrt'd), NaN
    when the noise was given."""
    residual = np.asarray(residual, float)
    var = float(noise_sd) ** 2
    n = len(residual)
    ratio = float(np.mean(residual ** 2)) / var if n and var > 0 else float('nan')
    n_eff = effective_samples(residual, np.asarray(sweep), var)
    se = resolution ** 2 / 2 if np.isfinite(resolution) else 0.0
    noise_df = 2.0 * (var / se) ** 2 if se > 0 else float('inf')
    if np.isfinite(noise_df):
        bound = float(stats.f.ppf(level, n_eff, noise_df))
    else:
        bound = float(stats.chi2.ppf(level, n_eff) / n_eff)
    return NoiseFloor(ratio, bound, n, n_eff, noise_df, float(noise_sd), level)
