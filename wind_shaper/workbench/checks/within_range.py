"""Does a finding keep its fitted parameters inside the range its physics allows?
(``consistency.check_within_range``) A fit that runs to the edge asks for more than the
family's form can give: the physics is of another form."""
from __future__ import annotations

from ..consistency import within_range
from ..trial import node_of
from .base import Check, CheckResult, Round, register_check


@register_check
class WithinRange(Check):
    name = 'within_range'
    question = 'Do its fitted parameters stay inside the range its physics allows?'
    refusal = 'its ... ran to the edge of the range its physics allows'
    setting = 'check_range'

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        t = rnd.kept[i]
        numbers, why = within_range(node_of(rnd.final.model, t.candidate.label), t.candidate.null)
        return self.result(not why, numbers, why)
