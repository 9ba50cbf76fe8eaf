"""Does a fitted term keep its parameters inside the range its physics allows?"""
from __future__ import annotations

import numpy as np

from ...model import Term

__all__ = ['check_within_range', 'within_range']


def check_within_range(node: Term, null: dict, *, edge: float = 0.005) -> str:
    """Does the fitted term ``node`` keep its parameters inside their physical range? '' if
    so, else why not, in words (``within_range``'s words)."""
    return within_range(node, null, edge=edge)[1]


def within_range(node: Term, null: dict, *, edge: float = 0.005) -> tuple[dict, str]:
    """Does the fitted term ``node`` keep its parameters inside their physical range? (numbers,
    why not in words: '' if it does); numbers: the least distance of a parameter from a bound
    that is not its no-effect value, as a share of its range's span (None: no bounded one).

    Each family's bounds are the range its physics allows (a jet-interaction exponent from
    0.25 to 2, a width factor from 0.5 to 2). A fit that runs to the edge of that range is
    asking for more than the family's form can give: the best member of the family is the
    extreme one, and the physics is of another form (a jet that spreads with its thrust,
    fitted as an interaction between jets with the largest exponent allowed). A parameter is
    at the edge when it lies within ``edge`` of its range's span from a bound that is not its
    no-effect value (an elongation ratio of 1 is no elongation, not an edge)."""
    nearest = None
    for h in node._free():
        values = np.atleast_1d(np.asarray(getattr(node, h.name), float))
        bounds = h.element_bounds()
        nulls = np.broadcast_to(np.asarray(null.get(h.name, np.nan), float), values.shape)
        for value, (lo, hi), none in zip(values, bounds, nulls):
            if not (np.isfinite(lo) and np.isfinite(hi)):
                continue
            tol = edge * (hi - lo)
            for bound in (lo, hi):
                if np.isfinite(none) and abs(none - bound) <= tol:
                    continue
                share = float(abs(value - bound) / max(hi - lo, 1e-300))
                nearest = share if nearest is None else min(nearest, share)
                if abs(value - bound) <= tol:
                    return ({'nearest_edge_share': round(share, 5)},
                            f'its {h.name} ran to the edge of the range its physics allows '
                            f'({value:.3g}; the range is {lo:g} to {hi:g}): the data ask for more '
                            f'than this form can give, so the physics is of another form')
    return {'nearest_edge_share': None if nearest is None else round(nearest, 5)}, ''
