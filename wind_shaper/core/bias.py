"""When to bias (zero) the force sensor: the plan shared by designed experiments and shaping
iterations. A strain-gauge sensor's zero drifts with temperature and time; biasing it with
every fan off and settled takes the drift out, at the cost of a spin-down before the sweep.
Commands are fractions 0..1 of full PWM, one per fan."""
from __future__ import annotations

import numpy as np

from .errors import ConfigError

#: never: leave the sensor as it is; fans_off: bias on a sweep whose own commands are every fan
#: off, once they settled; every_sweep: also before any other sweep, with every fan off first.
BIAS_MODES = ('never', 'fans_off', 'every_sweep')
#: What ``bias_plan`` says for one sweep: nothing, bias once the sweep's own (fans-off) commands
#: have settled, or turn every fan off and bias before commanding the sweep.
NO_BIAS, BIAS_AT_ROW, BIAS_BEFORE_ROW = '', 'at_row', 'before_row'


def check_bias_mode(mode: str, u_min: float = 0.0) -> str:
    """``mode`` if it is one of ``BIAS_MODES``, else a ConfigError that lists them. ``u_min``
    [fraction]: the lowest command the fans may receive; 'every_sweep' turns every fan off before
    each sweep, which a tunnel whose fans must not go below u_min > 0 refuses (the fans would
    never report 0, and a sensor biased with them running would take their force for its zero)."""
    if mode not in BIAS_MODES:
        raise ConfigError(f'bias_zero must be one of {", ".join(BIAS_MODES)}; got {mode!r} '
                          f'(never: leave the force sensor as it is; fans_off: bias on the sweeps '
                          f'with every fan off; every_sweep: before every sweep, with the fans off)')
    if mode == 'every_sweep' and u_min > 0:
        raise ConfigError(f'bias_zero every_sweep turns every fan off before each sweep, but the '
                          f'lowest command the fans may receive is u_min = {u_min:g} '
                          f'(shaping.u_min): set u_min to 0 if the fans may stop, or bias_zero to '
                          f'never (or fans_off, for designed sweeps with every fan off)')
    return mode


def bias_plan(commands, mode: str) -> list[str]:
    """Per row of ``commands`` (rows x fans) [fraction], when to bias the force sensor under
    ``mode`` (one of ``BIAS_MODES``): ``BIAS_AT_ROW`` for a row with every fan off,
    ``BIAS_BEFORE_ROW`` for any other row with 'every_sweep', else ``NO_BIAS``."""
    check_bias_mode(mode)
    rows = np.atleast_2d(np.asarray(commands, dtype=float))
    plan = []
    for u in rows:
        if mode == 'never':
            plan.append(NO_BIAS)
        elif np.all(np.abs(u) < 1e-9):
            plan.append(BIAS_AT_ROW)
        else:
            plan.append(BIAS_BEFORE_ROW if mode == 'every_sweep' else NO_BIAS)
    return plan
