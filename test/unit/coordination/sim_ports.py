"""The rig's ports on the in-process simulator, for the coordination tests (no rclpy)."""
import asyncio

import numpy as np

from wind_shaper.coordination import CANCELLED, SWEEPING, FieldAnswer, IterationStopped
from wind_shaper.core.tunnel import Sweep


class SimPorts:
    """The rig's ports on the in-process simulator: commands go to the plant, a sweep records
    1000 samples (a region sweep: 400 over its region), the estimate is the core
    FieldEstimator's. ``refuse`` sweeps are refused first
    (as an estimator does on coverage gaps); ``cancel_after`` raises at that boundary."""

    def __init__(self, setup, seed=0, refuse=0, cancel_after=None):
        self.sim = setup.make_sim(seed=seed)
        self.estimator = setup.shaping.make_estimator(setup.load_model())
        self.key_points = setup.geometry.key_points
        self.states, self.warnings, self.commanded = [], [], []
        self.refuse, self.cancel_after, self.boundaries = refuse, cancel_after, 0
        self.samples, self.plans = [], []
        self.rows, self.done = [], []

    def set_state(self, state, message):
        self.states.append(state)

    def warn(self, message):
        self.warnings.append(message)

    def check_boundary(self):
        self.boundaries += 1
        if self.cancel_after is not None and self.boundaries > self.cancel_after:
            raise IterationStopped(CANCELLED, 'cancelled by the test')

    async def command_fans(self, U):
        self.commanded.append(np.array(U))
        self.sim.apply(U)
        await asyncio.sleep(0)

    async def compute(self, fn, *args, **kwargs):
        return fn(*args, **kwargs)

    async def begin_sweep(self):
        self.samples = []

    async def sweep(self, k, attempt, plan=None):
        self.set_state(SWEEPING, f'sweep {attempt}')
        self.plans.append(plan)
        self.samples.append(self.sim.sweep(1000 if plan is None else 400,
                                           region=None if plan is None else plan.area))
        await asyncio.sleep(0)

    def pooled(self, U):
        s = self.samples
        return Sweep(np.concatenate([x.positions for x in s]), np.concatenate([x.forces for x in s]),
                     np.concatenate([x.times for x in s]), U)

    async def estimate(self, k, U, plan=None):
        if self.refuse:
            self.refuse -= 1
            # a refused sweep's pairs come back, as the field estimator sends them
            return FieldAnswer(False, 'a gap of 9 cm', sweep=self.pooled(U))
        sweep = self.pooled(U)
        est = self.estimator.estimate(sweep, self.key_points,
                                      required=None if plan is None else plan.needed)
        return FieldAnswer(True, '', self.key_points, est.mean, est.std, sweep, est.n_used, 0.01)

    # an experiment's two extra ports
    def at_row(self, index, attempt):
        self.rows.append((index, attempt))

    def row_done(self, index, outcome, sweep, coverage):
        self.done.append((index, outcome, None if sweep is None else len(sweep), coverage))
