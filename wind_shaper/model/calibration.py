"""Calibration: collect the paper's batch on a tunnel and fit the prior's parameters to it.

The batch (as in the paper's appendix): each enabled fan alone, stepped from PWM 0 to 80 % in
5 % steps with the plate held over its hub; plus, at one PWM, the plate held at offsets around
each hub so the footprint width can be fitted. Positions [m], forces [N], PWM fraction.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..core.errors import ConfigError, SweepError
from .terms import Term
from ..core.tunnel import Measurements, Tunnel


@dataclass(frozen=True)
class CalibrationPlan:
    """levels: PWM steps for the over-hub curve; spread_level: PWM of the footprint batch;
    offsets: radial plate offsets [m] used along +-x and +-y around each hub;
    samples_per_point: plate samples averaged at each held position."""

    levels: tuple[float, ...] = tuple(np.round(np.arange(0.0, 0.8001, 0.05), 3))
    spread_level: float = 0.5
    offsets: tuple[float, ...] = (0.05, 0.10, 0.15, 0.20)
    samples_per_point: int = 20


def collect_calibration(tunnel: Tunnel, plan: CalibrationPlan = CalibrationPlan()) -> Measurements:
    """Run the calibration batch on ``tunnel`` and return every held-plate measurement."""
    fans = tunnel.geometry.fans
    parts = []
    for j in np.flatnonzero(fans.enabled):
        hub = fans.positions[j]
        for level in plan.levels:
            U = np.zeros(fans.n_fans)
            U[j] = level
            applied = tunnel.apply(U)
            f = tunnel.measure_at(hub[None, :], plan.samples_per_point)
            parts.append(Measurements(applied[None, :], hub[None, :], f))
        U = np.zeros(fans.n_fans)
        U[j] = plan.spread_level
        applied = tunnel.apply(U)
        pts = np.array([hub + s * np.array(d) for s in plan.offsets
                        for d in ((1, 0), (-1, 0), (0, 1), (0, -1))])
        f = tunnel.measure_at(pts, plan.samples_per_point)
        parts.append(Measurements(np.tile(applied, (len(pts), 1)), pts, f))
    tunnel.apply(np.zeros(fans.n_fans))
    return Measurements.concatenate(parts)


@dataclass(frozen=True)
class ModelFit:
    """A fitted model with its parameter uncertainties.

    model: the fitted term; theta, theta_std: free parameters and their 1-sigma standard
    errors (from the Gauss-Newton covariance); rmse [N] on the fitting data; n: sample count.
    """

    model: Term
    theta: np.ndarray
    theta_std: np.ndarray
    names: list
    rmse: float
    n: int

    def summary(self) -> dict:
        return {'model': repr(self.model), 'rmse_N': self.rmse, 'n_samples': self.n,
                'parameters': {n: {'value': float(v), 'std': float(s)}
                               for n, v, s in zip(self.names, self.theta, self.theta_std)}}


def fit_model(model: Term, data: Measurements, *, max_nfev: int = 2000) -> ModelFit:
    """Bounded least squares of the model's free parameters on ``data``."""
    if len(data) == 0:
        raise SweepError('no measurements to fit the model to')
    ok = np.all(np.isfinite(data.pwm), 1) & np.all(np.isfinite(data.positions), 1) & np.isfinite(data.forces)
    if ok.sum() < len(model.theta) + 1:
        raise SweepError(f'{int(ok.sum())} finite samples cannot determine {len(model.theta)} parameters')
    U, Z, y = data.pwm[ok], data.positions[ok], data.forces[ok]
    if U.shape[1] != model.n_fans:
        raise ConfigError(f'data has commands for {U.shape[1]} fans, the model has {model.n_fans}')
    lo, hi = model.bounds.T
    theta0 = np.clip(model.theta, lo + 1e-12 * np.abs(lo), hi - 1e-12 * np.abs(hi))

    def residual(theta):
        return model.with_theta(theta)(U, Z) - y

    sol = least_squares(residual, theta0, bounds=(lo, hi), max_nfev=max_nfev, x_scale='jac')
    fitted = model.with_theta(sol.x)
    r = sol.fun
    dof = max(len(y) - len(sol.x), 1)
    s2 = float(r @ r) / dof
    JtJ = sol.jac.T @ sol.jac
    cov = np.linalg.pinv(JtJ) * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return ModelFit(fitted, sol.x, std, fitted.theta_names, float(np.sqrt(np.mean(r ** 2))), len(y))
