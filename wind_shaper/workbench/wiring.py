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

Sweeps of the ``single-off`` design (every fan at one command, then each switched off in turn)
are checked another way, which needs no search and no margin against the prior's misfit, so it
holds on fan walls too: each command switched off leaves a gap in the field, the level sweep's
field less that sweep's, cell by cell; the gap is scored against every fan's footprint (a
matched filter: the weighted covariance of the gap with the footprint over the cells the sweep
passed, per unit of the footprint's norm), the commands are assigned to the fans by those
scores (``linear_sum_assignment``), and each cycle of commands moved round is named when
their gaps together score higher at the fans they are assigned to than at their own by
``Z_NAMED`` times the noise of that difference (the samples' scatter within a cell, pooled;
more on large rigs, ``FAMILY_RISK``), each move by ``Z_NOTED``; a cycle with the joint evidence
but a weaker move is reported as not settled, one without it taken for noise.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import norm

from ..model.modelfile import routing_text

__all__ = ['WiringCheck', 'check_wiring', 'is_single_off', 'MARGIN', 'STEP', 'EXHAUSTIVE', 'MAX_FANS', 'Z_NAMED',
           'Z_NOTED', 'FAMILY_RISK']

#: A routing is reported when it leaves at most this share of the RMSE as wired.
MARGIN = 0.7
#: Up to this many enabled fans every routing is tried (8! = 40320 fits: 0.2-0.3 s CPU, measured).
EXHAUSTIVE = 8
#: Above EXHAUSTIVE fans, a round of the greedy search keeps its best exchange only when it
#: leaves at most this share of the RMSE before it.
STEP = 0.9
#: Above this many enabled fans the exchanges are too many to try (n (n - 1) / 2 fits a round).
MAX_FANS = 40
#: In single-off sweeps a cycle of moved commands is named when their gaps together fit the fans
#: they are assigned to better than their own by at least this many noise sds (and each move by
#: Z_NOTED); measured on the bench's tunnels: every misrouting at 42 or more, no alternative to a
#: correct wiring above 0.2. On larger rigs the bar rises with the number of commands, so that
#: the chance of naming a cycle from noise anywhere stays near FAMILY_RISK.
Z_NAMED = 3.0
FAMILY_RISK = 0.01
#: A cycle with the joint evidence is named only when each of its moves has this much too (noise
#: sds); otherwise it is reported as not settled (on a wall, a corner fan's gap, which the wall's
#: edge cuts, may be the weak link). A cycle short of the joint evidence is taken for noise.
Z_NOTED = 1.0


@dataclass(frozen=True)
class WiringCheck:
    """checked: whether the check ran (``why`` says why not); drives: ((command meant for fan,
    fan whose motor it drives), ...) of the routing that fits best, empty when none fits better
    than ``MARGIN`` x as wired; rmse_as_wired, rmse_swapped [N]: the fit's RMSE over the cell
    means as wired and with the commands so rerouted (the best single exchange's when none is
    reported; nan when not checked or checked on single-off sweeps); method: 'fit' (the routings'
    fits) or 'located' (single-off sweeps, each command's gap located); evidence [noise sds]:
    for 'located', the weakest named cycle's joint margin when a routing is named (of the
    cycles not settled when none is), else the largest margin by which any command's gap alone
    fits another fan better than its own (negative: none does)."""

    checked: bool
    drives: tuple[tuple[str, str], ...]
    rmse_as_wired: float
    rmse_swapped: float
    why: str = ''
    method: str = 'fit'
    evidence: float = float('nan')

    @property
    def swapped(self) -> tuple[str, ...] | None:
        """The fans whose commands are misrouted, or None."""
        return tuple(a for a, _ in self.drives) or None

    @property
    def text(self) -> str:
        if not self.checked:
            return f'wiring not checked: {self.why}'
        if self.method == 'located':
            return self._located_text()
        if not self.drives:
            return (f'wiring: as configured (no rerouting of the fans\' commands fits the sweeps '
                    f'better; RMSE {self.rmse_as_wired:.3f} N as wired)')
        return (f'WIRING: {routing_text(self.drives)}: the sweeps fit {self.rmse_as_wired:.3f} N RMSE '
                f'as wired and {self.rmse_swapped:.3f} N with the commands so rerouted. Check these '
                f'fans\' ESC leads on the flight controller (or their entries in `channels` in '
                f'config/fan_output.yaml), record the designed sweeps again and calibrate on those; '
                f'a prior fitted on these sweeps describes the fans in the wrong places.')

    def _located_text(self) -> str:
        if not self.drives:
            if self.why:
                return f'wiring: not settled: {self.why}'
            if self.evidence < 0:
                nearest = f'no other fan fits a gap as well, the nearest by {-self.evidence:.1f} noise sds'
            else:
                nearest = (f'one gap alone fits a neighbour {self.evidence:.1f} noise sds better, too '
                           f'little to name a routing')
            return (f'wiring: as configured (in the sweeps with one fan off, each command left its '
                    f'gap at its own fan; {nearest})')
        also = f' Not settled: {self.why}.' if self.why else ''
        return (f'WIRING: {routing_text(self.drives)}: in the sweeps with one fan off, these '
                f'commands left their gaps where the other fans\' jets land (by {self.evidence:.1f} '
                f'noise sds or more). Check these fans\' ESC leads on the flight controller (or '
                f'their entries in `channels` in config/fan_output.yaml), record the sweeps again and '
                f'calibrate on those; a prior fitted on these sweeps describes the fans in the wrong '
                f'places.{also}')

    def to_json(self) -> dict:
        def rounded(x, keep):
            return round(float(x), 5) if keep and np.isfinite(x) else None
        return {'checked': self.checked, 'swapped': None if not self.drives else list(self.swapped),
                'drives': [list(p) for p in self.drives],
                'rmse_as_wired_N': rounded(self.rmse_as_wired, self.checked),
                'rmse_swapped_N': rounded(self.rmse_swapped, self.checked and self.drives),
                'why': self.why, 'method': self.method,
                'evidence_sd': rounded(self.evidence, self.checked)}


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
    singles = _single_off_sweeps(data, on)
    if singles is not None:
        return _located_check(data, fans, on, *singles, cell=cell)
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


def is_single_off(data, fans) -> bool:
    """Whether ``data`` holds the ``single-off`` design for ``fans``: a level sweep and, for
    every enabled fan, one with only that fan off (the check then locates each command's gap)."""
    return _single_off_sweeps(data, np.flatnonzero(np.asarray(fans.enabled, bool))) is not None


def _cycles(order) -> list[list[int]]:
    """The cycles (longer than one) of the permutation ``order`` (i -> order[i])."""
    seen, cycles = set(), []
    for start in range(len(order)):
        if start in seen or order[start] == start:
            continue
        cycle, i = [], start
        while i not in seen:
            seen.add(i)
            cycle.append(i)
            i = int(order[i])
        cycles.append(cycle)
    return cycles


def _single_off_sweeps(data, on) -> tuple[int, dict] | None:
    """(index of the level sweep, {enabled fan: index of the sweep with only it off}) when
    ``data`` holds a sweep with every enabled fan at one command above 0 and, for every enabled
    fan, a sweep with it off and the others at that command; else None."""
    U = np.array([np.asarray(s.pwm, float) for s in data.sweeps])
    if U.ndim != 2 or not len(U):
        return None
    level = next((i for i, u in enumerate(U[:, on]) if np.all(u > 0) and np.ptp(u) < 1e-6), None)
    if level is None:
        return None
    u_level = U[level, on[0]]
    singles: dict[int, int] = {}
    for i, u in enumerate(U[:, on]):
        off = np.flatnonzero(u <= 0)
        if len(off) == 1 and np.all(np.abs(np.delete(u, off) - u_level) < 1e-6):
            singles.setdefault(int(on[off[0]]), i)
    return (level, singles) if len(singles) == len(on) else None


def _located_check(data, fans, on, level: int, singles: dict, cell: float) -> WiringCheck:
    """The check on single-off sweeps (module docstring): each command's gap located among the
    fans' footprints (the paper's prior at the level command)."""
    from ..control.basis import FanBasis
    from ..model import paper_prior
    names = list(fans.names)
    n = len(on)
    fd = data.fit_data(None)
    used = [level] + [singles[int(c)] for c in on]
    keep = np.isin(fd.sweep, used)
    y = np.asarray(fd.y, float)[keep]
    row = {s: r for r, s in enumerate(used)}
    rows = np.array([row[int(s)] for s in fd.sweep[keep]], dtype=int)
    keys, cells = np.unique(np.floor(fd.Z[keep] / cell).astype(np.int64), axis=0, return_inverse=True)
    cells = cells.ravel()
    S, K = len(used), len(keys)
    sums, count, squares = np.zeros((S, K)), np.zeros((S, K)), np.zeros((S, K))
    np.add.at(sums, (rows, cells), y)
    np.add.at(count, (rows, cells), 1.0)
    np.add.at(squares, (rows, cells), y ** 2)
    # the samples' scatter within a cell, pooled: the noise of one sample [N]
    dof = float(np.maximum(count - 1, 0).sum())
    if dof < 10:
        return WiringCheck(False, (), float('nan'), float('nan'),
                           'too few samples share a cell of the sweeps with one fan off', method='located')
    sigma = float(np.sqrt(max((squares - sums ** 2 / np.maximum(count, 1)).sum(), 0.0) / dof))
    # the level field: every used sweep pooled (each gap is spread over the rest by 1 / S, the
    # same for every command, so the assignment is not moved by it)
    reference = sums.sum(axis=0) / np.maximum(count.sum(axis=0), 1.0)
    W = count[1:]                                                       # (n, K) samples per cell
    D = np.where(W > 0, reference - sums[1:] / np.maximum(W, 1.0), 0.0)   # the gaps [N]
    basis = FanBasis.from_term(paper_prior(fans), (keys + 0.5) * cell, sparse=False)
    u_level = np.asarray(data.sweeps[level].pwm, float)
    F = np.asarray(basis.shape)[:, on] * basis.thrust(u_level)[0][on]   # (K, n) footprints [N]
    total = W.sum(axis=1, keepdims=True)
    cross = (W * D) @ F - (W * D).sum(axis=1, keepdims=True) * (W @ F) / total
    norm2 = W @ F ** 2 - (W @ F) ** 2 / total
    score = cross / np.sqrt(np.maximum(norm2, 1e-30))   # (command, fan) [N]; noise sd sigma each
    centred = F - F.mean(axis=0)
    centred /= np.maximum(np.linalg.norm(centred, axis=0), 1e-30)

    def gain(c: int, k: int) -> tuple[float, float]:
        """How much better command c's gap fits fan k than its own fan [N], and the noise sd of
        that difference [N]."""
        spread = sigma * np.sqrt(max(2.0 - 2.0 * float(centred[:, c] @ centred[:, k]), 1e-12))
        return float(score[c, k] - score[c, c]), spread

    def margin(c: int, k: int) -> float:
        """The same in noise sds."""
        better, spread = gain(c, k)
        return better / spread

    # every score has the same noise (sigma), so the assignment that fits the gaps best overall
    # is the one with the largest summed score
    _, assigned = linear_sum_assignment(-score)
    bar = max(Z_NAMED, float(norm.isf(FAMILY_RISK / n)))
    named, unsure, weakest_named, weakest_unsure = [], [], np.inf, np.inf
    for cycle in _cycles(assigned):
        # A routing moves commands round in cycles. A cycle is judged on all its moves together
        # (their summed gain against its noise), and named only when each move has some evidence
        # too: on a large wall noise may move two faint neighbours, and the gap of a corner fan,
        # which the wall's edge cuts, may be the one weak link of a real cycle.
        gains = [gain(c, int(assigned[c])) for c in cycle]
        joint = sum(g for g, _ in gains) / np.sqrt(sum(sd ** 2 for _, sd in gains))
        weakest = min(g / sd for g, sd in gains)
        if joint >= bar and weakest >= Z_NOTED:
            named += cycle
            weakest_named = min(weakest_named, joint)
        elif joint >= bar:   # a real cycle with a weak link; below the bar, noise
            unsure += cycle
            weakest_unsure = min(weakest_unsure, joint)
    why = ''
    if unsure:
        seen = routing_text([(names[on[c]], names[on[assigned[c]]]) for c in unsure])
        why = (f'{seen}, by {weakest_unsure:.1f} noise sds together, but with a move short of '
               f'{Z_NOTED:g}; record the sweeps with one fan off again with more samples, '
               f'or check those leads by hand')
    if named:
        drives = tuple((names[on[c]], names[on[assigned[c]]]) for c in sorted(named))
        return WiringCheck(True, drives, float('nan'), float('nan'), why, method='located',
                           evidence=weakest_named)
    if unsure:
        return WiringCheck(True, (), float('nan'), float('nan'), why, method='located',
                           evidence=weakest_unsure)
    others = score.copy()
    np.fill_diagonal(others, -np.inf)
    nearest = max(margin(c, int(np.argmax(others[c]))) for c in range(n))
    return WiringCheck(True, (), float('nan'), float('nan'), method='located', evidence=nearest)
