"""Closed loop on the simulator: does the improved model shape the field better?

The shaping loop (``wind_shaper.control.ShapingLoop``, as ``wind-shaper shape`` runs it) uses the model for its
start (the warm start: the prior's optimum, unless ``u0`` is a command) and for its steps (the
Jacobian dPhi/dU, the search direction). ``compare_closed_loop`` runs the same loop with each
model as the prior, on the same simulated tunnel (same hidden effects, same seeds, so the same
turbulence), and records the true-field RMSE to the target at every iteration [N].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from ..control import ShapingLoop
from ..model import Term

__all__ = ['LoopComparison', 'compare_closed_loop']


@dataclass(frozen=True)
class LoopComparison:
    """errors: {model label: (n_seeds, iterations + 1) true-field RMSE [N] per iteration};
    pwm: {label: (n_seeds, iterations + 1, n_fans) commands}; target: its description."""

    target: str
    seeds: tuple
    errors: dict
    pwm: dict

    def at(self, k: int) -> dict:
        """Median over seeds of the true RMSE at iteration k, per model [N]."""
        return {label: float(np.median(e[:, k])) for label, e in self.errors.items()}

    def to_json(self) -> dict:
        return {'target': self.target, 'seeds': list(self.seeds),
                'true_rmse_N': {k: np.round(v, 5).tolist() for k, v in self.errors.items()},
                'median_true_rmse_N': {k: np.round(np.median(v, axis=0), 5).tolist()
                                       for k, v in self.errors.items()}}


def compare_closed_loop(setup, models: Mapping[str, Term], make_sim: Callable[[int], object], *,
                        target='parabolic', iterations: int = 6, seeds: Sequence[int] = (0,),
                        u0=None, rule_overrides: dict | None = None) -> LoopComparison:
    """Run ``iterations`` updates of the shaping loop with each model on ``make_sim(seed)`` for
    every seed; ``setup`` is a ``wind_shaper.app.Setup`` (key points, update rule, estimator);
    ``rule_overrides`` go to ``setup.shaping.make_rule`` (e.g. another update method)."""
    kp = setup.geometry.key_points
    errors, pwm, described = {}, {}, ''
    for label, model in models.items():
        tgt = setup.make_target(target, model=model)
        described = tgt.describe()
        e_runs, p_runs = [], []
        for seed in seeds:
            sim = make_sim(seed)
            loop = ShapingLoop.from_settings(sim, model, tgt.values(kp), setup.shaping, u0=u0,
                                             rule_overrides=rule_overrides,
                                             truth=lambda U, sim=sim: sim.true_field(U, kp))
            records = loop.run(iterations)
            e_runs.append([np.sqrt(r.true_error) for r in records])
            p_runs.append([r.pwm for r in records])
        errors[label] = np.array(e_runs)
        pwm[label] = np.array(p_runs)
    return LoopComparison(described, tuple(seeds), errors, pwm)
