"""Unmodelled effects of what sits in the flow's path: a blocked patch of the flow
straightener, warped straightener vanes, and the wake of the bar that carries the force plate.
Each scales the force density by a fixed pattern over the tunnel, whichever fans blow.
Registered, with the others, by ``wind_shaper.sim.unmodelled_effects``.

Positions [m, tunnel frame].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .effects import HiddenEffect

__all__ = ['HoneycombBlockage', 'StandWake', 'VaneRipple']


@dataclass(frozen=True)
class HoneycombBlockage(HiddenEffect):
    """Dirt or a dent blocks part of the flow straightener: the flow through a patch of it
    centred at (``x``, ``y``) [m] is cut by the fraction ``depth`` at its centre,

        density *= 1 - depth * exp(-|p - c|^2 / (2 radius^2)),

    whichever fans blow through it. Unlike a weak fan it does not follow one fan's command; unlike
    the wall layer it is not radial."""

    x: float = 0.08
    y: float = -0.10
    radius: float = 0.05
    depth: float = 0.35
    name: ClassVar[str] = 'honeycomb_blockage'
    bounds: ClassVar = {'x': (-0.5, 0.5), 'y': (-0.5, 0.5), 'radius': (0.01, 0.3),
                        'depth': (0.0, 1.0)}

    def scale(self, points, geometry):
        d2 = (points[:, 0] - self.x) ** 2 + (points[:, 1] - self.y) ** 2
        return 1.0 - self.depth * np.exp(-d2 / (2 * self.radius ** 2))


@dataclass(frozen=True)
class StandWake(HiddenEffect):
    """The bar that carries the force plate, reaching in from the wall along +x at height
    ``y`` [m], sits in the flow below the plate and leaves a wake: the force falls by the
    fraction ``depth`` along a strip ``width`` [m] wide (Gaussian across it) over the bar, from
    the wall in to its tip at ``tip_x`` [m] (a 2 cm soft end):

        density *= 1 - depth * exp(-(y' - y)^2 / (2 width^2)) * sigmoid((x' - tip_x) / 0.02)."""

    y: float = 0.04
    tip_x: float = -0.05
    width: float = 0.025
    depth: float = 0.3
    name: ClassVar[str] = 'stand_wake'
    bounds: ClassVar = {'y': (-0.5, 0.5), 'tip_x': (-0.5, 0.5), 'width': (0.005, 0.2),
                        'depth': (0.0, 1.0)}

    def scale(self, points, geometry):
        across = np.exp(-(points[:, 1] - self.y) ** 2 / (2 * self.width ** 2))
        along = 1.0 / (1.0 + np.exp(-(points[:, 0] - self.tip_x) / 0.02))
        return 1.0 - self.depth * across * along


@dataclass(frozen=True)
class VaneRipple(HiddenEffect):
    """The flow straightener's vanes are warped in a wave: the flow through it is modulated in
    stripes across the tunnel,

        density *= 1 + depth * cos(2 pi (p . e) / wavelength + phase),

    e = (cos direction, sin direction), ``wavelength`` [m], ``direction`` [deg from +x],
    ``phase`` [rad]. A fixed pattern over the whole tunnel, neither a fan's nor radial."""

    depth: float = 0.15
    wavelength: float = 0.3
    direction: float = 30.0
    phase: float = 0.5
    name: ClassVar[str] = 'vane_ripple'
    bounds: ClassVar = {'depth': (0.0, 0.9), 'wavelength': (0.05, 2.0),
                        'direction': (-360.0, 360.0), 'phase': (-10.0, 10.0)}

    def scale(self, points, geometry):
        e = np.array([np.cos(np.radians(self.direction)), np.sin(np.radians(self.direction))])
        return 1.0 + self.depth * np.cos(2 * np.pi * (points @ e) / self.wavelength + self.phase)
