"""Are the forces and the positions in step? The lag between motion capture and the force sensor.

Each sweep pairs every force sample with the plate's position at the same time stamp. When the
two clocks disagree (motion capture delivered late, a force sensor buffered, a wrong time
offset), each force is paired with where the plate was some time before or after. The field is
then read smeared along the plate's path, which no term of position and fan commands describes,
and with a 20 cm plate a lag of a few samples hides under the averaging.

The plate moves back and forth in every direction, so the model's own errors of the field (which
do not depend on the path) pull the best lag neither way; a real lag pulls every sweep the same
way. For lags L on a grid of the sampling interval, each force is paired with the position
interpolated at t + L, and the model's squared error is summed per sweep; the best lag per
sweep comes from a parabola through the three grid values around its minimum. ``check_sync``
reports the median over the sweeps that move the plate under a flow, and says the clocks are
out of step when it is at least half a sample from zero, and the sweeps agree on its sign.

A clock can also step during an experiment (a time sync that jumps, a stream started again):
then some sweeps are out of step and the others are not, and the median says nothing. Each
sweep is also tried at lags up to ``MAX_REPAIR_S`` either way (coarsely beyond ``max_lag``,
then refined), and a sweep is named on its own when its best lag lies at least
``STEP_MIN_S`` from the median and pairing it there removes at least half of its own squared
error: the model's errors of the field move with the fans, not with the path, and do not
vanish by sliding the positions along it.

Times [s], positions [m], forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import ConfigError
from ..model import Term
from .data import SweepSet

__all__ = ['SyncCheck', 'check_sync', 'repaired', 'MAX_REPAIR_S', 'STEP_MIN_S']

#: The largest lag [s] ``repaired`` accepts: beyond it the recording is broken, not late.
MAX_REPAIR_S = 1.0
#: A sweep is out of step on its own when its best lag lies this far [s] from the others'.
STEP_MIN_S = 0.05
#: ... and pairing it at that lag removes at least this share of its squared error.
STEP_MIN_DROP = 0.5
#: The coarse grid [s] of lags beyond ``max_lag`` (a lag bowl is wider: the plate crosses a jet in longer).
_COARSE_S = 0.1


@dataclass(frozen=True)
class SyncCheck:
    """lag_s: the median over the sweeps of the best lag [s] (> 0: each position belongs to a
    force recorded that much earlier, i.e. the positions arrive late); per_sweep: each sweep's
    best lag [s]; dt: the sampling interval [s]; drop: the share of the model's mean squared
    error removed by pairing at the best lag instead of 0; agree: the share of sweeps whose
    best lag has the median's sign; out_of_step: whether the two clocks disagree."""

    lag_s: float
    per_sweep: np.ndarray
    dt: float
    drop: float
    agree: float
    out_of_step: bool
    #: per_sweep's sweeps: their places in the sweep set (0-based) and labels
    sweeps: tuple = ()
    labels: tuple = ()
    #: each of those sweeps' share of its own squared error removed at its best lag
    per_sweep_drop: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: the places (0-based) of the sweeps out of step on their own (see the module docstring)
    stepped: tuple = ()

    def text(self) -> str:
        return ' '.join(t for t in (self._constant_text(), self._stepped_text()) if t)

    def _stepped_text(self) -> str:
        if not self.stepped:
            return ''
        at = {i: k for k, i in enumerate(self.sweeps)}
        lags = np.array([self.per_sweep[at[i]] for i in self.stepped])
        drops = np.array([self.per_sweep_drop[at[i]] for i in self.stepped])
        names = ', '.join(str(self.labels[at[i]]) if self.labels else f'#{i + 1}' for i in self.stepped)
        lo, hi = 1000 * np.min(np.abs(lags)), 1000 * np.max(np.abs(lags))
        ms = f'{1000 * np.median(np.abs(lags)):.0f}' if hi - lo < 10 else f'{lo:.0f}-{hi:.0f}'
        way = 'late' if np.median(lags) > 0 else 'early'
        n = len(self.stepped)
        return (f'{"Sweep" if n == 1 else "Sweeps"} {names} of {len(self.sweeps)} with the plate moving '
                f'under a flow {"looks" if n == 1 else "look"} out of step on {"its" if n == 1 else "their"} '
                f'own: in {"it" if n == 1 else "them"} the positions arrive {ms} ms {way} (pairing them so '
                f'removes {100 * np.min(drops):.0f}-{100 * np.max(drops):.0f} % of '
                f'{"its" if n == 1 else "their"} squared error), in the others '
                f'{1000 * abs(self.lag_s):.0f} ms. A clock stepped while the experiment was recorded (a '
                f'time sync that jumped, a force or motion-capture stream started again): those forces are '
                f'paired with the wrong places, and the noise estimated from the sweeps counts that as '
                f'turbulence, so the verdict above reads the model error too small. Record '
                f'{"it" if n == 1 else "them"} again: in an experiment folder remove '
                f'{"its folder" if n == 1 else "their folders"} (sweeps/sNNN, NNN the row less one) and '
                f'run the same `wind-shaper collect` command, which records the rows not stored.')

    def _constant_text(self) -> str:
        if not self.out_of_step:
            return ''
        ms = 1000.0 * abs(self.lag_s)
        late = 'late' if self.lag_s > 0 else 'early'
        lo, hi = (1000.0 * np.percentile(np.abs(self.per_sweep), q) for q in (25, 75))
        return (f'The forces and the plate\'s positions look out of step: the model fits best with each '
                f'position paired with the force recorded {ms:.0f} ms {"earlier" if self.lag_s > 0 else "later"} '
                f'(the positions arrive {ms:.0f} ms {late}; {lo:.0f}-{hi:.0f} ms over the middle half of '
                f'the sweeps, {100 * self.agree:.0f} % of them agree on the direction; pairing them so '
                f'removes {100 * self.drop:.0f} % of the model\'s mean squared error). Check that motion '
                f'capture and the force sensor share one clock. A lag smears the field along the plate\'s '
                f'path: no effect of the library describes it, and the noise estimated from the sweeps '
                f'counts it as turbulence, so the model error above reads too small until it is mended. '
                f'To diagnose these sweeps as they should have been paired, give `--position-lag '
                f'{self.lag_s:.3f}` (seconds).')


def repaired(sweeps: SweepSet, lag_s: float, only=None) -> SweepSet:
    """``sweeps`` with each force paired with the plate's position ``lag_s`` [s] later (held at
    a sweep's end): what motion capture that arrives ``lag_s`` late should have recorded (a
    negative lag for positions that arrive early). Forces, times and commands are unchanged.
    ``only``: the places (0-based) of the sweeps to re-pair (default: all), e.g. those a clock
    step hit."""
    lag = float(lag_s)
    if not (np.isfinite(lag) and abs(lag) <= MAX_REPAIR_S):
        raise ConfigError(f'a position lag must be a number of seconds within +-{MAX_REPAIR_S:g} (the '
                          f'diagnosis measures it: "the positions arrive 40 ms late" is 0.040); got {lag_s!r}')
    if lag == 0:
        return sweeps
    picked = set(range(len(sweeps.sweeps)) if only is None else only)
    moved = tuple(type(s)(s.positions_at(s.times + lag), s.forces, s.times, s.pwm) if i in picked else s
                  for i, s in enumerate(sweeps.sweeps))
    source = f'{sweeps.source} (positions re-paired {1000 * lag:+.0f} ms)'.strip()
    return type(sweeps)(moved, sweeps.fan_names, source, sweeps.labels)


def check_sync(model: Term, sweeps: SweepSet, *, max_lag: float = 0.2, min_force: float = 0.05,
               min_travel: float = 0.05, min_agree: float = 0.75) -> SyncCheck | None:
    """The lag between forces and positions of ``sweeps`` under ``model`` (see the module
    docstring), or None when no sweep can show it (every sweep fans off, or the plate held
    still: less than ``min_travel`` [m] of path, or forces under ``min_force`` [N] RMS).
    ``max_lag`` [s]: the largest lag tried either way at every sample (beyond it, up to
    ``MAX_REPAIR_S``, on a grid of 0.1 s, refined around a minimum found there)."""
    best, drops, places, labels, sse0, sse_best, dts = [], [], [], [], 0.0, 0.0, []
    for place, s in enumerate(sweeps.sweeps):
        s = s.finite()
        if len(s) < 20:
            continue
        dt = float(np.median(np.diff(s.times)))
        travel = float(np.sum(np.hypot(*np.diff(s.positions, axis=0).T)))
        if not (dt > 0 and travel >= min_travel and np.sqrt(np.mean(s.forces ** 2)) >= min_force):
            continue
        U = np.broadcast_to(np.asarray(s.pwm, float), (len(s), len(s.pwm)))

        def sse_at(lags):
            return np.array([float(np.sum((s.forces - model(U, s.positions_at(s.times + lag))) ** 2))
                             for lag in lags])
        steps = int(np.ceil(max_lag / dt))
        lags = np.arange(-steps, steps + 1) * dt
        sse = sse_at(lags)
        at_zero = sse[steps]
        far = np.arange(max_lag + _COARSE_S, MAX_REPAIR_S + 1e-9, _COARSE_S)
        far = np.concatenate([-far[::-1], far])
        sse_far = sse_at(far)
        if sse_far.size and sse_far.min() < sse.min():
            # a minimum beyond the fine grid: the fine grid again around it
            centre = far[int(np.argmin(sse_far))]
            lags = centre + np.arange(-int(np.ceil(_COARSE_S / dt)), int(np.ceil(_COARSE_S / dt)) + 1) * dt
            sse = sse_at(lags)
        k = int(np.argmin(sse))
        lag = lags[k]
        if 0 < k < len(lags) - 1:  # a parabola through the minimum and its neighbours
            a, b, c = sse[k - 1], sse[k], sse[k + 1]
            curve = a - 2 * b + c
            if curve > 0:
                lag += 0.5 * dt * (a - c) / curve
        best.append(lag)
        drops.append(1.0 - float(np.min(sse)) / at_zero if at_zero > 0 else 0.0)
        places.append(place)
        labels.append(sweeps.labels[place] if place < len(sweeps.labels) else f'#{place}')
        dts.append(dt)
        sse0 += at_zero
        sse_best += float(np.min(sse))
    if not best:
        return None
    best, drops = np.array(best), np.array(drops)
    dt = float(np.median(dts))
    median = float(np.median(best))
    agree = float(np.mean(np.sign(best) == np.sign(median))) if median != 0 else 0.0
    drop = 1.0 - sse_best / sse0 if sse0 > 0 else 0.0
    out = abs(median) >= 0.5 * dt and agree >= min_agree and len(best) >= 3
    stepped = tuple(p for p, lag, d in zip(places, best, drops)
                    if abs(lag - median) >= max(STEP_MIN_S, 2 * dt) and d >= STEP_MIN_DROP)
    if len(stepped) > len(best) // 2:   # most sweeps stepped: the clocks are out of step as a whole
        stepped = ()
    return SyncCheck(median, best, dt, float(drop), agree, bool(out), tuple(places), tuple(labels),
                     drops, stepped)
