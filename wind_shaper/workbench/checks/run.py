"""The diagnosis's checks of its findings, as a stage: every registered check of each effect the
selection added (``Case.steps``), in rounds.

Each round refits the findings together (``Round.final``) and each without it
(``Round.withouts``); every check of stage ``'sweeps'`` (with its second chance) judges every
finding; the first check that refuses a finding, in registry order, demotes one (its ``worst``)
and a new round checks the rest again without it, until all pass. ``steps`` keeps what passed,
``demoted`` the rest (in the order refused; "partly explained by ..., but ..."), ``final`` the
model with what passed. Each finding's ``Trial.checks`` holds every check's result of the last
round it was checked in: passed, refused, or not run and why.
"""
from __future__ import annotations

import numpy as np

from ...model import param_slices, term_label
from ..trial import by_parameter, candidate_std, node_of
from ..uncertainty import reported_std
from .base import CHECKS, Check, CheckResult, Round

__all__ = ['check_findings']


def _finding_checks() -> list[Check]:
    return [c for c in CHECKS.values() if c.stage != 'candidate']


def _run(check: Check, case, rnd: Round, only=None) -> dict:
    """{index: result} of ``check`` on the round's findings (``only``: those indices)."""
    if not check.enabled(case.settings):
        return {i: check.skipped(f'switched off ({check.setting}=False)')
                for i in range(len(rnd.kept)) if only is None or i in only}
    if only is None:
        return check.measure(case, rnd)
    sub = Round([rnd.kept[i] for i in only], rnd.final, [rnd.withouts[i] for i in only])
    return {only[j]: r for j, r in check.measure(case, sub).items()}


def _round(case, kept: list):
    """One round: every check on the findings ``kept`` -> (finding to demote, the check that
    refused it, its result) or None when all pass. Records every result in ``Trial.checks``."""
    final = case.rebuild(kept)
    rnd = Round(kept, final, [case.rebuild([o for o in kept if o is not t]) for t in kept])
    for t in kept:
        t.checks = {k: r for k, r in t.checks.items() if CHECKS[k].stage == 'candidate'}
    checks = _finding_checks()
    refused = None
    for check in checks:
        if check.second_chance_for:
            continue  # run below, after the check it may overrule
        results = _run(check, case, rnd)
        lifted = set()
        for second in (c for c in checks if c.second_chance_for == check.name):
            retry = [i for i, r in results.items() if r.passed is False]
            again = _run(second, case, rnd, retry) if retry else {}
            for i in results:
                r = again.get(i) or second.skipped(f'not needed: {check.name} passed it'
                                                   if results[i].passed else f'{check.name} did not run')
                rnd.kept[i].checks[second.name] = r
                if r.passed:
                    lifted.add(i)
        for i, r in results.items():
            if i in lifted:
                r.why += f' (lifted by {", ".join(c.name for c in checks if c.second_chance_for == check.name)})'
            rnd.kept[i].checks[check.name] = r
        failed = {i: r for i, r in results.items() if r.passed is False and i not in lifted}
        if failed:
            i = check.worst(failed)
            refused = (kept[i], check, failed[i])
            break
    for t in kept:  # what this round did not get to
        for check in checks:
            if check.name not in t.checks:
                why = (f'not reached: {refused[1].name} refused {refused[0].candidate.title} first'
                       if refused is not None else 'not needed')
                t.checks[check.name] = CheckResult(check.name, None, {}, why)
        t.checks = {c.name: t.checks[c.name] for c in CHECKS.values() if c.name in t.checks}
    return refused


def check_findings(case):
    """The stage (see the module docstring): fills ``steps``, ``demoted``, ``final``,
    ``final_rmse`` and ``final_raw`` [N]. With the check across sweeps switched off
    (``check_sweeps=False``) the selection's findings stand unchecked."""
    s = case.settings
    kept = list(case.steps)
    case.demoted = []
    if not (s.check_sweeps and kept):
        for t in kept:
            for check in _finding_checks():
                t.checks[check.name] = check.skipped('switched off (check_sweeps=False)')
        case.final, case.final_rmse = case.current, case.current_rmse
        case.final_raw = case.evaluate(case.final.model)[1]
        return case
    while kept:
        refused = _round(case, kept)
        if refused is None:
            break
        worst, check, result = refused
        check.demote(worst, result)
        worst.passed, worst.reasons = False, list(worst.check.reasons)
        case.demoted.append(worst)
        kept = [t for t in kept if t is not worst]
    final = case.rebuild(kept)
    for t in kept:  # the parameters as the final model has them
        node = node_of(final.model, t.candidate.label)
        t.params = t.candidate.params(node)
        t.selection_std = dict(t.std)
        t.std = _widest(t.std, reported_std(case, t.candidate.label, final,
                                            candidate_std(final, t.candidate.label),
                                            loosen=t.candidate.loosen))
        t.finding = (t.candidate.describe(node, t.std) + _fans_off_text(t, s.min_gain)
                     + _beside_text(t, final.model))
    case.steps, case.final = kept, final
    case.final_rmse = case.evaluate(final.model)[0]
    case.final_raw = case.evaluate(final.model)[1]
    return case


def _widest(a: dict, b: dict) -> dict:
    """Per parameter, the larger of two error bars (the selection's, and the final model's
    with the whole-model jackknife, ``uncertainty.reported_std``)."""
    return {name: np.fmax(np.asarray(a.get(name, [np.nan] * len(np.atleast_1d(v))), float),
                          np.asarray(v, float)).tolist() for name, v in b.items()}


def _fans_off_text(t, min_gain: float) -> str:
    """What a finding judged on the fans-off sweeps (its held-out gain short of ``min_gain``)
    must say."""
    if t.gain_off is None or t.gain >= min_gain:
        return ''
    return (f'. It shows with every fan off: there it lowers the held-out model error '
            f'{100 * t.gain_off:.0f} %, over all held-out sweeps only {100 * t.gain:.0f} % (with the '
            f'fans on, something the library lacks carries most of the residual)')


def _beside_text(t, model) -> str:
    """What a finding that holds only beside a discrepancy model must say, with the effect as
    estimated jointly with that model (``model``: the final model the finding sits in)."""
    b = t.check.beside if t.check is not None else None
    if b is None or not b.passed:
        return ''
    sl = next(sl for node, sl in param_slices(model) if term_label(node) == t.candidate.label)
    theta = np.array(model.theta, float)
    theta[sl] = b.mean
    node = node_of(model.with_theta(theta), t.candidate.label)
    joint = t.candidate.describe(node, by_parameter(node, b.mean_std))
    return (f'. It holds across sweeps only with a discrepancy model beside it (something the '
            f'library lacks perturbs it sweep by sweep); estimated jointly with that model: {joint}')
