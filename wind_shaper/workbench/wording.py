"""Numbers of the diagnosis in words: a held-out error's change, a BIC change."""
from __future__ import annotations

__all__ = ['drop_text']


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
