"""What ``wind-shaper model fit | compare | diagnose | add`` do, without the argument parsing.

Each function takes a model, sweeps and the tunnel geometry, does its job and writes a report
folder (``report.html``, ``report.md``, PNG plots, ``summary.json``); it returns the objects it
made so that scripts and tests can use them directly. ``add`` lives in ``workbench.add`` and is
importable from here too.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..core.config import parse_spec
from ..core.geometry import TunnelGeometry
from ..experiment import write_design
from ..model import Term, save_model
from .add import AddOutcome, _added_text, add_command, model_with_additions
from .checks import CHECKS
from .data import SweepSet, design_commands, from_sim
from .diagnose import Diagnosis, drop_text, fit_mask
from .errors import CandidateError
from .fitting import FitResult, fit_model
from .library import Library, candidate_for_hidden_effect
from .metrics import HeldOut, evaluate
from .report import (Report, plot_discrepancy, plot_measured_vs_model, plot_ranking,
                     residual_sections)
from .residuals import analyse_residuals
from .suggest import suggest_sweeps
from .time_checks.stage import time_rows
from .wording import error_text, fixed_text

__all__ = ['simulated_sweeps', 'fit_command', 'compare_command', 'diagnose_command', 'add_command',
           'parse_spec', 'model_with_additions', 'FitOutcome', 'AddOutcome', '_added_text']


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
    rows = [['training (cell means)', fixed_text(ov.rmse), fixed_text(ov.r2, 4), fixed_text(ov.max_error), fixed_text(ov.bias), ov.n]]
    if held is not None:
        h = held['raw']
        rows.append(['held out (raw samples)', fixed_text(h.rmse), fixed_text(h.r2, 4), fixed_text(h.max_error), fixed_text(h.bias), h.n])
    rep.table(['data', 'RMSE [N]', 'R²', 'largest error [N]', 'bias [N]', 'n'], rows, heading='Scores')
    if held is not None:
        rep.text(f'Held-out model error (measurement noise removed): '
                 f'{error_text(held["model_rmse"], held.get("resolution", 0.0))}; the '
                 f'measurement noise is {held["noise_sd"]:.3f} N per sample.')
    per = [[k, fixed_text(s.rmse), fixed_text(s.r2, 4), fixed_text(s.max_error), s.n] for k, s in train_scores['per_sweep'].items()]
    if held is not None:
        per += [[f'{k} (held out)', fixed_text(s.rmse), fixed_text(s.r2, 4), fixed_text(s.max_error), s.n]
                for k, s in held['per_sweep'].items()]
    rep.table(['sweep', 'RMSE [N]', 'R²', 'largest error [N]', 'n'], per, heading='Per sweep')
    rep.table(['parameter', 'value', 'std'], [[n, f'{v:.5g}', f'{s:.2g}'] for n, v, s in
                                              zip(fit.names, fit.theta, fit.theta_std)],
              heading='Fitted parameters (1-sigma, Gauss-Newton)')
    rep.figure('measured_vs_model', plot_measured_vs_model(fit.model(fd.U, fd.Z), fd.y, train_scores['per_sweep']),
               'measured against model on the training cells; RMSE per sweep')
    residual_sections(rep, {'fitted model': analysis}, geometry, 'residual')
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
    rows = [[label, fixed_text(ev['model_rmse']), fixed_text(ev['raw'].rmse), fixed_text(ev['raw'].r2, 4),
             fixed_text(ev['raw'].max_error), repr(m)[:90]] for label, (m, ev) in results.items()]
    rep.table(['model', 'held-out model error [N]', 'held-out RMSE [N]', 'R²', 'largest error [N]',
               'model'], rows, heading='Held-out scores')
    residual_sections(rep, analyses, geometry, 'compare')
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
    if d.time_:
        rep.table(['check', 'question', 'result', 'numbers'], time_rows(d.case_),
                  heading='Time: does the residual depend on when a force was recorded?')
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
                  [[k + 1, t.candidate.name, fixed_text(t.heldout_rmse), drop_text(t.gain), f'{t.dbic:+.0f}',
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
        rows = [[labels[i] if i < len(labels) else i, fixed_text(c.signal[i]),
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
    residual_sections(rep, analyses, geometry, 'diagnosis')
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
