"""Does a finding keep one value whatever the commands? (``consistency.check_across_sweeps``)

Every effect the selection added is refitted sweep by sweep in the model with all the others
(an effect checked before a second real one is in the model would be perturbed by it). Its
record (``Trial.check``, a ``SweepCheck``) is the one every later check writes its refusal
into. A finding it refuses may get a second chance (``beside_discrepancy``); of the findings
still refused, the one whose spread is least likely by chance is demoted first.
"""
from __future__ import annotations

from ..consistency import check_across_sweeps
from .base import Check, CheckResult, Round, number, register_check


def sweep_numbers(c) -> dict:
    """The numbers of a ``SweepCheck``: sweeps that show the effect and that disagree, the
    chance of the spread, held-out sweeps it touches and improves."""
    return {'informative_sweeps': int(c.informative.sum()), 'disagree': int(c.disagree.sum()),
            'p_value': number(c.p_value, 6),
            'heldout_touched': int(c.heldout_informative.sum()),
            'heldout_better': int((c.heldout_better & c.heldout_informative).sum())}


@register_check
class AcrossSweeps(Check):
    name = 'across_sweeps'
    question = 'Does it keep one value whatever the commands, sweep by sweep?'
    refusal = 'it does not hold across sweeps'
    setting = 'check_sweeps'
    stage = 'sweeps'
    first_only = False

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        s, t = case.settings, rnd.kept[i]
        t.check = c = check_across_sweeps(rnd.final.model, t.candidate.label, t.candidate.null,
                                          case.train, case.heldout, rnd.withouts[i].model,
                                          min_sweeps=s.check_min_sweeps, tolerance=s.check_tolerance)
        # of the findings refused, the one whose spread is least likely by chance goes first
        return self.result(c.passed, sweep_numbers(c), '; '.join(c.reasons), rank=c.p_value)

    def demote(self, trial, result: CheckResult) -> None:
        """The check wrote its reasons into the record already."""
