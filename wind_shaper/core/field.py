"""Field estimation: GET_CLOSEST subsampling of a sweep and Gaussian-process regression.

Positions are plate centres [m, tunnel frame]; forces are vertical plate forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, LinAlgError
from scipy.spatial import cKDTree

from .errors import ConfigError, SweepError
from .tunnel import Sweep


def get_closest(sample_positions: np.ndarray, key_points: np.ndarray) -> np.ndarray:
    """Index of the sample nearest to each key point (the paper's GET_CLOSEST).

    sample_positions: (M, 2) [m]; key_points: (N, 2) [m]. Returns (N,) indices into the
    samples. Two key points may share a sample; ``closest_samples`` drops such repeats.
    """
    sample_positions = np.asarray(sample_positions, dtype=float)
    if len(sample_positions) == 0:
        raise SweepError('the sweep has no samples: record a sweep before estimating the field')
    _, idx = cKDTree(sample_positions).query(np.asarray(key_points, dtype=float))
    return np.asarray(idx, dtype=int)


@dataclass(frozen=True)
class Subsample:
    """The samples picked for the GP. positions (n, 2) [m], forces (n,) [N], and for each key
    point the distance [m] to its nearest sample (coverage)."""

    positions: np.ndarray
    forces: np.ndarray
    key_distance: np.ndarray


def closest_samples(sweep: Sweep, key_points: np.ndarray) -> Subsample:
    """GET_CLOSEST on a sweep: finite samples only, each picked sample used once."""
    clean = sweep.finite()
    if len(clean) == 0:
        raise SweepError(f'none of the sweep\'s {len(sweep)} samples is finite: check the force '
                         f'sensor and motion-capture streams')
    idx = get_closest(clean.positions, key_points)
    dist = np.linalg.norm(clean.positions[idx] - key_points, axis=1)
    unique = np.unique(idx)
    return Subsample(clean.positions[unique], clean.forces[unique], dist)


class GaussianProcessField:
    """GP regression of the force field with a squared-exponential kernel.

    k(z1, z2) = signal_std^2 exp(-|z1 - z2|^2 / (2 length_scale^2)) + noise_std^2 [z1 == z2].
    length_scale [m] (paper: 0.10, half the plate side); noise_std [N] (turbulence on single
    samples); signal_std [N], when None, is taken from the data's spread. The prior mean is
    the data's mean (the paper's zero mean would pull the field to 0 away from samples).

    ``fit(positions, forces)`` returns self; fitted state ends in ``_``.
    """

    def __init__(self, length_scale: float = 0.10, noise_std: float = 0.05,
                 signal_std: float | None = None):
        if not length_scale > 0:
            raise ConfigError(f'GP length_scale must be > 0 m, got {length_scale}')
        if not noise_std >= 0:
            raise ConfigError(f'GP noise_std must be >= 0 N, got {noise_std}')
        if signal_std is not None and not signal_std > 0:
            raise ConfigError(f'GP signal_std must be > 0 N or None, got {signal_std}')
        self.length_scale = length_scale
        self.noise_std = noise_std
        self.signal_std = signal_std

    def kernel(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """Signal covariance between point sets A (n, 2) and B (m, 2) [N^2]."""
        sq = (np.sum(A * A, 1)[:, None] + np.sum(B * B, 1)[None, :] - 2.0 * A @ B.T)
        np.maximum(sq, 0.0, out=sq)
        return self.signal_var_ * np.exp(-sq / (2.0 * self.length_scale ** 2))

    def fit(self, positions: np.ndarray, forces: np.ndarray) -> 'GaussianProcessField':
        X = np.asarray(positions, dtype=float).reshape(-1, 2)
        y = np.asarray(forces, dtype=float).ravel()
        if len(X) != len(y):
            raise SweepError(f'{len(X)} positions but {len(y)} forces')
        if len(y) < 3:
            raise SweepError(f'only {len(y)} samples: a field estimate needs at least 3; sweep '
                             f'the plate over the whole operating area')
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
            raise SweepError('positions or forces contain NaN or inf: drop those samples first')
        self.X_ = X
        self.mean_ = float(np.mean(y))
        spread = float(np.std(y))
        self.signal_var_ = (self.signal_std if self.signal_std is not None
                            else max(spread, 1e-3)) ** 2
        K = self.kernel(X, X)
        # A floor on the diagonal keeps near-duplicate positions from making K singular.
        jitter = max(self.noise_std ** 2, 1e-8 * self.signal_var_)
        K[np.diag_indices_from(K)] += jitter
        try:
            self.chol_ = cho_factor(K, lower=True, check_finite=False)
        except LinAlgError:
            raise SweepError('the GP covariance is singular (many samples at the same place): '
                             'raise noise_std or sweep over more distinct positions') from None
        self.alpha_ = cho_solve(self.chol_, y - self.mean_, check_finite=False)
        return self

    def predict(self, points: np.ndarray, return_std: bool = False):
        """Posterior mean (K,) [N] at points (K, 2) [m], and its standard deviation [N]."""
        if not hasattr(self, 'alpha_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces) first')
        Q = np.asarray(points, dtype=float).reshape(-1, 2)
        Ks = self.kernel(Q, self.X_)
        mean = self.mean_ + Ks @ self.alpha_
        if not return_std:
            return mean
        v = cho_solve(self.chol_, Ks.T, check_finite=False)
        var = self.signal_var_ - np.einsum('ij,ji->i', Ks, v)
        return mean, np.sqrt(np.maximum(var, 0.0))


@dataclass(frozen=True)
class FieldEstimate:
    """The estimated field at the key points: mean and std (N,) [N], coverage (N,) [m]."""

    key_points: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    key_distance: np.ndarray
    n_used: int


@dataclass(frozen=True)
class FieldEstimator:
    """Sweep -> field at the key points, with the checks a lab needs before trusting it.

    min_samples: fewer finite samples than this is an error; max_gap [m]: a key point whose
    nearest sample is farther than this means the sweep missed part of the area.
    """

    length_scale: float = 0.10
    noise_std: float = 0.05
    signal_std: float | None = None
    min_samples: int = 50
    max_gap: float = 0.08

    def estimate(self, sweep: Sweep, key_points: np.ndarray) -> FieldEstimate:
        clean = sweep.finite()
        if len(clean) < self.min_samples:
            raise SweepError(f'the sweep has {len(clean)} usable samples (of {len(sweep)}); at least '
                             f'{self.min_samples} are needed: sweep longer or check the streams')
        sub = closest_samples(clean, key_points)
        far = sub.key_distance > self.max_gap
        if np.any(far):
            worst = int(np.argmax(sub.key_distance))
            raise SweepError(
                f'the sweep missed {int(far.sum())} of {len(key_points)} key points (nearest sample '
                f'farther than {self.max_gap} m; worst {sub.key_distance[worst]:.3f} m at '
                f'{np.round(key_points[worst], 3).tolist()}): sweep the plate over the whole area')
        gp = GaussianProcessField(self.length_scale, self.noise_std, self.signal_std)
        gp.fit(sub.positions, sub.forces)
        mean, std = gp.predict(key_points, return_std=True)
        return FieldEstimate(np.asarray(key_points, float), mean, std, sub.key_distance, len(sub.forces))
