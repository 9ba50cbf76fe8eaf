"""What a check is, what it returns, and the registry of checks.

A check is a small object that answers one question about a candidate effect; it has a
``name``, the ``question`` it answers, ``refusal`` (how its refusal begins, in words), the
``setting`` of ``Diagnosis`` that switches it off ('' when it cannot be switched off) and
``stage``: ``'candidate'`` (the guard, run on every candidate the selection tries),
``'sweeps'`` (run on every finding in every round of the checks; the first thing a finding must
pass) or ``'finding'`` (run in registry order once every finding passes the ``'sweeps'``
checks; the first refusal demotes a finding). A check with ``second_chance_for`` set is run
on the findings the named check refused, and lifts the refusal where it passes.

Each run gives a ``CheckResult`` per finding: passed, refused or not run, the numbers the check
measured, and its refusal in words (or why it did not run). ``register_check`` adds a check to
``CHECKS``; the package's ``__init__`` imports one module per check, in the order they run.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['Check', 'CheckResult', 'Round', 'CHECKS', 'register_check', 'number']


def number(value, digits: int = 4):
    """A measured number for the report: rounded, None when it is not finite or missing."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    v = float(value)
    return round(v, digits) if np.isfinite(v) else None


@dataclass
class CheckResult:
    """One check's result for one trial: ``passed`` True (passed), False (refused) or None (not
    run); the ``numbers`` it measured; ``why``: its refusal in words, or why it did not run, or
    (passed) a note such as a second chance that lifted a refusal."""

    check: str
    passed: bool | None
    numbers: dict = field(default_factory=dict)
    why: str = ''
    #: Orders refused findings for demotion, lowest first (None: in the order selected).
    rank: float | None = None

    @property
    def state(self) -> str:
        return {True: 'passed', False: 'refused', None: 'not run'}[self.passed]

    def to_json(self) -> dict:
        return {'check': self.check, 'question': CHECKS[self.check].question if self.check in CHECKS else '',
                'result': self.state, 'numbers': dict(self.numbers), 'why': self.why}


@dataclass
class Round:
    """One round of the checks of the findings: ``kept``, the findings still in (``Trial``s,
    in the order they were selected); ``final``, the model with all of them refitted; and
    ``withouts``, per finding, the model with all the others."""

    kept: list
    final: object
    withouts: list


class Check:
    """A check (see the module docstring). Subclasses set the class attributes and implement
    ``judge`` (one trial, for ``stage`` 'candidate'; see ``guard``) or ``measure`` (every
    finding of a ``Round``)."""

    name: str = ''
    question: str = ''
    refusal: str = ''
    setting: str = ''
    stage: str = 'finding'
    #: For a second chance: the name of the check whose refusals this one may lift.
    second_chance_for: str = ''
    #: Stop at the first finding refused in a round (the next are not judged in it).
    first_only: bool = True

    def enabled(self, settings) -> bool:
        """Is the check switched on in the ``Diagnosis`` ``settings``?"""
        return not self.setting or bool(getattr(settings, self.setting))

    def applies(self, trial) -> bool:
        """Does the check apply to the finding ``trial`` (e.g. to its family)?"""
        return True

    def not_applying(self, trial) -> str:
        """Why the check does not apply to ``trial``, in words."""
        return f'does not apply to {trial.candidate.family}'

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        """The result for the ``i``-th finding of ``rnd`` (for checks that judge each finding on
        its own)."""
        raise NotImplementedError

    def measure(self, case, rnd: Round) -> dict:
        """{index in ``rnd.kept``: CheckResult} for the findings of the round: each finding it
        applies to in order, stopping after the first refusal when ``first_only``."""
        out = {}
        for i, t in enumerate(rnd.kept):
            if not self.applies(t):
                out[i] = self.skipped(self.not_applying(t))
                continue
            out[i] = r = self.judge_one(case, rnd, i)
            if r.passed is False and self.first_only:
                break
        return out

    def worst(self, refused: dict) -> int:
        """Which refused finding ({index into ``Round.kept``: result}) is demoted: the lowest
        ``rank``, else the first selected."""
        return min(refused, key=lambda i: (refused[i].rank if refused[i].rank is not None else 0.0, i))

    def demote(self, trial, result: CheckResult) -> None:
        """Write the refusal into the finding's record: like a value that does not hold across
        sweeps, a patch of something else, never promising (the verdict says the physics is
        likely outside the library)."""
        trial.check.passed, trial.check.spread = False, True
        trial.check.reasons.append(result.why)

    def result(self, passed: bool, numbers: dict, why: str = '', rank: float | None = None) -> CheckResult:
        return CheckResult(self.name, passed, numbers, why, rank)

    def skipped(self, why: str) -> CheckResult:
        return CheckResult(self.name, None, {}, why)

    def __repr__(self) -> str:
        return f'{type(self).__name__}()  # {self.name}: {self.question}'


#: Registry of checks by name, in the order they run (see the package's ``__init__``).
CHECKS: dict[str, Check] = {}


def register_check(cls: type) -> type:
    """Class decorator: register one instance of a ``Check`` subclass under its ``name``."""
    if not (isinstance(cls, type) and issubclass(cls, Check) and cls.name and cls.question
            and cls.refusal):
        raise TypeError(f'{cls!r} is not a Check subclass with a name, a question and a refusal')
    if cls.stage not in ('candidate', 'sweeps', 'finding'):
        raise TypeError(f'{cls.__name__}.stage must be candidate, sweeps or finding, not {cls.stage!r}')
    CHECKS[cls.name] = cls()
    return cls
