"""What ``wind-shaper model add`` does, without the argument parsing: effects added to a model
(library candidates, registered term kinds, or a discrepancy or formula fitted to what is left),
both models refitted on the training sweeps and shown side by side on the held-out ones.

``add_command`` writes a report folder (``report.html``, ``report.md``, PNG plots,
``summary.json``) and returns what it made; ``model_with_additions`` only builds the extended
model. Forces and errors [N].
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.config import parse_spec
from ..core.geometry import TunnelGeometry
from ..model import TERMS, Term, Wrapper, save_model, term_label, walk
from .data import SweepSet
from .diagnose import candidate_std, drop_text, fit_mask
from .discrepancy import SCALE_FEATURES, describe_discrepancy, fit_discrepancy
from .errors import CandidateError
from .fitting import FitResult, fit_model
from .formula import fit_formula
from .library import Library, _pm, apply_candidate, default_library
from .metrics import HeldOut
from .report import Report, plot_closed_loop, residual_sections
from .residuals import analyse_residuals
from .wording import error_text, fixed_text

__all__ = ['AddOutcome', 'add_command', 'model_with_additions']


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
              [['before', fixed_text(before['model_rmse']), fixed_text(before['raw'].rmse), fixed_text(before['raw'].r2, 4),
                fixed_text(before['raw'].max_error), f'{old_fit.bic:.0f}'],
               ['after', fixed_text(after['model_rmse']), fixed_text(after['raw'].rmse), fixed_text(after['raw'].r2, 4),
                fixed_text(after['raw'].max_error), f'{new_fit.bic:.0f}']],
              heading='Before and after: ' + ('the old model was already below the noise level' if below
                                               else f'held-out model error {drop_text(drop)}'))
    params = []
    for n, v, s in zip(new_fit.names, new_fit.theta, new_fit.theta_std):
        if n not in old_fit.names:
            params.append([n, f'{v:.4g}', f'{s:.2g}'])
    rep.table(['new parameter', 'value', 'std'], params, heading='The added effects, fitted')
    residual_sections(rep, analyses, geometry, 'add')
    loop = None
    if closed_loop is not None:
        loop = closed_loop({'before': model, 'after (refitted)': new_fit.model})
        rep.figure('closed_loop', plot_closed_loop(loop),
                   'true-field RMSE to the target per iteration on the simulated tunnel', heading='Closed loop')
        rep.table(['iteration'] + list(loop.errors),
                  [[k] + [fixed_text(float(np.median(e[:, k]))) for e in loop.errors.values()]
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
