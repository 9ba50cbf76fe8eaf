"""Hidden effects that no candidate family of the workbench stands for.

A real tunnel always holds physics the candidate library lacks. These effects are physically
plausible and each differs in form from every family of ``wind_shaper.workbench.library``, so a
diagnosis of data that carries one must say "none of my candidates fits" and describe it, never
name a wrong effect. ``QuadraticSwirl`` and ``MergingJets`` are the opposite case: effects of the
library (swirl, jet interaction) in another functional form than their family's first
candidate, which the diagnosis should still find.

Positions [m, tunnel frame], thrusts and densities [N], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import neighbour_pairs
from ..core.tunnel import path_at
from .effects import HiddenEffect, JetInteraction, Swirl, register_effects
from .errors import EffectError
from .physics import FlatTop, JetGroup

__all__ = ['HoneycombBlockage', 'StandWake', 'PlenumStarvation', 'SideDraft', 'QuadraticSwirl',
           'MergingJets', 'ThermalGradient', 'UnequalCurves', 'JetDeflection', 'EscCrosstalk',
           'WallReturnFlow', 'VaneRipple', 'JetSpreading', 'HubShadow', 'NeighbourStarvation',
           'CoandaAttachment', 'WallLeak', 'DragLaw', 'MocapLatency', 'CeilingDownwash', 'WallReflection',
           'OUTSIDE_LIBRARY', 'OUTSIDE_FRESH', 'OUTSIDE_SECOND', 'OUTSIDE_THIRD', 'OTHER_FORM',
           'PLANT_VARIATIONS']


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
class UnequalCurves(HiddenEffect):
    """Every fan's ESC maps the command through its own throttle curve: fan j runs at
    U_j ** p_j, with p_j = exp(``spread`` x z_j) and z_j standard normal draws of ``seed``
    (clipped to +-2). At 50 % command a fan with p = 1.35 gives the thrust of 39 %, one with
    p = 0.75 that of 59 %. The prior's calibration fits one curve per fan group, so the per-fan
    shapes are model error the shaping loop must absorb. Used by the convergence benchmark as a
    plant whose fans differ; the workbench is not yet tested on it."""

    spread: float = 0.3
    seed: int = 11
    name: ClassVar[str] = 'unequal_curves'
    bounds: ClassVar = {'spread': (0.0, 1.0)}
    priority: ClassVar[int] = -1   # the throttle curve first, then a dead band acts on its output

    def exponents(self, n_fans: int) -> np.ndarray:
        z = np.clip(np.random.default_rng(int(self.seed)).standard_normal(n_fans), -2.0, 2.0)
        return np.exp(self.spread * z)

    def command(self, u, geometry):
        u = np.clip(np.asarray(u, dtype=float), 0.0, None)
        return u ** self.exponents(len(u))


# -- Outside the library, written after the checks were tuned (the held-out set of issue 12) ------
# No setting of the diagnosis was chosen looking at these: bench/detection.py --kinds fresh runs
# them to measure how the checks carry over to physics they were not shaped on.

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
class EscCrosstalk(HiddenEffect):
    """Fan ``fan``'s ESC picks up part of fan ``source``'s PWM signal (a shared ground, cables
    bundled together): it runs at

        U_eff = min(U_fan + coupling * U_source, 1).

    Its thrust then depends on another fan's command; a gain of ``fan`` fitted to it changes
    with the ratio of the two commands from sweep to sweep."""

    fan: str = 'LM1'
    source: str = 'HM1'
    coupling: float = 0.25
    name: ClassVar[str] = 'esc_crosstalk'
    priority: ClassVar[int] = -2  # at the signal, before a throttle curve or a dead band
    bounds: ClassVar = {'coupling': (0.0, 1.0)}

    def validate(self, geometry):
        self._indices(geometry)

    def _indices(self, geometry) -> tuple[int, int]:
        try:
            return geometry.fans.index(self.fan), geometry.fans.index(self.source)
        except ConfigError as exc:
            raise EffectError(f'EscCrosstalk: {exc}') from None

    def command(self, u, geometry):
        j, k = self._indices(geometry)
        u = np.asarray(u, dtype=float).copy()
        u[j] = min(u[j] + self.coupling * max(u[k], 0.0), 1.0)
        return u


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
class NeighbourStarvation(HiddenEffect):
    """Fans mounted close together draw their inflow from the same air: a fan's thrust falls
    with what its neighbours (hubs within ``reach`` times the closest hub spacing) deliver,

        T_j' = T_j / (1 + coupling * mean_{k near j} T_k / thrust_ref).

    Unlike a starved plenum it is local (a fan beside two idle neighbours runs free whatever
    the rest do), and unlike an ESC's crosstalk every fan is coupled to several others."""

    coupling: float = 0.3
    thrust_ref: float = 4.0
    reach: float = 1.2
    name: ClassVar[str] = 'neighbour_starvation'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'coupling': (0.0, 3.0), 'thrust_ref': (0.1, 100.0), 'reach': (1.0, 3.0)}

    def thrust(self, t, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        pairs = on[neighbour_pairs(np.asarray(geometry.fans.positions)[on], self.reach)]
        if len(pairs) == 0 or self.coupling == 0:
            return t
        near = np.zeros((len(t), len(t)), bool)
        near[pairs[:, 0], pairs[:, 1]] = near[pairs[:, 1], pairs[:, 0]] = True
        count = near.sum(axis=1)
        mean = np.where(count > 0, (near * np.maximum(t, 0.0)[None, :]).sum(axis=1) / np.maximum(count, 1), 0.0)
        return t / (1.0 + self.coupling * mean / self.thrust_ref)


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
class DragLaw(HiddenEffect):
    """The plate's drag coefficient falls as the air speeds up (its Reynolds number grows), so
    the force it takes up grows more slowly than the flow's dynamic pressure. With F the force
    a plate of constant drag coefficient would take up [N],

        F' = F (max(|F|, floor) / force_ref)^(-exponent / 2)

    (Cd ~ Re^-exponent, Re ~ speed ~ sqrt(F)); F' = F at ``force_ref``. It acts on the local
    force, whichever fans make it: not on one fan's thrust curve, not on where jets land."""

    exponent: float = 0.25
    force_ref: float = 2.0
    floor: float = 0.05
    name: ClassVar[str] = 'drag_law'
    bounds: ClassVar = {'exponent': (0.0, 0.8), 'force_ref': (0.1, 50.0), 'floor': (0.001, 1.0)}

    def reading(self, force, geometry):
        if self.exponent == 0:
            return force
        size = np.maximum(np.abs(force), self.floor) / self.force_ref
        return force * size ** (-0.5 * self.exponent)


@dataclass(frozen=True)
class MocapLatency(HiddenEffect):
    """Motion capture and the force sensor are out of step: each force sample is recorded with
    the plate's position ``lag`` [s] earlier (the path is held at its start before that). The
    field is unchanged; a sweep's force map is smeared and shifted along the plate's own path,
    which no term of position and commands can describe."""

    lag: float = 0.04
    name: ClassVar[str] = 'mocap_latency'
    bounds: ClassVar = {'lag': (0.0, 0.5)}

    def recorded(self, positions, dt):
        if self.lag == 0 or len(positions) < 2:
            return positions
        t = np.arange(len(positions)) * dt
        return path_at(t, positions, t - self.lag)


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


#: Effects of physics that no library family stands for, and in-library effects in another form.
OUTSIDE_LIBRARY = (HoneycombBlockage, StandWake, PlenumStarvation, SideDraft, ThermalGradient)
#: Outside the library too, written after every check was set: the held-out physics.
OUTSIDE_FRESH = (JetDeflection, EscCrosstalk, WallReturnFlow, VaneRipple, JetSpreading)
#: Outside the library, written in a later session after every check was set, and run once
#: before any setting looked at them: the second batch of held-out physics.
OUTSIDE_SECOND = (HubShadow, NeighbourStarvation, CoandaAttachment, WallLeak)
#: Outside the library, written in session 15 after every check was set, run once before any
#: setting looked at them: the third batch of held-out physics (a new plate drag law and a
#: recording out of step are the first effects outside the flow itself).
OUTSIDE_THIRD = (DragLaw, MocapLatency, CeilingDownwash, WallReflection)
OTHER_FORM = (QuadraticSwirl, MergingJets)
#: Plant variations for benchmarks (not in the workbench's detection table yet).
PLANT_VARIATIONS = (UnequalCurves,)

register_effects(*OUTSIDE_LIBRARY, *OUTSIDE_FRESH, *OUTSIDE_SECOND, *OUTSIDE_THIRD, *OTHER_FORM,
                 *PLANT_VARIATIONS)
