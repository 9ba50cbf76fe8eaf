"""Field estimation: the samples a GP takes from a sweep (the paper's GET_CLOSEST, or every
sample averaged in short windows along the plate's path) and Gaussian-process regression.

Positions are plate centres [m, tunnel frame]; forces are vertical plate forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Mapping

import numpy as np
from scipy.linalg import cho_factor, cho_solve, LinAlgError, solve_triangular
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from ..core.errors import ConfigError, SweepError
from ..core.tunnel import Sweep
from .local_turbulent import LocalTurbulentGaussianProcessField
from .tiles import tiles
from .turbulent import TurbulenceParameters, TurbulentGaussianProcessField, check_bounds


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
    point the distance [m] to its nearest sample (coverage), and the picked samples' times [s]."""

    positions: np.ndarray
    forces: np.ndarray
    key_distance: np.ndarray
    #: (n,) sample times [s] since the sweep started (None when the source has none)
    times: np.ndarray | None = None


def closest_samples(sweep: Sweep, key_points: np.ndarray, min_picked: int = 0) -> Subsample:
    """GET_CLOSEST on a sweep: finite samples only, each picked sample used once. With fewer key
    points than ``min_picked``, each key point brings its ceil(min_picked / N) nearest samples:
    a few dozen key points would otherwise leave the GP's noise and gusts to be learned from
    as many samples (on a 4 x 4 wall's 121 key points the fitted share of gusts ran 0.3-0.95
    from sweep to sweep)."""
    clean = sweep.finite()
    if len(clean) == 0:
        raise SweepError(f'none of the sweep\'s {len(sweep)} samples is finite: check the force '
                         f'sensor and motion-capture streams')
    key_points = np.asarray(key_points, dtype=float)
    idx = get_closest(clean.positions, key_points)
    dist = np.linalg.norm(clean.positions[idx] - key_points, axis=1)
    per_point = int(np.ceil(min_picked / max(len(key_points), 1)))
    if per_point > 1 and len(clean) > len(key_points):
        _, near = cKDTree(clean.positions).query(key_points, k=min(per_point, len(clean)))
        idx = np.asarray(near, dtype=int).ravel()
    unique = np.unique(idx)
    return Subsample(clean.positions[unique], clean.forces[unique], dist, clean.times[unique])


#: A window spans at most this much of the plate's path [m] (``windowed_samples``), so a fast
#: plate's windows hold fewer samples: the average of a window is the field at its mean
#: position only while the field is nearly straight across it, and the field is smooth over
#: the 20 cm plate. A longer step (a mocap glitch, a gap after lost samples, sensors at fixed
#: places read at one time: ``sim.static_grid``) always starts a new window.
WINDOW_PATH_M = 0.03


def windowed_samples(sweep: Sweep, key_points: np.ndarray, window_s: float) -> Subsample:
    """Every finite sample of ``sweep``, averaged over consecutive windows of ``window_s`` [s]
    along the plate's path (position, force and time averaged; a window never spans more than
    ``WINDOW_PATH_M`` of path or a repeated time), with each key point's distance to its
    nearest raw sample (coverage).

    Why all samples: the nearest sample per key point (GET_CLOSEST) leaves the GP interpolating
    between passes on a smoothness it has to assume, and the std it reports there was 1.1-1.4
    times too small on short sweeps (bench/convergence.py, z RMS). Why windows: the GP's cost
    grows with the cube of its samples; 0.04 s windows halve them at the simulated rig's 50 Hz,
    and a faster force sensor gives more samples per window instead of a larger GP."""
    clean = sweep.finite()
    if len(clean) == 0:
        raise SweepError(f'none of the sweep\'s {len(sweep)} samples is finite: check the force '
                         f'sensor and motion-capture streams')
    if not window_s > 0:
        raise ConfigError(f'the sample window must be > 0 s; got {window_s!r}')
    key_points = np.asarray(key_points, dtype=float)
    dist = np.linalg.norm(clean.positions[get_closest(clean.positions, key_points)] - key_points, axis=1)
    order = np.argsort(clean.times, kind='stable')
    X, y, t = clean.positions[order], clean.forces[order], clean.times[order]
    # a sample on a window's edge (every other one at 50 Hz) stays in the same window when its
    # time was rounded on the way (a bag keeps nanoseconds)
    slot = np.floor((t - t[0]) / window_s + 1e-6)
    step = np.linalg.norm(np.diff(X, axis=0), axis=1)
    new = np.ones(len(t), dtype=bool)
    new[1:] = (slot[1:] != slot[:-1]) | (t[1:] <= t[:-1]) | (step > WINDOW_PATH_M)
    # a window of time that runs over more path than WINDOW_PATH_M is cut into pieces of it
    path = np.concatenate([[0.0], np.cumsum(step)])
    first = np.maximum.accumulate(np.where(new, np.arange(len(t)), 0))
    piece = np.floor((path - path[first]) / WINDOW_PATH_M + 1e-9)
    new[1:] |= piece[1:] != piece[:-1]
    starts = np.flatnonzero(new)
    count = np.diff(np.append(starts, len(t)))[:, None]
    return Subsample(np.add.reduceat(X, starts, axis=0) / count,
                     np.add.reduceat(y, starts) / count[:, 0], dist,
                     np.add.reduceat(t, starts) / count[:, 0])


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
        self.X_, self.y_ = X, y
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
        # var = k(q, q) - |L^-1 k(X, q)|^2: one triangular solve, half the work of cho_solve
        v = solve_triangular(self.chol_[0], Ks.T, lower=self.chol_[1], check_finite=False)
        var = self.signal_var_ - np.einsum('ij,ij->j', v, v)
        return mean, np.sqrt(np.maximum(var, 0.0))

    def log_marginal_likelihood(self) -> float:
        """log p(forces | positions) of the fitted GP [nats]."""
        if not hasattr(self, 'alpha_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces) first')
        L = self.chol_[0]
        r = self.y_ - self.mean_
        return float(-0.5 * r @ self.alpha_ - np.sum(np.log(np.diag(L)))
                     - 0.5 * len(r) * np.log(2 * np.pi))


#: Bounds of the GP hyperparameters when they are estimated from a sweep: length scale [m]
#: (the plate's 20 cm averaging makes anything much below 5 cm implausible), noise [N] and
#: signal standard deviation [N].
LENGTH_SCALE_BOUNDS = (0.05, 0.30)
NOISE_STD_BOUNDS = (0.01, 0.5)
SIGNAL_STD_BOUNDS = (0.05, 20.0)


def fit_hyperparameters(positions, forces, *, length_scale=0.10, noise_std=0.05, signal_std=None,
                        length_scale_bounds=LENGTH_SCALE_BOUNDS, noise_std_bounds=NOISE_STD_BOUNDS,
                        signal_std_bounds=SIGNAL_STD_BOUNDS, max_iter: int = 30) -> dict:
    """Type-II maximum likelihood of (length_scale [m], noise_std [N], signal_std [N]) of the
    squared-exponential GP on samples (n, 2) [m] -> (n,) [N], each kept inside its bounds
    (L-BFGS-B on the logs, analytic gradient, starting from the given values). Returns
    ``{'length_scale', 'noise_std', 'signal_std', 'log_likelihood'}``."""
    X = np.asarray(positions, dtype=float).reshape(-1, 2)
    y = np.asarray(forces, dtype=float).ravel()
    if len(y) < 10:
        raise SweepError(f'{len(y)} samples are too few to estimate GP hyperparameters (need 10)')
    r = y - np.mean(y)
    sq = np.maximum(np.sum(X * X, 1)[:, None] + np.sum(X * X, 1)[None, :] - 2.0 * X @ X.T, 0.0)
    bounds = np.log(np.array([length_scale_bounds, noise_std_bounds, signal_std_bounds], dtype=float))
    s0 = signal_std if signal_std is not None else max(float(np.std(y)), 1e-3)
    x0 = np.clip(np.log([length_scale, noise_std, s0]), bounds[:, 0], bounds[:, 1])
    n = len(y)

    def nll(x):
        ell, sn, sf = np.exp(x)
        E = np.exp(-sq / (2 * ell ** 2))
        K = sf ** 2 * E
        K[np.diag_indices(n)] += sn ** 2 + 1e-10 * sf ** 2
        try:
            L = np.linalg.cholesky(K)
        except np.linalg.LinAlgError:
            return 1e25, np.zeros(3)
        alpha = cho_solve((L, True), r, check_finite=False)
        Kinv = cho_solve((L, True), np.eye(n), check_finite=False)
        value = 0.5 * r @ alpha + np.sum(np.log(np.diag(L)))
        W = np.outer(alpha, alpha) - Kinv  # d(-nll)/dK
        dK_ell = sf ** 2 * E * sq / ell ** 2  # dK / dlog(ell)
        grad = -0.5 * np.array([np.sum(W * dK_ell), 2 * sn ** 2 * np.trace(W),
                                np.sum(W * (2 * sf ** 2 * E))])
        return value, grad

    sol = minimize(nll, x0, jac=True, method='L-BFGS-B', bounds=bounds,
                   options={'maxiter': max_iter})
    ell, sn, sf = np.exp(np.clip(sol.x, bounds[:, 0], bounds[:, 1]))
    return {'length_scale': float(ell), 'noise_std': float(sn), 'signal_std': float(sf),
            'log_likelihood': float(-sol.fun - 0.5 * n * np.log(2 * np.pi))}


class LocalGaussianProcessField(GaussianProcessField):
    """The same GP, solved tile by tile for large areas.

    The query area is cut into square tiles of side ``block`` [m]; each tile's posterior uses
    only the samples within ``halo`` [m] of the tile (the squared-exponential kernel's weight
    has all but vanished ~2 length scales away when samples are dense), with the global prior
    mean and signal variance. Cost grows linearly with the area (about (block + 2 halo)^6 /
    block^2 per unit area) instead of with the cube of the sample count, and memory with one
    tile. ``fit`` stores the samples; the work happens in ``predict``.
    """

    def __init__(self, length_scale: float = 0.10, noise_std: float = 0.05,
                 signal_std: float | None = None, block: float = 0.10, halo: float = 0.15):
        super().__init__(length_scale, noise_std, signal_std)
        if not (block > 0 and halo >= 0):
            raise ConfigError(f'local GP needs block > 0 and halo >= 0 [m]; got {block}, {halo}')
        self.block, self.halo = float(block), float(halo)

    def fit(self, positions, forces) -> 'LocalGaussianProcessField':
        X = np.asarray(positions, dtype=float).reshape(-1, 2)
        y = np.asarray(forces, dtype=float).ravel()
        if len(X) != len(y):
            raise SweepError(f'{len(X)} positions but {len(y)} forces')
        if len(y) < 3:
            raise SweepError(f'only {len(y)} samples: a field estimate needs at least 3')
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
            raise SweepError('positions or forces contain NaN or inf: drop those samples first')
        self.X_, self.y_ = X, y
        self.mean_ = float(np.mean(y))
        self.signal_var_ = (self.signal_std if self.signal_std is not None
                            else max(float(np.std(y)), 1e-3)) ** 2
        self.tree_ = cKDTree(X)
        return self

    def predict(self, points, return_std: bool = False):
        if not hasattr(self, 'tree_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces) first')
        Q = np.asarray(points, dtype=float).reshape(-1, 2)
        mean = np.full(len(Q), self.mean_)
        std = np.full(len(Q), np.sqrt(self.signal_var_))
        jitter = max(self.noise_std ** 2, 1e-8 * self.signal_var_)
        for rows, near in tiles(Q, self.X_, self.tree_, self.block, self.halo):
            if len(near) == 0:
                continue        # no sample near the tile: the prior answers
            q, Xl, yl = Q[rows], self.X_[near], self.y_[near]
            K = self.kernel(Xl, Xl)
            K[np.diag_indices_from(K)] += jitter
            try:
                L = np.linalg.cholesky(K)
            except np.linalg.LinAlgError:
                raise SweepError('the GP covariance is singular (many samples at the same place): '
                                 'raise noise_std or sweep over more distinct positions') from None
            alpha = cho_solve((L, True), yl - self.mean_, check_finite=False)
            Ks = self.kernel(q, Xl)
            mean[rows] = self.mean_ + Ks @ alpha
            if return_std:
                v = solve_triangular(L, Ks.T, lower=True, check_finite=False)
                std[rows] = np.sqrt(np.maximum(self.signal_var_ - np.einsum('ij,ij->j', v, v), 0.0))
        return (mean, std) if return_std else mean


@dataclass(frozen=True)
class FieldEstimate:
    """The estimated field at the key points: mean and std (N,) [N], coverage (N,) [m]; ``gp``,
    when the estimator kept it, answers for any other position (``at``)."""

    key_points: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    key_distance: np.ndarray
    n_used: int
    gp: object = field(default=None, repr=False, compare=False)

    def at(self, positions, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimated force and its std [N] at ``positions`` (M, 2) [m, tunnel frame], each
        within ``radius`` [m] of the tunnel axis (the disc the sweep measured; beyond it the GP
        only returns its prior). SweepError says which position is wrong."""
        if self.gp is None:
            raise SweepError('this estimate kept no GP to query: estimate the sweep again')
        P = np.asarray(positions, dtype=float)
        if P.ndim != 2 or P.shape[1] != 2 or len(P) == 0:
            raise SweepError(f'give positions as (x, y) pairs [m]; got an array of shape {P.shape}')
        bad = ~np.all(np.isfinite(P), axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise SweepError(f'position {i} is not a finite number: {P[i].tolist()}')
        r = np.hypot(P[:, 0], P[:, 1])
        out = r > radius + 1e-9
        if out.any():
            i = int(np.argmax(r))
            raise SweepError(f'{int(out.sum())} of {len(P)} positions lie outside the measured disc '
                             f'(radius {radius:.3f} m around the tunnel axis), farthest '
                             f'{P[i].round(3).tolist()} at {r[i]:.3f} m: the sweeps measure nothing '
                             f'there, so no force can be given; ask within {radius:.3f} m')
        mean, std = self.gp.predict(P, return_std=True)
        return np.asarray(mean, float), np.asarray(std, float)


@dataclass(frozen=True)
class FieldEstimator:
    """Sweep -> field at the key points, with the checks a lab needs before trusting it.

    noise_model: ``turbulent`` (default): the GP with noise sd sqrt(absolute^2 + (relative F)^2)
    and gusts correlated over sample time, all six hyperparameters fitted to each sweep
    (``estimation.turbulent``, tile by tile on large walls: ``estimation.local_turbulent``; its
    std is calibrated); ``white``: the paper's GP with one white noise_std [N] (its std is too
    small when the noise grows with the force or comes in gusts).
    min_samples: fewer finite samples than this is an error; max_gap [m]: a key point whose
    nearest sample is farther than this means the sweep missed part of the area.
    """

    noise_model: str = 'turbulent'
    length_scale: float = 0.10
    noise_std: float = 0.05
    signal_std: float | None = None
    min_samples: int = 50
    max_gap: float = 0.08
    #: turbulent model: the GP takes every sample of the sweep, averaged over windows of this
    #: many seconds along the plate's path (``windowed_samples``), unless that leaves more than
    #: ``max_exact`` (a large wall: then, and with 0 here, the samples nearest to the key
    #: points, as the white model always takes: GET_CLOSEST)
    sample_window_s: float = 0.04
    #: turbulent model with sample_window_s 0: it picks at least about this many samples (with
    #: fewer key points each brings its nearest few, ``closest_samples``); the white model
    #: keeps GET_CLOSEST's one
    min_picked: int = 300
    #: exact: one GP on all picked samples; local: the same model solved tile by tile for large
    #: walls (``LocalTurbulentGaussianProcessField``, or ``LocalGaussianProcessField`` for the
    #: white model); auto: local above ``max_exact`` picked samples. local_block [m]: the
    #: tiles' side; local_halo [m]: a tile uses the samples this close to it.
    method: str = 'auto'
    max_exact: int = 2000
    local_block: float = 0.20
    local_halo: float = 0.15
    #: turbulent model, local method: the hyperparameters are fitted on at most this many
    #: picked samples (runs of ``fit_block`` spread over the sweep; a 36 x 36 wall picks ~10,000)
    max_fit_samples: int = 2000
    #: white model: estimate length_scale, noise_std and signal_std from each sweep (type-II
    #: maximum likelihood inside the bounds below, starting from the values above); exact GP only.
    fit_hyperparameters: bool = False
    length_scale_bounds: tuple = LENGTH_SCALE_BOUNDS
    noise_std_bounds: tuple = NOISE_STD_BOUNDS
    #: the length scale beyond which a fit pays a prior [m] (None: length_scale_bounds alone):
    #: the length the fans' footprints imply (``model.length_scale``), so that an estimate does
    #: not take the field for smoother than a change of the fans can leave it unless the sweep
    #: clearly says so. Set from the prior by ``ShapingConfig.make_estimator``
    #: (``max_length_scale: footprint`` in shaping.yaml).
    max_length_scale: float | None = None
    #: turbulent model: above ``max_length_scale`` the fit's likelihood pays a half-normal
    #: prior in log length of this sd, so that a sweep whose data clearly say longer still
    #: gets it; 0: a hard bound (the white model's fit always takes it as one)
    max_length_scale_sd: float = 0.1
    #: turbulent model: the start values of the fit (and the values used when a sweep has fewer
    #: than ``min_fit_samples`` picked samples): absolute noise sd [N], relative noise sd
    #: [fraction of the force], gust share of the noise variance [0..1], gust time [s]; with
    #: length_scale and signal_std (None: the forces' spread) above.
    absolute_noise: float = 0.03
    relative_noise: float = 0.04
    gust_fraction: float = 0.5
    gust_time: float = 0.1
    #: bounds (low, high) of absolute, relative, gust_fraction, gust_time and signal_std
    #: overriding ``estimation.turbulent.TURBULENCE_BOUNDS``; the length scale keeps
    #: ``length_scale_bounds``
    turbulence_bounds: Mapping | None = None
    min_fit_samples: int = 60
    #: turbulent model: the fit's composite likelihood runs over about this many seconds of
    #: sweep (``fit_runs``): long enough for the plate to pass a place again within a run, so
    #: the field's length scale is told apart from the gusts (runs of 1.6 s took the length
    #: scale 20 % too long); 0: runs of ``fit_block`` samples
    fit_run_s: float = 9.6
    #: the most samples per run (a graph's plate is fast and its windows short: runs of 9.6 s
    #: held 900 samples and an estimate took over 12 s on a loaded machine), and the samples per
    #: run when fit_run_s is 0 or the samples' times do not advance (0: no limit; with
    #: fit_run_s 0 the exact likelihood, n^3 per step)
    fit_block: int = 240
    #: turbulent model, exact GP: scale each sweep's std by the long-run variance of its
    #: whitened residuals over lags up to this span [s], where above 1
    #: (``estimation.turbulent.long_run_scale``): gusts slower than the fitted gust time, which
    #: one sweep cannot tell from the field, then widen the std instead of hiding in it; 0: off
    long_run_span_s: float = 1.5
    #: pair each force with the plate's position this long [s] after the force's own time (a
    #: motion capture that stamps its frames late; negative: early), as the diagnosis's
    #: ``--position-lag`` does on recorded sweeps, whose clocks check measures the lag; 0: as
    #: recorded
    position_lag_s: float = 0.0

    def __post_init__(self):
        if self.method not in ('auto', 'exact', 'local'):
            raise ConfigError(f'estimator method must be auto, exact or local; got {self.method!r}')
        if self.noise_model not in ('turbulent', 'white'):
            raise ConfigError(f'estimator noise_model must be turbulent or white; got {self.noise_model!r}')
        for name in ('length_scale_bounds', 'noise_std_bounds'):
            lo, hi = (float(v) for v in getattr(self, name))
            if not 0 < lo <= hi:
                raise ConfigError(f'estimator {name} must be (low, high) with 0 < low <= high; got '
                                  f'{getattr(self, name)}')
            object.__setattr__(self, name, (lo, hi))
        if self.max_length_scale is not None:
            cap = self.max_length_scale
            if not (isinstance(cap, (int, float)) and np.isfinite(cap) and cap > 0):
                raise ConfigError(f'estimator max_length_scale must be a length > 0 [m] or None; '
                                  f'got {cap!r}')
            object.__setattr__(self, 'max_length_scale', float(cap))
        sd = self.max_length_scale_sd
        if not (isinstance(sd, (int, float)) and np.isfinite(sd) and sd >= 0):
            raise ConfigError(f'estimator max_length_scale_sd must be >= 0 (0: a hard bound); '
                              f'got {sd!r}')
        if not (isinstance(self.fit_run_s, (int, float)) and 0 <= self.fit_run_s <= 600):
            raise ConfigError(f'estimator fit_run_s must be 0 (runs of fit_block samples) or up to '
                              f'600 s; got {self.fit_run_s!r}')
        if not (isinstance(self.long_run_span_s, (int, float)) and 0 <= self.long_run_span_s <= 10):
            raise ConfigError(f'estimator long_run_span_s must be 0 (off) or a span of up to '
                              f'10 s; got {self.long_run_span_s!r}')
        if not (isinstance(self.sample_window_s, (int, float)) and 0 <= self.sample_window_s <= 1):
            raise ConfigError(f'estimator sample_window_s must be 0 (the closest samples) or a '
                              f'window of up to 1 s; got {self.sample_window_s!r}')
        lag = self.position_lag_s
        if not (isinstance(lag, (int, float)) and np.isfinite(lag) and abs(lag) <= 1.0):
            raise ConfigError(f'estimator position_lag_s must be a number of seconds within +-1 '
                              f'(the diagnosis measures it: "the positions arrive 40 ms late" is '
                              f'0.040; 0: as recorded); got {lag!r}')
        if self.noise_model == 'turbulent':
            self.turbulence_start(1.0)             # validates the start values
            LocalTurbulentGaussianProcessField(  # validates the fit and tile settings
                bounds=self.fit_bounds, min_fit_samples=self.min_fit_samples, block=self.fit_block,
                tile=self.local_block, halo=self.local_halo, max_fit_samples=self.max_fit_samples)

    @property
    def fitted_length_scales(self) -> tuple:
        """(low, high) [m] of a fitted length scale: ``length_scale_bounds`` with the high end
        at most ``max_length_scale`` (never below the low end)."""
        lo, hi = self.length_scale_bounds
        if self.max_length_scale is not None:
            hi = max(lo, min(hi, self.max_length_scale))
        return lo, hi

    @property
    def length_prior(self) -> tuple | None:
        """The turbulent fit's soft bound on the length scale, (length [m], sd in log length),
        or None (no bound, or a hard one in ``fit_bounds``)."""
        if self.max_length_scale is None or self.max_length_scale_sd == 0:
            return None
        return self.max_length_scale, self.max_length_scale_sd

    @property
    def fit_bounds(self) -> dict:
        """The turbulent model's bounds, name -> (low, high)."""
        lengths = self.fitted_length_scales if self.length_prior is None else self.length_scale_bounds
        return check_bounds({**dict(self.turbulence_bounds or {}), 'length_scale': lengths})

    def turbulence_start(self, spread: float) -> TurbulenceParameters:
        """The turbulent model's start values; ``spread`` [N]: the forces' sd, the signal sd's
        start unless ``signal_std`` is set."""
        return TurbulenceParameters(self.length_scale,
                                    self.signal_std if self.signal_std is not None else max(spread, 1e-3),
                                    self.absolute_noise, self.relative_noise, self.gust_fraction,
                                    self.gust_time)

    def fit_runs(self, times=None) -> int:
        """Samples per run of the turbulent fit's composite likelihood: about ``fit_run_s`` of
        sweep at the samples' median spacing in ``times`` [s] (10 at least, ``fit_block`` at
        most: a run's cost grows with its cube), or ``fit_block`` when fit_run_s is 0 or the
        times do not advance (sensors read at one time)."""
        if self.fit_run_s > 0 and times is not None and len(times) > 1:
            spacing = float(np.median(np.diff(np.sort(np.asarray(times, dtype=float)))))
            if spacing > 0:
                runs = max(10, int(round(self.fit_run_s / spacing)))
                return min(runs, self.fit_block) if self.fit_block > 0 else runs
        return self.fit_block

    def make_gp(self, n_samples: int, positions=None, forces=None, reuse=None, times=None):
        """The GP this estimator uses for ``n_samples`` picked samples (hyperparameters
        estimated from positions/forces when fitted; ``reuse``: an earlier estimate of the same
        sweep whose fitted hyperparameters to take instead of fitting again; ``times`` [s]: the
        samples' times, for the length of the fit's runs, ``fit_runs``)."""
        local = self.method == 'local' or (self.method == 'auto' and n_samples > self.max_exact)
        old = getattr(reuse, 'gp', None)
        if self.noise_model == 'turbulent':
            # the same model either way: a sweep's interim estimates may cross max_exact, and the
            # hyperparameters fitted on the exact GP carry over to the tiled one (and back)
            if local:
                make = partial(LocalTurbulentGaussianProcessField, tile=self.local_block,
                               halo=self.local_halo, max_fit_samples=self.max_fit_samples)
            else:
                make = partial(TurbulentGaussianProcessField, long_run_span_s=self.long_run_span_s)
            if isinstance(old, TurbulentGaussianProcessField) and (old.fitted_ or old.reused_):
                gp = make(old.params_, self.fit_bounds, fit_parameters=False, block=self.fit_runs(times))
                gp.reused_ = True   # fitted values, carried on (they may be reused again)
                return gp
            spread = float(np.std(forces)) if forces is not None and len(forces) else 1.0
            return make(self.turbulence_start(spread), self.fit_bounds,
                        min_fit_samples=self.min_fit_samples, block=self.fit_runs(times),
                        length_prior=self.length_prior)
        if local:
            return LocalGaussianProcessField(self.length_scale, self.noise_std, self.signal_std,
                                             self.local_block, self.local_halo)
        if isinstance(old, GaussianProcessField) and self.fit_hyperparameters:
            return GaussianProcessField(old.length_scale, old.noise_std, old.signal_std)
        if self.fit_hyperparameters and positions is not None:
            hp = fit_hyperparameters(positions, forces, length_scale=self.length_scale,
                                     noise_std=self.noise_std, signal_std=self.signal_std,
                                     length_scale_bounds=self.fitted_length_scales,
                                     noise_std_bounds=self.noise_std_bounds)
            return GaussianProcessField(hp['length_scale'], hp['noise_std'], hp['signal_std'])
        return GaussianProcessField(self.length_scale, self.noise_std, self.signal_std)

    def check_coverage(self, sweep: Sweep, key_points: np.ndarray, required=None) -> None:
        """SweepError unless ``sweep`` has enough finite samples and passed every (``required``)
        key point within ``max_gap``: the checks ``estimate`` makes before its GP."""
        self._checked(sweep, key_points, required)

    def _checked(self, sweep: Sweep, key_points: np.ndarray, required=None) -> Subsample:
        clean = sweep.finite()
        if self.position_lag_s and len(clean):
            # the path's position position_lag_s after each force (held at the sweep's ends)
            clean = Sweep(clean.positions_at(clean.times + self.position_lag_s), clean.forces,
                          clean.times, clean.pwm)
        if len(clean) < self.min_samples:
            raise SweepError(f'the sweep has {len(clean)} usable samples (of {len(sweep)}); at least '
                             f'{self.min_samples} are needed: sweep longer or check the streams')
        sub = None
        if self.noise_model == 'turbulent' and self.sample_window_s > 0:
            sub = windowed_samples(clean, key_points, self.sample_window_s)
            if len(sub.forces) > self.max_exact:
                # a large wall's long sweep: the tiled GP on the samples nearest the key points,
                # as measured at scale (bench/scale.py); all of them would cost several times more
                sub = None
        if sub is None:
            sub = closest_samples(clean, key_points,
                                  self.min_picked if self.noise_model == 'turbulent' else 0)
        far = sub.key_distance > self.max_gap
        if required is not None:
            far &= np.asarray(required, dtype=bool)
        if np.any(far):
            worst = int(np.argmax(np.where(far, sub.key_distance, -1.0)))
            area = 'the whole area' if required is None else 'the region asked for'
            raise SweepError(
                f'the sweep missed {int(far.sum())} of {int(np.sum(required)) if required is not None else len(key_points)} '
                f'key points (nearest sample farther than {self.max_gap} m; worst '
                f'{sub.key_distance[worst]:.3f} m at {np.round(key_points[worst], 3).tolist()}): '
                f'sweep the plate over {area}')
        return sub

    def estimate(self, sweep: Sweep, key_points: np.ndarray, required=None, reuse=None) -> FieldEstimate:
        """The field at ``key_points`` (N, 2) [m] from ``sweep``; ``required`` (N,) bool: only
        these key points must have been passed (a region sweep, ``control.region``); the others
        get the GP's answer however far the samples are (a large std there). The GP does not
        depend on ``required``, only the check does (``check_coverage``). ``reuse``: an earlier
        estimate of the same sweep (fewer samples) whose fitted hyperparameters to use instead
        of fitting them again (an adaptive sweep's interim estimates)."""
        sub = self._checked(sweep, key_points, required)
        gp = self.make_gp(len(sub.forces), sub.positions, sub.forces, reuse=reuse, times=sub.times)
        if isinstance(gp, TurbulentGaussianProcessField):
            gp.fit(sub.positions, sub.forces, sub.times)
        else:
            gp.fit(sub.positions, sub.forces)
        mean, std = gp.predict(key_points, return_std=True)
        return FieldEstimate(np.asarray(key_points, float), mean, std, sub.key_distance,
                             len(sub.forces), gp)
