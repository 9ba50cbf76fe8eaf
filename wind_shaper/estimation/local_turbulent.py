"""The turbulent GP solved tile by tile: a calibrated std on fan walls too large for one GP.

Same model as ``estimation.turbulent`` (noise sd sqrt(absolute^2 + (relative F)^2), a share of
it in gusts correlated over sample time, a squared-exponential field), split the way
``LocalGaussianProcessField`` splits the white GP: the query area is cut into square tiles and
each tile's posterior uses only the samples near it, with their full turbulent noise covariance
(force-dependent sd and the gust correlation over their sample times). A gust is local in time,
and in space along the plate's path, so the samples of a tile carry nearly all that is known of
the gusts that touched it.

Positions [m, tunnel frame], forces [N], times [s].
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy.linalg import LinAlgError, cho_solve, solve_triangular
from scipy.spatial import cKDTree

from ..core.errors import ConfigError, SweepError
from .tiles import tiles
from .turbulent import (TurbulenceParameters, TurbulentGaussianProcessField, _cholesky, _Design,
                        _runs, fit_turbulence, gust_noise_cov, local_level)

#: samples per run when the fit's likelihood is exact (block 0): the runs of ``fit_subset`` and
#: of the force level (an exact solve over a whole large wall is what this class avoids)
EXACT_BLOCK_RUN = 80

#: samples farther apart in time than this many gust times share no gust worth keeping (their
#: correlation is below e^-25 ~ 1e-11)
GUST_REACH = 25.0


class _TileDesign(_Design):
    """A tile's samples (in time order): the noise covariance is built pass by pass. The plate
    crosses a tile many times, each pass far in time from the next, so the gust correlation
    is block diagonal over the passes; only the blocks are computed (a fraction of the
    exponentials of the whole tile's lags)."""

    def noise_cov(self, p: TurbulenceParameters, level):
        """(N, s, None): noise covariance [N^2] and per-sample sd [N] (no time kernel: only the
        likelihood's gradient needs it)."""
        s = p.noise_sd(level)
        N = np.zeros((self.n, self.n))
        # a block diagonal with principal submatrices of a covariance for blocks: positive
        # (semi)definite like the whole
        cuts = np.flatnonzero(np.diff(self.t) > GUST_REACH * p.gust_time) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, self.n]):
            N[a:b, a:b] = gust_noise_cov(p, s[a:b], self.lag[a:b, a:b])[0]
        return N, s, None


def fit_subset(n: int, run: int, max_samples: int) -> np.ndarray:
    """Indices of at most ``max_samples`` of n time-ordered samples for the hyperparameter fit:
    all of them when they fit, else ``max_samples // run`` runs of ``run`` consecutive samples
    spread evenly over the sweep (every part of the wall and of the sweep's time is seen; a run
    keeps the neighbours in time that show the gusts)."""
    if n <= max_samples:
        return np.arange(n)
    k = max(1, max_samples // run)
    starts = (np.round(np.linspace(0, n - run, k)) if k > 1 else np.array([(n - run) // 2]))
    return (starts.astype(np.int64)[:, None] + np.arange(run)[None, :]).ravel()


class LocalTurbulentGaussianProcessField(TurbulentGaussianProcessField):
    """``TurbulentGaussianProcessField`` for large areas, solved tile by tile.

    start, bounds, fit_parameters, min_fit_samples, block, max_iter: as for
    ``TurbulentGaussianProcessField``. tile [m]: side of the square tiles of query points
    (``estimation.tiles``: a fixed grid); halo [m]: each tile uses the samples within this
    distance of it. The samples beyond hold a little information, so the tiles' std is a
    little larger than the exact GP's and their means differ from its by a fraction of the std
    (on the 7-fan rig with the default 0.15 m: std up to 3 % larger, means 0.1-0.2 std apart
    RMS, 0.6 std at most);
    max_fit_samples: the hyperparameters are fitted (composite likelihood over runs of
    ``block`` samples) on at most this many samples, in runs spread evenly over the sweep
    (``fit_subset``): the composite likelihood grows linearly with the samples, but on a
    36 x 36 wall (~10,000 picked samples) fitting all of them took 1.3 s of CPU against 0.24 s
    for 2,000, and the std was as well calibrated either way (z RMS 1.03 and 0.98 on one sweep).

    ``fit(positions, forces, times)`` fits the hyperparameters, the force level of every sample
    (runs of ``block`` samples, ``local_level``) and a tree of the positions; the solves
    happen in ``predict``, one per tile (cost linear in the area, memory of one tile).
    Fitted state as for the exact GP, without its whole-sweep factor: ``params_``, ``fitted_``,
    ``evaluations_``, ``mean_`` [N], ``level_`` (n,) [N], ``fit_samples_`` (how many samples
    the fit used).
    """

    def __init__(self, start: TurbulenceParameters = TurbulenceParameters(), bounds: Mapping | None = None,
                 fit_parameters: bool = True, min_fit_samples: int = 60, block: int = 80,
                 max_iter: int = 40, tile: float = 0.20, halo: float = 0.15,
                 max_fit_samples: int = 2000, length_prior: tuple | None = None):
        super().__init__(start, bounds, fit_parameters, min_fit_samples, block, max_iter,
                         length_prior)
        if not (tile > 0 and halo >= 0):
            raise ConfigError(f'local GP needs tile > 0 and halo >= 0 [m]; got {tile}, {halo}')
        if not (isinstance(max_fit_samples, int) and max_fit_samples >= min_fit_samples):
            raise ConfigError(f'max_fit_samples must be a whole number >= min_fit_samples '
                              f'({min_fit_samples}); got {max_fit_samples!r}')
        self.tile, self.halo, self.max_fit_samples = float(tile), float(halo), max_fit_samples

    @property
    def _run(self) -> int:
        return self.block or EXACT_BLOCK_RUN

    def _fit_parameters(self, X, y, t) -> TurbulenceParameters:
        self.fitted_ = bool(self.fit_parameters and len(y) >= self.min_fit_samples)
        self.evaluations_ = 0
        p = self.start.clipped(self.bounds)
        subset = fit_subset(len(y), self._run, self.max_fit_samples)
        self.fit_samples_ = len(subset) if self.fitted_ else 0
        if self.fitted_:
            p, _, self.evaluations_ = fit_turbulence(X[subset], y[subset], t[subset], p, self.bounds,
                                                     block=self.block, max_iter=self.max_iter,
                                                     length_prior=self.length_prior)
        self.params_ = p
        return p

    def fit(self, positions, forces, times) -> 'LocalTurbulentGaussianProcessField':
        X, y, t = self._take_samples(positions, forces, times)
        p = self._fit_parameters(X, y, t)
        self.level_ = local_level(X, y, t, p, self.mean_, self._run)
        self.tree_ = cKDTree(X)
        self.log_likelihood_ = None     # the composite one is computed when asked
        return self

    def predict(self, points, return_std: bool = False):
        """Posterior mean of the field (K,) [N] at points (K, 2) [m], and its std [N]; a point
        with no sample near its tile gets the prior (the forces' mean, signal_std)."""
        if not hasattr(self, 'tree_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces, times) first')
        Q = np.asarray(points, dtype=float).reshape(-1, 2)
        p = self.params_
        mean = np.full(len(Q), self.mean_)
        std = np.full(len(Q), p.signal_std)
        for rows, near in tiles(Q, self.X_, self.tree_, self.tile, self.halo):
            if len(near) == 0:
                continue
            # near is ascending, i.e. in time order like X_: the gust lags are the samples' own
            d = _TileDesign(self.X_[near], self.y_[near], self.t_[near])
            K, _, _, _ = d.cov(p, self.level_[near])
            try:
                L = _cholesky(K)
            except LinAlgError:
                raise SweepError('the GP covariance is singular (many samples at the same place and '
                                 'time): sweep over more distinct positions') from None
            alpha = cho_solve((L, True), d.y - self.mean_, check_finite=False)
            Ks = self.kernel(Q[rows], d.X)
            mean[rows] = self.mean_ + Ks @ alpha
            if return_std:
                v = solve_triangular(L, Ks.T, lower=True, check_finite=False)
                std[rows] = np.sqrt(np.maximum(p.signal_std ** 2 - np.einsum('ij,ij->j', v, v), 0.0))
        return (mean, std) if return_std else mean

    def log_marginal_likelihood(self) -> float:
        """log p(forces | positions, times) [nats] as a composite likelihood: the sum of the
        exact log likelihoods of runs of ``block`` samples consecutive in time (the whole
        sweep's exact one is the solve this class avoids)."""
        if not hasattr(self, 'tree_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces, times) first')
        if self.log_likelihood_ is None:
            total = 0.0
            for run in _runs(len(self.y_), self._run):
                d = _Design(self.X_[run], self.y_[run], self.t_[run])
                K, _, _, _ = d.cov(self.params_, self.level_[run])
                L = _cholesky(K)
                r = d.y - self.mean_
                total += float(-0.5 * r @ cho_solve((L, True), r, check_finite=False)
                               - np.sum(np.log(np.diag(L))) - 0.5 * d.n * np.log(2 * np.pi))
            self.log_likelihood_ = total
        return self.log_likelihood_


__all__ = ['LocalTurbulentGaussianProcessField', 'fit_subset']
