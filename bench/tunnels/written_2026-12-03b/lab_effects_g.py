"""Two effects written on 2026-12-03 (evening), after the screen of a short map memory, apart
from the simulator's own and from the earlier written sets: physics that rewards or punishes
the contrast between neighbouring fans, or flips with a balance, which no per-fan gain, landing
point, width or curve holds."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.core.geometry import neighbour_pairs
from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect, fan_landings
from wind_shaper.sim.physics import FlatTop, JetGroup


@dataclass(frozen=True)
class ShearLayerTurbulence(HiddenEffect):
    """Two neighbouring jets at different speeds shear against each other; the shear layer
    between them is turbulent, and the plate's drag takes up the turbulence's momentum flux as
    force. With thrust proportional to the jet speed squared, the extra density

        strength * sum_{neighbour pairs} (sqrt(T_i) - sqrt(T_j))^2 * profile(|p - m_ij| / w_ij)  [N]

    sits at the midpoints m_ij of where the two jets land, w_ij the mean of their widths.
    Equal neighbours add nothing; the term grows with their contrast, and is not smooth where
    they cross (|sqrt(T_i) - sqrt(T_j)| has a kink there). The library's jet interaction grows
    with both jets (sqrt(T_i T_j)); this one with their difference."""

    strength: float = 0.4
    reach: float = 1.2
    name: ClassVar[str] = 'shear_layer_turbulence'
    priority: ClassVar[int] = 1
    bounds: ClassVar = {'strength': (0.0, 3.0), 'reach': (1.0, 2.0)}

    def sources(self, groups, thrust, geometry):
        pairs = neighbour_pairs(geometry.fans.positions, self.reach)
        if self.strength == 0 or len(pairs) == 0:
            return groups
        centre, width = fan_landings(groups, geometry.fans.n_fans)
        i, j = pairs[:, 0], pairs[:, 1]
        speed = np.sqrt(np.maximum(np.asarray(thrust, float), 0.0))
        amp = self.strength * (speed[i] - speed[j]) ** 2
        return groups + [JetGroup(FlatTop(2.0), 0.5 * (centre[i] + centre[j]), amp,
                                  0.5 * (width[i] + width[j]), np.full(len(pairs), -1))]


@dataclass(frozen=True)
class PlenumSwirlLock(HiddenEffect):
    """The plenum under the fans holds one large vortex, and it locks into the sense of the
    rotors that turn the most air: the whole field turns about the tunnel's axis by

        theta = turn * tanh(b / balance),   b = (sum T_ccw - sum T_cw) / sum T   [rad, CCW]

    A small imbalance already turns it nearly the whole way, and the turn flips when the
    balance crosses zero. The library's swirl turns in proportion to the balance; this one is
    a switch with a soft edge ``balance`` wide."""

    turn: float = 0.12
    balance: float = 0.05
    name: ClassVar[str] = 'plenum_swirl_lock'
    priority: ClassVar[int] = 0
    bounds: ClassVar = {'turn': (-0.6, 0.6), 'balance': (0.005, 1.0)}

    def angle(self, thrust, geometry) -> float:
        t = np.maximum(np.asarray(thrust, float), 0.0)
        total = float(np.sum(t))
        if total <= 0:
            return 0.0
        b = float(np.dot(geometry.fans.spin_sign, t)) / total
        return self.turn * float(np.tanh(b / self.balance))

    def warp(self, points, thrust, geometry):
        theta = self.angle(thrust, geometry)
        c, s = np.cos(theta), np.sin(theta)
        # the field turned by theta, read at p, is the unturned field at R(-theta) p
        return np.column_stack([c * points[:, 0] + s * points[:, 1],
                                -s * points[:, 0] + c * points[:, 1]])


register_effects(ShearLayerTurbulence, PlenumSwirlLock)
