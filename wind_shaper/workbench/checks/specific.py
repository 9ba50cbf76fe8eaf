"""Is a finding specific to what it claims? A change of chosen fans' jets (their landing point,
width, elongation or shape) must be specific to those fans, a jet interaction to its pairs of
jets.

Physics the library lacks that moves or widens every jet (a draft across the tunnel, jets that
spread with their thrust) is partly explained by moving or widening one fan or one group, and
that finding holds across sweeps, on both sides of the footprint and at every load. A real change
of one jet is specific: the same change of every fan's jet (``group='all'``, one shared value,
refitted from the finding's values) explains little of it, so beside that form the finding still
lowers the held-out error by at least ``min_specific`` of what it lowers it alone. A landing
offset is also checked beside every jet moved outwards from the axis by one distance
(``FanPush``): jets that cling to the wall move each in its own direction, which one shared
vector cannot follow. A jet interaction is checked beside the same bridges filled by the
tunnel's mean thrust: a leak or a recirculation that follows the tunnel's pressure fits as wide,
weak bridges, whose gain then owes nothing to each pair's thrusts (``broader_forms``). A gain is
not checked: the same gain for every fan is the refitted thrust curves.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...model import ALL_FANS, FanPush, FanShift, FanWrapper, JetInteraction, Term
from ..fitting import fit_model
from ..library import Candidate, apply_candidate
from ..trial import fit_mask, node_of
from ..wording import _change_text, pct_text
from .base import Check, CheckResult, Round, number, register_check

__all__ = ['Specific', 'SPECIFIC_FAMILIES', 'broader_forms', 'every_fan_form', 'mean_thrust_form']

#: Families whose findings must be specific to what they claim: chosen fans' jets, and the
#: pairs of neighbouring jets.
SPECIFIC_FAMILIES = ('fan_shift', 'fan_width', 'fan_elongation', 'fan_shape', 'jet_interaction')


def every_fan_form(candidate: Candidate, cls: type, title: str = 'every fan alike') -> Candidate:
    """``candidate``'s change applied to every enabled fan with one shared value: a term of
    class ``cls`` (a ``FanWrapper``) with ``group='all'``, placed as the candidate is."""
    kind = cls.kind
    return replace(candidate, name=f'{kind}[{ALL_FANS}]', label=f'{kind}[{ALL_FANS}]', family=kind,
                   title=f'{candidate.title} ({title})', fans=(),
                   make=lambda m, **p: cls(m.fans, m, group=ALL_FANS, **p))


def mean_thrust_form(candidate: Candidate) -> Candidate:
    """The jet-interaction ``candidate``'s bridges filled by the tunnel's mean thrust instead
    of each pair's (``JetInteraction(follows='mean')``), placed as the candidate is."""
    return replace(candidate, name='jet_interaction[mean]', label='jet_interaction', family='jet_interaction',
                   title=f'{candidate.title} (following the mean thrust)',
                   make=lambda m, **p: JetInteraction(m.fans, m, follows='mean', **p))


def broader_forms(candidate: Candidate, node: Term, fans) -> list:
    """[(broader form, its start values, words)] a finding is checked beside: the same kind of
    change without what makes the finding specific, started from the finding's values.

    A change of chosen fans' jets: the same change of every jet with one shared value; a
    landing offset also every jet moved outwards from the axis by one distance (jets that cling
    to the wall or are drawn to the middle move each in its own direction, which one shared
    vector cannot follow), started from the finding's outward part. A jet interaction: the
    same bridges filled by the tunnel's mean thrust rather than by each pair's thrusts."""
    if isinstance(node, JetInteraction):
        if node.follows == 'mean':
            return []
        start = {'strength': node.strength, 'width': node.width}
        return [(mean_thrust_form(candidate), start,
                 "the same bridges between the jets following the tunnel's mean thrust instead of "
                 "each pair's thrusts")]
    if not isinstance(node, FanWrapper) or node.group == ALL_FANS:
        return []
    out = [(every_fan_form(candidate, type(node)), candidate.params(node),
            "the same change of every fan's jet")]
    if isinstance(node, FanShift) and node.fan is not None:
        hubs = np.asarray(fans.positions, float)[[fans.index(name) for name in node.fan]]
        radius = np.hypot(hubs[:, 0], hubs[:, 1])
        shifts = node.shift.reshape(-1, 2)
        outward = [float(s @ h / r) for s, h, r in zip(shifts, hubs, radius) if r > 1e-6]
        if outward:
            (bounds,) = [h.bounds for h in FanPush.hypers if h.name == 'push']
            push = float(np.clip(np.mean(outward), *bounds))
            out.append((every_fan_form(candidate, FanPush, 'every jet pushed from the axis alike'),
                        {'push': push}, 'every jet moved outwards from the axis by one distance'))
    return out


@register_check
class Specific(Check):
    name = 'specific'
    question = ('Does it keep most of what it explains beside a broader form of the same change '
                '(every fan alike, every jet pushed from the axis, bridges following the mean thrust)?')
    refusal = 'it is not specific to its fans (or its pairs of jets)'
    setting = 'check_specific'

    def applies(self, trial) -> bool:
        return trial.candidate.family in SPECIFIC_FAMILIES

    def judge_one(self, case, rnd: Round, i: int) -> CheckResult:
        t, without = rnd.kept[i], rnd.withouts[i]
        node = node_of(rnd.final.model, t.candidate.label)
        forms = broader_forms(t.candidate, node, case.geometry.fans)
        if not forms:
            return self.skipped('no broader form of this change')
        error_without = case.evaluate(without.model)[0]
        alone = 1.0 - case.evaluate(rnd.final.model)[0] / error_without
        numbers = {'alone': number(alone), 'forms': []}
        if alone <= 0:
            return self.skipped('it does not lower the held-out error in this model')
        for every, start, words in forms:
            shared = apply_candidate(without.model, every, **start)
            shared = fit_model(shared, case.train, free=fit_mask(shared), max_nfev=15)
            both = apply_candidate(shared.model, t.candidate, **t.params)
            both = fit_model(both, case.train, free=fit_mask(both), max_nfev=15)
            before = case.evaluate(shared.model)[0]
            beside = 1.0 - case.evaluate(both.model)[0] / before if before > 0 else 0.0
            every_alone = 1.0 - before / error_without
            numbers['forms'].append({'form': every.name, 'form_alone': number(every_alone),
                                     'beside': number(beside)})
            if beside < case.settings.min_specific * alone:
                what = 'its pairs of jets' if isinstance(node, JetInteraction) else 'its fans'
                return self.result(False, numbers, (
                    f'it is not specific to {what}: a broader form, {words}, takes the '
                    f'held-out error down by {pct_text(every_alone)} (this finding alone: '
                    f'{pct_text(alone)}), and with this finding added beside it the held-out error '
                    f'{_change_text(beside)}; '
                    f'a change of the whole flow, such as a draft, jets that spread with their '
                    f'thrust or cling to the wall, or a leak that follows the tunnel\'s pressure, '
                    f'shows partly as this finding'))
        return self.result(True, numbers)
