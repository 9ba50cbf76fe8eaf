"""Three effects written on 2026-12-04 (the tenth set) apart from the simulator's own and from
the earlier written sets, to test the shaping on physics neither the prior nor its corrections
were tuned on: ESCs calibrated to different endpoints, a slow fan robbed of its inflow by a
faster neighbour, and a strong central jet that domes the flow outward."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.core.geometry import neighbour_pairs
from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect


@dataclass(frozen=True)
class EscEndpointSpread(HiddenEffect):
    """Each ESC was calibrated on its own: fan j starts to turn at ``lo_j`` and reaches full
    speed at ``hi_j`` of the PWM range, lo_j drawn in [0, spread] and 1 - hi_j in
    [0, spread / 2] (``seed`` fixes the draw), so

        U_eff,j = clip((U_j - lo_j) / (hi_j - lo_j), 0, 1).

    A fan's curve is then shifted along the command as well as scaled: a per-fan gain absorbs
    the scale, not the offset, which matters most where a fan runs slowly."""

    spread: float = 0.08
    seed: int = 0
    name: ClassVar[str] = 'esc_endpoint_spread'
    priority: ClassVar[float] = 0.5
    bounds: ClassVar = {'spread': (0.0, 0.3), 'seed': (0, 2 ** 31 - 1)}

    def endpoints(self, n_fans: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(self.seed)
        lo = rng.uniform(0.0, self.spread, n_fans)
        hi = 1.0 - rng.uniform(0.0, 0.5 * self.spread, n_fans)
        return lo, hi

    def command(self, u, geometry):
        lo, hi = self.endpoints(len(u))
        return np.clip((np.asarray(u, float) - lo) / (hi - lo), 0.0, 1.0)


@dataclass(frozen=True)
class InflowTheft(HiddenEffect):
    """A fan slower than its neighbours (hubs within ``reach`` times the closest spacing) loses
    inflow to them: the faster rotor's lower inlet pressure draws the air the slow one would
    take,

        T_j' = T_j * max(0, 1 - theft * mean_{k near j} max(0, T_k - T_j) / thrust_ref).

    Run level, no fan loses anything; the loss follows the differences between neighbours, so
    a fan's gain depends on what the others do and a per-fan or load correction cannot hold it."""

    theft: float = 0.4
    thrust_ref: float = 4.0
    reach: float = 1.2
    name: ClassVar[str] = 'inflow_theft'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'theft': (0.0, 2.0), 'thrust_ref': (0.1, 100.0), 'reach': (1.0, 3.0)}

    def thrust(self, t, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        pairs = on[neighbour_pairs(np.asarray(geometry.fans.positions)[on], self.reach)]
        if len(pairs) == 0 or self.theft == 0:
            return t
        t = np.maximum(np.asarray(t, float), 0.0)
        lost = np.zeros(len(t))
        count = np.zeros(len(t))
        for a, b in pairs:
            lost[a] += max(0.0, t[b] - t[a])
            lost[b] += max(0.0, t[a] - t[b])
            count[a] += 1
            count[b] += 1
        mean_lost = np.where(count > 0, lost / np.maximum(count, 1), 0.0)
        return t * np.maximum(0.0, 1.0 - self.theft * mean_lost / self.thrust_ref)


@dataclass(frozen=True)
class CentreJetDome(HiddenEffect):
    """A strong central jet domes the flow outward: its dynamic pressure pushes what the jets
    carry away from the axis, most near the axis and fading over ``extent`` [m]. The field at a
    point p is the jets' field at

        p * (1 - push * x * exp(-(|p| / extent)^2)),   x = T_c / (T_c + thrust_ref),

    T_c the central fan's thrust [N]: near the axis the jets' pattern appears stretched
    outward by up to ``push`` (a fraction). With the central fan idle the field is as built."""

    push: float = 0.3
    extent: float = 0.2
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'centre_jet_dome'
    priority: ClassVar[float] = 0.5
    bounds: ClassVar = {'push': (0.0, 0.9), 'extent': (0.02, 1.0), 'thrust_ref': (0.1, 100.0)}

    def warp(self, points, thrust, geometry):
        pos = np.asarray(geometry.fans.positions, float)
        central = np.flatnonzero((np.hypot(pos[:, 0], pos[:, 1]) < 0.05) & np.asarray(geometry.fans.enabled))
        if self.push == 0 or not len(central):
            return points
        t_c = max(0.0, float(np.asarray(thrust, float)[central[0]]))
        x = t_c / (t_c + self.thrust_ref)
        r2 = np.sum(np.asarray(points, float) ** 2, axis=1)
        shrink = 1.0 - self.push * x * np.exp(-r2 / self.extent ** 2)
        return np.asarray(points, float) * shrink[:, None]


register_effects(EscEndpointSpread, InflowTheft, CentreJetDome)
