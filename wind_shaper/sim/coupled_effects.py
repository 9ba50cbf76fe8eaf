"""Physics that couples the fans to each other, written for the shaping benchmark's unfamiliar
tunnels (``bench/convergence.py``): a per-fan correction of the prior (gain, landing point,
width) cannot absorb either, because each fan's share of the field depends on what the other
fans do.

* ``SupplySag``: the fans share one power supply whose voltage sags with the total current,
  so every fan turns slower when the others run harder.
* ``RecirculationCore``: the edge jets drive a recirculating bubble over the middle of the
  tunnel, a deficit there that grows with the edge fans' mean thrust and widens with it.
* ``JetPairing``: two neighbouring edge jets running alike entrain each other and land closer
  together; a much stronger neighbour does not pair with a weak one.
* ``StallDip``: an axial fan stalls at part load, so each fan's curve dips there, by its own
  depth (not a coupling, but a curve no polynomial of the prior holds).
* ``CoflowCarry``: a jet among running jets entrains moving air instead of still air, so it
  spreads less and carries more of its force to the plate: every fan gives more the harder the
  others run (the opposite of a sagging supply).
* ``EscCurrentLimit``: each ESC limits its motor's current, so each fan's thrust flattens off
  towards a ceiling of its own (not a coupling either, but a knee in the curve that the prior's
  polynomial per fan group does not have).
* ``DiffuserSeparation``: past a total thrust the flow separates from one side of the diffuser
  wall, and the fans on that side lose part of their force, the more the harder all fans blow
  (a coupling that acts on one side only, so no shared slope of every fan's gain holds it).
* ``SideInlet``: the fans draw their air from a plenum fed through one side, so the fans far
  from the inlet starve more as the total flow grows (a load slope of its own for every fan).
* ``JetConfinement``: the edge jets hem the central jet in, so it lands narrower and taller
  the harder they blow (its force kept; a width that follows the other fans' commands).
* ``FlowScreen``: a mesh screen above the fans evens the flow out, taking a share of every jet
  and spreading it over the whole section; a screen's loss falls as the flow through it grows,
  so the share is largest when the fans run slowly (a broad pedestal no footprint holds, of a
  height that follows every fan's command).

Positions [m, tunnel frame], thrusts and densities [N], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .effects import HiddenEffect, register_effects
from .errors import EffectError
from .physics import FlatTop, JetGroup


@dataclass(frozen=True)
class SupplySag(HiddenEffect):
    """A shared supply of internal resistance: its voltage falls with the total current the
    motors draw, and a motor's speed follows the voltage, so each fan runs at

        U_eff,j = U_j * (1 - sag * (sum_k U_k^1.5 / n_enabled))

    (a motor's current grows roughly as its command to the power 1.5). ``sag`` [-] is the
    relative voltage drop with every fan at full command."""

    sag: float = 0.25
    name: ClassVar[str] = 'supply_sag'
    priority: ClassVar[int] = 3
    bounds: ClassVar = {'sag': (0.0, 0.6)}

    def command(self, u, geometry):
        on = geometry.fans.enabled
        if not on.any():
            return u
        load = float(np.sum(np.maximum(u[on], 0.0) ** 1.5)) / int(on.sum())
        return u * (1.0 - self.sag * load)


@dataclass(frozen=True)
class RecirculationCore(HiddenEffect):
    """A bubble of recirculating air over the middle of the tunnel, driven by the edge jets:

        density -= share * mean(T_edge) * exp(-r^2 / w^2),   w = width * (1 + mean(T_edge) / T_ref)

    r the distance from the tunnel axis [m]. ``share`` [-]: the deficit at the axis as a share
    of the edge fans' mean thrust; ``width`` [m] the bubble's 1/e radius at low thrust; it
    widens as the edge jets strengthen (``thrust_ref`` [N]). Edge fans: fans off the axis."""

    share: float = 0.25
    width: float = 0.10
    thrust_ref: float = 6.0
    name: ClassVar[str] = 'recirculation_core'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'share': (0.0, 1.0), 'width': (0.02, 0.5), 'thrust_ref': (0.1, 100.0)}

    def validate(self, geometry):
        if not (np.hypot(*np.asarray(geometry.fans.positions, float).T) > 1e-3).any():
            raise EffectError('RecirculationCore needs fans off the tunnel axis')

    def sources(self, groups, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, dtype=float)
        edge = (np.hypot(pos[:, 0], pos[:, 1]) > 1e-3) & geometry.fans.enabled
        if self.share == 0 or not edge.any():
            return groups
        mean = float(np.mean(np.maximum(thrust[edge], 0.0)))
        if mean <= 0:
            return groups
        w = self.width * (1.0 + mean / self.thrust_ref)
        # a round Gaussian dip centred on the axis, its depth the amplitude (FlatTop(2): exp(-d^2/w^2))
        return groups + [JetGroup(FlatTop(2.0), np.zeros((1, 2)), np.array([-self.share * mean]),
                                  np.array([w]), np.full(1, -1))]


@dataclass(frozen=True)
class JetPairing(HiddenEffect):
    """Neighbouring edge jets that run alike entrain the air between them and land closer
    together. Each edge jet moves towards each of its two neighbours on the ring by

        pull * (min(T_i, T_j) / max(T_i, T_j)) * min(T_i, T_j) / (min(T_i, T_j) + thrust_ref)   [m],

    T the two fans' thrusts [N]: equal strong jets pair the most, a jet beside a much stronger
    or an idle one stays where it is. Edge fans: fans off the axis, ordered by their angle."""

    pull: float = 0.04
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'jet_pairing'
    priority: ClassVar[float] = 0.6   # after the central jet's deflection, before bridges
    bounds: ClassVar = {'pull': (0.0, 0.2), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, dtype=float)
        edge = np.flatnonzero((np.hypot(pos[:, 0], pos[:, 1]) > 1e-3) & geometry.fans.enabled)
        if self.pull == 0 or len(edge) < 2:
            return groups
        ring = edge[np.argsort(np.arctan2(pos[edge, 1], pos[edge, 0]))]
        t = np.maximum(np.asarray(thrust, dtype=float), 0.0)
        move = np.zeros_like(pos)
        for i, j in zip(ring, np.roll(ring, -1)):
            lo, hi = min(t[i], t[j]), max(t[i], t[j])
            if hi <= 0 or i == j:
                continue
            size = self.pull * (lo / hi) * lo / (lo + self.thrust_ref)
            towards = (pos[j] - pos[i]) / max(float(np.hypot(*(pos[j] - pos[i]))), 1e-9)
            move[i] += size * towards
            move[j] -= size * towards
        for g in groups:
            jet = g.fan >= 0
            g.centres[jet] = g.centres[jet] + move[g.fan[jet]]
        return groups


@dataclass(frozen=True)
class StallDip(HiddenEffect):
    """Rotating stall at part load: fan j runs at

        U_eff,j = U_j * (1 - depth_j * exp(-((U_j - at) / width)^2)),

    depth_j drawn once per fan in [0.5, 1.5] x ``depth`` (seeded by ``seed``), so each fan's
    curve dips by its own amount around the command ``at``."""

    depth: float = 0.2
    at: float = 0.35
    width: float = 0.08
    seed: int = 0
    name: ClassVar[str] = 'stall_dip'
    priority: ClassVar[int] = 4   # on the speed the motor reaches, after a supply's sag (3)
    bounds: ClassVar = {'depth': (0.0, 0.6), 'at': (0.05, 0.95), 'width': (0.01, 0.5)}

    def command(self, u, geometry):
        n = len(u)
        depth = self.depth * np.random.default_rng([int(self.seed), 0x57A11]).uniform(0.5, 1.5, n)
        return u * (1.0 - depth * np.exp(-((u - self.at) / self.width) ** 2))


@dataclass(frozen=True)
class CoflowCarry(HiddenEffect):
    """Jets in a co-flow: a jet spreads by entraining the air around it, and air that already
    moves with it slows it less. Fan j's footprint narrows and its peak grows, and it brings to
    the plate a share of its force that a jet in still air loses on the way:

        c_j = carry * T_o / (T_o + thrust_ref),   T_o = mean thrust of the other enabled fans [N]
        width_j /= (1 + c_j) ** 0.5,   amplitude_j *= (1 + c_j) ** 2

    so each jet's force at the plate (amplitude x width^2) grows by 1 + c_j. ``carry`` [-]: the
    largest relative gain of a jet's force, in a co-flow of far more than ``thrust_ref``."""

    carry: float = 0.3
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'coflow_carry'
    priority: ClassVar[float] = 0.7   # on the jets as they land, after pairing moved them
    bounds: ClassVar = {'carry': (0.0, 1.0), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        on = np.asarray(geometry.fans.enabled, bool)
        t = np.where(on, np.maximum(np.asarray(thrust, dtype=float), 0.0), 0.0)
        n_on = int(on.sum())
        if self.carry == 0 or n_on < 2:
            return groups
        others = (float(np.sum(t)) - t) / (n_on - 1)
        c = self.carry * others / (others + self.thrust_ref)
        for g in groups:
            jet = g.fan >= 0
            cj = c[g.fan[jet]]
            g.width[jet] = g.width[jet] / np.sqrt(1.0 + cj)
            g.amplitude[jet] = g.amplitude[jet] * (1.0 + cj) ** 2
        return groups


@dataclass(frozen=True)
class EscCurrentLimit(HiddenEffect):
    """Each ESC limits its motor's current (its setting, or a thin cable's): the thrust T_j [N]
    the curve would give flattens off towards the fan's own ceiling,

        T'_j = cap_j tanh(T_j / cap_j),   cap_j = ceiling (1 + spread z_j),

    z_j uniform in [-1, 1], drawn once per fan (seeded by ``seed``). With the default ceiling of
    4 N a fan that would give 1.5 N gives 5 % less, 3.2 N 17 % less, 5.7 N 37 % less."""

    ceiling: float = 4.0
    spread: float = 0.2
    seed: int = 7
    name: ClassVar[str] = 'esc_current_limit'
    priority: ClassVar[int] = 5   # on the thrust the motor would give, after its speed is set
    bounds: ClassVar = {'ceiling': (0.1, 100.0), 'spread': (0.0, 0.9)}

    def caps(self, n_fans: int) -> np.ndarray:
        """Each fan's ceiling [N]."""
        z = np.random.default_rng([int(self.seed), 0xE5C]).uniform(-1.0, 1.0, n_fans)
        return self.ceiling * (1.0 + self.spread * z)

    def thrust(self, t, geometry):
        t = np.asarray(t, dtype=float)
        cap = self.caps(len(t))
        return cap * np.tanh(t / cap)


@dataclass(frozen=True)
class DiffuserSeparation(HiddenEffect):
    """The diffuser's wall on one side (towards ``direction`` [deg from +x]) is steeper than the
    rest, and past a total thrust the flow separates from it: each fan loses the share

        loss_j = depth * w_j * s(T),   s(T) = 1 / (1 + exp(-(T - onset) / width)),

    of its thrust, T = sum_k T_k [N] the fans' total thrust and w_j = max(0, cos(phi_j -
    direction)) * r_j / r_max the fan's lean towards that side (phi_j, r_j its hub's angle and
    radius; the central fan keeps its thrust). With the defaults an edge fan facing the wall
    loses 4 % of its thrust at a total of 10 N, 15 % at 20 N and 26 % at 30 N."""

    depth: float = 0.3
    onset: float = 20.0
    width: float = 5.0
    direction: float = 30.0
    name: ClassVar[str] = 'diffuser_separation'
    priority: ClassVar[int] = 6   # on the thrust each fan delivers, after its ESC's limit
    bounds: ClassVar = {'depth': (0.0, 0.9), 'onset': (0.0, 1000.0), 'width': (0.01, 1000.0),
                        'direction': (-360.0, 360.0)}

    def lean(self, geometry) -> np.ndarray:
        """w_j (n_fans,): each fan's lean towards the separating side, 0..1."""
        pos = np.asarray(geometry.fans.positions, dtype=float)
        r = np.hypot(pos[:, 0], pos[:, 1])
        if r.max() <= 0:
            return np.zeros(len(r))
        phi = np.arctan2(pos[:, 1], pos[:, 0])
        return np.maximum(0.0, np.cos(phi - np.radians(self.direction))) * r / r.max()

    def thrust(self, t, geometry):
        t = np.asarray(t, dtype=float)
        total = float(np.sum(np.maximum(t, 0.0)))
        separated = 1.0 / (1.0 + np.exp(-(total - self.onset) / self.width))
        return t * (1.0 - self.depth * separated * self.lean(geometry))


@dataclass(frozen=True)
class SideInlet(HiddenEffect):
    """The plenum under the fans is fed through one side (towards ``direction`` [deg from +x]):
    the air reaching a fan far from the inlet has lost more pressure on its way, so each fan
    runs at the effective command

        U_eff,j = U_j / (1 + coupling * mean_k U_k * (1 + spread * d_j)),

    d_j = -(p_j . e) / r_max in [-1, 1] the fan's distance across the plenum away from the
    inlet (p_j its hub, e the unit vector towards the inlet; the central fan 0). With the
    defaults and every fan at 0.5 the fan beside the inlet runs at 0.48, the central one at
    0.43 and the one across the plenum at 0.38. A plenum fed evenly (``plenum_starvation``)
    slows every fan alike; here each fan has its own slope."""

    coupling: float = 0.35
    spread: float = 0.8
    direction: float = 200.0
    name: ClassVar[str] = 'side_inlet'
    priority: ClassVar[float] = 2.5   # after an ESC dead band and an evenly fed plenum's loss
    bounds: ClassVar = {'coupling': (0.0, 3.0), 'spread': (0.0, 1.0), 'direction': (-360.0, 360.0)}

    def distance(self, geometry) -> np.ndarray:
        """d_j (n_fans,): each hub's distance across the plenum from the inlet, -1..1."""
        pos = np.asarray(geometry.fans.positions, dtype=float)
        r_max = float(np.max(np.hypot(pos[:, 0], pos[:, 1])))
        if r_max <= 0:
            return np.zeros(len(pos))
        a = np.radians(self.direction)
        return -(pos @ np.array([np.cos(a), np.sin(a)])) / r_max

    def command(self, u, geometry):
        u = np.asarray(u, dtype=float)
        enabled = geometry.fans.enabled
        mean = max(float(np.mean(u[enabled])), 0.0) if enabled.any() else 0.0
        return u / (1.0 + self.coupling * mean * (1.0 + self.spread * self.distance(geometry)))


@dataclass(frozen=True)
class JetConfinement(HiddenEffect):
    """The edge jets hem the central jet in: it lands narrower, and taller by as much (its
    force kept), the harder they blow. The central footprint's width is scaled by

        1 / (1 + squeeze * T_e / (T_e + thrust_ref)),   its peak by the square of the inverse,

    T_e the edge fans' mean thrust [N]. With the defaults and every edge fan at 3 N the central
    jet is 11 % narrower and its peak 27 % higher. The central fan's width fitted per fan is
    right for one load of the edge fans only."""

    squeeze: float = 0.25
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'jet_confinement'
    priority: ClassVar[float] = 0.45   # on the jets as they land, before the edge jets move
    bounds: ClassVar = {'squeeze': (0.0, 2.0), 'thrust_ref': (0.1, 100.0)}

    def narrowing(self, edge_thrust: float) -> float:
        """The central jet's width factor for the edge fans' mean thrust [N]."""
        t = max(float(edge_thrust), 0.0)
        return 1.0 / (1.0 + self.squeeze * t / (t + self.thrust_ref))

    def sources(self, groups, thrust, geometry):
        central = np.array(geometry.fans.groups) == 'central'
        edge = ~central & geometry.fans.enabled
        if not central.any() or not edge.any() or self.squeeze == 0:
            return groups
        k = self.narrowing(float(np.mean(np.maximum(np.asarray(thrust, dtype=float)[edge], 0.0))))
        for g in groups:
            jet = (g.fan >= 0) & central[np.maximum(g.fan, 0)]
            g.width[jet] = g.width[jet] * k
            g.amplitude[jet] = g.amplitude[jet] / k ** 2
        return groups


@dataclass(frozen=True)
class FlowScreen(HiddenEffect):
    """A wire-mesh screen above the fans evens the flow out. It takes the share

        s = share * (thrust_ref / (thrust_ref + T)) ** exponent

    of every jet (T the fans' total thrust [N]; a screen's loss coefficient falls with the
    Reynolds number, so a slow flow is evened out more) and spreads that force evenly over the
    section: each jet keeps (1 - s) of its peak, and a flat pedestal over the wall's radius
    carries what was taken (each jet's force counted as peak x pi w^2, a Gaussian footprint's).
    With the defaults and 20 N in all, s = 0.28. A per-fan correction cannot hold it: the
    pedestal has no fan's footprint, and its height and every jet's share follow the total."""

    share: float = 0.4
    thrust_ref: float = 10.0
    exponent: float = 0.33
    name: ClassVar[str] = 'flow_screen'
    priority: ClassVar[float] = 4   # last: it evens out the flow every other effect has shaped
    bounds: ClassVar = {'share': (0.0, 1.0), 'thrust_ref': (0.1, 1000.0), 'exponent': (0.0, 1.0)}

    def taken(self, total_thrust: float) -> float:
        """The share s [-] of every jet the screen spreads out, for the total thrust [N]."""
        t = max(float(total_thrust), 0.0)
        return self.share * (self.thrust_ref / (self.thrust_ref + t)) ** self.exponent

    def sources(self, groups, thrust, geometry):
        total = float(np.sum(np.maximum(np.asarray(thrust, dtype=float)[geometry.fans.enabled], 0.0)))
        s = self.taken(total)
        if s == 0 or not groups:
            return groups
        spread = 0.0
        for g in groups:
            spread += s * float(np.sum(g.amplitude * np.pi * g.width ** 2))
            g.amplitude[:] = g.amplitude * (1.0 - s)
        wall = geometry.wall_radius
        # a flat top (exp(-(d/w)^8)) as wide as the wall, scaled to carry the force taken:
        # its area is pi w^2 Gamma(1 + 2/8) = 0.906 pi w^2
        level = spread / (0.906 * np.pi * wall ** 2)
        return groups + [JetGroup(FlatTop(8.0), np.zeros((1, 2)), np.array([level]),
                                  np.array([wall]), np.array([-1]))]


register_effects(SupplySag, RecirculationCore, JetPairing, StallDip, CoflowCarry, EscCurrentLimit,
                 DiffuserSeparation, SideInlet, JetConfinement, FlowScreen)

__all__ = ['SupplySag', 'RecirculationCore', 'JetPairing', 'StallDip', 'CoflowCarry', 'EscCurrentLimit',
           'DiffuserSeparation', 'SideInlet', 'JetConfinement', 'FlowScreen']
