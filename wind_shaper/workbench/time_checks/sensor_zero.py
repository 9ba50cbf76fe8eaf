"""Do the fans-off sweeps read the same zero?

With every fan off the plate reads the sensor's zero (and any draft with the fans off, which
holds from sweep to sweep). Each fans-off sweep's level is its mean residual over its second
half, after a fan still spinning down from the sweep before has stopped, with a batch-means
standard error (gusts correlate neighbouring samples). The zero moved when the two levels
furthest apart differ by ``Recording.z`` standard errors and by a material force
(``Recording.size``).
"""
from __future__ import annotations

import numpy as np

from .base import Recording, TimeCheck, TimeResult, batch_mean_se, register_time_check

__all__ = ['SensorZero', 'fans_off_levels', 'ZERO_REPAIR']

#: The repair of recorded sweeps that subtracts the zero's change (``time_repairs``).
ZERO_REPAIR = '--zero-drift interpolate'


def fans_off_levels(rec: Recording) -> list[tuple[int, float, float]]:
    """[(index in ``rec.sweeps``, level [N], its standard error [N])] of the fans-off sweeps,
    in recording order: the mean residual over each one's second half."""
    out = []
    for i, s in enumerate(rec.sweeps):
        if s.off:
            half = s.residual[len(s.residual) // 2:]
            out.append((i, *batch_mean_se(half)))
    return out


@register_time_check
class SensorZero(TimeCheck):
    name = 'sensor_zero'
    question = 'Do the fans-off sweeps read the same zero?'

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        levels = fans_off_levels(rec)
        if len(levels) < 2:
            return self.skipped(f'{len(levels)} fans-off sweep(s): record the first and the last '
                                f'sweep with every fan off to see the sensor\'s zero')
        best = None
        for a in range(len(levels)):
            for b in range(a + 1, len(levels)):
                (i, la, sa), (j, lb, sb) = levels[a], levels[b]
                z = abs(lb - la) / max(np.hypot(sa, sb), 1e-12)
                if best is None or abs(lb - la) > abs(best[2]):
                    best = (i, j, lb - la, z)
        i, j, moved, z = best
        first, last = rec.sweeps[levels[0][0]], rec.sweeps[levels[-1][0]]
        span = levels[-1][1] - levels[0][1]
        apart = float(np.median(last.clock) - np.median(first.clock))
        fault = z >= rec.z and abs(moved) >= rec.size
        numbers = {'moved_N': moved, 'z': z, 'first_to_last_N': span, 'apart_s': apart,
                   'fans_off_sweeps': len(levels), 'material_N': rec.size}
        a, b = rec.sweeps[i], rec.sweeps[j]
        ends = (f'between the first and the last fans-off sweep ({first.label} and {last.label}, '
                f'{apart:.0f} s of plate time apart)' if (a is first and b is last) else
                f'between the fans-off sweeps {a.label} and {b.label}')
        message = (f'The force sensor\'s zero moved {moved:+.2f} N {ends}: with every fan off the '
                   f'plate read {levels[0][1]:+.3f} N at first and {levels[-1][1]:+.3f} N at last '
                   f'({z:.0f} standard errors apart; noise {rec.noise_sd:.3f} N per sample). Every '
                   f'sweep between carries its own part of that, which no effect of the flow '
                   f'describes. Bias the sensor with the fans off before each sweep (the '
                   f'coordinator\'s parameter bias_zero: every_sweep, in designed experiments and '
                   f'shaping runs), or '
                   f'repair these sweeps with {ZERO_REPAIR} (the zero\'s change interpolated '
                   f'linearly in recording time between the fans-off sweeps and subtracted).')
        return self.result(fault, numbers, message, ZERO_REPAIR)
