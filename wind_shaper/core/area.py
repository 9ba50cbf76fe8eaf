"""A part of the sweep disc: every position within ``reach`` of some centre (``SweepArea``).

What a region sweep asks the plate to cover (``control.region``), what the simulated plate's
path keeps to (``sim.paths``) and what an operator is told to sweep. Positions [m, tunnel frame].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError
from .limits import excerpt


@dataclass(frozen=True)
class SweepArea:
    """centres: (K, 2) [m]; reach [m]: the area is within ``reach`` of a centre."""

    centres: np.ndarray
    reach: float

    def __post_init__(self):
        c = np.asarray(self.centres, dtype=float).reshape(-1, 2)
        if len(c) == 0 or not np.all(np.isfinite(c)):
            raise ConfigError(f'a sweep area needs at least one finite centre (x, y) [m]; got '
                              f'{len(c)} centres: {excerpt(c.tolist(), quote=False)}')
        if not (np.isfinite(self.reach) and self.reach > 0):
            raise ConfigError(f'a sweep area needs reach > 0 m; got {excerpt(self.reach)}')
        object.__setattr__(self, 'centres', c)
        object.__setattr__(self, 'reach', float(self.reach))

    def contains(self, positions) -> np.ndarray:
        """(M,) whether each position (M, 2) [m] lies in the area."""
        P = np.asarray(positions, dtype=float).reshape(-1, 2)
        d = np.linalg.norm(P[:, None, :] - self.centres[None, :, :], axis=2)
        return np.min(d, axis=1) <= self.reach

    def disc_share(self, radius: float) -> float:
        """The share of the disc of ``radius`` [m] around the tunnel axis that the area covers
        (on a 41 x 41 grid)."""
        g = np.linspace(-radius, radius, 41)
        X, Y = np.meshgrid(g, g)
        P = np.column_stack([X.ravel(), Y.ravel()])
        return float(np.mean(self.contains(P[np.hypot(P[:, 0], P[:, 1]) <= radius])))

    def clusters(self) -> list[np.ndarray]:
        """The centres in groups whose discs overlap (single linkage at 2 x reach), each group
        an index array into ``centres``: the separate patches of the area."""
        K = len(self.centres)
        label = np.arange(K)
        d = np.linalg.norm(self.centres[:, None] - self.centres[None], axis=2)
        for i in range(K):
            for j in range(i + 1, K):
                if d[i, j] < 2 * self.reach and label[i] != label[j]:
                    label[label == label[j]] = label[i]
        return [np.flatnonzero(label == v) for v in np.unique(label)]

    def text(self) -> str:
        """Where the area is, for an operator: each patch's centre and size."""
        parts = []
        for group in self.clusters():
            pts = self.centres[group]
            mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            size = float(np.max(np.linalg.norm(pts - mid, axis=1))) + self.reach
            parts.append(f'within {100 * size:.0f} cm of ({mid[0]:+.2f}, {mid[1]:+.2f}) m')
        return '; '.join(parts)


__all__ = ['SweepArea']
