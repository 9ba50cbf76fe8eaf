"""A GP field estimate whose std can be trusted: the noise grows with the force and gusts last.

The force on the moving plate is y_i = f(z_i) + e_i [N] at plate centre z_i [m, tunnel frame]
and sample time t_i [s]. The field f is a Gaussian process with a squared-exponential kernel,

    cov(f(z_i), f(z_j)) = signal_std^2 exp(-|z_i - z_j|^2 / (2 length_scale^2)),

and the measurement noise e is turbulence: its sd grows with the local force level F_i [N],
and a share of it comes in gusts that last, correlated over sample time:

    s_i^2 = absolute^2 + (relative F_i)^2,
    cov(e_i, e_j) = s_i s_j [(1 - gust_fraction) [i == j] + gust_fraction exp(-|t_i - t_j| / gust_time)].

A plate moving at 0.8 m/s covers 8 cm in a 0.1 s gust, so samples next to each other in time
(and thus in space) share their gust: a GP that took them as independent averages the gust into
the field and reports a std several times too small. Here the gust term is part of the noise,
the spatial posterior (mean and std at any position) is the field alone. F_i is the field's
level at the sample: the posterior mean of a pilot GP (the same model with F the sweep's mean
force), so a noisy sample does not raise its own noise.

The six hyperparameters (``TurbulenceParameters``) are estimated from each sweep by type-II
maximum likelihood (L-BFGS-B, analytic gradient, each inside its bounds in ``TURBULENCE_BOUNDS``
or the ones given). A sweep with fewer than ``min_fit_samples`` samples is too short to tell
them apart: the estimate then uses the start values unchanged and says so (``fitted_`` False).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Mapping

import numpy as np
from scipy.linalg import LinAlgError, cho_solve, lapack, solve_triangular
from scipy.optimize import minimize

from ..core.errors import ConfigError, SweepError


@dataclass(frozen=True)
class TurbulenceParameters:
    """The model's hyperparameters. length_scale [m]: the field's spatial scale; signal_std [N]:
    the field's spread about its mean; absolute [N]: noise sd at zero force; relative [fraction
    of the local force]: the turbulence sd that grows with it; gust_fraction [0..1]: the share
    of the noise variance that comes in gusts; gust_time [s]: how long a gust lasts (the
    correlation time of an exponential kernel over sample time)."""

    length_scale: float = 0.10
    signal_std: float = 0.5
    absolute: float = 0.03
    relative: float = 0.04
    gust_fraction: float = 0.5
    gust_time: float = 0.1

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ConfigError(f'turbulence parameter {f.name} must be a finite number >= 0; '
                                  f'got {v!r}')
        if self.length_scale <= 0 or self.signal_std <= 0 or self.gust_time <= 0:
            raise ConfigError(f'length_scale, signal_std and gust_time must be > 0; got {self}')
        if self.gust_fraction > 1:
            raise ConfigError(f'gust_fraction is a share of the noise, 0..1; got {self.gust_fraction}')

    def noise_sd(self, force) -> np.ndarray:
        """Per-sample noise sd [N] at local force level ``force`` [N]."""
        return np.sqrt(self.absolute ** 2 + (self.relative * np.asarray(force, dtype=float)) ** 2)

    def clipped(self, bounds: Mapping) -> 'TurbulenceParameters':
        """These values moved into ``bounds`` (name -> (low, high))."""
        return replace(self, **{k: float(np.clip(getattr(self, k), *bounds[k])) for k in bounds})

    def to_json(self) -> dict:
        return {k: round(float(v), 6) for k, v in asdict(self).items()}


#: Bounds of each hyperparameter when fitted: length scale [m] (the 20 cm plate averages away
#: anything much below 5 cm), signal sd [N], absolute noise sd [N], relative noise sd
#: [fraction], gust share [0..1] (below 1: some noise stays white), gust time [s] (above the
#: 50 Hz sample period's half, below the length of a short sweep's lane).
TURBULENCE_BOUNDS = {
    'length_scale': (0.05, 0.30),
    'signal_std': (0.01, 20.0),
    'absolute': (0.002, 0.5),
    'relative': (0.001, 0.3),
    'gust_fraction': (0.0, 0.95),
    'gust_time': (0.01, 1.0),
}
_LOG = ('length_scale', 'signal_std', 'absolute', 'relative', 'gust_time')  # fitted as logs
_ORDER = ('length_scale', 'signal_std', 'absolute', 'relative', 'gust_fraction', 'gust_time')


def check_bounds(bounds: Mapping | None) -> dict:
    """``TURBULENCE_BOUNDS`` updated by ``bounds`` (name -> (low, high)); ConfigError when a
    name is unknown or a pair is not 0 <= low <= high (low > 0 for the ones fitted as logs)."""
    out = dict(TURBULENCE_BOUNDS)
    for k, pair in dict(bounds or {}).items():
        if k not in out:
            raise ConfigError(f'no turbulence parameter {k!r} to bound; known: {list(out)}')
        try:
            lo, hi = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise ConfigError(f'bounds of {k} must be (low, high); got {pair!r}') from None
        if not (0 <= lo <= hi and np.isfinite(hi)) or (k in _LOG and lo <= 0):
            raise ConfigError(f'bounds of {k} must be (low, high) with 0 {"<" if k in _LOG else "<="} '
                              f'low <= high; got {pair!r}')
        out[k] = (lo, hi)
    if out['gust_fraction'][1] >= 1:
        raise ConfigError('gust_fraction must stay below 1 (some noise is white, or the '
                          'covariance of a sweep at rest is singular)')
    return out


def _squared_distances(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """|a - b|^2 [m^2] between point sets A (..., n, 2) and B (..., m, 2)."""
    sq = (np.sum(A * A, -1)[..., :, None] + np.sum(B * B, -1)[..., None, :]
          - 2.0 * A @ np.swapaxes(B, -1, -2))
    return np.maximum(sq, 0.0, out=sq)


def _diag(M: np.ndarray) -> np.ndarray:
    """The writable diagonal(s) of M (..., n, n)."""
    return np.einsum('...ii->...i', M)


def gust_noise_cov(p: TurbulenceParameters, s: np.ndarray, lag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, T): the noise covariance [N^2] of samples with noise sd ``s`` (..., n) [N] and time
    lags ``lag`` (..., n, n) [s] between them, and the time kernel exp(-lag / gust_time)."""
    T = np.exp(-lag / p.gust_time)
    R = p.gust_fraction * T
    _diag(R)[...] = 1.0
    return s[..., :, None] * R * s[..., None, :], T


class _Design:
    """What the likelihood needs of samples, computed once: squared spatial distances [m^2],
    time lags [s] and forces [N], for one set (X (n, 2), y (n,), t (n,)) or a stack of equal
    runs (X (k, m, 2), ...)."""

    def __init__(self, X, y, t):
        self.X, self.y, self.t = X, y, t
        self.sq = _squared_distances(X, X)
        self.lag = np.abs(t[..., :, None] - t[..., None, :])
        self.n = y.shape[-1]

    def noise_cov(self, p: TurbulenceParameters, level) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, s, T): the noise covariance [N^2], per-sample sd [N], time kernel exp(-lag/tau)."""
        s = p.noise_sd(level)
        N, T = gust_noise_cov(p, s, self.lag)
        return N, s, T

    def cov(self, p: TurbulenceParameters, level):
        E = np.exp(-self.sq / (2.0 * p.length_scale ** 2))
        N, s, T = self.noise_cov(p, level)
        K = p.signal_std ** 2 * E + N
        _diag(K)[...] += 1e-10 * p.signal_std ** 2
        return K, E, s, T


def _cholesky(K):
    L, info = lapack.dpotrf(K, lower=1, clean=1, overwrite_a=0)
    if info != 0:
        raise LinAlgError('not positive definite')
    return L


def _inverse_from_cholesky(L) -> np.ndarray:
    """K^-1 (k, m, m) from the lower Cholesky factors L (k, m, m) of K, run by run (LAPACK
    potri on the factor the likelihood has anyway, not a second, LU factorisation; faster for
    the runs of up to 240 samples the shipped fit uses, slower for many runs of ~100: see
    docs/benchmarks.md, "CPU per iteration"); LinAlgError where a factor's diagonal holds a
    zero."""
    out = np.empty_like(L)
    for i, Li in enumerate(L):
        inv, info = lapack.dpotri(Li, lower=1)
        if info != 0:
            raise LinAlgError('not positive definite')
        out[i] = np.tril(inv) + np.tril(inv, -1).T
    return out


def _nll(x, design: _Design, level, r):
    """Negative log (composite) marginal likelihood without the constant, and its gradient in
    x: the sum over the stacked runs of ``design`` (k, m) of their own likelihoods; level and
    r (k, m) [N]: force levels and centred forces."""
    p = _from_vector(x)
    K, E, s, T = design.cov(p, level)
    try:
        L = np.linalg.cholesky(K)
        Kinv = _inverse_from_cholesky(L)
    except np.linalg.LinAlgError:
        return 1e25, np.zeros(len(x))
    alpha = np.einsum('kij,kj->ki', Kinv, r)
    value = 0.5 * np.sum(r * alpha) + np.sum(np.log(_diag(L)))
    W = alpha[:, :, None] * alpha[:, None, :]
    W -= Kinv                                   # 2 d(log likelihood) / dK
    W_E = W * E
    c = p.gust_fraction
    WT = W * T
    _diag(WT)[...] = 0.0
    WTs = np.einsum('kij,kj->ki', WT, s)        # sum_j W_ij T_ij s_j, off the diagonal
    WRs = c * WTs + _diag(W) * s                # R = c T off the diagonal, 1 on it
    d_abs = p.absolute ** 2 / s                 # ds / dlog(absolute)
    d_rel = (p.relative * level) ** 2 / s       # ds / dlog(relative)
    sf2 = p.signal_std ** 2
    g = np.array([
        sf2 * np.sum(W_E * design.sq) / p.length_scale ** 2,
        2.0 * sf2 * np.sum(W_E),
        2.0 * np.sum(d_abs * WRs),
        2.0 * np.sum(d_rel * WRs),
        np.sum(s * WTs),
        c * np.einsum('ki,kij,kj->', s, WT * design.lag, s) / p.gust_time,
    ])
    return value, -0.5 * g


def _to_vector(p: TurbulenceParameters) -> np.ndarray:
    return np.array([np.log(getattr(p, k)) if k in _LOG else getattr(p, k) for k in _ORDER])


def _from_vector(x) -> TurbulenceParameters:
    return TurbulenceParameters(**{k: float(np.exp(v)) if k in _LOG else float(v)
                                   for k, v in zip(_ORDER, x)})


def _vector_bounds(bounds: Mapping) -> np.ndarray:
    return np.array([np.log(bounds[k]) if k in _LOG else bounds[k] for k in _ORDER], dtype=float)


def _runs(n: int, block: int) -> list:
    """Slices cutting n samples into runs of about ``block`` (one run for block 0)."""
    k = max(1, int(round(n / block))) if block > 0 else 1
    edges = np.linspace(0, n, k + 1).round().astype(int)
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def local_level(X, y, t, p: TurbulenceParameters, mean: float, block: int) -> np.ndarray:
    """The field's level at each sample [N] (samples in time order): per run of ``block``
    samples the posterior mean of the model at ``p`` (noise sd of the sweep's mean force), kept
    >= 0 (turbulence is relative to |F|). Runwise, so it costs a few small solves, not one of
    the whole sweep."""
    out = []
    for run in _runs(len(y), block):
        d = _Design(X[run], y[run], t[run])
        level = np.full(d.n, abs(mean))
        K, E, _, _ = d.cov(p, level)
        try:
            L = _cholesky(K)
        except LinAlgError:
            out.append(level)
            continue
        alpha = cho_solve((L, True), d.y - mean, check_finite=False)
        out.append(np.abs(mean + p.signal_std ** 2 * E @ alpha))
    return np.concatenate(out)


def _length_penalty(x, prior):
    """(value, d value / d log length) of the one-sided prior on the length scale: 0 up to the
    length ``prior[0]`` [m], then a half-normal in log length of sd ``prior[1]``."""
    if prior is None:
        return 0.0, 0.0
    excess = x[0] - np.log(prior[0])
    if excess <= 0:
        return 0.0, 0.0
    return 0.5 * (excess / prior[1]) ** 2, excess / prior[1] ** 2


def fit_turbulence(positions, forces, times, start: TurbulenceParameters = TurbulenceParameters(),
                   bounds: Mapping | None = None, *, block: int = 80, max_iter: int = 40,
                   tolerance: float = 0.05, length_prior: tuple | None = None) -> tuple:
    """Type-II maximum likelihood of the ``TurbulenceParameters`` on samples: positions (n, 2)
    [m], forces (n,) [N], times (n,) [s]. The likelihood is the product of the likelihoods of
    runs of ``block`` samples consecutive in time (a composite likelihood: a gust and the
    plate's local neighbourhood both lie within a run; cost n block^2 instead of n^3; block 0:
    the exact likelihood). Starts from ``start`` (clipped into the bounds), keeps every value
    inside its bounds (L-BFGS-B on the logs, analytic gradient; stops when an iteration gains
    less than ``tolerance`` [nats] of log likelihood: far below what tells two values apart). Each sample's force level is the blockwise
    posterior mean at ``start`` (``local_level``). ``length_prior`` (length [m], sd): a length
    scale beyond that length pays a half-normal prior of that sd in log length (the maximum is
    then a posterior mode). Returns (parameters, log likelihood [nats] without the prior,
    number of likelihood evaluations)."""
    bounds = check_bounds(bounds)
    X = np.asarray(positions, dtype=float).reshape(-1, 2)
    y = np.asarray(forces, dtype=float).ravel()
    t = np.asarray(times, dtype=float).ravel()
    order = np.argsort(t, kind='stable')
    X, y, t = X[order], y[order], t[order]
    mean = float(np.mean(y))
    start = start.clipped(bounds)
    level = local_level(X, y, t, start, mean, block)
    # equal runs, stacked (k, m): the likelihood of all runs in one batch of array operations
    # (a run's last few samples, fewer than the number of runs, are left out of the fit)
    k = len(_runs(len(y), block))
    m = len(y) // k
    take = (np.arange(k)[:, None] * (len(y) / k)).astype(int) + np.arange(m)[None, :]
    args = (_Design(X[take], y[take], t[take]), level[take], y[take] - mean)
    vb = _vector_bounds(bounds)
    x0 = np.clip(_to_vector(start), vb[:, 0], vb[:, 1])

    def objective(x, *a):
        value, grad = _nll(x, *a)
        if value < 1e25:
            extra, slope = _length_penalty(x, length_prior)
            value += extra
            grad = grad.copy()
            grad[0] += slope
        return value, grad

    first = objective(x0, *args)
    memo = {x0.tobytes(): first}   # L-BFGS-B asks for the start again: answer from memory
    sol = minimize(lambda x, *a: memo.pop(x.tobytes(), None) or objective(x, *a), x0, args=args,
                   jac=True, method='L-BFGS-B', bounds=vb,
                   options={'maxiter': max_iter, 'ftol': tolerance / max(abs(first[0]), 1.0),
                            'gtol': 1e-3})
    x = np.clip(sol.x, vb[:, 0], vb[:, 1])
    p = _from_vector(x).clipped(bounds)
    ll = (float(-(sol.fun - _length_penalty(x, length_prior)[0]) - 0.5 * len(y) * np.log(2 * np.pi))
          if sol.fun < 1e25 else -np.inf)
    return p, ll, int(sol.nfev)


class TurbulentGaussianProcessField:
    """The GP field with force-proportional, gusty noise (see the module docstring).

    start: the ``TurbulenceParameters`` to fit from, and to use as they are when the sweep has
    fewer than ``min_fit_samples`` samples or ``fit_parameters`` is False; bounds: name ->
    (low, high), overriding ``TURBULENCE_BOUNDS``; block: samples per run of the composite
    likelihood (``fit_turbulence``); max_iter: L-BFGS-B iterations; long_run_span_s [s]: scale
    the std by the whitened residuals' long-run variance over lags up to this span
    (``long_run_scale``; 0: off).

    ``fit(positions, forces, times)`` returns self. Fitted state: ``std_scale_`` (the factor
    the std is scaled by, >= 1), ``params_`` (the parameters
    used), ``fitted_`` (True when estimated from this sweep, False for the start values),
    ``evaluations_`` (likelihood evaluations of the fit), ``log_likelihood_`` [nats, exact],
    ``mean_`` [N] (the prior mean: the forces' mean), ``level_`` (n,) [N] (each sample's force
    level). ``predict(points, return_std)``: the field alone (gusts and noise excluded) at
    (K, 2) [m].
    """

    def __init__(self, start: TurbulenceParameters = TurbulenceParameters(), bounds: Mapping | None = None,
                 fit_parameters: bool = True, min_fit_samples: int = 60, block: int = 80,
                 max_iter: int = 40, length_prior: tuple | None = None, long_run_span_s: float = 0.0):
        if not (isinstance(min_fit_samples, int) and min_fit_samples >= 10):
            raise ConfigError(f'min_fit_samples must be a whole number >= 10; got {min_fit_samples!r}')
        if not (isinstance(block, int) and (block == 0 or block >= 10)):
            raise ConfigError(f'block must be 0 (exact likelihood) or a whole number >= 10; got {block!r}')
        if not (isinstance(max_iter, int) and max_iter >= 1):
            raise ConfigError(f'max_iter must be a whole number >= 1; got {max_iter!r}')
        if not isinstance(start, TurbulenceParameters):
            raise ConfigError(f'start must be TurbulenceParameters; got {start!r}')
        self.start, self.bounds = start, check_bounds(bounds)
        self.fit_parameters, self.min_fit_samples = bool(fit_parameters), min_fit_samples
        self.block, self.max_iter = block, max_iter
        if length_prior is not None:
            length, sd = (float(v) for v in length_prior)
            if not (length > 0 and sd > 0):
                raise ConfigError(f'length_prior must be (length [m] > 0, sd > 0); got {length_prior!r}')
            length_prior = (length, sd)
        self.length_prior = length_prior
        if not (isinstance(long_run_span_s, (int, float)) and 0 <= long_run_span_s <= 10):
            raise ConfigError(f'long_run_span_s must be 0 (off) or a span of up to 10 s; got '
                              f'{long_run_span_s!r}')
        self.long_run_span_s = float(long_run_span_s)
        #: True when the start values are an earlier sweep's fitted ones (``FieldEstimator.make_gp``)
        self.reused_ = False

    def __repr__(self) -> str:
        p = getattr(self, 'params_', self.start)
        return (f'{p.signal_std:.3g}^2 SE(z; {p.length_scale:.3g} m) + noise sd sqrt({p.absolute:.3g}^2 '
                f'+ ({p.relative:.3g} F)^2), {p.gust_fraction:.2f} of its variance in gusts of '
                f'{p.gust_time:.3g} s')

    def _take_samples(self, positions, forces, times) -> tuple:
        """The samples as arrays in time order (X (n, 2) [m], y (n,) [N], t (n,) [s]), stored
        with the prior mean; SweepError when they do not make a sweep."""
        X = np.asarray(positions, dtype=float).reshape(-1, 2)
        y = np.asarray(forces, dtype=float).ravel()
        t = np.asarray(times, dtype=float).ravel()
        if not len(X) == len(y) == len(t):
            raise SweepError(f'{len(X)} positions, {len(y)} forces and {len(t)} times: every sample '
                             f'needs all three')
        if len(y) < 3:
            raise SweepError(f'only {len(y)} samples: a field estimate needs at least 3; sweep '
                             f'the plate over the whole operating area')
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y)) and np.all(np.isfinite(t))):
            raise SweepError('positions, forces or times contain NaN or inf: drop those samples first')
        order = np.argsort(t, kind='stable')
        X, y, t = X[order], y[order], t[order]
        self.X_, self.y_, self.t_ = X, y, t
        self.mean_ = float(np.mean(y))
        return X, y, t

    def _fit_parameters(self, X, y, t) -> TurbulenceParameters:
        """The hyperparameters for these samples (time-ordered): fitted when asked and the
        sweep is long enough, else the start values; sets ``params_``, ``fitted_`` and
        ``evaluations_``."""
        self.fitted_ = bool(self.fit_parameters and len(y) >= self.min_fit_samples)
        self.evaluations_ = 0
        p = self.start.clipped(self.bounds)
        if self.fitted_:
            p, _, self.evaluations_ = fit_turbulence(X, y, t, p, self.bounds, block=self.block,
                                                     max_iter=self.max_iter,
                                                     length_prior=self.length_prior)
        self.params_ = p
        return p

    def fit(self, positions, forces, times) -> 'TurbulentGaussianProcessField':
        X, y, t = self._take_samples(positions, forces, times)
        p = self._fit_parameters(X, y, t)
        self.level_ = local_level(X, y, t, p, self.mean_, self.block)
        K, _, _, _ = _Design(X, y, t).cov(p, self.level_)
        try:
            L = _cholesky(K)
        except LinAlgError:
            raise SweepError('the GP covariance is singular (many samples at the same place and '
                             'time): sweep over more distinct positions') from None
        self.L_ = L
        self.alpha_ = cho_solve((L, True), y - self.mean_, check_finite=False)
        self.log_likelihood_ = float(-0.5 * (y - self.mean_) @ self.alpha_ - np.sum(np.log(np.diag(L)))
                                     - 0.5 * len(y) * np.log(2 * np.pi))
        self.std_scale_ = 1.0
        if self.long_run_span_s > 0:
            white = solve_triangular(L, y - self.mean_, lower=True, check_finite=False)
            self.std_scale_ = long_run_scale(white, t, self.long_run_span_s)
        return self

    def kernel(self, A, B) -> np.ndarray:
        """Field covariance between point sets A (n, 2) and B (m, 2) [N^2]."""
        p = self.params_
        return p.signal_std ** 2 * np.exp(-_squared_distances(np.asarray(A, float), np.asarray(B, float))
                                          / (2.0 * p.length_scale ** 2))

    def predict(self, points, return_std: bool = False):
        """Posterior mean of the field (K,) [N] at points (K, 2) [m], and its std [N]."""
        if not hasattr(self, 'alpha_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces, times) first')
        Q = np.asarray(points, dtype=float).reshape(-1, 2)
        Ks = self.kernel(Q, self.X_)
        mean = self.mean_ + Ks @ self.alpha_
        if not return_std:
            return mean
        v = solve_triangular(self.L_, Ks.T, lower=True, check_finite=False)
        var = self.params_.signal_std ** 2 - np.einsum('ij,ij->j', v, v)
        return mean, getattr(self, 'std_scale_', 1.0) * np.sqrt(np.maximum(var, 0.0))

    def log_marginal_likelihood(self) -> float:
        """log p(forces | positions, times) of the fitted model [nats]."""
        if not hasattr(self, 'alpha_'):
            raise SweepError('the GP is not fitted yet: call fit(positions, forces, times) first')
        return self.log_likelihood_


def long_run_scale(white, times, span_s: float) -> float:
    """How much a local average's std is underrated by the fitted noise model, from a sweep's
    whitened residuals ``white`` (L^-1 (y - mean), time order; unit variance and uncorrelated
    when the model holds) at sample times ``times`` [s]: the square root of their long-run
    variance (Bartlett weights over lags up to ``span_s`` [s]) where it exceeds 1, else 1.
    Gusts slower than the fitted gust time leave the residuals correlated over seconds; within
    one sweep they cannot be told from the field by the likelihood, but their correlation
    shows here. Never below 1: a sweep's value scatters, and a std made smaller on a lucky
    sweep would claim more than the model can."""
    w = np.asarray(white, dtype=float)
    t = np.asarray(times, dtype=float)
    n = len(w)
    if n < 20 or span_s <= 0:
        return 1.0
    step = float(np.median(np.diff(t)))
    lags = int(min(n // 4, max(1, round(span_s / step)))) if step > 0 else 1
    lrv = float(w @ w) / n
    for lag in range(1, lags + 1):
        lrv += 2.0 * (1.0 - lag / (lags + 1)) * float(w[:-lag] @ w[lag:]) / n
    return float(np.sqrt(lrv)) if lrv > 1.0 else 1.0


__all__ = ['TURBULENCE_BOUNDS', 'long_run_scale', 'TurbulenceParameters', 'TurbulentGaussianProcessField',
           'check_bounds', 'fit_turbulence']
