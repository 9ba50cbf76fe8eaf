"""Hidden effects that no candidate family of the workbench stands for.

A real tunnel always holds physics the candidate library lacks. These effects are physically
plausible and each differs in form from every family of ``wind_shaper.workbench.library``, so a
diagnosis of data that carries one must say "none of my candidates fits" and describe it, never
name a wrong effect. ``QuadraticSwirl`` is the opposite case: an effect of the library (swirl) in
another functional form than its family, which the diagnosis should still find.

Positions [m, tunnel frame], thrusts and densities [N], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .effects import HIDDEN_EFFECTS, HiddenEffect, Swirl
from .errors import EffectError

__all__ = ['HoneycombBlockage', 'StandWake', 'PlenumStarvation', 'SideDraft', 'QuadraticSwirl',
           'OUTSIDE_LIBRARY', 'OTHER_FORM']


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
class PlenumStarvation(HiddenEffect):
    """All fans draw from one inlet plenum whose pressure drop grows with the total flow: each
    fan runs at the effective command

        U_eff,j = U_j / (1 + coupling * mean_k U_k),

    so a fan's thrust depends on what the others do. No family couples fans: a per-fan gain or
    curve fitted to it changes with the total command from sweep to sweep."""

    coupling: float = 0.6
    name: ClassVar[str] = 'plenum_starvation'
    priority: ClassVar[int] = 2  # after an ESC dead band: the plenum limits what the motor drives
    bounds: ClassVar = {'coupling': (0.0, 3.0)}

    def command(self, u, geometry):
        enabled = geometry.fans.enabled
        mean = float(np.mean(u[enabled])) if enabled.any() else 0.0
        return u / (1.0 + self.coupling * max(mean, 0.0))


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
class QuadraticSwirl(Swirl):
    """Swirl (see ``effects.Swirl``) whose angle grows faster than the CW/CCW imbalance b:

        theta = gain * b + curvature * b |b|   [rad]

    The library's swirl family is linear in b; this is the same physical effect in another form,
    which a diagnosis should still find (as swirl, with a gain between the two slopes)."""

    gain: float = 0.35
    curvature: float = 0.9
    name: ClassVar[str] = 'quadratic_swirl'
    bounds: ClassVar = {'gain': (-1.5, 1.5), 'curvature': (-5.0, 5.0)}

    def angle(self, thrust, geometry):
        total = float(np.sum(thrust))
        if total <= 0:
            return 0.0
        b = float(np.dot(geometry.fans.spin_sign, thrust)) / total
        return self.gain * b + self.curvature * b * abs(b)


#: Effects of physics that no library family stands for, and an in-library effect in another form.
OUTSIDE_LIBRARY = (HoneycombBlockage, StandWake, PlenumStarvation, SideDraft)
OTHER_FORM = (QuadraticSwirl,)

for _cls in OUTSIDE_LIBRARY + OTHER_FORM:
    if _cls.name in HIDDEN_EFFECTS and HIDDEN_EFFECTS[_cls.name] is not _cls:
        raise EffectError(f'hidden effect name {_cls.name!r} is taken')
    HIDDEN_EFFECTS[_cls.name] = _cls
