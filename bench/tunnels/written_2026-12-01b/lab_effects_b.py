"""Three more effects written apart from the simulator's own and from the first written set,
to test the shaping on physics neither the prior nor its corrections were tuned on."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.core.geometry import neighbour_pairs
from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect
from wind_shaper.sim.physics import FlatTop, JetGroup


@dataclass(frozen=True)
class ThrottleSteps(HiddenEffect):
    """An ESC with a coarse throttle: each fan runs at its command rounded to the nearest
    multiple of ``step`` [PWM fraction], so a change of less than half a step may do nothing and
    the thrust curve is a staircase no smooth curve follows."""

    step: float = 0.025
    name: ClassVar[str] = 'throttle_steps'
    bounds: ClassVar = {'step': (0.0, 0.2)}

    def command(self, u, geometry):
        if self.step == 0:
            return u
        return self.step * np.round(np.asarray(u, float) / self.step)


@dataclass(frozen=True)
class InletAssist(HiddenEffect):
    """Neighbouring jets feed each other's inlets (each drags co-flowing air past the other's
    intake): a fan gives more the harder its neighbours run,

        T_j' = T_j (1 + assist * m_j / (m_j + thrust_ref)),

    m_j the mean thrust [N] of the fans whose hubs lie within ``reach`` x the closest hub spacing.
    The opposite sign of a starved inlet: a fan idle beside busy neighbours is not helped (it
    makes no thrust to raise)."""

    assist: float = 0.4
    thrust_ref: float = 3.0
    reach: float = 1.2
    name: ClassVar[str] = 'inlet_assist'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'assist': (0.0, 2.0), 'thrust_ref': (0.1, 100.0), 'reach': (1.0, 3.0)}

    def thrust(self, t, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        pairs = neighbour_pairs(np.asarray(geometry.fans.positions, float)[on], self.reach)
        near = np.zeros((len(on), len(on)), bool)
        near[pairs[:, 0], pairs[:, 1]] = near[pairs[:, 1], pairs[:, 0]] = True
        out = t.copy()
        for a, j in enumerate(on):
            if near[a].any():
                m = float(np.mean(np.maximum(t[on[near[a]]], 0.0)))
                out[j] = t[j] * (1.0 + self.assist * m / (m + self.thrust_ref))
        return out


@dataclass(frozen=True)
class RingSuction(HiddenEffect):
    """The ring of edge jets entrains air from the tunnel's core and lowers the flow there: a
    round deficit of peak ``share`` x the edge fans' mean thrust [N] and 1/e radius ``width`` [m]
    sits on the axis, whatever the central fan does."""

    share: float = 0.25
    width: float = 0.12
    name: ClassVar[str] = 'ring_suction'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'share': (0.0, 1.0), 'width': (0.02, 0.5)}

    def sources(self, groups, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, float)
        edge = np.flatnonzero((np.hypot(pos[:, 0], pos[:, 1]) > 1e-3) & geometry.fans.enabled)
        if self.share == 0 or len(edge) == 0 or not groups:
            return groups
        mean = float(np.mean(np.maximum(thrust[edge], 0.0)))
        deficit = JetGroup(profile=FlatTop(2.0), centres=np.zeros((1, 2)),
                           amplitude=np.array([-self.share * mean]),
                           width=np.array([self.width]), fan=np.array([-1]))
        return [*groups, deficit]


register_effects(ThrottleSteps, InletAssist, RingSuction)
