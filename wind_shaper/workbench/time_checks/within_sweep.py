"""Does the residual change with time within a sweep?

Each sweep's residual is regressed on the time since the sweep started (its slope [N/s]); a
flow effect gives slopes that scatter about zero (the plate's path wanders through the field in
no order of time), a sensor warming up or a zero that moves gives them one sign. The sweeps'
slopes are tested against zero with the Student-t across sweeps at the level of
``Recording.z``; a fault needs a material change over a typical sweep as well. When the first
seconds read the previous commands (``since_command``), the slopes leave them out; when the
residual drifts across the recording at the same rate (``recording_order``), the slope within
the sweeps is that drift and not a second fault.
"""
from __future__ import annotations

import numpy as np

from .base import Recording, TimeCheck, TimeResult, register_time_check, t_limit

__all__ = ['WithinSweep']


@register_time_check
class WithinSweep(TimeCheck):
    name = 'within_sweep'
    question = 'Does the residual change with time within a sweep?'

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        settle = earlier.get('since_command')
        skip = settle.numbers['skip_s'] if settle is not None and settle.fault else 0.0
        slopes, durations = [], []
        for s in rec.sweeps:
            keep = s.t >= skip
            t, r = s.t[keep], s.residual[keep]
            if len(t) < 20 or np.ptp(t) <= 0:
                continue
            tc = t - t.mean()
            slopes.append(float(tc @ (r - r.mean()) / (tc @ tc)))
            durations.append(s.duration - skip)
        n = len(slopes)
        if n < 4:
            return self.skipped(f'{n} sweeps long enough for a slope: too few')
        slopes = np.array(slopes)
        mean, se = float(slopes.mean()), float(slopes.std(ddof=1) / np.sqrt(n))
        t = mean / max(se, 1e-12)
        typical = float(np.median(durations))
        change = mean * typical
        limit = t_limit(rec.z, n - 1)
        fault = abs(t) >= limit and abs(change) >= rec.size
        numbers = {'slope_N_per_s': mean, 'slope_se': se, 't': t, 't_limit': limit,
                   'change_over_sweep_N': change, 'left_out_s': skip, 'material_N': rec.size}
        order = earlier.get('recording_order')
        if fault and order is not None and order.fault:
            across, across_se = order.numbers['slope_N_per_s'], order.numbers['slope_se']
            if abs(mean - across) <= 3 * np.hypot(se, across_se):
                numbers['same_as_recording_drift'] = True
                return TimeResult(self.name, False, numbers,
                                  f'the residual rises {mean:+.4f} N/s within the sweeps, as across '
                                  f'the recording ({across:+.4f} N/s): the same drift, named above')
        message = (f'The residual changes with time within the sweeps: {change:+.2f} N over a '
                   f'typical sweep of {typical:.0f} s ({mean:+.4f} N/s on average over {n} sweeps, '
                   f't = {t:.1f}, the test\'s limit {limit:.1f}), which no effect of the flow does. '
                   f'A sensor warming up after a bias, or a plate or mount settling, would: check '
                   f'the force sensor\'s reading with the fans off over a sweep\'s length.')
        return self.result(fault, numbers, message, '')
