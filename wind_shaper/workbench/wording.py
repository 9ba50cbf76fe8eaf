"""Numbers of the diagnosis in words: a held-out error's change, a BIC change, a parameter's value."""
from __future__ import annotations

import numpy as np

__all__ = ['drop_text', 'error_text', 'fixed_text', 'pct_text', 'values_text']


def _change_text(gain: float) -> str:
    """A relative drop of the held-out error in words: 'falls only 12 %', 'rises 912 %'."""
    pct = 100 * gain
    if pct <= -0.5:
        return f'rises {-pct:.0f} %'
    if pct < 0.5:
        return 'does not change'
    return f'falls only {pct:.0f} %'


def _bic_text(dbic: float) -> str:
    """A BIC change in words: 'falls only 4.1', 'rises 15.0'."""
    if dbic >= 0.05:
        return f'rises {dbic:.1f}'
    if dbic > -0.05:
        return 'does not change'
    return f'falls only {-dbic:.1f}'


def drop_text(gain: float) -> str:
    """The held-out error's relative change for a table cell: '76 % lower', '912 % higher'."""
    pct = 100 * gain
    if abs(pct) < 0.5:
        return '0 %'
    return f'{pct:.0f} % lower' if pct > 0 else f'{-pct:.0f} % higher'


def pct_text(gain: float) -> str:
    """A relative drop of the held-out error as a plain percentage: '62 %', '-1 %'."""
    return f'{100 * gain:.0f} %'


def values_text(value) -> str:
    """A parameter's value(s), 3 significant digits: '0.955' or '(0.047, -0.003)'."""
    v = np.atleast_1d(np.asarray(value, float))
    return f'{v[0]:.3g}' if len(v) == 1 else '(' + ', '.join(f'{x:.3g}' for x in v) + ')'


def error_text(model_error: float, floor: float = 0.0) -> str:
    """A held-out model error [N] in words: '0.062 N', or 'at the noise level (below 0.039 N)'
    when it is no larger than ``floor`` [N], the smallest error the noise lets the sweeps
    resolve (``noise_floor.NoiseFloor.floor``). The model error is the residual with the noise
    taken out, so it reads 0 whenever the residual is no larger than the noise: a fit cannot
    do better than the noise, and 0.000 N would claim it did."""
    floor = float(floor) if np.isfinite(floor) else 0.0
    if model_error <= max(floor, 0.0005):
        return f'at the noise level (below {floor:.3f} N)' if floor >= 0.0005 else 'at the noise level'
    return f'{model_error:.3f} N'


def fixed_text(x: float, digits: int = 3) -> str:
    """A number with ``digits`` decimals, as the reports' tables show errors: '0.123'."""
    return f'{x:.{digits}f}'
