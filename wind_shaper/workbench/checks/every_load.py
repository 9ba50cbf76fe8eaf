"""Does a finding keep its value whether the nearest fan runs high or low against the others?
(``consistency.across_load``) A term of another form than the physics (a boundary layer for a
return flow down the wall that follows the whole tunnel's thrust) holds in every sweep, since
each sweep averages strong and weak jets, but not at every load."""
from __future__ import annotations

from ..consistency import across_load
from .base import Check, CheckResult, Round, register_check


@register_check
class EveryLoad(Check):
    name = 'every_load'
    question = 'Does it keep its value where the nearest fan runs high and where it runs low?'
    refusal = 'it does not hold at every load'
    setting = 'check_load'

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        t = rnd.kept[i]
        numbers, why = across_load(rnd.final.model, t.candidate.label, t.candidate.null, case.train,
                                   rnd.withouts[i].model, case.geometry,
                                   tolerance=case.settings.check_tolerance)
        return self.result(not why, numbers, why)
