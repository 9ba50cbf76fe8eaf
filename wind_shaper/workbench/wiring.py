"""Two fans whose command channels are swapped, found in the commissioning's sweeps.

An ESC lead on the wrong output of the flight controller (or two entries of
``config/fan_output.yaml``'s ``channels`` exchanged) sends fan A's command to fan B's motor. The
fans and their jets are as built; only not where the commands say. No correction of a prior
holds that, and shaping on such a tunnel fails from either start, so it is checked where the
designed sweeps are fitted (``calibrate --data``, ``calibrate --sim --design``).

The check fits the sweeps' cell means [N] with each fan's footprint shape from the paper's
prior at its starting values, one gain per fan and one offset (linear least squares: the shapes
and the thrust curve stay the prior's), once as wired and once with each pair of enabled fans'
commands exchanged. A pair is reported when exchanging it lowers the fit's RMSE below
``margin`` times the RMSE as wired (docs/commissioning.md gives the figures measured on the
bench's tunnels).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ['WiringCheck', 'check_wiring', 'MARGIN', 'MAX_FANS']

#: An exchange is reported when it leaves at most this share of the RMSE as wired.
MARGIN = 0.7
#: Above this many enabled fans the pairs are too many to try (n (n - 1) / 2 fits).
MAX_FANS = 40


@dataclass(frozen=True)
class WiringCheck:
    """checked: whether the check ran (``why`` says why not); swapped: the two fans' names whose
    exchange fits best, or None when none fits better than ``MARGIN`` x as wired; rmse_as_wired,
    rmse_swapped [N]: the fit's RMSE over the cell means as wired and with that pair exchanged
    (nan when not checked)."""

    checked: bool
    swapped: tuple[str, str] | None
    rmse_as_wired: float
    rmse_swapped: float
    why: str = ''

    @property
    def text(self) -> str:
        if not self.checked:
            return f'wiring not checked: {self.why}'
        if self.swapped is None:
            return (f'wiring: as configured (no two fans fit the sweeps better with their commands '
                    f'exchanged; RMSE {self.rmse_as_wired:.3f} N as wired)')
        a, b = self.swapped
        return (f'WIRING: fans {a} and {b} look swapped: the sweeps fit {self.rmse_as_wired:.3f} N RMSE '
                f'as wired and {self.rmse_swapped:.3f} N with their commands exchanged. Check their ESC '
                f'leads on the flight controller (or exchange their entries in `channels` in '
                f'config/fan_output.yaml), record the designed sweeps again and calibrate on those; '
                f'a prior fitted on these sweeps describes the fans in the wrong places.')

    def to_json(self) -> dict:
        return {'checked': self.checked, 'swapped': None if self.swapped is None else list(self.swapped),
                'rmse_as_wired_N': round(self.rmse_as_wired, 5) if self.checked else None,
                'rmse_swapped_N': round(self.rmse_swapped, 5) if self.checked and self.swapped else None,
                'why': self.why}


def check_wiring(data, fans, *, cell: float = 0.03, margin: float = MARGIN) -> WiringCheck:
    """Whether two of ``fans``' enabled fans' commands look exchanged in ``data`` (a ``SweepSet``
    of designed sweeps), judged with the paper's prior at its starting values: footprints at the
    hubs and one thrust curve for all. Not the prior fitted on the same sweeps: fitted as wired,
    it bends its thrust curves and widths to hold a swap (a fan's gain near 0 or below), and its
    footprints then tell the pairs apart no better than the wiring as it is."""
    from ..control.basis import FanBasis
    from ..core.errors import ConfigError
    from ..model import paper_prior
    model = paper_prior(fans)
    on = np.flatnonzero(np.asarray(fans.enabled, bool))
    names = list(fans.names)
    if len(on) < 2:
        return WiringCheck(False, None, float('nan'), float('nan'), 'fewer than two fans enabled')
    if len(on) > MAX_FANS:
        return WiringCheck(False, None, float('nan'), float('nan'),
                           f'{len(on)} fans enabled, more than the {MAX_FANS} whose pairs it tries')
    fd = data.fit_data(cell)
    if len(np.unique(fd.sweep)) < 3:
        return WiringCheck(False, None, float('nan'), float('nan'), 'fewer than three sweeps')
    try:
        basis = FanBasis.from_term(model, fd.Z, sparse=False)
    except ConfigError:
        return WiringCheck(False, None, float('nan'), float('nan'), 'the model is not separable over fans')
    shape = np.asarray(basis.shape)[:, on]
    y = np.asarray(fd.y, float) - np.asarray(basis.offset, float)
    sweeps = [np.flatnonzero(fd.sweep == s) for s in np.unique(fd.sweep)]

    def rmse(order) -> float:
        thrust = np.empty((len(y), len(on)))
        for rows in sweeps:
            U = np.asarray(fd.U[rows[0]], float)[order]
            thrust[rows] = basis.thrust(U)[0][on]
        A = np.column_stack([shape * thrust, np.ones(len(y))])
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(np.sqrt(np.mean((A @ coef - y) ** 2)))

    identity = np.arange(len(names))
    as_wired = rmse(identity)
    best, pair = np.inf, None
    for i, j in itertools.combinations(on, 2):
        order = identity.copy()
        order[i], order[j] = j, i
        r = rmse(order)
        if r < best:
            best, pair = r, (names[i], names[j])
    if best < margin * as_wired:
        return WiringCheck(True, pair, as_wired, best)
    return WiringCheck(True, None, as_wired, best)
