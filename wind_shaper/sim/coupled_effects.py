"""Physics that couples the fans to each other, written for the shaping benchmark's unfamiliar
tunnels (``bench/convergence.py``): a per-fan correction of the prior (gain, landing point,
width) cannot absorb either, because each fan's share of the field depends on what the other
fans do.

* ``SupplySag``: the fans share one power supply whose voltage sags with the total current,
  so every fan turns slower when the others run harder.
* ``RecirculationCore``: the edge jets drive a recirculating bubble over the middle of the
  tunnel, a deficit there that grows with the edge fans' mean thrust and widens with it.

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


register_effects(SupplySag, RecirculationCore)

__all__ = ['SupplySag', 'RecirculationCore']
