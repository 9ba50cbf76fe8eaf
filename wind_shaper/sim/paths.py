"""Plate paths for sweeps: smooth random trajectories over the disc the plate may visit.

A path is a callable ``path(n, dt, radius, rng, region=None) -> (n, 2)`` positions [m, tunnel
frame] of the plate centre, sampled every ``dt`` [s], all within ``radius`` [m] of the axis;
``region``, when given, is the part of the disc to sweep (a ``core.area.SweepArea``): a tour
then sweeps each of its patches in turn.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..core.errors import ConfigError

#: Most tours of the disc (or a region) one path is made of: a region's tours are short, and one
#: far smaller than the lanes would never add up to the path's length.
MAX_TOURS = 10_000


def _resample(poly: np.ndarray, step: float, n: int) -> np.ndarray:
    """n points at constant arc-length ``step`` [m] along a polyline (m, 2); stops at its end."""
    seg = np.hypot(*np.diff(poly, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    target = np.minimum(np.arange(n) * step, s[-1])
    return np.column_stack([np.interp(target, s, poly[:, 0]), np.interp(target, s, poly[:, 1])])


def _keep(poly: np.ndarray, inside, step: float) -> np.ndarray:
    """The parts of polyline ``poly`` inside the region, resampled every ``step`` [m]; joined in
    order, so the plate moves straight from one part to the next."""
    seg = np.hypot(*np.diff(poly, axis=0).T)
    fine = _resample(poly, step, int(np.sum(seg) / step) + 2)
    kept = fine[inside(fine)]
    return kept if len(kept) >= 2 else poly


def _inside(p: np.ndarray, radius: float) -> np.ndarray:
    r = np.hypot(p[:, 0], p[:, 1])
    over = r > radius
    p = p.copy()
    p[over] *= (radius / r[over])[:, None]
    return p


@dataclass(frozen=True)
class TourPath:
    """A jittered serpentine tour, the way an operator sweeps a plate: parallel lanes
    ``lane_spacing`` [m] apart across the disc, in a random direction with a random lane phase,
    each lane wiggling sideways by ~``jitter`` x lane spacing; corners are rounded by a
    Gaussian smoother and the plate moves at constant ``speed`` [m/s]. When a tour is done the
    next starts in a new random direction; the lanes widen if one tour would be longer than the
    path, so a short sweep still crosses the whole disc. The defaults (0.8 m/s, 4.5 cm lanes) give
    16 m of path in a 20 s sweep: one full tour of a 0.44 m disc and part of a second."""

    speed: float = 0.8
    lane_spacing: float = 0.045
    jitter: float = 0.15

    def __post_init__(self):
        if not (self.speed > 0 and self.lane_spacing > 0 and 0 <= self.jitter <= 1):
            raise ConfigError(f'tour path needs speed > 0, lane_spacing > 0, 0 <= jitter <= 1; got {self}')

    def _tour(self, radius: float, spacing: float, rng) -> np.ndarray:
        angle = rng.uniform(0, 2 * np.pi)
        lanes = np.arange(-radius + spacing * rng.uniform(0.3, 0.7), radius, spacing)
        pts = []
        for k, y in enumerate(lanes):
            half = np.sqrt(max(radius ** 2 - y ** 2, 0.0))
            m = max(2, int(np.ceil(2 * half / spacing)) + 1)
            x = np.linspace(-half, half, m)
            if k % 2:
                x = x[::-1]
            wiggle = np.clip(self.jitter * spacing * rng.standard_normal(m), -0.45 * spacing, 0.45 * spacing)
            pts.append(np.column_stack([x, y + wiggle]))
        poly = np.vstack(pts)
        c, s = np.cos(angle), np.sin(angle)
        return poly @ np.array([[c, s], [-s, c]])

    def _region_tour(self, radius: float, spacing: float, region, rng) -> np.ndarray:
        """One pass over ``region``: a tour of the circle around each cluster of its centres,
        kept to the region, the clusters in nearest-next order from a random first."""
        centres = np.asarray(region.centres, dtype=float).reshape(-1, 2)

        def inside(P):
            return region.contains(P) & (np.hypot(P[:, 0], P[:, 1]) <= radius)

        groups = region.clusters()
        order, left = [], list(range(len(groups)))
        at = centres[groups[int(rng.integers(len(groups)))]].mean(axis=0)
        while left:
            nxt = min(left, key=lambda g: np.min(np.linalg.norm(centres[groups[g]] - at, axis=1)))
            left.remove(nxt)
            order.append(nxt)
            at = centres[groups[nxt]].mean(axis=0)
        parts = []
        for g in order:
            pts = centres[groups[g]]
            mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            local = min(float(np.max(np.linalg.norm(pts - mid, axis=1))) + region.reach, radius)
            parts.append(_keep(self._tour(local, min(spacing, local), rng) + mid, inside, 0.1 * spacing))
        return np.vstack(parts)

    def __call__(self, n: int, dt: float, radius: float, rng: np.random.Generator,
                 region=None) -> np.ndarray:
        step = self.speed * dt
        length = step * max(n - 1, 1)
        area = np.pi * radius ** 2
        if region is not None:  # lanes as dense over the region as over the disc
            area *= max(region.disc_share(radius), 0.02)
        # one tour is about area / spacing long (plus turns): widen the lanes of a path too short
        # for one full tour at lane_spacing, so it still crosses the whole disc
        spacing = min(max(self.lane_spacing, 1.1 * area / max(length, 1e-9)), radius)
        tours, total = [], 0.0
        while total < length + step:
            tour = (self._tour(radius, spacing, rng) if region is None
                    else self._region_tour(radius, spacing, region, rng))
            tours.append(tour)
            total += float(np.sum(np.hypot(*np.diff(tour, axis=0).T))) + (
                2 * radius if region is None else region.reach)
            if len(tours) > MAX_TOURS:   # a region far smaller than the lanes: no path ends
                raise ConfigError(f'a path of {length:.3g} m needs more than {MAX_TOURS} tours '
                                  f'of this region ({total:.3g} m so far): give a larger region '
                                  f'or a shorter sweep')
        poly = _resample(np.vstack(tours), 0.1 * spacing, int((total + step) / (0.1 * spacing)) + 2)
        poly = gaussian_filter1d(poly, sigma=3.0, axis=0, mode='nearest')
        return _inside(_resample(poly, step, n), radius)


@dataclass(frozen=True)
class RandomWalkPath:
    """A momentum random walk: the plate moves at constant ``speed`` [m/s] while its heading
    diffuses with rate ``turn_sd`` [rad/sqrt(s)], and it reflects off the disc boundary like a
    billiard ball. Smooth and random but covers the disc less evenly than ``TourPath``. It knows
    no region: given one, it still wanders over the whole disc."""

    speed: float = 0.8
    turn_sd: float = 3.0

    def __post_init__(self):
        if not (self.speed > 0 and self.turn_sd >= 0):
            raise ConfigError(f'random walk path needs speed > 0 and turn_sd >= 0; got {self}')

    def __call__(self, n: int, dt: float, radius: float, rng: np.random.Generator,
                 region=None) -> np.ndarray:
        r0 = radius * np.sqrt(rng.uniform())
        a0 = rng.uniform(0, 2 * np.pi)
        p = np.array([r0 * np.cos(a0), r0 * np.sin(a0)])
        heading = np.cumsum(self.turn_sd * np.sqrt(dt) * rng.standard_normal(n)) + rng.uniform(0, 2 * np.pi)
        v = np.array([np.cos(heading[0]), np.sin(heading[0])])
        out = np.empty((n, 2))
        turn = np.diff(heading, prepend=heading[0])
        for k in range(n):
            c, s = np.cos(turn[k]), np.sin(turn[k])
            v = np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])
            q = p + self.speed * dt * v
            r = np.hypot(*q)
            if r > radius:  # reflect the velocity about the boundary normal, mirror the step
                normal = q / r
                v = v - 2 * np.dot(v, normal) * normal
                q = normal * (2 * radius - r)
            out[k] = p = q
        return out


PATHS = {'tour': TourPath, 'walk': RandomWalkPath}


def path_from_config(cfg: Mapping | None):
    """``{kind: tour, speed: 0.6, lane_spacing: 0.05}`` or ``{kind: walk, ...}``."""
    cfg = dict(cfg or {})
    kind = cfg.pop('kind', 'tour')
    if kind not in PATHS:
        raise ConfigError(f'unknown sweep path kind {kind!r}; use one of {sorted(PATHS)}')
    try:
        return PATHS[kind](**{k: float(v) for k, v in cfg.items()})
    except TypeError as exc:
        raise ConfigError(f'bad {kind} path config: {exc}') from None
