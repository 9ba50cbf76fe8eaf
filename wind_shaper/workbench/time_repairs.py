"""Repairs of recorded sweeps for faults in time, like ``sync.repaired`` for clocks out of step.

The time checks (``time_checks``) name the repair that fits what they found:

* ``zero_drift_repaired`` (``--zero-drift interpolate``): the force sensor's zero drifted. Each
  fans-off sweep measures the zero at its moment (its mean force over its second half, after any
  fan still spinning down has stopped). Between them the zero is interpolated linearly in
  recording time (held before the first and after the last), and its *change* since the first
  fans-off sweep is subtracted from every force: the zero stays as it was at the start, where a
  lab biases the sensor, and so does a draft with every fan off (physics, not the zero; one
  fans-off sweep cannot tell the two apart).
* ``skip_first`` (``--skip-first S``): the fans had not settled when the sweeps began; the first
  ``S`` seconds of every sweep are left out.

Recording time: the data hold no clock between sweeps, so the sweeps' plate time is laid end to
end in the order given (the order they were recorded in: a design's rows, a run's iterations).
Times [s], forces [N].
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.tunnel import Sweep
from .data import SweepSet

__all__ = ['zero_drift_repaired', 'skip_first', 'ZERO_DRIFT_METHODS', 'recording_clock',
           'fans_off']

#: How ``--zero-drift`` may repair the zero ('none': leave the forces as recorded).
ZERO_DRIFT_METHODS = ('none', 'interpolate')


def recording_clock(sweeps: SweepSet) -> list[np.ndarray]:
    """Each sweep's sample times on one recording clock [s]: the sweeps laid end to end."""
    out, offset = [], 0.0
    for s in sweeps.sweeps:
        t = np.asarray(s.times, float)
        out.append(offset + (t - t[0] if len(t) else t))
        offset += s.duration_s
    return out


def fans_off(sweeps: SweepSet, enabled=None) -> list[int]:
    """Indices of the sweeps with every (enabled) fan off."""
    U = sweeps.commands
    enabled = np.ones(U.shape[1], bool) if enabled is None else np.asarray(enabled, bool)
    return [i for i, u in enumerate(U) if np.all(np.abs(u[enabled]) < 1e-6)]


def zero_drift_repaired(sweeps: SweepSet, method: str = 'interpolate', enabled=None) -> SweepSet:
    """``sweeps`` with the sensor zero's drift subtracted (see the module docstring);
    ``method``: one of ``ZERO_DRIFT_METHODS``; ``enabled``: the tunnel's enabled fans (a fans-off
    sweep has every enabled fan at 0; default: every fan)."""
    if method not in ZERO_DRIFT_METHODS:
        raise ConfigError(f'--zero-drift must be one of {", ".join(ZERO_DRIFT_METHODS)}; got '
                          f'{method!r} (interpolate: the zero interpolated between the fans-off sweeps)')
    if method == 'none':
        return sweeps
    off = fans_off(sweeps, enabled)
    if len(off) < 2:
        raise ConfigError(f'--zero-drift interpolate needs at least two sweeps with every fan off '
                          f'(they measure the zero); these {len(sweeps)} sweeps have {len(off)}. '
                          f'Record the first and the last sweep with the fans off (a design of '
                          f'`wind-shaper collect --design lhs:12` does), or bias the sensor before '
                          f'each sweep')
    clocks = recording_clock(sweeps)
    at, level = [], []
    for i in off:
        s, t = sweeps.sweeps[i], clocks[i]
        ok = np.isfinite(s.forces)
        half = np.arange(len(s.forces)) >= len(s.forces) // 2
        if not np.any(ok & half):
            raise ConfigError(f'fans-off sweep {sweeps.labels[i]} has no finite force in its second '
                              f'half: it cannot measure the zero; leave it out or record it again')
        at.append(float(np.mean(t[ok & half])))
        level.append(float(np.mean(s.forces[ok & half])))
    at, level = np.array(at), np.array(level)
    change = level - level[0]
    fixed = tuple(Sweep(s.positions, s.forces - np.interp(t, at, change), s.times, s.pwm)
                  for s, t in zip(sweeps.sweeps, clocks))
    source = (f'{sweeps.source} (sensor zero interpolated between {len(off)} fans-off sweeps and '
              f'subtracted: it moved {level[-1] - level[0]:+.3f} N)').strip()
    return SweepSet(fixed, sweeps.fan_names, source, sweeps.labels)


def skip_first(sweeps: SweepSet, seconds: float) -> SweepSet:
    """``sweeps`` without the first ``seconds`` [s] of each sweep (the fans still settling)."""
    skip = float(seconds)
    if not (np.isfinite(skip) and skip >= 0):
        raise ConfigError(f'--skip-first must be a number of seconds >= 0 (the diagnosis names it: '
                          f'"the first 3 s of each sweep read the previous commands" is 3); got '
                          f'{seconds!r}')
    if skip == 0:
        return sweeps
    shortest = min((s.duration_s for s in sweeps.sweeps), default=0.0)
    if skip >= 0.8 * shortest:
        raise ConfigError(f'--skip-first {skip:g} leaves too little of the shortest sweep '
                          f'({shortest:.1f} s): skip less than {0.8 * shortest:.1f} s, or record '
                          f'with a longer settle time (the coordinator\'s settle_s) instead')
    kept = []
    for s in sweeps.sweeps:
        keep = np.asarray(s.times, float) >= float(s.times[0]) + skip
        kept.append(Sweep(s.positions[keep], s.forces[keep], s.times[keep], s.pwm))
    source = f'{sweeps.source} (first {skip:g} s of each sweep left out)'.strip()
    return SweepSet(tuple(kept), sweeps.fan_names, source, sweeps.labels)
