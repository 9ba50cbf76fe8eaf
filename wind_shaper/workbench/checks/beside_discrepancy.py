"""A second chance for a finding whose values spread across sweeps: does it hold once what the
library lacks is modelled beside it? (``consistency.check_beside_discrepancy``)

A real effect perturbed by physics the library lacks spreads sweep by sweep. Only the spread is
forgiven: an effect too few sweeps show, or that helps too few held-out sweeps, stays refused.
The discrepancy is tried as bumps x command features, then with the model's own scale beside
them (``discrepancy.SCALE_FEATURES``); the first form it holds beside is kept.
"""
from __future__ import annotations

from ..consistency import check_beside_discrepancy
from ..discrepancy import SCALE_FEATURES
from .base import Check, CheckResult, Round, number, register_check


@register_check
class BesideDiscrepancy(Check):
    name = 'beside_discrepancy'
    question = ('Where its values spread across sweeps: do they agree once a discrepancy model '
                'of what the library lacks is fitted beside it?')
    refusal = 'beside a discrepancy model it ...'
    setting = 'check_beside'
    stage = 'sweeps'
    second_chance_for = 'across_sweeps'
    first_only = False

    def applies(self, trial) -> bool:
        c = trial.check
        return c is not None and c.spread and not c.heldout_short

    def not_applying(self, trial) -> str:
        return 'only a spread across sweeps is forgiven, not this refusal'

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        """Rerun the check beside a discrepancy; where it holds, the finding's record passes."""
        s, t = case.settings, rnd.kept[i]
        c = t.check
        for scale in ((), SCALE_FEATURES):  # bumps only; then with the model's own scale too
            c.beside = check_beside_discrepancy(rnd.final.model, t.candidate.label, t.candidate.null,
                                                case.train, case.heldout, rnd.withouts[i].model,
                                                case.geometry, c.informative,
                                                tolerance=s.check_tolerance, scale_features=scale,
                                                values_before=c.values[c.informative])
            if c.beside.passed:
                break
        if c.beside.passed:
            c.passed, c.spread, c.reasons = True, False, []
        else:
            c.reasons += c.beside.reasons
        b = c.beside
        numbers = {'disagree': b.disagree, 'p_value': number(b.p_value, 6),
                   'kept_share': number(b.kept_share), 'z_null': number(b.z_null, 3),
                   'heldout_gain': number(b.heldout_gain), 'with_scale': bool(scale)}
        return self.result(b.passed, numbers, '; '.join(b.reasons))
