"""Tiles of a query area and the samples near each: the common ground of the local GPs.

A local GP answers each tile of query points from the samples near that tile alone, so its cost
grows with the area instead of with the cube of the sample count. Positions [m, tunnel frame].
"""
from __future__ import annotations

from typing import Iterator

import numpy as np
from scipy.spatial import cKDTree


def tiles(points: np.ndarray, samples: np.ndarray, tree: cKDTree, side: float,
          halo: float) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Cut the plane into square tiles of ``side`` [m] (a fixed grid with a corner at the
    origin) and yield, per tile that holds some of ``points`` (K, 2) [m], (rows, near): those
    rows of ``points`` and the indices of the ``samples`` (n, 2) [m] inside the tile grown by
    ``halo`` [m] on every side (ascending; possibly empty). ``tree``: a ``cKDTree`` of
    ``samples``. The grid does not depend on the points asked for, so a position gets the same
    answer whatever else is asked with it (the key points, or a query of a few)."""
    Q = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(Q) == 0:
        return
    cell = np.floor(Q / side).astype(np.int64)
    cells, inverse = np.unique(cell, axis=0, return_inverse=True)
    order = np.argsort(inverse.ravel(), kind='stable')
    ends = np.cumsum(np.bincount(inverse.ravel(), minlength=len(cells)))
    groups = np.split(order, ends[:-1])
    centres = (cells + 0.5) * side
    half = 0.5 * side + halo
    # the ball around the box holds the box: one tree query per tile, then the exact box test
    candidates = tree.query_ball_point(centres, np.sqrt(2.0) * half)
    for rows, centre, near in zip(groups, centres, candidates):
        near = np.sort(np.asarray(near, dtype=np.int64))
        if len(near):
            near = near[np.all(np.abs(samples[near] - centre) <= half, axis=1)]
        yield rows, near


__all__ = ['tiles']
