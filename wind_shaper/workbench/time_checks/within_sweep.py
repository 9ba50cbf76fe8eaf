"""Does the residual change with time within a sweep?

Each sweep's slope [N/s] of the residual with the time since the sweep started comes from the
places its path visits twice: over pairs of samples within ``REVISIT_M`` of each other and at
least ``REVISIT_S`` apart, the change of the residual against the time between them. At one
place the field, and whatever the model misses of it, is the same at both visits, so a flow
effect the model lacks cancels, while a sensor warming up or a zero that moves does not. (The
residual's plain slope over the sweep would read a spatial pattern as a drift wherever the
paths tend to reach it late, as a path leaving the axis reaches the walls: a wall layer, at 24
sweeps, was called a drift in every run.) Sweeps with too few revisits use that plain slope.
The sweeps' slopes are tested against zero with the Student-t across sweeps at the level of
``Recording.z``; a fault needs a material change over a typical sweep as well. When the first
seconds read the previous commands (``since_command``), the slopes leave them out; when the
residual drifts across the recording at the same rate (``recording_order``), the slope within
the sweeps is that drift and not a second fault.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..metrics import REVISIT_M, REVISIT_S
from .base import Recording, TimeCheck, TimeResult, register_time_check, t_limit

__all__ = ['WithinSweep']

#: Fewest revisit pairs a sweep's slope is taken from (else its plain slope over time).
MIN_REVISITS = 20


def _revisit_slope(t: np.ndarray, Z: np.ndarray, r: np.ndarray) -> float | None:
    """The residual's change per second between the visits of a place twice [N/s] (None with
    fewer than ``MIN_REVISITS`` pairs)."""
    pairs = cKDTree(Z).query_pairs(REVISIT_M, output_type='ndarray')
    if len(pairs) < MIN_REVISITS:
        return None
    dt = t[pairs[:, 1]] - t[pairs[:, 0]]
    far = np.abs(dt) >= REVISIT_S
    if int(far.sum()) < MIN_REVISITS:
        return None
    dt, dr = dt[far], (r[pairs[:, 1]] - r[pairs[:, 0]])[far]
    return float(dt @ dr / (dt @ dt))


@register_time_check
class WithinSweep(TimeCheck):
    name = 'within_sweep'
    question = 'Does the residual change with time within a sweep?'

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        settle = earlier.get('since_command')
        skip = settle.numbers['skip_s'] if settle is not None and settle.fault else 0.0
        slopes, durations, revisited = [], [], 0
        for s in rec.sweeps:
            keep = s.t >= skip
            t, r = s.t[keep], s.residual[keep]
            if len(t) < 20 or np.ptp(t) <= 0:
                continue
            slope = _revisit_slope(t, s.Z[keep], r)
            if slope is None:
                tc = t - t.mean()
                slope = float(tc @ (r - r.mean()) / (tc @ tc))
            else:
                revisited += 1
            slopes.append(slope)
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
                   'change_over_sweep_N': change, 'left_out_s': skip, 'material_N': rec.size,
                   'sweeps_from_revisits': revisited}
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
