"""Three effects written on 2026-12-04 (the ninth set) apart from the simulator's own and from
the earlier written sets, to test the shaping on physics neither the prior nor its corrections
were tuned on: ring jets pushed outward by their own speed, a central jet that flaps when it
outruns the ring, and the wake of a gantry strut across the outlet."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect

_AXIS = 0.05   # [m]: a hub closer than this to the tunnel's axis is the central fan


@dataclass(frozen=True)
class OwnThrustOutflow(HiddenEffect):
    """Each ring jet lands farther out the faster its own fan runs (the rotor's swirl flings
    the jet outward): fan j's jet lands moved radially by

        drift * T_j / (T_j + thrust_ref)   [m],

    T_j its own thrust [N]; the central jet, on the axis, stays. A prior's landing point per
    fan is one place; here it moves with that fan's command alone."""

    drift: float = 0.04
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'own_thrust_outflow'
    priority: ClassVar[float] = 0.6
    bounds: ClassVar = {'drift': (-0.1, 0.1), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        if self.drift == 0:
            return groups
        t = np.maximum(np.asarray(thrust, float), 0.0)
        for g in groups:
            ok = np.flatnonzero(g.fan >= 0)
            if not len(ok):
                continue
            c = g.centres[ok]
            r = np.hypot(c[:, 0], c[:, 1])
            fans = g.fan[ok]
            push = self.drift * t[fans] / (t[fans] + self.thrust_ref)
            grow = np.where(r > _AXIS, (r + push) / np.maximum(r, _AXIS), 1.0)
            g.centres = g.centres.copy()
            g.centres[ok] = c * grow[:, None]
        return groups


@dataclass(frozen=True)
class CentreJetFlapping(HiddenEffect):
    """The central jet flaps when its fan outruns the ring: with x = min(cap, max(0, T_c /
    mean ring T - 1)) its footprint widens by 1 + flap * x and its peak falls so that the force
    it carries stays the same (peak / (1 + flap * x)^2). Run level, the jets hold each other
    steady; a lone strong centre jet wanders and smears. What one fan's jet looks like here
    depends on how hard the others run."""

    flap: float = 0.5
    cap: float = 3.0
    name: ClassVar[str] = 'centre_jet_flapping'
    priority: ClassVar[float] = 0.7
    bounds: ClassVar = {'flap': (0.0, 2.0), 'cap': (0.0, 10.0)}

    def sources(self, groups, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, float)
        on = np.asarray(geometry.fans.enabled, bool)
        centre = np.hypot(pos[:, 0], pos[:, 1]) <= _AXIS
        ring = ~centre & on
        if self.flap == 0 or not (centre & on).any() or not ring.any():
            return groups
        t = np.maximum(np.asarray(thrust, float), 0.0)
        ring_mean = float(np.mean(t[ring]))
        c = int(np.flatnonzero(centre)[0])
        x = self.cap if ring_mean <= 1e-9 else min(self.cap, max(0.0, t[c] / ring_mean - 1.0))
        if x == 0:
            return groups
        widen = 1.0 + self.flap * x
        for g in groups:
            rows = g.index_of(c)
            if len(rows):
                g.width = g.width.copy()
                g.amplitude = g.amplitude.copy()
                g.width[rows] *= widen
                g.amplitude[rows] /= widen ** 2
        return groups


@dataclass(frozen=True)
class GantryStrutWake(HiddenEffect):
    """A strut of the plate's gantry crosses the outlet: on the straight line whose normal
    points toward ``angle`` [deg] at ``distance`` [m] from the axis, the flow falls by ``depth``,
    across a Gaussian strip ``width`` [m] wide,

        scale(p) = 1 - depth * exp(-((p . n - distance) / width)^2).

    It stays where it is whatever the fans do, and no fan's footprint has its shape."""

    depth: float = 0.3
    width: float = 0.04
    distance: float = 0.1
    angle: float = 30.0
    name: ClassVar[str] = 'gantry_strut_wake'
    priority: ClassVar[int] = 1
    bounds: ClassVar = {'depth': (0.0, 0.9), 'width': (0.005, 0.5), 'distance': (-0.4, 0.4),
                        'angle': (-360.0, 360.0)}

    def scale(self, points, geometry):
        n = np.array([np.cos(np.radians(self.angle)), np.sin(np.radians(self.angle))])
        across = (np.asarray(points, float) @ n - self.distance) / self.width
        return 1.0 - self.depth * np.exp(-across ** 2)


register_effects(OwnThrustOutflow, CentreJetFlapping, GantryStrutWake)
