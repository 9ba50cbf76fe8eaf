"""The guard: what makes a candidate a finding at all (run on every candidate the selection
tries).

On the held-out sweeps the model error (noise removed, see ``metrics``) falls by at least
``min_gain`` (20 %); on the training sweeps the BIC falls by at least ``min_dbic`` (10, "very
strong" evidence); a parameter lies ``min_z`` (3) standard errors from its no-effect value; the
error before was *material*: at least ``material`` (half) of the measurement noise; and the
sweeps' commands vary (``min_spread``). An effect that shows with every fan off
(``Candidate.fans_off``: the background draft) may instead lower the model error on the held-out
fans-off sweeps by ``min_gain``, leaving the fans-on ones no worse: beside physics the library
lacks that dominates the fans-on residual (a draft that bends the plume), a real offset is all
of the fans-off sweeps' error but a small share of the whole.
"""
from __future__ import annotations

from ..fitting import z_from_null
from ..wording import _bic_text, _change_text
from .base import Check, CheckResult, number, register_check


def gain_with_fans_off(case, t, current_model) -> float | None:
    """For an effect that shows with every fan off (a background draft): the share of the
    held-out fans-off sweeps' model error it removes, when it leaves the fans-on held-out
    sweeps no worse; else None. With the fans on, physics the library lacks (a draft that
    bends the plume) can carry most of the residual, so an offset that is all of the
    fans-off sweeps' error removes only a small share of the whole."""
    if not (t.candidate.fans_off and case.heldout_off is not None and current_model is not None):
        return None
    off, on = case.heldout_off
    before = off.evaluate(current_model)['model_rmse']
    if before <= 0 or on.evaluate(t.model)['model_rmse'] > on.evaluate(current_model)['model_rmse']:
        return None
    return float(1.0 - off.evaluate(t.model)['model_rmse'] / before)


@register_check
class Guard(Check):
    name = 'guard'
    question = ('Does it lower the held-out error by 20 % and the BIC by 10, lie 3 standard errors '
                'from no effect, on a material error and on sweeps whose commands vary?')
    refusal = 'held-out error falls only ... / BIC rises ... / parameter only ... standard errors'
    stage = 'candidate'

    def judge(self, case, t, current_rmse: float, current_model=None) -> CheckResult:
        """Judge the trial ``t`` against the model before it (its held-out model error
        ``current_rmse`` [N]): sets ``t.passed``, ``t.reasons``, ``t.gain_off`` and
        ``t.checks['guard']``."""
        s = case.settings
        reasons = []
        if case.low_spread:
            reasons.append('not identifiable: the sweeps\' commands barely vary (see the verdict)')
        if current_rmse < s.material * case.noise_sd:
            reasons.append(f'nothing material to explain (held-out model error {current_rmse:.3f} N '
                           f'< {s.material:.2f} x noise {case.noise_sd:.3f} N)')
        t.gain_off = gain_with_fans_off(case, t, current_model) if t.gain < s.min_gain else None
        if t.gain < s.min_gain and (t.gain_off is None or t.gain_off < s.min_gain):
            off = '' if t.gain_off is None else f', on the fans-off sweeps {_change_text(t.gain_off)}'
            reasons.append(f'held-out error {_change_text(t.gain)}{off} (needs to fall >= '
                           f'{100 * s.min_gain:.0f} %)')
        if t.dbic > -s.min_dbic:
            reasons.append(f'BIC {_bic_text(t.dbic)} (needs to fall >= {s.min_dbic:g})')
        z = z_from_null(t.params, t.std, t.candidate.null)
        if z is not None and z < s.min_z:
            reasons.append(f'parameter only {z:.1f} standard errors from no effect (< {s.min_z:g})')
        t.reasons = reasons
        t.passed = not reasons
        numbers = {'heldout_gain': number(t.gain), 'heldout_gain_fans_off': number(t.gain_off),
                   'dbic': number(t.dbic, 3), 'z_from_null': number(z, 3),
                   'error_over_noise': number(current_rmse / case.noise_sd if case.noise_sd > 0 else None),
                   'command_spread': number(case.command_spread['median'])}
        t.checks[self.name] = r = self.result(t.passed, numbers, '; '.join(reasons))
        return r
