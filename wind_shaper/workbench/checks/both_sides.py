"""Does a change of one jet (its gain, landing point, width or shape), or an effect that held
only beside a discrepancy, hold on both sides of its footprint?
(``consistency.across_space``)

A patch that passes a fixed share of the flow beside a hub, or a stand's wake across one jet,
changes that jet the same way in every sweep, so the check across sweeps cannot refuse it; the
two sides of a real change of that jet agree. Other whole-tunnel effects are not cut: they would
fail for any pattern the library lacks on one side (swirl beside a warm wall).
"""
from __future__ import annotations

from ..consistency import across_space
from .base import Check, CheckResult, Round, register_check

#: The candidate families that change one fan's jet (checked on both sides of its footprint).
ONE_JET_FAMILIES = ('fan_gain', 'fan_shift', 'fan_width', 'fan_elongation', 'fan_shape')


@register_check
class BothSides(Check):
    name = 'both_sides'
    question = 'Does a change of one jet keep its value on both sides of its footprint?'
    refusal = 'it does not hold on both sides of its footprint'
    setting = 'check_space'

    def applies(self, trial) -> bool:
        rescued = trial.check.beside is not None and trial.check.beside.passed
        return trial.candidate.family in ONE_JET_FAMILIES or rescued

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        t = rnd.kept[i]
        numbers, why = across_space(rnd.final.model, t.candidate.label, t.candidate.null, case.train,
                                    rnd.withouts[i].model, tolerance=case.settings.check_tolerance)
        return self.result(not why, numbers, why)
