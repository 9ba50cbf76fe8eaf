"""Which key points a moving plate has passed: the coverage of a sweep, live or afterwards.

A key point counts as passed once a plate position came within ``radius`` [m] of it; the field
estimator refuses a sweep with a key point farther than its ``max_gap`` from every sample, so
with ``radius = max_gap`` a coverage of 1.0 is what an estimate needs. Positions [m, tunnel frame].
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class Coverage:
    """Key points passed so far. ``add`` takes positions as they arrive (a pose at a time, or
    many); ``share`` is the fraction passed [0..1]; ``missed`` the key points not passed yet."""

    def __init__(self, key_points, radius: float):
        self.key_points = np.asarray(key_points, dtype=float).reshape(-1, 2)
        if not radius > 0:
            raise ValueError(f'coverage radius must be > 0 m; got {radius!r}')
        self.radius = float(radius)
        self._tree = cKDTree(self.key_points)
        self.passed = np.zeros(len(self.key_points), dtype=bool)

    def reset(self) -> None:
        self.passed[:] = False

    def add(self, positions) -> None:
        """Mark the key points within ``radius`` of any of ``positions`` (M, 2) or (2,) [m];
        non-finite positions are ignored."""
        P = np.asarray(positions, dtype=float).reshape(-1, 2)
        P = P[np.all(np.isfinite(P), axis=1)]
        for hits in self._tree.query_ball_point(P, self.radius):
            self.passed[hits] = True

    @property
    def share(self) -> float:
        return float(self.passed.mean()) if len(self.passed) else 1.0

    @property
    def missed(self) -> np.ndarray:
        """(K, 2) key points not passed yet [m]."""
        return self.key_points[~self.passed]


def coverage_share(positions, key_points, radius: float) -> float:
    """The share of ``key_points`` within ``radius`` [m] of some position of a whole sweep."""
    c = Coverage(key_points, radius)
    c.add(positions)
    return c.share


__all__ = ['Coverage', 'coverage_share']
