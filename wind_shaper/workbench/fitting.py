"""Fitting a model to sweeps: bounded least squares with uncertainties, and a frozen model.

``fit_model`` moves a model's free parameters (all, or those picked by ``free``) to minimise the
squared error on ``FitData`` within each parameter's bounds (scipy's trust-region reflective
least squares), and gives their 1-sigma uncertainties from the Gauss-Newton covariance
s^2 (J^T J)^-1, s^2 = SSE / (n - k). Samples of one sweep share turbulence, so that covariance is
optimistic; ``jackknife_std`` gives the sweep-level (delete-one-sweep) jackknife instead, which
the diagnosis uses for the parameters it reports.

``Frozen`` holds a model with every parameter fixed and remembers its last evaluations: the
diagnosis screens each candidate effect around the frozen current model, fitting only the
candidate's own parameters, so the frozen part is computed once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..model import Term, fan_landing, fan_part_batched, fan_thrust_batched, fan_width, is_fan_sum
from .data import FitData
from .errors import FitError

__all__ = ['Frozen', 'FitResult', 'fit_model', 'jackknife_std', 'bic', 'z_from_null']


class Frozen(Term):
    """``term`` with every parameter held fixed (no free parameters), caching its value,
    Jacobian and fan parts for the last few (U, Z) arrays it was called with. Not a model-file
    term: ``to_dict`` gives the frozen term's own entry."""

    kind = ''

    def __init__(self, term: Term, cache_size: int = 4):
        self.inner = term
        self.fans = term.fans
        self.hypers = ()
        self._cache: dict = {}
        self._size = cache_size

    @staticmethod
    def _key(*arrays):
        return tuple((a.__array_interface__['data'][0], a.shape, a.strides) for a in arrays)

    def _remember(self, key, refs, value):
        if len(self._cache) >= self._size * 8:
            self._cache.clear()
        self._cache[key] = (refs, value)  # refs keep the arrays (and so their addresses) alive
        return value

    def _value_and_grad(self, U, Z, jacobian):
        key = ('v', jacobian) + self._key(U, Z)
        hit = self._cache.get(key)
        if hit is not None:
            return hit[1]
        return self._remember(key, (U, Z), self.inner._value_and_grad(U, Z, jacobian))

    def fan_part(self, U, Z, j, jacobian):
        key = ('p', int(j), jacobian) + self._key(U, Z)
        hit = self._cache.get(key)
        if hit is not None:
            return hit[1]
        return self._remember(key, (U, Z), fan_part_batched(self.inner, U, Z, j, jacobian))

    def fan_thrust(self, U, jacobian):
        return fan_thrust_batched(self.inner, U, jacobian)

    def fan_width(self, j):
        return fan_width(self.inner, j)

    def fan_landing(self, j):
        return fan_landing(self.inner, j)

    def is_fan_sum(self):
        return is_fan_sum(self.inner)

    @property
    def theta(self):
        return np.zeros(0)

    @property
    def theta_names(self):
        return []

    @property
    def bounds(self):
        return np.zeros((0, 2))

    def with_theta(self, theta):
        if len(np.asarray(theta)):
            raise FitError('a frozen term has no free parameters')
        return self

    def clone(self, **overrides):
        return self

    def to_dict(self):
        return self.inner.to_dict()

    def __repr__(self):
        return f'Frozen({self.inner!r})'


def bic(sse: float, n: int, k: int) -> float:
    """Bayesian information criterion n ln(SSE / n) + k ln(n) (Gaussian errors, unknown variance)."""
    return float(n * np.log(max(sse, 1e-300) / n) + k * np.log(n))


@dataclass(frozen=True)
class FitResult:
    """A fitted model. model: the fitted term; mask: which entries of ``model.theta`` were
    fitted; theta, theta_std, names: those parameters, their 1-sigma (Gauss-Newton) errors and
    names; sse [N^2], n samples, k fitted parameters, rmse [N], bic; nfev, converged."""

    model: Term
    mask: np.ndarray
    theta: np.ndarray
    theta_std: np.ndarray
    names: list
    sse: float
    n: int
    k: int
    nfev: int
    converged: bool

    @property
    def rmse(self) -> float:
        return float(np.sqrt(self.sse / self.n))

    @property
    def bic(self) -> float:
        return bic(self.sse, self.n, self.k)

    def std_of(self) -> np.ndarray:
        """Standard errors aligned with the full ``model.theta`` (NaN where not fitted)."""
        out = np.full(len(self.model.theta), np.nan)
        out[self.mask] = self.theta_std
        return out

    def summary(self) -> dict:
        return {'model': repr(self.model), 'rmse_N': self.rmse, 'n': self.n, 'k': self.k,
                'bic': self.bic, 'converged': self.converged,
                'parameters': {n: {'value': float(v), 'std': float(s)}
                               for n, v, s in zip(self.names, self.theta, self.theta_std)}}


def _residual_fn(model: Term, data: FitData, mask: np.ndarray, theta_all: np.ndarray):
    def residual(x):
        th = theta_all.copy()
        th[mask] = x
        return model.with_theta(th)(data.U, data.Z) - data.y
    return residual


def fit_model(model: Term, data: FitData, *, free=None, max_nfev: int = 60,
              ftol: float = 1e-6, xtol: float = 1e-8) -> FitResult:
    """Bounded least squares of ``model``'s free parameters on ``data``.

    free: None (every free parameter) or a boolean mask / index array over ``model.theta``
    choosing the ones to move (the rest stay as they are). Starts from the model's current
    values (clipped just inside the bounds); ``max_nfev`` caps the trust-region iterations,
    ``ftol`` and ``xtol`` are scipy's stopping tolerances."""
    if len(data) == 0:
        raise FitError('no data to fit: the sweeps have no finite samples')
    if data.U.shape[1] != model.n_fans:
        raise FitError(f'the data has commands for {data.U.shape[1]} fans, the model is for {model.n_fans}')
    theta_all = np.asarray(model.theta, dtype=float)
    mask = np.ones(len(theta_all), bool) if free is None else np.zeros(len(theta_all), bool)
    if free is not None:
        mask[np.asarray(free)] = True
    k = int(mask.sum())
    if len(data) <= k:
        raise FitError(f'{len(data)} data points cannot determine {k} parameters: record more sweeps')
    if k == 0:
        r = model(data.U, data.Z) - data.y
        return FitResult(model, mask, np.zeros(0), np.zeros(0), [], float(r @ r), len(data), 0, 1, True)
    lo, hi = model.bounds.T
    lo, hi = lo[mask], hi[mask]
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.clip(theta_all[mask], lo + 1e-9 * span, hi - 1e-9 * span)
    residual = _residual_fn(model, data, mask, theta_all)
    sol = least_squares(residual, x0, bounds=(lo, hi), max_nfev=max_nfev, x_scale='jac',
                        ftol=ftol, xtol=xtol, method='trf')
    th = theta_all.copy()
    th[mask] = sol.x
    fitted = model.with_theta(th)
    sse = float(sol.fun @ sol.fun)
    s2 = sse / max(len(data) - k, 1)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    names = [n for n, m in zip(model.theta_names, mask) if m]
    return FitResult(fitted, mask, sol.x.copy(), std, names, sse, len(data), k, int(sol.nfev),
                     bool(sol.status > 0))


def jackknife_std(model: Term, data: FitData, free, *, max_nfev: int = 30) -> np.ndarray:
    """Delete-one-sweep jackknife standard errors of the parameters picked by ``free`` (a mask
    or indices over ``model.theta``), refitting from ``model``'s values without each sweep in
    turn: sqrt((g - 1) / g * sum (theta_i - mean)^2) over the g sweeps. Needs >= 3 sweeps."""
    sweeps = np.unique(data.sweep[data.sweep >= 0])
    mask = np.zeros(len(model.theta), bool)
    mask[np.asarray(free)] = True
    if len(sweeps) < 3 or not mask.any():
        return np.full(int(mask.sum()), np.nan)
    est = []
    for s in sweeps:
        est.append(fit_model(model, data.subset(data.sweep != s), free=mask, max_nfev=max_nfev).theta)
    est = np.array(est)
    g = len(sweeps)
    return np.sqrt((g - 1) / g * np.sum((est - est.mean(axis=0)) ** 2, axis=0))


def z_from_null(params: dict, std: dict, null: dict):
    """Largest |value - null| / std over the parameters with a null value (None if none)."""
    zs = []
    for name, ref in null.items():
        if name not in params:
            continue
        v = np.atleast_1d(np.asarray(params[name], float))
        s = np.atleast_1d(np.asarray(std.get(name, [np.nan] * len(v)), float))
        r = np.broadcast_to(np.asarray(ref, float), v.shape)
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.abs(v - r) / s
        z = z[np.isfinite(z)]
        if len(z):
            zs.append(float(z.max()))
    return max(zs) if zs else None
