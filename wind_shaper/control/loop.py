"""The online-learning loop (Algorithm 1), independent of ROS and of the tunnel behind it.

Each iteration: apply U_k, sweep, estimate the field at the key points, compare with the target,
step the commands through the model's Jacobian. Errors are mean squared differences over the key
points, Err = (1/N) sum_i (F_i - F_des,i)^2 [N^2]; their root (RMSE) is in newtons.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from ..core.errors import ConfigError
from ..estimation import FieldEstimate, FieldEstimator
from ..model import Term
from ..core.tunnel import Sweep, Tunnel
from .update import PastIteration, UpdateInput, UpdateRule


def mean_squared_error(field_values: np.ndarray, target: np.ndarray) -> float:
    """(1/N) sum (F - F_des)^2 [N^2]."""
    return float(np.mean((np.asarray(field_values) - np.asarray(target)) ** 2))


@dataclass
class IterationRecord:
    """One iteration. pwm: commands applied during the sweep; next_pwm: the update's answer
    (None on the final, measure-only iteration); errors in N^2; true_error only where a
    ground truth exists (the simulator)."""

    k: int
    pwm: np.ndarray
    estimate: FieldEstimate
    target: np.ndarray
    error: float
    next_pwm: Optional[np.ndarray]
    step_size: Optional[float]
    sweep: Sweep = field(repr=False)
    true_error: Optional[float] = None
    true_field: Optional[np.ndarray] = field(default=None, repr=False)
    info: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        def arr(a):
            return None if a is None else np.round(np.asarray(a, dtype=float), 6).tolist()
        return {
            'k': self.k, 'pwm': arr(self.pwm), 'next_pwm': arr(self.next_pwm),
            'step_size': self.step_size, 'error_N2': self.error, 'rmse_N': float(np.sqrt(self.error)),
            'true_error_N2': self.true_error,
            'true_rmse_N': None if self.true_error is None else float(np.sqrt(self.true_error)),
            'n_sweep_samples': len(self.sweep), 'n_gp_samples': self.estimate.n_used,
            'field_mean_N': arr(self.estimate.mean), 'field_std_N': arr(self.estimate.std),
            'target_N': arr(self.target), 'true_field_N': arr(self.true_field),
            'max_key_point_gap_m': float(np.max(self.estimate.key_distance)), 'info': self.info,
        }


class ShapingLoop:
    """Drives a tunnel toward a target field.

    tunnel: anything satisfying ``Tunnel``; model: the prior (its Jacobian gives the search
    direction); target: (N,) desired force at the key points [N]; rule: the update rule
    (holds the command bounds); estimator: sweep -> field; u0: starting commands (scalar or
    (n_fans,)); truth: optional U -> true field at the key points, for scoring on a simulator.
    """

    def __init__(self, tunnel: Tunnel, model: Term, target: np.ndarray, rule: UpdateRule,
                 estimator: FieldEstimator = FieldEstimator(), u0=0.5, n_samples: int = 1000,
                 truth: Callable[[np.ndarray], np.ndarray] | None = None):
        geo = tunnel.geometry
        self.tunnel, self.model, self.rule, self.estimator = tunnel, model, rule, estimator
        self.key_points = geo.key_points
        self.enabled = geo.fans.enabled
        self.target = np.asarray(target, dtype=float)
        if self.target.shape != (len(self.key_points),):
            raise ConfigError(f'target has {self.target.shape} values for {len(self.key_points)} key points')
        if model.n_fans != geo.fans.n_fans:
            raise ConfigError(f'model is for {model.n_fans} fans, the tunnel has {geo.fans.n_fans}')
        if n_samples < 1:
            raise ConfigError(f'n_samples must be >= 1, got {n_samples}')
        self.n_samples = n_samples
        self.truth = truth
        self.U = rule.bounds.project(np.broadcast_to(np.asarray(u0, dtype=float), (geo.fans.n_fans,)),
                                     self.enabled)
        self.k = 0
        self.history: list[IterationRecord] = []

    @classmethod
    def from_settings(cls, tunnel: Tunnel, model: Term, target: np.ndarray, shaping, *, u0=None,
                      rule_overrides: dict | None = None,
                      truth: Callable[[np.ndarray], np.ndarray] | None = None) -> 'ShapingLoop':
        """The loop that ``shaping`` (a ``control.settings.ShapingConfig``) configures: its update
        rule (``rule_overrides={'method': 'paper'}`` for Algorithm 1), estimator, samples per
        sweep and u0 (unless given)."""
        return cls(tunnel, model, target, shaping.make_rule(**(rule_overrides or {})),
                   shaping.make_estimator(), u0=shaping.u0 if u0 is None else u0,
                   n_samples=shaping.samples_per_sweep, truth=truth)

    def measure(self) -> tuple[np.ndarray, Sweep, FieldEstimate]:
        applied = self.tunnel.apply(self.U)
        sweep = self.tunnel.sweep(self.n_samples)
        return applied, sweep, self.estimator.estimate(sweep, self.key_points)

    def iterate(self, update: bool = True) -> IterationRecord:
        """One iteration; ``update=False`` only measures (used after the last update)."""
        applied, sweep, est = self.measure()
        delta = self.target - est.mean
        next_pwm = step_size = None
        info = {}
        if update:
            J = (self.model.jacobian(self.U, self.key_points)
                 if getattr(self.rule, 'needs_jacobian', True) else None)
            history = tuple(PastIteration(r.pwm, r.estimate.mean, r.estimate.std, r.info)
                            for r in self.history)
            step = self.rule.step(UpdateInput(self.k, self.U.copy(), delta, J, self.enabled, est.std,
                                              model=self.model, key_points=self.key_points,
                                              target=self.target, history=history))
            next_pwm, step_size, info = step.U_next, step.step_size, dict(step.info)
        true_field = true_error = None
        if self.truth is not None:
            true_field = self.truth(applied)
            true_error = mean_squared_error(true_field, self.target)
        rec = IterationRecord(self.k, applied, est, self.target, mean_squared_error(est.mean, self.target),
                              next_pwm, step_size, sweep, true_error, true_field, info)
        self.history.append(rec)
        if update:
            self.U = next_pwm
            self.k += 1
        return rec

    def run(self, iterations: int, on_iteration: Callable[[IterationRecord], None] | None = None,
            stop_early: bool = False):
        """``iterations`` updates, then one final measurement at the last commands.

        stop_early: end after the update whose rule says more iterations will not help
        (``info['stop']``, see ``stopping.StoppingRule``); the measurement at its commands
        is still taken, so the last record is always a measurement of the final commands."""
        for i in range(iterations + 1):
            rec = self.iterate(update=i < iterations)
            if on_iteration:
                on_iteration(rec)
            if stop_early and rec.info.get('stop') and i < iterations:
                rec = self.iterate(update=False)
                if on_iteration:
                    on_iteration(rec)
                break
        return self.history
