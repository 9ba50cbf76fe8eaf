"""Does a finding hold against the thrust curves as commissioned, not only against the
refitted ones?

The diagnosis refits each mount group's thrust curve, so a per-fan effect is measured against its
group: when a pattern the library lacks pulls the group's curve, the one fan it spares looks
stronger than commissioned ("HM3 delivers 17 % more thrust") although it is unchanged. A real
change since commissioning is there against the curves as commissioned too: the findings are
refitted together with the curves held as the model had them, and one whose distance from no
effect keeps less than ``MIN_SHARE`` of the reported one is not reported (the one that keeps
least first).
"""
from __future__ import annotations

import numpy as np

from ...model import param_slices, term_label
from ..fitting import fit_model
from ..library import apply_candidate
from ..trial import node_of
from ..wording import values_text
from .base import Check, Round, number, register_check

#: The least share of its distance from no effect a finding keeps against the curves as
#: commissioned.
MIN_SHARE = 0.5


@register_check
class ThrustCurves(Check):
    name = 'thrust_curves'
    question = 'Does it keep its size against the thrust curves as commissioned?'
    refusal = 'it leans on the refitted thrust curves'
    first_only = False

    def measure(self, case, rnd: Round) -> dict:
        """Refit every finding of the round at once, with the rest of the model as given."""
        model = case.model
        for t in rnd.kept:
            model = apply_candidate(model, t.candidate, **t.params)
        labels = {t.candidate.label for t in rnd.kept}
        free = np.zeros(len(model.theta), bool)
        for node, sl in param_slices(model):
            if term_label(node) in labels:
                free[sl] = True
        held = fit_model(model, case.train, free=free, max_nfev=15)
        out = {}
        for i, t in enumerate(rnd.kept):
            reported = t.params
            as_held = t.candidate.params(node_of(held.model, t.candidate.label))
            least = None  # (share kept, parameter)
            for name, null in t.candidate.null.items():
                if name not in reported:
                    continue
                ref = np.broadcast_to(np.asarray(null, float), np.shape(reported[name]))
                far = float(np.linalg.norm(np.asarray(reported[name], float) - ref))
                kept_share = float(np.linalg.norm(np.asarray(as_held[name], float) - ref)) / max(far, 1e-12)
                if far > 0 and (least is None or kept_share < least[0]):
                    least = (kept_share, name)
            numbers = {'kept_share': number(least[0]) if least else None,
                       'parameter': least[1] if least else None}
            if least is None or least[0] >= MIN_SHARE:
                out[i] = self.result(True, numbers)
                continue
            name = least[1]
            out[i] = self.result(False, numbers, (
                f'it leans on the refitted thrust curves: against the curves as commissioned its '
                f'{name} is {values_text(as_held[name])}, not {values_text(reported[name])} (a pattern '
                f'the library lacks pulls its group\'s curve and this fan only looks different)'),
                rank=least[0])  # the one that keeps least is demoted first
        return out
