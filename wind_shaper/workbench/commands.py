"""What ``wind-shaper model fit | compare | diagnose | add`` do, without the argument parsing.

Each function takes a model, sweeps and the tunnel geometry, does its job and writes a report
folder (``report.html``, ``report.md``, PNG plots, ``summary.json``); it returns the objects it
made so that scripts and tests can use them directly.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..core.config import parse_spec
from ..core.geometry import TunnelGeometry
from ..experiment import write_design
from ..model import TERMS, Term, Wrapper, save_model, term_label, walk
from .checks import CHECKS
from .data import SweepSet, design_commands, from_sim
from .diagnose import Diagnosis, candidate_std, drop_text, fit_mask
from .discrepancy import SCALE_FEATURES, describe_discrepancy, fit_discrepancy
from .formula import fit_formula
from .wording import error_text
from .errors import CandidateError
from .fitting import FitResult, fit_model
from .library import Library, _pm, apply_candidate, candidate_for_hidden_effect, default_library
from .metrics import HeldOut, evaluate
from .report import (Report, plot_closed_loop, plot_discrepancy, plot_fan_curves,
                     plot_measured_vs_model, plot_radial_angular, plot_ranking, plot_residual_maps)
from .residuals import analyse_residuals
from .suggest import suggest_sweeps

__all__ = ['simulated_sweeps', 'fit_command', 'compare_command', 'diagnose_command', 'add_command',
           'parse_spec', 'model_with_additions', 'FitOutcome', 'AddOutcome']


def simulated_sweeps(tunnel, n_sweeps: int = 12, *, seed: int = 0, n_samples: int = 1000,
                     high: float = 0.9) -> SweepSet:
    """A diagnostic data set on a (simulated) tunnel: ``n_sweeps`` sweeps, the first and last
    with every fan off (a background or dead band shows there), the rest at Latin-hypercube
    commands in [0, ``high``] (``design_commands``, seeded by ``seed``)."""
    n = tunnel.geometry.fans.n_fans
    enabled = tunnel.geometry.fans.enabled
    inner = design_commands(n, max(n_sweeps - 2, 1), high=high, seed=seed, enabled=enabled)
    U = np.vstack([np.zeros(n), inner, np.zeros(n)]) if n_sweeps >= 3 else inner
    effects = ', '.join(e.name for e in getattr(tunnel, 'effects', ())) or 'none'
    return from_sim(tunnel, U, n_samples=n_samples,
                    source=f'simulated tunnel (seed {getattr(tunnel, "seed", "?")}, hidden effects: {effects})')


def _fmt(x, digits=3):
    return f'{x:.{digits}f}'


def _residual_sections(report: Report, analyses: Mapping, geometry: TunnelGeometry, key: str):
    report.figure(f'{key}_maps', plot_residual_maps(analyses, geometry),
                  'GP-smoothed residual (measured - model) over the tunnel, fans drawn; right: its '
                  'standard deviation', heading='Where the model fails')
    last = list(analyses.values())[-1]
    report.figure(f'{key}_fans', plot_fan_curves(last, geometry),
                  'residual near each fan against that fan\'s command (share of the residual variance '
                  'each fan\'s command explains)')
    report.figure(f'{key}_radial', plot_radial_angular(last), 'residual against radius and angle')
    report.bullets(last.describe(), heading='Structure of the residual')


# -- fit ------------------------------------------------------------------------------------------

@dataclass
class FitOutcome:
    fit: FitResult
    heldout: dict
    train: dict
    analysis: object
    report: Path


def fit_command(model: Term, data: SweepSet, geometry: TunnelGeometry, out, *,
                test_fraction: float = 1 / 3, cell: float = 0.04, save: Path | None = None,
                source_model: str = '') -> FitOutcome:
    """Fit the model's free parameters (bounded least squares, Gauss-Newton uncertainties) on
    the training sweeps; score it per sweep and overall, and on the held-out sweeps; map where it
    fails. ``save``: write the fitted model file there."""
    data.check_fans(geometry.fans.names)
    train, test = data.split(test_fraction) if len(data) >= 3 else (data, None)
    fd = train.fit_data(cell)
    fit = fit_model(model, fd, free=fit_mask(model), max_nfev=80)
    train_scores = evaluate(fit.model, fd, train.labels)
    held = None
    if test is not None:
        ho = HeldOut(test)
        held = ho.evaluate(fit.model)
    raw = (test or train).fit_data(cell)
    analysis = analyse_residuals(fit.model, raw, geometry)
    rep = Report('Model fit')
    rep.text(f'Data: {data.source}, {len(data)} sweeps ({data.n_samples} samples); fitted on {len(train)} '
             f'sweeps ({len(fd)} cell means of {cell * 100:.0f} cm), held out: '
             f'{", ".join(test.labels) if test is not None else "none"}.\n\nModel: {source_model}\n\n'
             f'Fitted: {fit.model!r}')
    ov = train_scores['overall']
    rows = [['training (cell means)', _fmt(ov.rmse), _fmt(ov.r2, 4), _fmt(ov.max_error), _fmt(ov.bias), ov.n]]
    if held is not None:
        h = held['raw']
        rows.append(['held out (raw samples)', _fmt(h.rmse), _fmt(h.r2, 4), _fmt(h.max_error), _fmt(h.bias), h.n])
    rep.table(['data', 'RMSE [N]', 'R²', 'largest error [N]', 'bias [N]', 'n'], rows, heading='Scores')
    if held is not None:
        rep.text(f'Held-out model error (measurement noise removed): '
                 f'{error_text(held["model_rmse"], held.get("resolution", 0.0))}; the '
                 f'measurement noise is {held["noise_sd"]:.3f} N per sample.')
    per = [[k, _fmt(s.rmse), _fmt(s.r2, 4), _fmt(s.max_error), s.n] for k, s in train_scores['per_sweep'].items()]
    if held is not None:
        per += [[f'{k} (held out)', _fmt(s.rmse), _fmt(s.r2, 4), _fmt(s.max_error), s.n]
                for k, s in held['per_sweep'].items()]
    rep.table(['sweep', 'RMSE [N]', 'R²', 'largest error [N]', 'n'], per, heading='Per sweep')
    rep.table(['parameter', 'value', 'std'], [[n, f'{v:.5g}', f'{s:.2g}'] for n, v, s in
                                              zip(fit.names, fit.theta, fit.theta_std)],
              heading='Fitted parameters (1-sigma, Gauss-Newton)')
    rep.figure('measured_vs_model', plot_measured_vs_model(fit.model(fd.U, fd.Z), fd.y, train_scores['per_sweep']),
               'measured against model on the training cells; RMSE per sweep')
    _residual_sections(rep, {'fitted model': analysis}, geometry, 'residual')
    if save is not None:
        save_model(save, fit.model, fitted_from=data.source, rmse_N=round(fit.rmse, 5), n_samples=fit.n,
                   fitted_at=time.strftime('%Y-%m-%dT%H:%M:%S'))
        rep.text(f'Fitted model written to {save}.', heading='Model file')
    rep.summary = {'command': 'fit', 'data': data.source, 'sweeps': list(data.labels),
                   'fit': fit.summary(), 'train': {k: v.to_json() for k, v in train_scores['per_sweep'].items()},
                   'train_overall': ov.to_json(),
                   'heldout': None if held is None else {
                       'model_rmse_N': held['model_rmse'], 'noise_sd_N': held['noise_sd'],
                       'raw': held['raw'].to_json(),
                       'per_sweep': {k: v.to_json() for k, v in held['per_sweep'].items()}},
                   'residual': analysis.to_json(), 'saved_model': str(save) if save else None}
    return FitOutcome(fit, held, train_scores, analysis, rep.write(out))


# -- compare --------------------------------------------------------------------------------------

def compare_command(models: Mapping[str, Term], data: SweepSet, geometry: TunnelGeometry, out, *,
                    refit: bool = True, test_fraction: float = 1 / 3, cell: float = 0.04) -> dict:
    """Several models against the same sweeps, side by side: held-out scores and model error,
    residual maps on one colour scale. ``refit``: fit each model's free parameters on the
    training sweeps first (as ``fit`` does); else score them as they are."""
    data.check_fans(geometry.fans.names)
    train, test = data.split(test_fraction)
    fd = train.fit_data(cell)
    ho = HeldOut(test)
    results, analyses, noise = {}, {}, None
    tf = test.fit_data(cell)
    for label, model in models.items():
        m = fit_model(model, fd, free=fit_mask(model), max_nfev=80).model if refit else model
        if noise is None:
            noise = ho.estimate_noise(m)
            ho.noise_sd = noise
        results[label] = (m, ho.evaluate(m))
        analyses[label] = analyse_residuals(m, tf, geometry)
    rep = Report('Model comparison')
    rep.text(f'Data: {data.source}; {"refitted on" if refit else "scored as given; training sweeps"} '
             f'{", ".join(train.labels)}; held out: {", ".join(test.labels)}. Measurement noise '
             f'{noise:.3f} N per sample.')
    rows = [[label, _fmt(ev['model_rmse']), _fmt(ev['raw'].rmse), _fmt(ev['raw'].r2, 4),
             _fmt(ev['raw'].max_error), repr(m)[:90]] for label, (m, ev) in results.items()]
    rep.table(['model', 'held-out model error [N]', 'held-out RMSE [N]', 'R²', 'largest error [N]',
               'model'], rows, heading='Held-out scores')
    _residual_sections(rep, analyses, geometry, 'compare')
    rep.summary = {'command': 'compare', 'data': data.source, 'refit': refit, 'noise_sd_N': noise,
                   'models': {label: {'model': repr(m), 'heldout_model_rmse_N': ev['model_rmse'],
                                      'heldout_raw': ev['raw'].to_json(),
                                      'residual': analyses[label].to_json()}
                              for label, (m, ev) in results.items()}}
    rep.write(out)
    return {label: m for label, (m, _) in results.items()}


# -- diagnose -------------------------------------------------------------------------------------

def diagnose_command(model: Term, data: SweepSet, geometry: TunnelGeometry, out, *,
                     library: Library | None = None, truth: Sequence = (),
                     diagnosis: Diagnosis | None = None, suggest: int = 0, goal: str = 'auto',
                     bounds: tuple = (0.0, 0.9)) -> Diagnosis:
    """Run the diagnosis and report it: verdict, findings with parameters and uncertainties,
    the ranked table of candidates, residual maps before and after. ``truth``: the simulator's
    hidden effects, when known, to set the findings beside. ``suggest`` > 0: also the next
    sweeps (``suggest.suggest_sweeps`` with ``goal`` within ``bounds`` = (u_min, u_max)), saved
    as ``suggested_design.csv`` and kept as ``d.suggestion_``."""
    d = (diagnosis or Diagnosis(library)).fit(model, data, geometry)
    if suggest <= 0 and d.undecided_ is not None and d.undecided_.more is not None:
        # a promising candidate short of the bar: the sweeps that would decide it, as a design
        suggest, goal = min(d.undecided_.more, 12), 'separate'
    d.suggestion_ = (suggest_sweeps(d, suggest, bounds[0], bounds[1], goal=goal)
                     if suggest > 0 else None)
    rep = Report('Model diagnosis')
    rep.text(f'Data: {data.source}, {len(data)} sweeps; held out: {", ".join(d.test_sweeps_.labels)}.\n\n'
             f'Model: {model!r}')
    rep.text(d.summary(), heading='Verdict')
    if d.discrepancy_ is not None:
        rep.figure('discrepancy', plot_discrepancy(d.discrepancy_, d.train_sweeps_.commands, geometry),
                   'what lies outside the library: a discrepancy model fitted to the residual (no '
                   'physics in it)', heading='What lies outside the library')
        rep.bullets(d.discrepancy_.words)
    if truth:
        rows = []
        found = {t.candidate.name: t for t in d.steps_}
        for effect in truth:
            try:
                name, expected = candidate_for_hidden_effect(effect)
            except CandidateError:
                rows.append([effect.name, '-', str(effect.truth()), 'no library candidate'])
                continue
            got = found.get(name)
            rows.append([effect.name, name, str(expected), str(got.params) if got else 'not found'])
        rep.table(['hidden effect (simulator)', 'candidate', 'truth', 'fitted'], rows,
                  heading='Against the simulator\'s truth')
    for i, ranking in enumerate(d.rankings_):
        rep.table(['rank', 'candidate', 'held-out model error [N]', 'change', 'ΔBIC', 'parameters', 'verdict'],
                  [[k + 1, t.candidate.name, _fmt(t.heldout_rmse), drop_text(t.gain), f'{t.dbic:+.0f}',
                    _short_params(t.params), 'reported' if t.passed and t in d.steps_ else
                    ('; '.join(t.reasons) or 'passes, not the best')] for k, t in enumerate(ranking[:15])],
                  heading=f'Step {i + 1}: candidates in order of training BIC (lowest first): the refined '
                          f'ones, then those only screened')
        before = d.baseline_rmse_ if i == 0 else d.selected_[i - 1].heldout_rmse
        rep.figure(f'ranking_step{i + 1}', plot_ranking(ranking, before),
                   f'held-out model error with each candidate at step {i + 1} (in the table\'s order)')
    for t in d.selected_:  # every effect the selection added, checked across sweeps
        c = t.check
        if c is None:
            continue
        labels = list(d.train_sweeps_.labels)
        rows = [[labels[i] if i < len(labels) else i, _fmt(c.signal[i]),
                 ', '.join(f'{v:.4g} ± {e:.2g}' for v, e in zip(c.values[i], c.stds[i]))
                 if c.informative[i] else 'too little signal',
                 ('disagrees' if c.disagree[i] else 'agrees') if c.informative[i] else '']
                for i in range(len(c.signal))]
        verdict = 'holds' if c.passed else 'refused: ' + '; '.join(c.reasons)
        rep.table(['training sweep', 'signal [N]', f'{", ".join(c.names)} refitted on the sweep',
                   'with the pooled fit'], rows,
                  heading=f'{t.candidate.title} across sweeps (pooled '
                          f'{", ".join(f"{v:.4g}" for v in c.pooled)}): {verdict}')
        if c.beside is not None:
            b = c.beside
            shown = [labels[i] if i < len(labels) else i for i in np.flatnonzero(c.informative)]
            rep.table(['training sweep', f'{", ".join(b.names)} with the discrepancy'],
                      [[name, ', '.join(f'{v:.4g} ± {e:.2g}' for v, e in zip(b.values[k], b.stds[k]))]
                       for k, name in enumerate(shown)],
                      heading=f'{t.candidate.title} across sweeps, refitted jointly with a discrepancy '
                              f'model (mean {", ".join(f"{v:.4g}" for v in b.mean)}): '
                              + ('holds' if b.passed else 'refused: ' + '; '.join(b.reasons)))
    if d.selected_:  # every check of each effect the selection added: passed, refused or not run
        checked = d.steps_ + d.demoted_
        titles = [f'{t.candidate.title} ({"reported" if t in d.steps_ else "not reported"})' for t in checked]
        rep.table(['check', 'its question'] + titles,
                  [[name, check.question] + [_check_cell(t.checks.get(name)) for t in checked]
                   for name, check in CHECKS.items()],
                  heading='Every check of each effect the selection added')
    every = data.fit_data(d.cell)  # all sweeps: the structure needs many commands
    analyses = {'before': analyse_residuals(d.baseline_.model, every, geometry)}
    if d.steps_:
        analyses['after'] = analyse_residuals(d.final_.model, every, geometry)
    _residual_sections(rep, analyses, geometry, 'diagnosis')
    if d.suggestion_ is not None:
        _suggestion_section(rep, d.suggestion_, out)
    rep.summary = {'command': 'diagnose', 'data': data.source, **d.to_json(),
                   'suggestion': d.suggestion_.summary() if d.suggestion_ is not None else None,
                   'residual_before': analyses['before'].to_json(),
                   'residual_after': analyses['after'].to_json() if 'after' in analyses else None,
                   'truth': [e.spec() for e in truth]}
    rep.write(out)
    return d


def _check_cell(result) -> str:
    """A check's result for the report's table: 'passed', 'refused: why' or 'not run (why)'."""
    if result is None:
        return 'not run'
    if result.passed is False:
        return f'refused: {result.why}'
    return result.state + (f' ({result.why})' if result.why else '')


def _suggestion_section(rep: Report, s, out) -> None:
    """The suggested sweeps: their commands, and what they are expected to do."""
    Path(out).mkdir(parents=True, exist_ok=True)
    write_design(Path(out) / 'suggested_design.csv', s.design)
    rep.table(['sweep', *s.design.fan_names],
              [[lab, *(f'{100 * u:.1f}' for u in row)] for lab, row in zip(s.design.labels, s.design.commands)],
              heading=f'Suggested next sweeps ({s.goal}), commands in % of full PWM: '
                      f'suggested_design.csv, for `wind-shaper collect --design`')
    rep.text(s.outcome_text())


def _short_params(params: dict) -> str:
    out = []
    for k, v in params.items():
        v = np.round(np.asarray(v, float), 3)
        out.append(f'{k}={v.tolist() if v.ndim else float(v)}')
    return ', '.join(out)


# -- add ------------------------------------------------------------------------------------------

def model_with_additions(model: Term, additions: Sequence, geometry: TunnelGeometry,
                         library: Library | None = None) -> Term:
    """``model`` extended by each addition: a library candidate name (``fan_gain[HM2]``,
    ``swirl``) or ``(name, params)``, or a registered term kind (``(kind, params)``; a
    ``Wrapper`` subclass wraps the model, any other term is added with ``+``)."""
    return _apply_additions(model, additions, geometry, library)[0]


def _apply_additions(model: Term, additions: Sequence, geometry: TunnelGeometry,
                     library: Library | None = None) -> tuple[Term, list]:
    """(extended model, [(name, start params, term label)] per addition): see
    ``model_with_additions``. The label finds the added term in the refitted model."""
    library = library or default_library()
    added = []
    for item in additions:
        name, params = (parse_spec(item) if isinstance(item, str) else (item[0], dict(item[1])))
        cands = {c.name: c for c in library.candidates(model, geometry)}
        if name in cands:
            model = apply_candidate(model, cands[name], **params)
            added.append((name, params, cands[name].label))
            continue
        cls = TERMS.get(name)
        if cls is None:
            raise CandidateError(f'{name!r} is neither a candidate for this model ({sorted(cands)}) nor a '
                                 f'registered term kind ({sorted(TERMS)}); a term of your own must be '
                                 f'imported first (--plugin FILE or WIND_SHAPER_PLUGINS)')
        try:
            term = cls(model.fans, model, **params) if issubclass(cls, Wrapper) else cls(model.fans, **params)
        except TypeError as exc:
            raise CandidateError(f'cannot build {name!r} with {params}: {exc}') from None
        model = term if issubclass(cls, Wrapper) else model + term
        added.append((name, params, term_label(term)))
    return model, added


def _residual_term(item) -> str:
    """'discrepancy' or 'formula' when an addition asks for a term fitted to the residual (not a
    candidate), else ''."""
    name = item if isinstance(item, str) else item[0]
    return name if name in ('discrepancy', 'formula') else ''


def _added_parameters(fit: FitResult, added: list) -> list[dict]:
    """Each addition's own parameters as refitted in ``fit``: [{'effect', 'start', 'fitted':
    {parameter: {'value', 'std'}}}] (free parameters only; values and 1-sigma as lists for
    vector parameters)."""
    out = []
    for name, start, label in added:
        node = next((n for n in walk(fit.model) if term_label(n) == label), None)
        fitted = {}
        if node is not None:
            std = candidate_std(fit, label)
            values = node.get_params()
            for h in node._free():
                v = np.atleast_1d(np.asarray(values[h.name], float))
                e = np.atleast_1d(np.asarray(std.get(h.name, [np.nan] * len(v)), float))
                fitted[h.name] = {'value': [round(float(x), 6) for x in v],
                                  'std': [round(float(x), 6) for x in e]}
        out.append({'effect': name, 'start': {k: (np.asarray(v, float).round(6).tolist()
                                                  if not isinstance(v, str) else v)
                                              for k, v in start.items()},
                    'fitted': fitted})
    return out


def _added_text(entry: dict) -> str:
    """``fan_gain[HM2] with gain 1.031 ± 0.012``: an addition with its refitted parameters."""
    parts = []
    for pname, vs in entry['fitted'].items():
        cells = [_pm(v, s, '{:.3f}') for v, s in zip(vs['value'], vs['std'])]
        parts.append(f'{pname} ' + (cells[0] if len(cells) == 1 else '(' + ', '.join(cells) + ')'))
    return entry['effect'] + (f' with {", ".join(parts)}' if parts else '')


def _error_change(before: float, after: float, floor: float) -> tuple[str, bool]:
    """The held-out model error before -> after in words, and whether the old model was already
    below the noise level ``floor`` [N] (then no % drop is claimed: the sweeps cannot show one)."""
    head = f'held-out model error {error_text(before)} -> {error_text(after)}'
    if before < floor:
        if after < floor:
            return (f'{head}: both below the noise level ({floor:.3f} N), so these sweeps cannot '
                    f'tell the two models apart (the old one already explains them)'), True
        return f'{head}: the new model is worse (the old one was already below the noise level, ' \
               f'{floor:.3f} N)', True
    drop = 1 - after / before if before > 0 else 0.0
    change = drop_text(drop) if abs(drop) >= 0.005 else 'unchanged'
    at_floor = ', at the noise level' if after < floor else ''
    return f'{head} ({change}{at_floor})', False


@dataclass
class AddOutcome:
    model: Term
    before: dict
    after: dict
    closed_loop: object
    report: Path
    change: str = ''            # the held-out model error before -> after, in words
    added: list = field(default_factory=list)   # each addition with its refitted parameters


def add_command(model: Term, additions: Sequence, data: SweepSet, geometry: TunnelGeometry, out, *,
                save: Path | None = None, library: Library | None = None, test_fraction: float = 1 / 3,
                cell: float = 0.04, closed_loop=None, noise_sd: float | None = None) -> AddOutcome:
    """Add effects to the model, refit both old and new on the training sweeps and show them
    side by side on the held-out sweeps (model error, residual maps). ``closed_loop``: a
    callable ``(models) -> LoopComparison`` (the CLI runs the simulator's shaping loop);
    noise_sd [N]: the measurement noise, when the sweeps are too short to estimate it."""
    data.check_fans(geometry.fans.names)
    residual_terms = [_residual_term(a) for a in additions if _residual_term(a)]
    new, added = _apply_additions(model, [a for a in additions if not _residual_term(a)], geometry,
                                  library)
    train, test = data.split(test_fraction)
    fd = train.fit_data(cell)
    ho = HeldOut(test)
    old_fit = fit_model(model, fd, free=fit_mask(model), max_nfev=80)
    new_fit = fit_model(new, fd, free=fit_mask(new), max_nfev=80)
    disc_words = []
    for kind in residual_terms:  # fitted last: they take only what the named effects leave
        if kind == 'formula':
            term = fit_formula(new_fit.model, fd, geometry).term
            disc_words.append(f'The formula: residual = {term.formula()}.')
            new = new_fit.model + term
        else:
            dfit = fit_discrepancy(new_fit.model, fd, geometry, note=f'fitted to the residual of {data.source}',
                                   scale_features=SCALE_FEATURES)
            disc_words += describe_discrepancy(dfit, train.commands, geometry, model=new_fit.model)
            term = dfit.term
            new = dfit.added_to(new_fit.model)  # with the model's scale, when it was kept
        new_fit = fit_model(new, fd, free=fit_mask(new), max_nfev=20)
        added.append((kind, {}, term_label(term)))
    ho.noise_sd = noise_sd if noise_sd is not None else ho.estimate_noise(old_fit.model)
    before, after = ho.evaluate(old_fit.model), ho.evaluate(new_fit.model)
    tf = test.fit_data(cell)
    analyses = {'before': analyse_residuals(old_fit.model, tf, geometry),
                'after': analyse_residuals(new_fit.model, tf, geometry)}
    rep = Report('Adding effects to the model')
    drop = 1 - after['model_rmse'] / before['model_rmse'] if before['model_rmse'] > 0 else 0.0
    # the noise level: the diagnosis's materiality threshold (half the measurement noise per
    # sample) or the resolution of the held-out error, whichever is larger
    resolution = before.get('resolution', float('nan'))
    noise_known = bool(np.isfinite(ho.noise_sd))
    floor = max(0.5 * ho.noise_sd if noise_known else 0.0, resolution if np.isfinite(resolution) else 0.0)
    change, below = _error_change(before['model_rmse'], after['model_rmse'], floor)
    added_params = _added_parameters(new_fit, added)
    added_text = ', '.join(_added_text(a) for a in added_params)
    rep.text(f'Data: {data.source}; trained on {", ".join(train.labels)}; held out {", ".join(test.labels)}.\n\n'
             f'Added: {added_text}, refitted on these training sweeps (1 sigma).\n\n'
             f'{change[0].upper() + change[1:]}. '
             + (f'The noise level is {floor:.3f} N: half the measurement noise ({ho.noise_sd:.3f} N per '
                f'sample) or the resolution of the held-out model error, whichever is larger.'
                if noise_known else 'The measurement noise is unknown (give --noise-sd).')
             + (f'\n\nThe {" and ".join(residual_terms)} term names no physics: it is fitted to what '
                f'the rest of the model leaves on the training sweeps (discrepancy: a Gaussian process '
                f'over position and the fans\' commands; formula: a sparse sum of spatial modes x command '
                f'features), so the loop can shape with it while the physics is still unknown. '
                + ' '.join(disc_words) if disc_words else '')
             + f'\n\nNew model: {new_fit.model!r}')
    rep.table(['', 'held-out model error [N]', 'held-out RMSE [N]', 'R²', 'largest error [N]', 'training BIC'],
              [['before', _fmt(before['model_rmse']), _fmt(before['raw'].rmse), _fmt(before['raw'].r2, 4),
                _fmt(before['raw'].max_error), f'{old_fit.bic:.0f}'],
               ['after', _fmt(after['model_rmse']), _fmt(after['raw'].rmse), _fmt(after['raw'].r2, 4),
                _fmt(after['raw'].max_error), f'{new_fit.bic:.0f}']],
              heading='Before and after: ' + ('the old model was already below the noise level' if below
                                               else f'held-out model error {drop_text(drop)}'))
    params = []
    for n, v, s in zip(new_fit.names, new_fit.theta, new_fit.theta_std):
        if n not in old_fit.names:
            params.append([n, f'{v:.4g}', f'{s:.2g}'])
    rep.table(['new parameter', 'value', 'std'], params, heading='The added effects, fitted')
    _residual_sections(rep, analyses, geometry, 'add')
    loop = None
    if closed_loop is not None:
        loop = closed_loop({'before': model, 'after (refitted)': new_fit.model})
        rep.figure('closed_loop', plot_closed_loop(loop),
                   'true-field RMSE to the target per iteration on the simulated tunnel', heading='Closed loop')
        rep.table(['iteration'] + list(loop.errors),
                  [[k] + [_fmt(float(np.median(e[:, k]))) for e in loop.errors.values()]
                   for k in range(next(iter(loop.errors.values())).shape[1])])
    if save is not None:
        save_model(save, new_fit.model, fitted_from=data.source,
                   added=[{'effect': a['effect'], 'fitted (1 sigma)': a['fitted']} for a in added_params],
                   rmse_N=round(new_fit.rmse, 5), heldout_model_rmse_N=round(after['model_rmse'], 5),
                   fitted_at=time.strftime('%Y-%m-%dT%H:%M:%S'))
        rep.text(f'New model written to {save}; give it to the loop with `wind-shaper shape --model {save}`.',
                 heading='Model file')
    rep.summary = {'command': 'add', 'data': data.source, 'added': [_added_text(a) for a in added_params],
                   'discrepancy': disc_words or None,
                   'added_parameters': added_params, 'change': change, 'noise_level_N': floor,
                   'below_noise_level': below,
                   'before': {'model': repr(old_fit.model), 'heldout_model_rmse_N': before['model_rmse'],
                              'heldout_raw': before['raw'].to_json(), 'bic': old_fit.bic},
                   'after': {'model': repr(new_fit.model), 'heldout_model_rmse_N': after['model_rmse'],
                             'heldout_raw': after['raw'].to_json(), 'bic': new_fit.bic,
                             'parameters': new_fit.summary()['parameters']},
                   'heldout_drop': drop, 'noise_sd_N': ho.noise_sd,
                   'residual_before': analyses['before'].to_json(), 'residual_after': analyses['after'].to_json(),
                   'closed_loop': loop.to_json() if loop is not None else None,
                   'saved_model': str(save) if save else None}
    return AddOutcome(new_fit.model, before, after, loop, rep.write(out), change, added_params)
