"""Which of a run's field maps the adaptive update may build on: restarts and relearning.

A run's maps are measured at different commands; the adaptive update (``adaptive``) steps from
the best of them and fits its corrections of the prior to all of them. Two events change that:

* **A restart** ("start wider"): the warm start's first sweep showed that the prior's optimum is
  not this tunnel's (``warm_start.FirstSweep``), so the run goes on from a wider start. The map
  of the prior's optimum stays data for the corrections, but the steps start again from the new
  start: its measured error may be higher, and the prior's optimum may lie in a basin of the
  error that the tunnel does not share. Marked in that map's info as ``restart_next``.
* **Relearning**: the newest map contradicts what the earlier maps taught (the tunnel was
  repaired or changed between iterations, a run was resumed on another tunnel). The earlier maps
  are dropped: the fit and the steps start again from the newest map alone. Marked in the newest
  map's info as ``relearned``.

``contradiction`` is the test behind relearning: the newest map against the nearest earlier map
in command space, moved by the change the corrected prior predicts between them. Commands U are
fractions 0..1 of full PWM; fields F - F_des at the key points [N].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

#: The newest map contradicts the earlier ones when it misses their prediction by more than
#: this many times the noise of the two field estimates, on top of the predicted change itself
#: (the corrected prior may be wrong by as much as the change it predicts).
CONTRADICTION_FACTOR = 4.0


def chain_start(infos: Sequence[dict]) -> tuple[int, int]:
    """(first map the steps may build on, first map the corrections may use) for a run whose
    maps carry ``infos`` (oldest first; the newest map's info may be empty)."""
    base_from = fit_from = 0
    for i, info in enumerate(infos):
        if 'relearned' in info:
            base_from = fit_from = i
        if 'restart_next' in info:
            base_from = i + 1
    return min(base_from, len(infos) - 1), min(fit_from, len(infos) - 1)


@dataclass(frozen=True)
class Contradiction:
    """The newest map against the nearest earlier one: RMS miss of the predicted field [N], what
    noise and the predicted change allow [N], the earlier map's index, and the verdict."""

    miss: float
    allowed: float
    against: int
    contradicts: bool

    def text(self) -> str:
        return (f'the newest field map misses what the earlier maps predict at its commands by '
                f'{self.miss:.3f} N RMS (noise and the predicted change allow {self.allowed:.3f} N): '
                f'the tunnel no longer behaves as it did; the update learns again from this map on')

    def to_json(self) -> dict:
        return {'miss_N': round(self.miss, 5), 'allowed_N': round(self.allowed, 5),
                'against': int(self.against), 'contradicts': bool(self.contradicts),
                'text': self.text() if self.contradicts else ''}


def contradiction(maps: Sequence[tuple], first: int, model: Callable, floor: float,
                  factor: float = CONTRADICTION_FACTOR) -> Contradiction | None:
    """Test the newest of ``maps`` [(U (n,), F - F_des (N,) [N], std (N,) [N] or None, info)]
    against the nearest earlier map from index ``first`` on; ``model(U)`` returns the corrected
    prior's field (and anything else) at U; ``floor`` [N]: the noise floor of an estimate per key
    point. None when there is no earlier map to test against."""
    if len(maps) - 1 <= first:
        return None
    U_k, r_k, s_k = maps[-1][0], maps[-1][1], maps[-1][2]
    j = min(range(first, len(maps) - 1), key=lambda i: float(np.max(np.abs(maps[i][0] - U_k))))
    U_j, r_j, s_j = maps[j][0], maps[j][1], maps[j][2]
    change = np.asarray(model(U_k)[0]) - np.asarray(model(U_j)[0])
    miss = float(np.sqrt(np.mean((r_k - (r_j + change)) ** 2)))

    def var(s):
        return 0.0 if s is None else float(np.mean(np.asarray(s) ** 2))
    noise = float(np.sqrt(var(s_k) + var(s_j) + 2.0 * floor ** 2))
    allowed = factor * noise + float(np.sqrt(np.mean(change ** 2)))
    return Contradiction(miss, allowed, j, bool(miss > allowed))


__all__ = ['chain_start', 'contradiction', 'Contradiction', 'CONTRADICTION_FACTOR']
