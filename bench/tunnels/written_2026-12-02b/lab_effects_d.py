"""Three effects written on 2026-12-02 apart from the simulator's own and from the earlier
written sets, after off_margin became a default, to test the shaping on physics neither the
prior nor its corrections were tuned on."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect


def _central(geometry):
    """Index of the enabled fan nearest the tunnel's axis, or None if there is none near it."""
    pos = np.asarray(geometry.fans.positions, float)
    on = np.flatnonzero(geometry.fans.enabled)
    if len(on) == 0:
        return None
    r = np.hypot(pos[on, 0], pos[on, 1])
    return int(on[np.argmin(r)]) if r.min() < 0.05 else None


@dataclass(frozen=True)
class FrameYaw(HiddenEffect):
    """The motion-capture frame is turned about the tunnel's axis by ``angle`` [deg] against
    the frame the fans were surveyed in (a calibration wand laid a few degrees off): every
    position the plate reports is the true one turned by -angle, so the whole field appears
    turned by -angle. A shift of the field is fitted at commissioning; a turn is not, and it
    moves an edge fan's footprint sideways by its radius times the angle."""

    angle: float = 6.0
    name: ClassVar[str] = 'frame_yaw'
    priority: ClassVar[int] = 3
    bounds: ClassVar = {'angle': (-30.0, 30.0)}

    def warp(self, points, thrust, geometry):
        a = np.radians(self.angle)
        c, s = np.cos(a), np.sin(a)
        x, y = points[:, 0], points[:, 1]
        return np.column_stack([c * x - s * y, s * x + c * y])


@dataclass(frozen=True)
class ThrustFoldback(HiddenEffect):
    """Past a knee each fan's thrust folds back (blades that flutter and stall at high speed,
    an ESC's thermal foldback): above fan j's knee K_j [N]

        T_j = K_j + d - fold * d^2 / K_j,      d = T_j - K_j,

    which peaks at d = K_j / (2 fold) and falls after it; below the knee nothing changes. The
    knees spread by +-``spread`` about ``knee`` (a seeded draw per fan), so the curves differ
    only at the top, where the commissioning's sweeps seldom go."""

    knee: float = 4.0
    fold: float = 0.8
    spread: float = 0.2
    seed: int = 0
    name: ClassVar[str] = 'thrust_foldback'
    bounds: ClassVar = {'knee': (0.5, 50.0), 'fold': (0.0, 5.0), 'spread': (0.0, 0.5)}

    def thrust(self, t, geometry):
        rng = np.random.default_rng([int(self.seed), 0xF01D])
        knees = self.knee * (1.0 + self.spread * rng.uniform(-1.0, 1.0, len(t)))
        d = np.maximum(np.asarray(t, float) - knees, 0.0)
        return np.where(d > 0, knees + d - self.fold * d ** 2 / knees, t)


@dataclass(frozen=True)
class CentralEntrainment(HiddenEffect):
    """The central jet entrains the air the edge jets carry: each edge jet's peak falls by

        loss * T_c / (T_c + T_j + thrust_ref)

    of itself (T_c the central fan's thrust, T_j the edge fan's [N]), so the central fan weakens
    its neighbours the harder it runs and the weaker they are; the momentum goes into mixing
    (not into the field). Unlike a starved inlet it acts on the jets, not the thrusts, and only
    from the centre out."""

    loss: float = 0.3
    thrust_ref: float = 1.0
    name: ClassVar[str] = 'central_entrainment'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'loss': (0.0, 0.9), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        centre = _central(geometry)
        if centre is None or self.loss == 0:
            return groups
        t = np.maximum(np.asarray(thrust, float), 0.0)
        tc = t[centre]
        for g in groups:
            edge = (g.fan >= 0) & (g.fan != centre)
            tj = t[g.fan[edge]]
            g.amplitude[edge] = g.amplitude[edge] * (1.0 - self.loss * tc / (tc + tj + self.thrust_ref))
        return groups


register_effects(FrameYaw, ThrustFoldback, CentralEntrainment)
