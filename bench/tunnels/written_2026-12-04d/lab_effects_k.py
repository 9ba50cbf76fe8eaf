"""Three effects written on 2026-12-04 (the eleventh set) apart from the simulator's own and
from the earlier written sets, to test the shaping on physics neither the prior nor its
corrections were tuned on: two fans' command lines swapped at the flight controller, jets that
narrow as their own fan speeds up, and swirl a fan recovers from its counter-rotating
neighbours."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.core.geometry import neighbour_pairs
from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import EffectError, HiddenEffect


@dataclass(frozen=True)
class SwappedChannels(HiddenEffect):
    """Two fans' ESC leads are on each other's output: the command meant for ``fan_a`` drives
    ``fan_b``'s motor and the other way round. A wiring fault, not physics: every fan is as
    built, only not where the commands think it is."""

    fan_a: str = 'HM1'
    fan_b: str = 'LM3'
    name: ClassVar[str] = 'swapped_channels'
    priority: ClassVar[float] = -1.0   # on the commands as they leave the controller

    def _pair(self, geometry) -> tuple[int, int]:
        try:
            a, b = geometry.fans.index(self.fan_a), geometry.fans.index(self.fan_b)
        except Exception as exc:
            raise EffectError(f'SwappedChannels: {exc}') from None
        if a == b:
            raise EffectError(f'SwappedChannels needs two different fans, got {self.fan_a} twice')
        return a, b

    def validate(self, geometry):
        self._pair(geometry)

    def command(self, u, geometry):
        a, b = self._pair(geometry)
        out = np.array(u, float)
        out[a], out[b] = u[b], u[a]
        return out


@dataclass(frozen=True)
class OwnJetNarrowing(HiddenEffect):
    """Each jet narrows as its own fan speeds up (a faster jet entrains less before it reaches
    the plate): fan j's footprint is narrower by the factor

        1 + narrow * T_j / (T_j + thrust_ref),

    T_j its own thrust [N], and its peak higher by the square of that, so it carries the same
    force. A prior's footprint width per fan is one width; here it follows that fan's command."""

    narrow: float = 0.3
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'own_jet_narrowing'
    priority: ClassVar[float] = 0.65
    bounds: ClassVar = {'narrow': (0.0, 2.0), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        if self.narrow == 0:
            return groups
        t = np.maximum(np.asarray(thrust, float), 0.0)
        for g in groups:
            ok = np.flatnonzero(g.fan >= 0)
            if not len(ok):
                continue
            fans = g.fan[ok]
            factor = 1.0 + self.narrow * t[fans] / (t[fans] + self.thrust_ref)
            g.width = g.width.copy()
            g.amplitude = g.amplitude.copy()
            g.width[ok] /= factor
            g.amplitude[ok] *= factor ** 2
        return groups


@dataclass(frozen=True)
class SwirlRecovery(HiddenEffect):
    """A fan beside counter-rotating neighbours (hubs within ``reach`` times the closest
    spacing, spinning the other way) recovers part of their swirl as axial thrust, the more the
    harder they run:

        T_j' = T_j * (1 + recovery * mean_{k near j, opposite spin} T_k / (T_k + thrust_ref)).

    The reverse of a starved inlet: running the neighbours helps a fan. A fan alone gets none."""

    recovery: float = 0.2
    thrust_ref: float = 3.0
    reach: float = 1.2
    name: ClassVar[str] = 'swirl_recovery'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'recovery': (0.0, 1.0), 'thrust_ref': (0.1, 100.0), 'reach': (1.0, 3.0)}

    def thrust(self, t, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        pairs = on[neighbour_pairs(np.asarray(geometry.fans.positions)[on], self.reach)]
        spin = np.asarray(geometry.fans.spin_sign, float)
        if len(pairs) == 0 or self.recovery == 0:
            return t
        t = np.maximum(np.asarray(t, float), 0.0)
        share = t / (t + self.thrust_ref)
        gain = np.zeros(len(t))
        count = np.zeros(len(t))
        for a, b in pairs:
            if spin[a] != spin[b]:
                gain[a] += share[b]
                gain[b] += share[a]
                count[a] += 1
                count[b] += 1
        mean = np.where(count > 0, gain / np.maximum(count, 1), 0.0)
        return t * (1.0 + self.recovery * mean)


register_effects(SwappedChannels, OwnJetNarrowing, SwirlRecovery)
