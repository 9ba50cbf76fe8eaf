"""The diagnosis's first stage after the split: screen the library's candidates and select the
effects, one per step (forward selection).

Every candidate is *screened* (fitted alone around the frozen current model, a few parameters,
fast); the best ``refine`` by BIC on the training sweeps (and candidates marked
``refine_always``, whose effect the refitted polynomials partly absorb, such as a dead band)
are *refined* (refitted together with the model), and the refined candidate with the lowest BIC
that passes the guard (``checks.guard``) is added; the selection stops when none passes. Ranking
by BIC uses every training sweep; the few held-out sweeps judge the result (the guard) rather
than rank it. Reported parameters come from a refit on every training cell; their uncertainty is
the larger of the Gauss-Newton standard error and a delete-one-sweep jackknife (sweeps are the
independent units). Forces [N].
"""
from __future__ import annotations

import numpy as np

from ..model import param_slices, term_label
from .case import Case
from .checks import CHECKS
from .data import FitData
from .errors import FitError
from .fitting import FitResult, Frozen, bic, fit_model, jackknife_std
from .library import Candidate, apply_candidate
from .trial import Trial, by_parameter, candidate_std, fit_mask, node_of

__all__ = ['select']


def _trial(case: Case, cand: Candidate, stage: str, fit: FitResult, current: FitResult,
           current_rmse: float):
    """The ``Trial`` of ``cand`` fitted as ``fit``, scored against ``current``, and its term."""
    node = node_of(fit.model, cand.label)
    if node is None:
        raise FitError(f'candidate {cand.name} did not place its term {cand.label} in the model')
    held, raw = case.evaluate(fit.model)
    k = current.k + fit.k if stage == 'screened' else fit.k
    if fit.n == len(case.train):
        sse = fit.sse
    else:  # fitted on the screening cells: score on every training cell
        r = fit.model(case.train.U, case.train.Z) - case.train.y
        sse = float(r @ r)
    n = len(case.train)
    b = bic(sse, n, k)
    gain = 1.0 - held / current_rmse if current_rmse > 0 else 0.0
    return Trial(cand, stage, fit.model, cand.params(node), candidate_std(fit, cand.label),
                 sse, n, k, b, b - current.bic, held, raw, gain), node


def _screen(case: Case, cand: Candidate, current: FitResult, current_rmse: float,
            frozen: Frozen) -> Trial:
    """The candidate fitted alone around the frozen current model, from each of its starts."""
    best = None
    for start in cand.starts:
        model = apply_candidate(frozen, cand, **start)
        fit = fit_model(model, case.screen, max_nfev=15, ftol=1e-4, xtol=1e-5)
        if best is None or fit.sse < best.sse:
            best = fit
    return _trial(case, cand, 'screened', best, current, current_rmse)[0]


def _refine(case: Case, trial: Trial, current: FitResult, current_rmse: float,
            data: FitData | None = None, max_nfev: int | None = None):
    """Refit the candidate together with the model's free parameters (on the screening
    cells unless ``data`` is given; the accepted one is polished on every training cell)."""
    cand = trial.candidate
    model = apply_candidate(current.model, cand, **trial.params)
    fit = fit_model(model, data if data is not None else case.screen, free=fit_mask(model),
                    max_nfev=max_nfev or case.settings.max_nfev)
    out, _ = _trial(case, cand, 'refined', fit, current, current_rmse)
    return out, fit


def _uncertainty(case: Case, t: Trial, fit: FitResult) -> dict:
    """max(Gauss-Newton, delete-one-sweep jackknife) per parameter of the candidate; the
    jackknife refits the candidate's parameters with the rest of the fitted model held."""
    sl = next((sl for node, sl in param_slices(fit.model) if term_label(node) == t.candidate.label), None)
    if sl is None or sl.stop == sl.start:
        return t.std
    try:
        jk = jackknife_std(fit.model, case.train, np.arange(sl.start, sl.stop), max_nfev=10)
    except FitError:
        return t.std
    jk = by_parameter(node_of(fit.model, t.candidate.label), jk)
    return {name: np.fmax(np.asarray(t.std.get(name, [np.nan] * len(v)), float), v).tolist()
            for name, v in jk.items()}


def select(case: Case) -> Case:
    """Forward selection from the case's baseline: add the refined candidate with the lowest
    BIC that passes the guard, up to ``max_effects``. Fills ``steps`` (and ``selected``: every
    step, in order), ``rankings`` (per step, every candidate tried) and ``current``,
    ``current_rmse`` (the model with the steps and its held-out model error [N])."""
    s, guard = case.settings, CHECKS['guard']
    current, current_rmse = case.baseline, case.baseline_rmse
    steps, rankings = [], []
    accepted: set[str] = set()
    for _ in range(s.max_effects):
        if current_rmse < s.material * case.noise_sd:
            break
        cands = [c for c in case.library.candidates(current.model, case.geometry)
                 if c.name not in accepted and not c.other_form]
        if not cands:
            break
        frozen = Frozen(current.model)
        screened = sorted((_screen(case, c, current, current_rmse, frozen) for c in cands),
                          key=lambda t: t.bic)
        picks = screened[:s.refine] + [t for t in screened[s.refine:] if t.candidate.refine_always]
        refined = []
        for t in picks:
            trial, fit = _refine(case, t, current, current_rmse)
            guard.judge(case, trial, current_rmse, current.model)
            if trial.passed:  # judge the parameter by its sweep-to-sweep spread as well
                trial.std = _uncertainty(case, trial, fit)
                guard.judge(case, trial, current_rmse, current.model)
            refined.append((trial, fit))
        rest = [t for t in screened if all(t is not p for p in picks)]
        for t in rest:
            guard.judge(case, t, current_rmse)
            if t.passed:  # screened only: may not be reported without a refit
                t.passed = False
                t.reasons = ['not among the best refined candidates']
        ranking = sorted([t for t, _ in refined], key=lambda t: t.bic) + rest
        rankings.append(ranking)
        passing = [(t, f) for t, f in refined if t.passed]
        if not passing:
            break
        best, fit = min(passing, key=lambda tf: tf[0].bic)
        # a wider form of a family (swirl growing faster than the imbalance, a free thrust
        # exponent) must earn its extra parameters as an effect earns its place: by the BIC
        # bar over the narrower form, when that passes too
        narrower = [(t, f) for t, f in passing if t.candidate.family == best.candidate.family
                    and t.k < best.k and t.bic < best.bic + s.min_dbic]
        if narrower:
            best, fit = min(narrower, key=lambda tf: (tf[0].k, tf[0].bic))
        polished, fit = _refine(case, best, current, current_rmse, data=case.train, max_nfev=15)
        polished.std = _uncertainty(case, polished, fit)
        polished.passed, polished.reasons, polished.check = True, [], best.check
        polished.gain_off, polished.checks = best.gain_off, dict(best.checks)
        ranking[ranking.index(best)] = polished
        best = polished
        best.finding = best.candidate.describe(node_of(fit.model, best.candidate.label), best.std)
        steps.append(best)
        accepted.add(best.candidate.name)
        current, current_rmse = fit, best.heldout_rmse
    case.steps, case.rankings, case.selected = steps, rankings, list(steps)
    case.current, case.current_rmse = current, current_rmse
    return case
