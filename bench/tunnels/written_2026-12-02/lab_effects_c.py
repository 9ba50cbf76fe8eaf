"""Two effects written on 2026-12-02 apart from the simulator's own and from the earlier written
sets, after the shipped defaults were settled, to test the shaping on physics neither the prior
nor its corrections were tuned on."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect
from wind_shaper.sim.physics import FlatTop, JetGroup


def _enabled_thrust(thrust, geometry):
    on = np.flatnonzero(geometry.fans.enabled)
    return on, np.maximum(np.asarray(thrust, float), 0.0)


@dataclass(frozen=True)
class IdleBackflow(HiddenEffect):
    """A fan turning slower than the plenum's pressure needs lets air back down through its
    disc. The pressure follows the other fans' mean thrust P [N]; over fan j's hub the field
    loses a round patch (1/e radius ``width`` [m]) of peak

        share * P * thrust_ref / (T_j + thrust_ref)      (T_j: fan j's own thrust [N]),

    the most where the fan idles, half of it where it gives thrust_ref. An optimum that keeps
    fans low pays for it over their hubs, which no per-fan gain or curve holds (it depends on
    what the other fans do)."""

    share: float = 0.15
    width: float = 0.07
    thrust_ref: float = 1.0
    name: ClassVar[str] = 'idle_backflow'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'share': (0.0, 1.0), 'width': (0.02, 0.3), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        on, t = _enabled_thrust(thrust, geometry)
        if self.share == 0 or len(on) < 2 or not groups:
            return groups
        others = (float(np.sum(t[on])) - t[on]) / (len(on) - 1)
        depth = self.share * others * self.thrust_ref / (t[on] + self.thrust_ref)
        hubs = np.asarray(geometry.fans.positions, float)[on]
        back = JetGroup(profile=FlatTop(2.0), centres=hubs.copy(), amplitude=-depth,
                        width=np.full(len(on), self.width), fan=np.full(len(on), -1))
        return [*groups, back]


@dataclass(frozen=True)
class PlumeNecking(HiddenEffect):
    """The plume necks down above the fans (a vena contracta), the more the harder they blow:
    every off-axis jet lands nearer the axis by the fraction

        pull * T_mean / (T_mean + thrust_ref)       of its hub's distance from it,

    T_mean the enabled fans' mean thrust [N]. A per-fan landing point fitted at one load is off
    at another; unlike jets that pair or cling to a wall, all move in together, by the load."""

    pull: float = 0.2
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'plume_necking'
    priority: ClassVar[float] = 0.7   # on the jets as they land, with the other movers
    bounds: ClassVar = {'pull': (0.0, 0.6), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        on, t = _enabled_thrust(thrust, geometry)
        if self.pull == 0 or len(on) == 0:
            return groups
        mean = float(np.mean(t[on]))
        shrink = 1.0 - self.pull * mean / (mean + self.thrust_ref)
        for g in groups:
            jet = g.fan >= 0
            g.centres[jet] = g.centres[jet] * shrink
        return groups


register_effects(IdleBackflow, PlumeNecking)
