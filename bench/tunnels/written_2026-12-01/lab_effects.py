"""Two effects written apart from the simulator's own, to test the shaping on physics neither
the prior nor its corrections were tuned on."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect


@dataclass(frozen=True)
class NeighbourPreswirl(HiddenEffect):
    """Each edge fan draws in air its counter-clockwise neighbour has already set turning: the
    stronger that neighbour runs than the fan itself, the less thrust the fan makes,

        T_j *= 1 - loss * max(0, T_prev - T_j) / (T_prev + T_j + t0)

    (one-sided: a weaker neighbour does nothing). Edge fans ordered by angle."""

    loss: float = 0.5
    t0: float = 0.5
    name: ClassVar[str] = 'neighbour_preswirl'
    bounds: ClassVar = {'loss': (0.0, 1.0), 't0': (0.01, 10.0)}

    def thrust(self, t, geometry):
        pos = np.asarray(geometry.fans.positions, float)
        r = np.hypot(pos[:, 0], pos[:, 1])
        edge = np.flatnonzero(r > 1e-3)
        order = edge[np.argsort(np.arctan2(pos[edge, 1], pos[edge, 0]))]
        out = t.copy()
        for k, j in enumerate(order):
            prev = order[k - 1]
            gap = max(0.0, float(t[prev] - t[j]))
            out[j] = t[j] * (1.0 - self.loss * gap / (t[prev] + t[j] + self.t0))
        return out


@dataclass(frozen=True)
class PlumeLean(HiddenEffect):
    """The plume leans away from where the thrust is: the whole field moves by

        -lean * sum_j T_j p_j / (sum_j T_j + t0)    [m]

    (p_j the hub positions), so an unbalanced set of commands pushes the field towards the weak
    side, and a balanced one leaves it in place."""

    lean: float = 0.3
    t0: float = 2.0
    name: ClassVar[str] = 'plume_lean'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'lean': (0.0, 2.0), 't0': (0.01, 100.0)}

    def warp(self, points, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, float)
        tt = np.maximum(np.asarray(thrust, float), 0.0)
        shift = -self.lean * (tt @ pos) / (float(tt.sum()) + self.t0)
        return points - shift


register_effects(NeighbourPreswirl, PlumeLean)
