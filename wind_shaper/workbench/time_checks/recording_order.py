"""Does the residual follow the recording order?

A flow effect gives the same residual whenever a sweep is recorded; the sweeps of a design are
recorded in an order that has nothing to do with their commands. Each sweep's mean residual is
regressed on its recording time (its middle, the sweeps laid end to end: the data hold no clock
between sweeps); the sweeps' scatter about the line (their model error included) gives the
slope's standard error, tested with the Student-t at the level of ``Recording.z``. A fault: a
significant slope whose change from the first to the last sweep is material.
"""
from __future__ import annotations

import numpy as np

from .base import Recording, TimeCheck, TimeResult, register_time_check, t_limit
from .sensor_zero import ZERO_REPAIR

__all__ = ['RecordingOrder']


@register_time_check
class RecordingOrder(TimeCheck):
    name = 'recording_order'
    question = 'Does the residual follow the recording order?'

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        n = len(rec.sweeps)
        if n < 5:
            return self.skipped(f'{n} sweeps are too few for a trend')
        x = np.array([float(np.median(s.clock)) for s in rec.sweeps])
        m = np.array([float(np.mean(s.residual)) for s in rec.sweeps])
        xc = x - x.mean()
        slope = float(xc @ (m - m.mean()) / (xc @ xc))
        scatter = m - m.mean() - slope * xc
        se = float(np.sqrt(scatter @ scatter / (n - 2) / (xc @ xc)))
        t = slope / max(se, 1e-12)
        span = slope * (x[-1] - x[0])
        per_sweep = span / (n - 1)
        limit = t_limit(rec.z, n - 2)
        fault = abs(t) >= limit and abs(span) >= rec.size
        numbers = {'slope_N_per_s': slope, 'slope_se': se, 't': t, 't_limit': limit, 'first_to_last_N': span,
                   'per_sweep_N': per_sweep, 'material_N': rec.size}
        zero = earlier.get('sensor_zero')
        if zero is not None and zero.fault:
            why = (f'the same drift the fans-off sweeps show: {ZERO_REPAIR} repairs both')
        elif any(s.off for s in rec.sweeps):
            why = (f'if the fans-off sweeps at the start and the end agree, something else changed '
                   f'with time (the tunnel warming, a supply sagging); if the zero drifted, bias '
                   f'the sensor before each sweep or repair with {ZERO_REPAIR}')
        else:
            why = ('record the first and the last sweep with every fan off: they measure the '
                   'sensor\'s zero, and tell a drifting zero from a flow that changes with time')
        message = (f'The residual follows the recording order: the sweeps\' mean residual changes '
                   f'{per_sweep:+.3f} N per sweep, {span:+.2f} N from the first to the last '
                   f'(t = {t:.1f}, the test\'s limit {limit:.1f}). An effect of the flow does not '
                   f'depend on when a sweep was recorded; {why}.')
        return self.result(fault, numbers, message, ZERO_REPAIR if any(s.off for s in rec.sweeps) else '')
