"""Three effects written on 2026-12-04 apart from the simulator's own and from the earlier
written sets, to test the shaping on physics neither the prior nor its corrections were tuned
on: a supply split over two rails, a plume that widens with the load, an inlet filter clogged
on one side."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect


def _ring(geometry) -> tuple[np.ndarray, np.ndarray]:
    """((n_fans,) bool: the hub is off the tunnel's axis, (n_fans,) its angle about the axis
    [rad])."""
    pos = np.asarray(geometry.fans.positions, float)
    return np.hypot(pos[:, 0], pos[:, 1]) > 0.05, np.arctan2(pos[:, 1], pos[:, 0])


@dataclass(frozen=True)
class SplitRailSag(HiddenEffect):
    """The fans hang on two supply rails, every other ring fan on each and the central fan on
    the first: a rail's voltage falls with the mean command of its own fans, and each fan runs
    at

        U_eff,j = U_j * (1 - sag * mean_{i on j's rail} U_i).

    One shared supply (a load slope every fan follows) is what a prior's correction can learn;
    here a fan's loss depends on which of its neighbours run hard, and the central fan loads one
    rail only."""

    sag: float = 0.25
    name: ClassVar[str] = 'split_rail_sag'
    priority: ClassVar[int] = 4
    bounds: ClassVar = {'sag': (0.0, 0.8)}

    def rails(self, geometry) -> np.ndarray:
        """(n_fans,) 0 or 1: each fan's rail (by hub order round the ring; the axis fan on 0)."""
        ring, angle = _ring(geometry)
        order = np.argsort(np.where(ring, angle, -10.0))
        rail = np.zeros(len(ring), int)
        ring_order = [j for j in order if ring[j]]
        for k, j in enumerate(ring_order):
            rail[j] = k % 2
        return rail

    def command(self, u, geometry):
        u = np.asarray(u, float)
        rail = self.rails(geometry)
        on = np.asarray(geometry.fans.enabled, bool)
        load = np.zeros(u.shape, float)
        for r in (0, 1):
            members = on & (rail == r)
            if members.any():
                mean = np.mean(u[..., members], axis=-1, keepdims=True)
                load = np.where(rail == r, mean, load)
        return u * (1.0 - self.sag * load)


@dataclass(frozen=True)
class LoadExpansion(HiddenEffect):
    """The plume widens as a whole with the fans' total thrust (entrainment grows with the jets'
    momentum): the field at distance r from the axis is the unwidened one at r / (1 + e), with

        e = expansion * mean_j T_j / reference,

    over the enabled fans' thrusts [N]. Every footprint moves outward and widens together when
    all fans run harder; a prior's per-fan landing points and widths are fixed."""

    expansion: float = 0.15
    reference: float = 4.0
    name: ClassVar[str] = 'load_expansion'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'expansion': (0.0, 0.6), 'reference': (0.5, 50.0)}

    def warp(self, points, thrust, geometry):
        t = np.maximum(np.asarray(thrust, float), 0.0)
        on = np.asarray(geometry.fans.enabled, bool)
        mean = float(np.mean(t[on])) if on.any() else 0.0
        return np.asarray(points, float) / (1.0 + self.expansion * mean / self.reference)


@dataclass(frozen=True)
class CloggedInlet(HiddenEffect):
    """The inlet filter is clogged on one side (toward ``direction`` [deg]): fans on that side
    draw through the clogged part, and the harder they run the more its pressure drop costs
    them (it grows with the flow squared),

        U_eff,j = U_j * (1 - clog * w_j * U_j),   w_j = max(0, cos(angle_j - direction)),

    the axis fan half exposed (w = 0.5). A fan's curve flattens at the top by its place in the
    array, not by a draw per fan."""

    clog: float = 0.4
    direction: float = 60.0
    name: ClassVar[str] = 'clogged_inlet'
    priority: ClassVar[int] = 4
    bounds: ClassVar = {'clog': (0.0, 1.0), 'direction': (-360.0, 360.0)}

    def exposure(self, geometry) -> np.ndarray:
        ring, angle = _ring(geometry)
        w = np.maximum(0.0, np.cos(angle - np.radians(self.direction)))
        return np.where(ring, w, 0.5)

    def command(self, u, geometry):
        u = np.asarray(u, float)
        return u * (1.0 - self.clog * self.exposure(geometry) * u)


register_effects(SplitRailSag, LoadExpansion, CloggedInlet)
