"""Three effects written on 2026-12-04 (the thirteenth set) apart from the simulator's own and
from the earlier written sets, to test the shaping on physics neither the prior nor its
corrections were tuned on: a fan deck that rocks on soft mounts under a lopsided thrust, a ring
vortex that lifts the middle when the ring outruns the central fan, and weak jets drawn toward
a stronger neighbour."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.core.geometry import neighbour_pairs
from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect
from wind_shaper.sim.physics import FlatTop, JetGroup


@dataclass(frozen=True)
class DeckRock(HiddenEffect):
    """The fan deck sits on soft mounts; a lopsided thrust tips it, so every jet (the central
    one too) leans toward the side that pushes hardest and lands shifted by

        shift = rock * sum_j T_j p_j / (sum_j T_j + thrust_ref)     [m]

    p_j the hubs' positions [m], T_j the thrusts [N]. Evening the field by running one side
    harder moves every jet toward that side, which no fixed per-fan landing point holds."""

    rock: float = 0.6
    thrust_ref: float = 10.0
    name: ClassVar[str] = 'deck_rock'
    priority: ClassVar[float] = 0.6
    bounds: ClassVar = {'rock': (-2.0, 2.0), 'thrust_ref': (0.1, 500.0)}

    def sources(self, groups, thrust, geometry):
        if self.rock == 0:
            return groups
        on = np.asarray(geometry.fans.enabled, bool)
        t = np.where(on, np.maximum(np.asarray(thrust, float), 0.0), 0.0)
        hubs = np.asarray(geometry.fans.positions, float)
        shift = self.rock * (t @ hubs) / (t.sum() + self.thrust_ref)
        return _shift_jets(groups, np.broadcast_to(shift, hubs.shape))


@dataclass(frozen=True)
class RingVortexLift(HiddenEffect):
    """When the edge fans outrun the central one, the shear between them rolls up into a ring
    vortex whose induced flow lifts the middle of the tunnel: a round bump on the axis,

        density += lift * softplus(mean(T_edge) - ratio * T_centre),   width ``width`` [m]

    (softplus with a knee of ``knee`` [N], so the bump fades in rather than switching on). A
    hinge in the difference of two fans' thrusts; the fans alone know nothing of it."""

    lift: float = 0.3
    ratio: float = 1.0
    knee: float = 0.3
    width: float = 0.09
    name: ClassVar[str] = 'ring_vortex_lift'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'lift': (-1.0, 2.0), 'ratio': (0.0, 5.0), 'knee': (0.01, 5.0),
                        'width': (0.02, 0.5)}

    def sources(self, groups, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, float)
        on = np.asarray(geometry.fans.enabled, bool)
        radius = np.hypot(pos[:, 0], pos[:, 1])
        edge, centre = on & (radius > 1e-3), on & (radius <= 1e-3)
        if self.lift == 0 or not edge.any():
            return groups
        t = np.maximum(np.asarray(thrust, float), 0.0)
        excess = float(np.mean(t[edge]) - self.ratio * (np.sum(t[centre]) if centre.any() else 0.0))
        bump = self.lift * self.knee * np.logaddexp(0.0, excess / self.knee)
        return groups + [JetGroup(FlatTop(2.0), np.zeros((1, 2)), np.array([bump]),
                                  np.array([self.width]), np.full(1, -1))]


@dataclass(frozen=True)
class NeighbourCapture(HiddenEffect):
    """A jet beside a stronger one is drawn into it (the stronger jet's entrainment bends the
    weaker toward it); a stronger or equal neighbour's jet stays put:

        shift_j = capture * sum_{k near j} max(0, T_k - T_j) / (T_k + T_j + t0) * (p_k - p_j)

    over running neighbours k (hubs within ``reach`` times the closest spacing). One-sided, so
    raising a fan moves its neighbours' jets, not its own."""

    capture: float = 0.3
    t0: float = 0.5
    reach: float = 1.2
    name: ClassVar[str] = 'neighbour_capture'
    priority: ClassVar[float] = 0.6
    bounds: ClassVar = {'capture': (0.0, 1.5), 't0': (0.0, 50.0), 'reach': (1.0, 3.0)}

    def sources(self, groups, thrust, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        hubs = np.asarray(geometry.fans.positions, float)
        pairs = on[neighbour_pairs(hubs[on], self.reach)]
        if self.capture == 0 or len(pairs) == 0:
            return groups
        t = np.maximum(np.asarray(thrust, float), 0.0)
        shift = np.zeros_like(hubs)
        for a, b in pairs:
            for j, k in ((a, b), (b, a)):
                pull = max(0.0, t[k] - t[j]) / (t[k] + t[j] + self.t0)
                shift[j] += self.capture * pull * (hubs[k] - hubs[j])
        return _shift_jets(groups, shift)


def _shift_jets(groups, shift):
    """Every fan's jets moved by that fan's row of ``shift`` (n_fans, 2) [m]; sources that are
    not a fan's (interaction terms) stay."""
    for g in groups:
        ok = np.flatnonzero(g.fan >= 0)
        if len(ok):
            g.centres = np.asarray(g.centres, float).copy()
            g.centres[ok] += shift[g.fan[ok]]
    return groups


register_effects(DeckRock, RingVortexLift, NeighbourCapture)
