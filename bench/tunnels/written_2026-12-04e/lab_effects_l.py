"""Three effects written on 2026-12-04 (the twelfth set) apart from the simulator's own and
from the earlier written sets, to test the shaping on physics neither the prior nor its
corrections were tuned on: neighbouring rotors that beat against each other when they turn at
nearly the same speed, pairs of fans that share one ESC power stage, and a fan deck that bends
under the total thrust and tilts the ring jets toward the axis."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.core.geometry import neighbour_pairs
from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import EffectError, HiddenEffect


@dataclass(frozen=True)
class RotorBeat(HiddenEffect):
    """Neighbouring rotors (hubs within ``reach`` times the closest spacing) turning at nearly
    the same speed shed tip vortices in step and lose thrust to the interference; detuned, they
    do not. Rotor speed goes as the square root of thrust, so with s = sqrt(T):

        T_j' = T_j * (1 - depth * mean_{k near j} exp(-((s_j - s_k) / (band * (s_j + s_k) / 2))^2))

    over running neighbours k. A uniform field wants equal commands, which is where the loss
    is deepest; a prior of independent fans has no term for it."""

    depth: float = 0.12
    band: float = 0.08
    reach: float = 1.2
    name: ClassVar[str] = 'rotor_beat'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'depth': (0.0, 0.5), 'band': (0.01, 0.5), 'reach': (1.0, 3.0)}

    def thrust(self, t, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        pairs = on[neighbour_pairs(np.asarray(geometry.fans.positions)[on], self.reach)]
        if len(pairs) == 0 or self.depth == 0:
            return t
        t = np.maximum(np.asarray(t, float), 0.0)
        s = np.sqrt(t)
        loss = np.zeros(len(t))
        count = np.zeros(len(t))
        for a, b in pairs:
            count[a] += 1
            count[b] += 1
            mid = 0.5 * (s[a] + s[b])
            if mid <= 0 or s[a] == 0 or s[b] == 0:
                continue   # a stopped rotor sheds nothing to beat with
            lock = np.exp(-((s[a] - s[b]) / (self.band * mid)) ** 2)
            loss[a] += lock
            loss[b] += lock
        mean = np.where(count > 0, loss / np.maximum(count, 1), 0.0)
        return t * (1.0 - self.depth * mean)


@dataclass(frozen=True)
class SharedPowerStage(HiddenEffect):
    """Fans wired in pairs to one dual ESC whose power stage limits the pair's summed thrust
    [N]: the pair's total saturates smoothly at ``cap`` and each fan keeps its share,

        S = T_a + T_b,   T_a' = T_a * cap * tanh(S / cap) / S.

    ``pairs``: fan names, two per entry. One fan of a pair running hard takes thrust from the
    other; a fan alone on its stage is unaffected."""

    pairs: tuple = (('LM1', 'HM1'), ('LM2', 'HM2'), ('LM3', 'HM3'))
    cap: float = 6.0
    name: ClassVar[str] = 'shared_power_stage'
    priority: ClassVar[int] = 1
    bounds: ClassVar = {'cap': (0.5, 100.0)}

    def _indices(self, geometry) -> list[tuple[int, int]]:
        out = []
        for pair in self.pairs:
            try:
                a, b = (geometry.fans.index(n) for n in pair)
            except Exception as exc:
                raise EffectError(f'SharedPowerStage: {exc}') from None
            if a == b:
                raise EffectError(f'SharedPowerStage: a pair needs two different fans, got {pair}')
            out.append((a, b))
        return out

    def validate(self, geometry):
        self._indices(geometry)

    def thrust(self, t, geometry):
        t = np.maximum(np.asarray(t, float), 0.0).copy()
        for a, b in self._indices(geometry):
            total = t[a] + t[b]
            if total > 0:
                keep = self.cap * np.tanh(total / self.cap) / total
                t[a] *= keep
                t[b] *= keep
        return t


@dataclass(frozen=True)
class DeckFlex(HiddenEffect):
    """The fan deck bends under the fans' total thrust like a plate held at its rim, so the ring
    fans tilt toward the axis and their jets land nearer it by

        shift = flex * r_hub * sum_j T_j / (sum_j T_j + thrust_ref)

    (r_hub the hub's distance from the axis [m]); the axis fan does not move. The landing
    points follow the total load, which a prior's fixed per-fan landing points cannot."""

    flex: float = 0.25
    thrust_ref: float = 25.0
    name: ClassVar[str] = 'deck_flex'
    priority: ClassVar[float] = 0.6
    bounds: ClassVar = {'flex': (0.0, 0.8), 'thrust_ref': (0.5, 500.0)}

    def sources(self, groups, thrust, geometry):
        if self.flex == 0:
            return groups
        on = np.asarray(geometry.fans.enabled, bool)
        total = float(np.sum(np.maximum(np.asarray(thrust, float), 0.0)[on]))
        pull = self.flex * total / (total + self.thrust_ref)
        hubs = np.asarray(geometry.fans.positions, float)
        for g in groups:
            ok = np.flatnonzero(g.fan >= 0)
            if not len(ok):
                continue
            g.centres = np.asarray(g.centres, float).copy()
            g.centres[ok] -= pull * hubs[g.fan[ok]]
        return groups


register_effects(RotorBeat, SharedPowerStage, DeckFlex)
