"""Fans whose command channels are misrouted, found in the commissioning's sweeps.

An ESC lead on the wrong output of the flight controller (or entries of
``config/fan_output.yaml``'s ``channels`` out of order) sends fan A's command to fan B's motor:
two leads exchanged, three moved round, or a connector block plugged one output along. The fans
and their jets are as built; only not where the commands say. No correction of a prior holds
that, and shaping on such a tunnel fails from either start, so it is checked where the designed
sweeps are fitted (``calibrate --data``, ``calibrate --sim --design``).

The check fits the sweeps' cell means [N] with each fan's footprint shape from the paper's
prior at its starting values, one gain per fan and one offset (linear least squares: the shapes
and the thrust curve stay the prior's), as wired and with the commands rerouted. On rigs of up
to ``EXHAUSTIVE`` enabled fans it tries every routing (7! = 5040 for the default tunnel, each
fit a small normal-equation solve); on larger ones it searches greedily: each round tries every
exchange of two fans' commands on top of the routing so far and keeps the best while it lowers
the RMSE below ``STEP`` times the round before's. The routing found is reported when its RMSE
is below ``margin`` times the RMSE as wired (docs/commissioning.md gives the figures measured
on the bench's tunnels).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ..model.modelfile import routing_text

__all__ = ['WiringCheck', 'check_wiring', 'MARGIN', 'STEP', 'EXHAUSTIVE', 'MAX_FANS']

#: A routing is reported when it leaves at most this share of the RMSE as wired.
MARGIN = 0.7
#: Up to this many enabled fans every routing is tried (8! = 40320 fits: 0.2-0.3 s CPU, measured).
EXHAUSTIVE = 8
#: Above EXHAUSTIVE fans, a round of the greedy search keeps its best exchange only when it
#: leaves at most this share of the RMSE before it.
STEP = 0.9
#: Above this many enabled fans the exchanges are too many to try (n (n - 1) / 2 fits a round).
MAX_FANS = 40


@dataclass(frozen=True)
class WiringCheck:
    """checked: whether the check ran (``why`` says why not); drives: ((command meant for fan,
    fan whose motor it drives), ...) of the routing that fits best, empty when none fits better
    than ``MARGIN`` x as wired; rmse_as_wired, rmse_swapped [N]: the fit's RMSE over the cell
    means as wired and with the commands so rerouted (the best single exchange's when none is
    reported; nan when not checked)."""

    checked: bool
    drives: tuple[tuple[str, str], ...]
    rmse_as_wired: float
    rmse_swapped: float
    why: str = ''

    @property
    def swapped(self) -> tuple[str, ...] | None:
        """The fans whose commands are misrouted, or None."""
        return tuple(a for a, _ in self.drives) or None

    @property
    def text(self) -> str:
        if not self.checked:
            return f'wiring not checked: {self.why}'
        if not self.drives:
            return (f'wiring: as configured (no rerouting of the fans\' commands fits the sweeps '
                    f'better; RMSE {self.rmse_as_wired:.3f} N as wired)')
        return (f'WIRING: {routing_text(self.drives)}: the sweeps fit {self.rmse_as_wired:.3f} N RMSE '
                f'as wired and {self.rmse_swapped:.3f} N with the commands so rerouted. Check these '
                f'fans\' ESC leads on the flight controller (or their entries in `channels` in '
                f'config/fan_output.yaml), record the designed sweeps again and calibrate on those; '
                f'a prior fitted on these sweeps describes the fans in the wrong places.')

    def to_json(self) -> dict:
        return {'checked': self.checked, 'swapped': None if not self.drives else list(self.swapped),
                'drives': [list(p) for p in self.drives],
                'rmse_as_wired_N': round(self.rmse_as_wired, 5) if self.checked else None,
                'rmse_swapped_N': round(self.rmse_swapped, 5) if self.checked and self.drives else None,
                'why': self.why}


def check_wiring(data, fans, *, cell: float = 0.03, margin: float = MARGIN) -> WiringCheck:
    """Whether ``fans``' enabled fans' commands look misrouted in ``data`` (a ``SweepSet``
    of designed sweeps), judged with the paper's prior at its starting values: footprints at the
    hubs and one thrust curve for all. Not the prior fitted on the same sweeps: fitted as wired,
    it bends its thrust curves and widths to hold a swap (a fan's gain near 0 or below), and its
    footprints then tell the routings apart no better than the wiring as it is."""
    from ..control.basis import FanBasis
    from ..model import paper_prior
    model = paper_prior(fans)
    on = np.flatnonzero(np.asarray(fans.enabled, bool))
    names = list(fans.names)
    if len(on) < 2:
        return WiringCheck(False, (), float('nan'), float('nan'), 'fewer than two fans enabled')
    if len(on) > MAX_FANS:
        return WiringCheck(False, (), float('nan'), float('nan'),
                           f'{len(on)} fans enabled, more than the {MAX_FANS} whose exchanges it tries')
    fd = data.fit_data(cell)
    if len(np.unique(fd.sweep)) < 3:
        return WiringCheck(False, (), float('nan'), float('nan'), 'fewer than three sweeps')
    basis = FanBasis.from_term(model, fd.Z, sparse=False)   # the paper prior is a sum over fans
    shape = np.asarray(basis.shape)[:, on]
    y = np.asarray(fd.y, float) - np.asarray(basis.offset, float)
    sweeps = [np.flatnonzero(fd.sweep == s) for s in np.unique(fd.sweep)]
    n = len(on)
    # Per sweep s: the Gram matrix and right-hand side of [shapes, 1] over its cells, and the
    # thrust [N] each motor k would give at the command sent for each fan c: a routing's fit is
    # then a (n + 1) x (n + 1) solve on sums of these, whatever the number of cells.
    gram = np.empty((len(sweeps), n + 1, n + 1))
    rhs = np.empty((len(sweeps), n + 1))
    thrust = np.empty((len(sweeps), n, n))
    for s_, rows in enumerate(sweeps):
        X = np.column_stack([shape[rows], np.ones(len(rows))])
        gram[s_], rhs[s_] = X.T @ X, X.T @ y[rows]
        U = np.asarray(fd.U[rows[0]], float)
        for c in range(n):
            thrust[s_, :, c] = basis.thrust(np.full(len(names), U[on[c]]))[0][on]
    total = float(y @ y)
    ridge = 1e-9 * np.trace(gram.sum(axis=0)) / (n + 1)

    def rmse(routings) -> np.ndarray:
        """The fits' RMSE [N], one per routing (R, n): motor k runs the command sent for fan
        routings[r, k] (indices among the enabled fans)."""
        routings = np.atleast_2d(routings)
        scale = np.ones((len(routings), len(sweeps), n + 1))
        scale[:, :, :n] = thrust[:, np.arange(n)[None, :], routings].transpose(1, 0, 2)
        G = np.einsum('rsk,rsl,skl->rkl', scale, scale, gram) + ridge * np.eye(n + 1)
        h = np.einsum('rsk,sk->rk', scale, rhs)
        coef = np.linalg.solve(G, h[..., None])[..., 0]
        return np.sqrt(np.maximum(total - np.einsum('rk,rk->r', coef, h), 0.0) / len(y))

    identity = np.arange(n)
    as_wired = float(rmse(identity)[0])
    if n <= EXHAUSTIVE:
        routings = np.array(list(itertools.permutations(range(n)))[1:])   # the first is as wired
        errors = np.concatenate([rmse(chunk) for chunk in np.array_split(routings, max(1, len(routings) // 5000))])
        best = int(np.argmin(errors))
        order, current = routings[best], float(errors[best])
        first_best = current
    else:
        order, current, first_best = identity, as_wired, np.inf
        exchanges = list(itertools.combinations(range(n), 2))
        for _ in range(n - 1):   # n - 1 exchanges make any routing of n fans
            trials = np.repeat(order[None, :], len(exchanges), axis=0)
            for t, (i, j) in enumerate(exchanges):
                trials[t, i], trials[t, j] = order[j], order[i]
            errors = rmse(trials)
            best = int(np.argmin(errors))
            first_best = min(first_best, float(errors[best]))
            if not errors[best] < STEP * current:
                break
            order, current = trials[best], float(errors[best])
    if current < margin * as_wired:
        drives = tuple((names[on[order[k]]], names[on[k]]) for k in range(n) if order[k] != k)
        return WiringCheck(True, drives, as_wired, current)
    return WiringCheck(True, (), as_wired, first_best)
