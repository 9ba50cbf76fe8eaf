"""The diagnosis's last stage: the verdict, and the words and the JSON of a diagnosed ``Case``.

``word`` sets the verdict: 'found' (findings passed every check), 'explained' (the held-out model
error was not material against the noise to begin with, or the held-out residual is no more than
the noise by the test of ``noise_floor``), 'time fault' (a time check found the
sweeps depend on when they were recorded, and no effect is named until that is repaired) or
'unexplained'. ``summary_text``
writes it in plain words with the warnings about the data; ``checks_text`` lists every check's
result for each finding; ``to_json`` is the diagnosis's part of summary.json. Forces [N].
"""
from __future__ import annotations

from .checks import CHECKS
from .formula import formula_text
from .discrepancy import outside_text
from .wording import error_text
from .time_checks import TIME_CHECKS, time_text

__all__ = ['word', 'summary_text', 'warnings', 'spread_warning', 'time_warning', 'checks_text',
           'to_json']


def word(case):
    """The stage: set ``case.verdict``."""
    if case.held:
        case.verdict = 'time fault'
    elif case.steps:
        case.verdict = 'found'
    elif (case.baseline_rmse < case.settings.material * case.noise_sd
          or (case.noise_floor is not None and case.noise_floor.within)):
        case.verdict = 'explained'
    else:
        case.verdict = 'unexplained'
    return case


def spread_warning(case) -> str:
    """What is wrong with data whose commands barely vary, and what to record instead ('' when
    they vary enough)."""
    if not case.low_spread:
        return ''
    return (f'Warning: these sweeps were taken at nearly the same fan commands (command spread '
            f'{100 * case.command_spread["median"]:.1f} % PWM: the median over the fans of the '
            f'interquartile range of each fan\'s command across the sweeps; the diagnosis wants at '
            f'least {100 * case.settings.min_spread:.0f} %), as in a shaping run that has converged. On such '
            f'data per-fan effects (a fan\'s gain, width, landing point) are poorly identified: a '
            f'held-out sweep at the same commands cannot tell an effect from a patch of the residual '
            f'at this one operating point, so no finding is reported. Record instead 8-12 sweeps of '
            f'~1000 samples at varied commands: each fan spread over its range independently of the '
            f'others, the first and last with the fans off: on the node graph `wind-shaper collect '
            f'--design lhs:12 --out NAME` does that (see docs/workbench.md, "Data").')


def time_warning(case) -> str:
    """What the time checks found and what to do ('' when nothing, or when the verdict already
    says it)."""
    return '' if case.held else time_text(case)


def warnings(case) -> list[str]:
    """The warnings about the data: commands that barely vary, forces and positions out of step,
    sweeps that depend on when they were recorded."""
    sync = case.sync.text() if case.sync is not None else ''
    return [w for w in (spread_warning(case), sync, time_warning(case)) if w]


def summary_text(case) -> str:
    """The verdict in plain words, with the warnings."""
    return _verdict_text(case) + ''.join(f'\n\n{w}' for w in warnings(case))


def _floor(test) -> float:
    return test.floor if test is not None else 0.0


def _verdict_text(case) -> str:
    base = error_text(case.baseline_rmse, _floor(case.noise_floor))
    if case.verdict == 'time fault':
        return (f'No effect is named on these sweeps yet: the held-out model error is '
                f'{base} (noise {case.noise_sd:.3f} N), but part of the residual '
                f'depends on when each force was recorded, and every candidate effect would be '
                f'fitted to that. ' + time_text(case) + ' Then diagnose again.')
    if case.verdict == 'explained':
        test = f'; {case.noise_floor.text()}' if case.noise_floor is not None else ''
        if case.noise_floor is not None and not case.noise_floor.within:
            # resolved by the held-out sweeps, but too small to name an effect for
            return (f'Nothing to report: the held-out model error {base} is below '
                    f'{100 * case.settings.material:.0f} % of the measurement noise '
                    f'({case.noise_sd:.3f} N per sample), too small an error to name an effect for, '
                    f'though the held-out sweeps resolve it ({case.noise_floor.text()}).')
        return (f'Nothing to report: the model explains these sweeps to the noise level (held-out '
                f'model error {base} against measurement noise {case.noise_sd:.3f} N per '
                f'sample{test}).')
    undecided = case.undecided.text() if case.undecided is not None else None
    if case.verdict == 'unexplained':
        if case.low_spread:
            return (f'No effect can be identified on these sweeps: the held-out model error is '
                    f'{base} (noise {case.noise_sd:.3f} N), but the sweeps\' '
                    f'commands barely vary. See the residual\'s structure below.')
        if case.demoted:
            more = ' ' + _demoted_text(case)
        else:
            best = case.rankings[0][0] if case.rankings and case.rankings[0] else None
            lowers = (f'lowers it by only {100 * best.gain:.0f} %' if best is not None and best.gain >= 0.005
                      else 'does not lower it')
            more = f' The best candidate, {best.candidate.title}, {lowers}.' if best else ''
            if best is not None and best.family_note:
                more += f' Still, {best.family_note}.'
        return (f'No candidate explains the residual: the held-out model error stays at '
                f'{base} (noise {case.noise_sd:.3f} N).{more}'
                + (' ' + undecided if undecided is not None else '')
                + _outside_text(case) + ' See the residual\'s structure below.')
    lines = [f'{i + 1}. {t.finding}' for i, t in enumerate(case.steps)]
    tail = f'\n{_demoted_text(case)}' if case.demoted else ''
    final = error_text(case.final_rmse, _floor(case.final_floor or case.noise_floor))
    return (f'Found {len(case.steps)} effect(s); held-out model error '
            f'{base} -> {final} '
            f'({100 * (1 - case.final_rmse / case.baseline_rmse):.0f} % lower):\n' + '\n'.join(lines)
            + tail + ('\n' + undecided if undecided is not None else '')
            + ('\n\nThe rest is still material.' + _outside_text(case)
               if case.discrepancy is not None else ''))


def _outside_text(case) -> str:
    if case.discrepancy is None:
        return ''
    formula = (formula_text(case.formula, case.discrepancy.error_floor)
               if case.formula is not None else '')
    return ' ' + (formula + ' ' if formula else '') + outside_text(case.discrepancy)


def _demoted_text(case) -> str:
    """'Partly explained by X, but not reported: ...' for effects that failed a check."""
    parts = [f'{t.candidate.title} (it lowers the held-out error {100 * t.gain:.0f} %), but '
             f'{"; ".join(t.reasons)}' + (f'; {t.family_note}' if t.family_note else '')
             for t in case.demoted]
    patch = any(t.check is not None and t.check.spread for t in case.demoted)
    return ('Partly explained by ' + '; and by '.join(parts)
            + ('. So that is not reported as a finding: the physics is likely something the '
               'library lacks.' if patch else '. So that is not reported as a finding yet.'))


def checks_text(case) -> str:
    """Every check and its result for each effect the selection added, in words: one line per
    check under each finding (reported first, then those not reported)."""
    out = []
    for t in case.steps + case.demoted:
        status = 'reported' if t in case.steps else 'not reported'
        out.append(f'{t.candidate.title} ({status}):')
        for name, check in CHECKS.items():
            r = t.checks.get(name)
            state = r.state if r is not None else 'not run'
            why = f': {r.why}' if r is not None and r.why else ''
            out.append(f'  - {name} ({check.question}) {state}{why}')
    return '\n'.join(out)


def to_json(case) -> dict:
    """The diagnosis's part of summary.json."""
    s = case.settings
    return {
        'verdict': case.verdict, 'summary': summary_text(case),
        'noise_sd_N': case.noise_sd,
        'train_sweeps': list(case.train_sweeps.labels), 'test_sweeps': list(case.test_sweeps.labels),
        'baseline': {'model': repr(case.baseline.model), 'train_rmse_N': case.baseline.rmse,
                     'heldout_model_rmse_N': case.baseline_rmse, 'heldout_raw_rmse_N': case.baseline_raw,
                     'bic': case.baseline.bic},
        'final': {'model': repr(case.final.model), 'train_rmse_N': case.final.rmse,
                  'heldout_model_rmse_N': case.final_rmse, 'heldout_raw_rmse_N': case.final_raw},
        'noise_floor': case.noise_floor.to_json() if case.noise_floor is not None else None,
        'final_noise_floor': case.final_floor.to_json() if case.final_floor is not None else None,
        'findings': [t.to_json() for t in case.steps],
        'not_reported': [t.to_json() for t in case.demoted],
        'discrepancy': case.discrepancy.to_json() if case.discrepancy is not None else None,
        'formula': case.formula.to_json() if case.formula is not None else None,
        'undecided': case.undecided.to_json() if case.undecided is not None else None,
        'rankings': [[t.to_json() for t in r] for r in case.rankings],
        'guard': {'min_gain': s.min_gain, 'min_dbic': s.min_dbic, 'min_z': s.min_z,
                  'material': s.material, 'min_spread': s.min_spread},
        'command_spread': {'median': round(case.command_spread['median'], 4),
                           'per_fan': {k: round(v, 4) for k, v in case.command_spread['per_fan'].items()},
                           'too_little': bool(case.low_spread)},
        'clocks': ({'lag_s': round(case.sync.lag_s, 4), 'out_of_step': case.sync.out_of_step,
                    'agree': round(case.sync.agree, 3), 'mse_drop': round(case.sync.drop, 4),
                    'per_sweep_s': [round(float(x), 4) for x in case.sync.per_sweep],
                    'stepped_sweeps': [case.sync.labels[case.sync.sweeps.index(i)] for i in case.sync.stepped]}
                   if case.sync is not None else None),
        'time': [r.to_json() for r in (case.time or {}).values()],
        'time_checks': [{'check': c.name, 'question': c.question} for c in TIME_CHECKS.values()],
        'warnings': warnings(case),
        'checks': [{'check': c.name, 'question': c.question, 'refusal': c.refusal,
                    'setting': c.setting or None, 'stage': c.stage} for c in CHECKS.values()],
    }
