"""What a time check is, the recording it reads, and the registry of time checks.

A time check asks one question of the recording as a whole, before any candidate effect is
tried: does the residual (data minus the refitted model) depend on *when* a force was recorded
rather than on where the plate was and what the fans were commanded? An effect of the flow
cannot: the same commands and place give the same force at any time. A drifting sensor zero, or
fans still settling when a sweep starts, can, and beside such a fault every candidate of the
library is fitted to the wrong thing.

A check is a small registered object with a ``name``, the ``question`` it answers, and
``measure(recording, earlier)`` returning a ``TimeResult``: whether it found a fault (or did not
run, and why), the numbers it measured, and its message to the lab (what it is and what to do,
naming the repair, e.g. ``--zero-drift interpolate``). ``earlier`` holds the results of the
checks that ran before it (registry order), so a check can say a trend it sees is one an earlier
check already named. Thresholds are stated tests against the noise, never a number of one
simulator: a fault must be significant (``Recording.z``: a z or t statistic beyond it) *and*
material (``Recording.material`` times the noise per sample, the size of a model error the
diagnosis would chase).

Forces [N], times [s], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ...model import Term
from ..checks.base import number
from ..data import SweepSet

__all__ = ['TimeCheck', 'TimeResult', 'Recording', 'TIME_CHECKS', 'register_time_check',
           'batch_mean_se', 't_limit', 'number']


def t_limit(z: float, dof: int) -> float:
    """The Student-t quantile with ``dof`` degrees of freedom at the two-sided tail probability
    of a normal ``z`` (z = 5: p = 5.7e-7): the same false-alarm rate with few sweeps."""
    p = 2 * stats.norm.sf(z)
    return float(stats.t.isf(p / 2, max(int(dof), 1)))


def batch_mean_se(x: np.ndarray, blocks: int = 10) -> tuple[float, float]:
    """(mean, its standard error) of a series whose neighbouring samples are correlated
    (turbulent gusts): from the spread of the means of ``blocks`` consecutive blocks."""
    x = np.asarray(x, float)
    parts = np.array_split(x, min(blocks, max(len(x) // 5, 2)))
    means = np.array([p.mean() for p in parts if len(p)])
    return float(x.mean()), float(means.std(ddof=1) / np.sqrt(len(means)))


@dataclass
class SweepTrace:
    """One sweep in recording order: label; U (n_fans,) commands; t (K,) time within the sweep
    from its first sample; clock (K,) recording time (the sweeps laid end to end); Z (K, 2)
    positions; y (K,) forces; pred (K,) the model's forces; off: every enabled fan off."""

    label: str
    U: np.ndarray
    t: np.ndarray
    clock: np.ndarray
    Z: np.ndarray
    y: np.ndarray
    pred: np.ndarray
    off: bool

    @property
    def residual(self) -> np.ndarray:
        return self.y - self.pred

    @property
    def duration(self) -> float:
        return float(self.t[-1] + np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0


@dataclass
class Recording:
    """The sweeps in recording order with the model's forces, the noise and the thresholds.
    model: the refitted model; noise_sd [N] per sample; material [fraction of the noise]; z:
    the significance a fault must reach (normal quantile); enabled: the tunnel's enabled fans."""

    sweeps: list
    model: Term
    noise_sd: float
    material: float
    z: float
    enabled: np.ndarray

    @classmethod
    def of(cls, data: SweepSet, model: Term, *, noise_sd: float, material: float, z: float,
           enabled) -> 'Recording':
        traces, offset = [], 0.0
        enabled = np.asarray(enabled, bool)
        for label, s in zip(data.labels, data.sweeps):
            dur = s.duration_s
            s = s.finite()
            if len(s) >= 20:
                U = np.asarray(s.pwm, float)
                t = np.asarray(s.times, float) - float(s.times[0])
                pred = model(np.broadcast_to(U, (len(s), len(U))), s.positions)
                traces.append(SweepTrace(label, U, t, offset + t, s.positions, s.forces, pred,
                                         bool(np.all(np.abs(U[enabled]) < 1e-6))))
            offset += dur
        return cls(traces, model, float(noise_sd), float(material), float(z), enabled)

    @property
    def size(self) -> float:
        """The smallest material fault [N]: ``material`` times the noise per sample."""
        return self.material * self.noise_sd


@dataclass
class TimeResult:
    """One time check's result: ``fault`` True (found), False (none) or None (not run);
    ``numbers`` it measured; ``message``: what it found and what to do, or why it did not run;
    ``repair``: the option of ``wind-shaper model diagnose`` that repairs recorded sweeps
    ('' when none does)."""

    check: str
    fault: bool | None
    numbers: dict = field(default_factory=dict)
    message: str = ''
    repair: str = ''

    @property
    def state(self) -> str:
        return {True: 'fault', False: 'none', None: 'not run'}[self.fault]

    def to_json(self) -> dict:
        return {'check': self.check, 'question': TIME_CHECKS[self.check].question
                if self.check in TIME_CHECKS else '', 'result': self.state,
                'numbers': {k: number(v) for k, v in self.numbers.items()},
                'message': self.message, 'repair': self.repair}


class TimeCheck:
    """A time check (see the module docstring): set ``name`` and ``question``, implement
    ``measure``."""

    name: str = ''
    question: str = ''

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        raise NotImplementedError

    def result(self, fault: bool, numbers: dict, message: str = '', repair: str = '') -> TimeResult:
        return TimeResult(self.name, bool(fault), numbers, message if fault else '', repair if fault else '')

    def skipped(self, why: str) -> TimeResult:
        return TimeResult(self.name, None, {}, why)

    def __repr__(self) -> str:
        return f'{type(self).__name__}()  # {self.name}: {self.question}'


#: Registry of time checks by name, in the order they run (see the package's ``__init__``).
TIME_CHECKS: dict[str, TimeCheck] = {}


def register_time_check(cls: type) -> type:
    """Class decorator: register one instance of a ``TimeCheck`` subclass under its ``name``."""
    if not (isinstance(cls, type) and issubclass(cls, TimeCheck) and cls.name and cls.question):
        raise TypeError(f'{cls!r} is not a TimeCheck subclass with a name and a question')
    TIME_CHECKS[cls.name] = cls()
    return cls
