"""Unmodelled effects of the tunnel's walls and the room around it: a draft across the exit,
a warm wall, air returning down the wall, a leak between wall panels, the ceiling's downwash and
the wall's reflection of the jets. Registered, with the others, by
``wind_shaper.sim.unmodelled_effects``.

Positions [m, tunnel frame], thrusts and densities [N].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .effects import HiddenEffect
from .physics import FlatTop, JetGroup

__all__ = ['SideDraft', 'ThermalGradient', 'WallReturnFlow', 'WallLeak', 'CeilingDownwash', 'WallReflection']


def _mean_thrust(thrust, geometry) -> float:
    """The enabled fans' mean thrust [N] (negative thrusts count as 0): the tunnel's pressure."""
    enabled = geometry.fans.enabled
    return float(np.mean(np.maximum(thrust[enabled], 0.0))) if enabled.any() else 0.0


def _mean_thrust_deficit(groups, thrust, geometry, centre, share, spread):
    """``groups`` and a force against the jets ``share`` x the mean thrust deep at ``centre``
    (2,) [m], exp(-d^2 / spread^2) around it (spread [m])."""
    mean = _mean_thrust(thrust, geometry)
    if share == 0 or mean == 0:
        return groups
    return groups + [JetGroup(FlatTop(2.0), np.reshape(centre, (1, 2)), np.array([-share * mean]),
                              np.array([spread]), np.array([-1]))]


@dataclass(frozen=True)
class SideDraft(HiddenEffect):
    """A draft through the room (an open door, the air conditioning) blows across the top of the
    tunnel and bends the plume: the whole field lands displaced by

        (dx, dy) * reference / (reference + sum_j T_j)   [m],

    a weak plume far, a strong one little (``reference`` [N] of total thrust halves the shift).
    Unlike a tilted fan it moves every jet, by an amount that changes with the total thrust."""

    dx: float = 0.05
    dy: float = 0.02
    reference: float = 15.0
    name: ClassVar[str] = 'side_draft'
    priority: ClassVar[int] = 2  # after swirl: the draft bends the plume above the straightener
    bounds: ClassVar = {'dx': (-0.2, 0.2), 'dy': (-0.2, 0.2), 'reference': (0.1, 1000.0)}

    def shift(self, thrust: np.ndarray) -> np.ndarray:
        """Displacement (2,) [m] of the field for per-fan thrusts (n_fans,) [N]."""
        factor = self.reference / (self.reference + max(float(np.sum(thrust)), 0.0))
        return np.array([self.dx, self.dy]) * factor

    def warp(self, points, thrust, geometry):
        return points - self.shift(thrust)  # the displaced field at p is the field at p - shift


@dataclass(frozen=True)
class ThermalGradient(HiddenEffect):
    """A warm wall or a radiator on one side of the room: buoyant air rises faster on that side,
    a force on the plate that grows linearly across the tunnel towards ``direction`` [deg from
    +x], by ``slope`` [N per 10 cm], whatever the fans do (zero on the axis):

        density += slope * (p . e) / 0.1 m,   e = (cos direction, sin direction).

    No family stands for it (the background candidate is uniform); a formula does: a tilt."""

    slope: float = 0.12
    direction: float = 120.0
    name: ClassVar[str] = 'thermal_gradient'
    bounds: ClassVar = {'slope': (-2.0, 2.0), 'direction': (-360.0, 360.0)}

    def offset(self, points, geometry):
        e = np.array([np.cos(np.radians(self.direction)), np.sin(np.radians(self.direction))])
        return self.slope * (points @ e) / 0.1


@dataclass(frozen=True)
class WallReturnFlow(HiddenEffect):
    """The tunnel recirculates: part of the air comes back down along the wall, a downward
    force on a ring ``width`` [m] wide (Gaussian sd across it) centred ``gap`` [m] inside the
    wall, whose depth follows the fans' mean thrust T_mean [N]:

        density -= share * T_mean * exp(-(r - (R_wall - gap))^2 / (2 width^2))   [N],

    built from ``n_ring`` Gaussian sources around the ring. Unlike a wall boundary layer it
    takes away a share of the whole tunnel's thrust, not of the local flow: beside a weak edge
    jet the ring is as deep as beside a strong one."""

    share: float = 0.3
    gap: float = 0.03
    width: float = 0.04
    n_ring: int = 36
    name: ClassVar[str] = 'wall_return_flow'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'share': (0.0, 2.0), 'gap': (0.0, 0.3), 'width': (0.005, 0.3),
                        'n_ring': (6, 360)}

    def sources(self, groups, thrust, geometry):
        mean = _mean_thrust(thrust, geometry)
        if self.share == 0 or mean == 0:
            return groups
        n = int(self.n_ring)
        angle = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        radius = geometry.wall_radius - self.gap
        centres = radius * np.column_stack([np.cos(angle), np.sin(angle)])
        # blobs exp(-d^2 / w^2) spaced no wider than w sum to a smooth ring of depth
        # amp w sqrt(pi) / spacing
        spacing = 2 * np.pi * radius / n
        w = max(np.sqrt(2.0) * self.width, spacing)
        amp = np.full(n, -self.share * mean * spacing / (np.sqrt(np.pi) * w))
        return groups + [JetGroup(FlatTop(2.0), centres, amp, np.full(n, w), np.full(n, -1))]


@dataclass(frozen=True)
class WallLeak(HiddenEffect):
    """A gap between two wall panels at ``angle`` [deg from +x] lets the pressurised air out:
    near the gap the plate loses a force that follows the tunnel's pressure, i.e. the fans'
    mean thrust T_mean [N], not the local jet,

        density -= share * T_mean * exp(-|p - p_gap|^2 / spread^2),

    p_gap on the wall. Unlike a boundary layer it is at one place on the wall and does not take
    a share of the local flow; unlike a blocked patch it is there beside an idle fan too."""

    angle: float = 200.0
    share: float = 0.5
    spread: float = 0.1
    name: ClassVar[str] = 'wall_leak'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'angle': (-360.0, 360.0), 'share': (0.0, 2.0), 'spread': (0.01, 0.4)}

    def sources(self, groups, thrust, geometry):
        a = np.radians(self.angle)
        gap = geometry.wall_radius * np.array([np.cos(a), np.sin(a)])
        return _mean_thrust_deficit(groups, thrust, geometry, gap, self.share, self.spread)


@dataclass(frozen=True)
class CeilingDownwash(HiddenEffect):
    """The lab's ceiling above the tunnel's exit turns the plume back down over the middle: a
    broad force against the jets centred on the axis that follows the fans' mean thrust T_mean
    [N],

        density -= share * T_mean * exp(-r^2 / spread^2)     (r from the axis [m]).

    Unlike the central fan's jet it does not follow the central fan's command; unlike a uniform
    draft it is strongest in the middle; unlike a boundary layer it is away from the wall."""

    share: float = 0.12
    spread: float = 0.25
    name: ClassVar[str] = 'ceiling_downwash'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'share': (0.0, 2.0), 'spread': (0.02, 1.0)}

    def sources(self, groups, thrust, geometry):
        return _mean_thrust_deficit(groups, thrust, geometry, np.zeros(2), self.share, self.spread)


@dataclass(frozen=True)
class WallReflection(HiddenEffect):
    """The tunnel's wall confines the jets: the part of each jet's flow that would spread
    beyond the wall is turned back inside. Each off-axis jet gets an image: ``share`` of its
    strength, as wide, landing mirrored in the wall along the line from the axis through it
    (at distance 2 R_wall - r_j from the axis, r_j its own). It raises the force near the wall
    by the nearby jets' own thrusts: neither a boundary layer (which takes a share of the local
    flow) nor a moved or widened jet."""

    share: float = 0.6
    name: ClassVar[str] = 'wall_reflection'
    priority: ClassVar[float] = 1.5  # after jets have moved and reshaped, before added sources
    bounds: ClassVar = {'share': (0.0, 1.0)}

    def sources(self, groups, thrust, geometry):
        if self.share == 0:
            return groups
        wall = geometry.wall_radius
        images = []
        for g in groups:
            rows = np.flatnonzero(g.fan >= 0)
            c = g.centres[rows]
            r = np.hypot(c[:, 0], c[:, 1])
            keep = (r > 1e-6) & (r < wall)
            if not keep.any():
                continue
            rows, c, r = rows[keep], c[keep], r[keep]
            image = g.split(rows)[1]
            image.centres = c * ((2.0 * wall - r) / r)[:, None]
            image.amplitude = self.share * image.amplitude
            image.fan = np.full(len(rows), -1)
            if image.metric is not None:  # a stretched footprint is mirrored too: P A P
                n = c / r[:, None]
                mirror = np.eye(2)[None] - 2.0 * n[:, :, None] * n[:, None, :]
                image.metric = mirror @ image.metric @ mirror
            images.append(image)
        return groups + images
