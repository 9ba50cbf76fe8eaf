"""The online-learning loop (Algorithm 1), independent of ROS and of the tunnel behind it.

Each iteration: apply U_k, sweep, estimate the field at the key points, compare with the target,
step the commands through the model's Jacobian. Errors are mean squared differences over the key
points, Err = (1/N) sum_i (F_i - F_des,i)^2 [N^2]; their root (RMSE) is in newtons.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from ..core.bias import BIAS_AT_ROW, BIAS_BEFORE_ROW, bias_plan, check_bias_mode
from ..core.errors import ConfigError
from ..estimation import FieldEstimate, FieldEstimator
from ..model import Term
from ..core.tunnel import Sweep, Tunnel
from .region import RegionPlan, next_region, region_record
from .sweep_length import SweepLength, SweepMonitor, SweepProgress
from .update import PastIteration, UpdateInput, UpdateRule
from .warm_start import WarmStart, first_step_rule, warm_start


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
    settle_s: float = 0.0

    @property
    def plate_s(self) -> float:
        """Plate time of this iteration's sweep [s]."""
        return self.sweep.duration_s

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
            'max_key_point_gap_m': float(np.max(self.estimate.key_distance)),
            'plate_s': round(self.plate_s, 3), 'settle_s': round(self.settle_s, 3),
            'info': self.info,
        }


class ShapingLoop:
    """Drives a tunnel toward a target field.

    tunnel: anything satisfying ``Tunnel``; model: the prior (its Jacobian gives the search
    direction); target: (N,) desired force at the key points [N]; rule: the update rule
    (holds the command bounds); estimator: sweep -> field; u0: starting commands (scalar or
    (n_fans,)), or 'warm' for the prior's bounded optimum (``warm_start``; ``model_error`` [N]
    is the prior's calibration error, for the check of the first sweep); n_samples: the longest
    sweep; sweep_length: when a sweep may end early (``SweepLength``; None: always n_samples;
    needs a tunnel with ``sweep_chunks``); fan_settle_s: tunnel time the fans need after a new
    command before the sweep [s] (counted, not waited: the simulator settles at once);
    on_progress: called with a ``SweepProgress`` after every chunk of an adaptive sweep;
    truth: optional U -> true field at the key points, for scoring on a simulator; prior_maps:
    the commissioning's field maps of this tunnel at the same key points (``PastIteration``;
    ``workbench.calibrate.commissioning_maps``), for the rule's fit; bias_zero: when to bias the
    force sensor (``core.bias.BIAS_MODES``; 'every_sweep': every fan off, the tunnel's
    ``bias_sensor()``, then the iteration's commands, counted as two more ``fan_settle_s``).
    """

    def __init__(self, tunnel: Tunnel, model: Term, target: np.ndarray, rule: UpdateRule,
                 estimator: FieldEstimator = FieldEstimator(), u0=0.5, n_samples: int = 1000,
                 truth: Callable[[np.ndarray], np.ndarray] | None = None, *,
                 sweep_length: SweepLength | None = None, fan_settle_s: float = 0.0,
                 model_error: float = float('nan'), prior_maps: tuple = (),
                 on_progress: Callable[[SweepProgress], None] | None = None,
                 bias_zero: str = 'never'):
        geo = tunnel.geometry
        self.bias_zero = check_bias_mode(bias_zero, rule.bounds.u_min)
        if bias_zero != 'never' and not hasattr(tunnel, 'bias_sensor'):
            raise ConfigError(f'bias_zero {bias_zero!r} needs a tunnel that can bias its force '
                              f'sensor ({type(tunnel).__name__} has no bias_sensor); use never')
        self._biased = False   # whether the latest measure() biased the sensor first
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
        self.sweep_length, self.on_progress = sweep_length, on_progress
        self.fan_settle_s = float(fan_settle_s)
        self.prior_maps = tuple(prior_maps)
        for m in self.prior_maps:
            if np.shape(m.mean) != (len(self.key_points),) or np.shape(m.U) != (geo.fans.n_fans,):
                raise ConfigError(f'a commissioning map has {np.shape(m.mean)} values and '
                                  f'{np.shape(m.U)} commands for {len(self.key_points)} key points '
                                  f'and {geo.fans.n_fans} fans: estimate it at this tunnel\'s key points')
        self.warm: WarmStart | None = None
        if isinstance(u0, str):
            if u0 != 'warm':
                raise ConfigError(f"u0 must be a command (0..1) or 'warm'; got {u0!r}")
            self.warm = warm_start(model, self.key_points, self.target, rule.bounds, self.enabled,
                                   fan_names=geo.fans.names, model_error=model_error,
                                   idle_below=getattr(rule, 'idle_below', 0.0))
            u0 = self.warm.U
        self.U = rule.bounds.project(np.broadcast_to(np.asarray(u0, dtype=float), (geo.fans.n_fans,)),
                                     self.enabled)
        self.k = 0
        self.history: list[IterationRecord] = []

    @classmethod
    def from_settings(cls, tunnel: Tunnel, model: Term, target: np.ndarray, shaping, *, u0=None,
                      rule_overrides: dict | None = None,
                      truth: Callable[[np.ndarray], np.ndarray] | None = None,
                      model_error: float = float('nan'), sweep_length: SweepLength | None = None,
                      prior_maps: tuple = (), on_progress=None,
                      bias_zero: str = 'never') -> 'ShapingLoop':
        """The loop that ``shaping`` (a ``control.settings.ShapingConfig``) configures: its update
        rule (``rule_overrides={'method': 'paper'}`` for Algorithm 1), estimator, samples per
        sweep, sweep length, fan settle time and u0 (unless given); ``prior_maps``: the
        commissioning's field maps, ``bias_zero``: when to bias the sensor (see the class)."""
        return cls(tunnel, model, target, shaping.make_rule(**(rule_overrides or {})),
                   shaping.make_estimator(model), u0=shaping.u0 if u0 is None else u0,
                   n_samples=shaping.samples_per_sweep, truth=truth,
                   sweep_length=shaping.make_sweep_length() if sweep_length is None else sweep_length,
                   fan_settle_s=shaping.fan_settle_s, model_error=model_error,
                   prior_maps=prior_maps, on_progress=on_progress, bias_zero=bias_zero)

    def region_plan(self, U) -> RegionPlan | None:
        """Where the sweep at commands ``U`` must go (``control.region``): None for the whole
        area (the first sweep, region sweeps off, or too much of the field changed)."""
        if not self.history or not hasattr(self.tunnel, 'sweep_chunks'):
            return None
        last = self.history[-1]
        return next_region(self.sweep_length, self.rule, self.model, self.key_points,
                           PastIteration(last.pwm, last.estimate.mean, last.estimate.std, last.info), U)

    def measure(self) -> tuple[np.ndarray, Sweep, FieldEstimate, dict]:
        """Apply the commands, sweep, estimate: (applied, sweep, estimate, region), region the
        region sweep's plan and check as written to the record's info ({} for a whole sweep)."""
        when = bias_plan(self.U, self.bias_zero)[0]
        if when == BIAS_BEFORE_ROW:   # every fan off, settled, then zero the sensor
            self.tunnel.apply(np.zeros_like(self.U))
            self.tunnel.bias_sensor()
        applied = self.tunnel.apply(self.U)
        if when == BIAS_AT_ROW:
            self.tunnel.bias_sensor()
        self._biased = when == BIAS_BEFORE_ROW
        policy = self.sweep_length
        reuse = None   # the last sweep's fitted hyperparameters, between refits (SweepLength.refit_sweeps)
        if policy is not None and self.history and len(self.history) % policy.refit_sweeps:
            reuse = self.history[-1].estimate
        if policy is None or not policy.adaptive or not hasattr(self.tunnel, 'sweep_chunks'):
            sweep = self.tunnel.sweep(self.n_samples)
            return applied, sweep, self.estimator.estimate(sweep, self.key_points, reuse=reuse), {}
        plan = self.region_plan(applied)
        monitor = SweepMonitor(policy, self.estimator, self.key_points, policy.std_max(self.rule), plan,
                               reuse=reuse)
        parts = []
        for part in self.tunnel.sweep_chunks(self.n_samples, policy.chunk_samples,
                                             **({} if plan is None else {'region': plan.area})):
            parts.append(part)
            monitor.add(part.positions)
            progress = monitor.check(Sweep.concatenate(parts))
            if self.on_progress is not None:
                self.on_progress(progress)
            if progress.enough:
                return applied, Sweep.concatenate(parts), monitor.estimate, region_record(plan, monitor.consistency)
        sweep = Sweep.concatenate(parts)   # the longest sweep: estimated whatever its std
        estimate = monitor.final_estimate(sweep)
        return applied, sweep, estimate, region_record(plan, monitor.consistency)

    def iterate(self, update: bool = True) -> IterationRecord:
        """One iteration; ``update=False`` only measures (used after the last update)."""
        applied, sweep, est, region = self.measure()
        delta = self.target - est.mean
        next_pwm = step_size = None
        info = {'region': region} if region else {}
        rule, check = self.rule, None
        if self.k == 0 and not self.history and self.warm is not None:
            check = self.warm.compare(est.mean, est.std)
            info['warm_start'] = {**self.warm.to_json(), 'check': check.to_json(),
                                  'check_text': check.text()}
            rule = first_step_rule(rule, check)
        if update:
            J = (self.model.jacobian(self.U, self.key_points)
                 if getattr(self.rule, 'needs_jacobian', True) else None)
            history = tuple(PastIteration(r.pwm, r.estimate.mean, r.estimate.std, r.info)
                            for r in self.history)
            step = rule.step(UpdateInput(self.k, self.U.copy(), delta, J, self.enabled, est.std,
                                         model=self.model, key_points=self.key_points,
                                         target=self.target, history=history,
                                         prior_maps=self.prior_maps))
            next_pwm, step_size = step.U_next, step.step_size
            info = {**dict(step.info), **info}
            if check is not None:
                check = self.warm.after_first_step(check, step.info.get('predicted_error'))
                info['warm_start'] = {**info['warm_start'], 'check': check.to_json(),
                                      'check_text': check.text()}
                next_pwm, restart = self.warm.next_commands(check, next_pwm)
                info.update(restart)
        true_field = true_error = None
        if self.truth is not None:
            true_field = self.truth(applied)
            true_error = mean_squared_error(true_field, self.target)
        settle = self.fan_settle_s if (not self.history
                                       or not np.array_equal(self.history[-1].pwm, applied)) else 0.0
        if self._biased:   # the spin-down before the bias and the spin-up after it
            settle = 2.0 * self.fan_settle_s
        rec = IterationRecord(self.k, applied, est, self.target, mean_squared_error(est.mean, self.target),
                              next_pwm, step_size, sweep, true_error, true_field, info, settle)
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

    def tunnel_time(self) -> dict:
        """Tunnel time of the run so far [s]: plate (sweeping) and fan settling, per iteration
        and in total."""
        plate = [r.plate_s for r in self.history]
        settle = [r.settle_s for r in self.history]
        return {'plate_s': plate, 'settle_s': settle, 'plate_total_s': float(sum(plate)),
                'settle_total_s': float(sum(settle)), 'total_s': float(sum(plate) + sum(settle))}
