"""Unmodelled effects on the jets themselves: where they land, how wide they spread and how
they join, in forms the prior's jets lack.

``QuadraticSwirl`` and ``MergingJets`` are library effects (swirl, jet interaction) in another
functional form, which a diagnosis should still find; ``JetDeflection``, ``JetSpreading``,
``HubShadow`` and ``CoandaAttachment`` are outside the library. Registered, with the others, by
``wind_shaper.sim.unmodelled_effects``.

Positions [m, tunnel frame], thrusts and densities [N].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .effects import HiddenEffect, JetInteraction, Swirl
from .physics import FlatTop, JetGroup

__all__ = ['QuadraticSwirl', 'MergingJets', 'JetDeflection', 'JetSpreading', 'HubShadow', 'CoandaAttachment']


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


@dataclass(frozen=True)
class MergingJets(HiddenEffect):
    """Neighbouring jets merge above the straightener and the gap between them gains force
    that grows with the two thrusts T_i, T_j [N] faster than their geometric mean, spread as an
    elongated bridge along the line between where the two jets land:

        density += strength * thrust_ref * (T_i T_j / thrust_ref^2)^exponent
                   * exp(-(a / (length d_ij))^2 - (c / width)^2)   [N]

    for every pair of neighbours (hubs closer than ``reach`` x the nearest hub spacing), a and c
    the distances along and across the line from its midpoint [m], d_ij half the distance
    between the two landings [m], ``width`` [m] the bridge's 1/e half-width across it and
    ``length`` [-] its reach along it in units of d_ij. strength [-] is the bridge's peak as a
    share of the reference thrust ``thrust_ref`` [N] when both jets give that thrust.
    ``exponent`` 0.75 makes the bridge weak at low and strong at high thrust, where
    ``JetInteraction`` grows as sqrt(T_i T_j) over a round bridge as wide as the jets. Size on
    the default tunnel: between two edge fans the plate feels about +0.1 N at 20 % PWM on every
    fan, +1.7 N at 50 % and +8 N at 80 % (``JetInteraction``'s default: +0.4, +2.5 and +7 N).
    The library's jet-interaction family stands for it in its wider form (free exponent)."""

    strength: float = 0.5
    exponent: float = 0.75
    thrust_ref: float = 4.0
    width: float = 0.08
    length: float = 1.0
    reach: float = 1.2
    name: ClassVar[str] = 'merging_jets'
    priority: ClassVar[int] = 1  # after effects that move jets: the bridge joins where they land
    bounds: ClassVar = {'strength': (0.0, 2.0), 'exponent': (0.25, 2.0), 'thrust_ref': (0.1, 100.0),
                        'width': (0.01, 0.5), 'length': (0.2, 3.0), 'reach': (1.0, 2.0)}

    def pairs(self, geometry) -> np.ndarray:
        """(n_pairs, 2) fan indices of neighbouring hubs (as ``JetInteraction.pairs``)."""
        return JetInteraction(reach=self.reach).pairs(geometry)

    def sources(self, groups, thrust, geometry):
        pairs = self.pairs(geometry)
        if self.strength == 0 or len(pairs) == 0:
            return groups
        centre = np.array(geometry.fans.positions, dtype=float)
        for g in groups:
            ok = g.fan >= 0
            centre[g.fan[ok]] = g.centres[ok]
        i, j = pairs[:, 0], pairs[:, 1]
        t = np.maximum(thrust, 0.0)
        amp = self.strength * self.thrust_ref * (t[i] * t[j] / self.thrust_ref ** 2) ** self.exponent
        line = centre[j] - centre[i]
        half = np.maximum(0.5 * np.hypot(line[:, 0], line[:, 1]), 1e-6)
        along = line / (2 * half[:, None])
        across = np.column_stack([-along[:, 1], along[:, 0]])
        long = self.length * half
        # s = a^2 / long^2 + c^2 / width^2 as d^T A d / w^2 with w = 1 m
        metric = (along[:, :, None] * along[:, None, :] / long[:, None, None] ** 2
                  + across[:, :, None] * across[:, None, :] / self.width ** 2)
        return groups + [JetGroup(FlatTop(2.0), 0.5 * (centre[i] + centre[j]), amp,
                                  np.ones(len(pairs)), np.full(len(pairs), -1), metric,
                                  np.maximum(long, self.width))]


@dataclass(frozen=True)
class JetDeflection(HiddenEffect):
    """The central jet entrains the air around it and pulls the edge jets towards the axis
    (a Coanda-like attraction between a strong jet and its neighbours): every edge jet lands
    moved towards the axis by

        pull * T_c / (T_c + thrust_ref)   [m],

    T_c the central fan's thrust [N]. With the central fan off nothing moves. A landing offset
    of one fan (``fan_shift``) is fixed; this one follows another fan's thrust and moves all six
    edge jets at once."""

    pull: float = 0.04
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'jet_deflection'
    priority: ClassVar[float] = 0.5  # after tilts (0), before bridges between jets (1)
    bounds: ClassVar = {'pull': (0.0, 0.2), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        central = np.array(geometry.fans.groups) == 'central'
        if not central.any() or self.pull == 0:
            return groups
        t_c = float(np.sum(np.maximum(thrust[central], 0.0)))
        move = self.pull * t_c / (t_c + self.thrust_ref)
        for g in groups:
            edge = (g.fan >= 0) & ~central[np.maximum(g.fan, 0)]
            r = np.hypot(g.centres[edge, 0], g.centres[edge, 1])
            inward = -g.centres[edge] / np.maximum(r, 1e-9)[:, None]
            g.centres[edge] = g.centres[edge] + move * inward
        return groups


@dataclass(frozen=True)
class JetSpreading(HiddenEffect):
    """A jet's spreading depends on its speed (a weak jet is laminar longer and stays narrow,
    a strong one mixes and spreads): every fan's footprint width is scaled by

        (T_j / thrust_ref) ** exponent,   clipped to [0.6, 1.6],

    T_j its thrust [N], while its force over the hub stays as the thrust curve says. The
    library's footprint widths are fixed; a width fitted to this changes with the commands."""

    exponent: float = 0.12
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'jet_spreading'
    priority: ClassVar[int] = -1  # before effects that stretch or move jets
    bounds: ClassVar = {'exponent': (-1.0, 1.0), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        if self.exponent == 0:
            return groups
        for g in groups:
            ok = g.fan >= 0
            t = np.maximum(thrust[g.fan[ok]], 1e-6)
            g.width[ok] = g.width[ok] * np.clip((t / self.thrust_ref) ** self.exponent, 0.6, 1.6)
        return groups


@dataclass(frozen=True)
class HubShadow(HiddenEffect):
    """Each fan's motor and hub block the core of its own jet, and the straightener does not
    fill the hole in: every jet carries a narrow deficit where it lands,

        density_j -= depth * amplitude_j * exp(-|p - c_j|^2 / (core * w_j)^2),

    ``depth`` of its peak, ``core`` times its width across. A hollow core is no width, landing
    point or flatness of the jet (those keep a single peak) and no fan's gain (the jet's flanks
    keep their force)."""

    depth: float = 0.3
    core: float = 0.45
    name: ClassVar[str] = 'hub_shadow'
    priority: ClassVar[int] = 3  # after every effect that moves, stretches or adds jets
    bounds: ClassVar = {'depth': (0.0, 0.9), 'core': (0.1, 1.0)}

    def sources(self, groups, thrust, geometry):
        if self.depth == 0:
            return groups
        holes = []
        for g in groups:
            own = np.flatnonzero((g.fan >= 0) & (g.amplitude != 0))
            if len(own):
                holes.append(JetGroup(FlatTop(2.0), g.centres[own].copy(),
                                      -self.depth * g.amplitude[own], self.core * g.width[own],
                                      np.full(len(own), -1)))
        return groups + holes


@dataclass(frozen=True)
class CoandaAttachment(HiddenEffect):
    """Jets near the wall bend towards it and cling to it (the Coanda effect), the more the
    faster they are: every fan whose hub is off the axis lands moved outwards, away from the
    axis, by

        pull * T_j / (T_j + thrust_ref)   [m],

    T_j its own thrust [N]. A fan's landing offset (``fan_shift``) is fixed and a tilt does not
    grow with the fan's speed; the central fan does not move."""

    pull: float = 0.04
    thrust_ref: float = 4.0
    name: ClassVar[str] = 'coanda_attachment'
    priority: ClassVar[float] = 0.4  # after tilts (0), before the central jet's pull (0.5)
    bounds: ClassVar = {'pull': (0.0, 0.2), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        if self.pull == 0:
            return groups
        hubs = np.asarray(geometry.fans.positions, float)
        for g in groups:
            rows = np.flatnonzero(g.fan >= 0)
            hub = hubs[g.fan[rows]]
            r = np.hypot(hub[:, 0], hub[:, 1])
            off = r > 1e-6
            rows, hub, r = rows[off], hub[off], r[off]
            t = np.maximum(thrust[g.fan[rows]], 0.0)
            move = self.pull * t / (t + self.thrust_ref)
            g.centres[rows] = g.centres[rows] + (move / r)[:, None] * hub
        return groups
