"""The diagnosis's stage after the checks: other forms of a family that explains much but does
not hold.

A candidate that lowers the held-out model error by ``min_gain`` or more but whose value moves
from sweep to sweep (refused by the check ``across_sweeps``; or, when nothing was found, the
selection's best candidate refused by the guard, its jackknife error too large) has found the right physics in the
wrong form as often as a patch of something else: a swirl whose angle follows the net CW-CCW
thrust, not its share of the flow, fits a different gain at each balance. So before the
refusal stands, the family's other forms (``Candidate.other_form``: for swirl, the angle linear
in the CCW minus CW thrust, in the sign of the imbalance, in the total thrust) are fitted beside
the findings that passed, judged by the guard, and the first that passes it goes through every
check of a finding (``checks.check_findings``); one that holds replaces the refused candidate
as a finding. When none holds, a candidate refused across sweeps carries a family-level note
(``Trial.family_note``: "the field turns with the CW/CCW balance, but not as the swirl
candidate has it") naming the forms tried, so the lab learns which physics is at work even
though no form of it can be reported. Forces [N].
"""
from __future__ import annotations

from .checks import CHECKS, check_findings
from .fitting import fit_model
from .library import apply_candidate
from .selection import _trial, _uncertainty
from .trial import fit_mask, node_of

__all__ = ['try_other_forms', 'FAMILY_WORDS']

#: Family -> what a refused candidate of it still shows, in words.
FAMILY_WORDS = {
    'swirl': 'the field turns with the CW/CCW balance, but not as the swirl candidate has it',
    'jet_interaction': ('the gap between neighbouring jets gains force with their thrusts, but not '
                        'as the jet-interaction candidates have it'),
}


def _refused_across_sweeps(t) -> bool:
    r = t.checks.get('across_sweeps')
    return r is not None and r.passed is False


def _fit_form(case, cand, current, current_rmse):
    """The form ``cand`` refitted with the model's free parameters beside the findings that
    passed (``current``), from each of its starts; judged by the guard."""
    s, guard = case.settings, CHECKS['guard']
    best = None
    for start in cand.starts:
        model = apply_candidate(current.model, cand, **start)
        fit = fit_model(model, case.screen, free=fit_mask(model), max_nfev=s.max_nfev)
        if best is None or fit.sse < best.sse:
            best = fit
    trial, _ = _trial(case, cand, 'refined', best, current, current_rmse)
    guard.judge(case, trial, current_rmse, current.model)
    if not trial.passed:
        return trial
    polished = fit_model(trial.model, case.train, free=fit_mask(trial.model), max_nfev=15)
    out, _ = _trial(case, cand, 'refined', polished, current, current_rmse)
    out.std = _uncertainty(case, out, polished)
    guard.judge(case, out, current_rmse, current.model)
    if out.passed:
        out.finding = cand.describe(node_of(polished.model, cand.label), out.std)
    return out


def _explains_much_but_refused(case) -> list:
    """The refused candidates of a family with other forms that lower the held-out error by
    ``min_gain`` or more: findings refused across sweeps and, when nothing was found, the
    selection's best candidate refused by the guard (its value too uncertain across sweeps)."""
    s = case.settings
    out = [t for t in case.demoted if t.candidate.family in FAMILY_WORDS
           and t.gain >= s.min_gain and _refused_across_sweeps(t)]
    if not case.steps and not out and case.rankings and case.rankings[0]:
        best = case.rankings[0][0]
        if (best.candidate.family in FAMILY_WORDS and best.gain >= s.min_gain and not best.passed
                and not case.low_spread):
            out.append(best)
    return out


def try_other_forms(case):
    """The stage (see the module docstring): may move a finding from ``demoted`` to ``steps``
    in another form of its family, and sets ``family_note`` on refused candidates whose family
    shows but in none of its forms."""
    s = case.settings
    for refused in _explains_much_but_refused(case):
        family = refused.candidate.family
        current, current_rmse = case.final, case.final_rmse
        forms = [c for c in case.library.candidates(current.model, case.geometry)
                 if c.family == family and c.other_form]
        tried, holds = [], None
        for cand in forms:
            trial = _fit_form(case, cand, current, current_rmse)
            tried.append(cand)
            if not trial.passed:
                continue
            kept, demoted = list(case.steps), list(case.demoted)
            case.steps = kept + [trial]
            check_findings(case)
            if trial in case.steps:
                holds = trial
                case.demoted = [t for t in demoted if t is not refused] + case.demoted
                break
            if {id(t) for t in case.steps} != {id(t) for t in kept}:
                case.steps = kept  # beside the form a finding failed: check them as they were
                check_findings(case)
            case.demoted = demoted  # the form failed a check: the findings stand as before
        # the family-level words need the family's candidate to have held on the held-out
        # sweeps and failed only across sweeps; a candidate the guard refused is too uncertain
        # to say the field does what its family says
        if holds is None and _refused_across_sweeps(refused):
            refused.family_note = (f'{FAMILY_WORDS[family]}'
                                   + (f' (tried as well: {"; ".join(c.title for c in tried)}; none '
                                      f'passes the guard and every check)' if tried else ''))
    return case
