"""Three effects written on 2026-12-02, after the field estimate's position lag and the bias
between iterations landed, apart from the simulator's own and from the earlier written sets: to
test the shaping on physics neither the prior nor its corrections were tuned on."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect
from wind_shaper.sim.physics import FlatTop, JetGroup


@dataclass(frozen=True)
class OwnSwirlDrift(HiddenEffect):
    """Each fan's own swirl carries its jet sideways as it speeds up: fan j's jet lands moved
    along the circle about the tunnel's axis by

        drift * T_j / (T_j + thrust_ref)   [m],

    counter-clockwise for the 'higher' fans and clockwise for the others (their rotors turn
    the other way), T_j its own thrust [N]; the central jet, on the axis, does not move. The
    library's swirl turns the whole field with the balance of all fans; here every jet moves on
    its own, by its own speed."""

    drift: float = 0.03
    thrust_ref: float = 3.0
    name: ClassVar[str] = 'own_swirl_drift'
    priority: ClassVar[float] = 0.6
    bounds: ClassVar = {'drift': (-0.1, 0.1), 'thrust_ref': (0.1, 100.0)}

    def sources(self, groups, thrust, geometry):
        if self.drift == 0:
            return groups
        spin = np.where(np.array(geometry.fans.groups) == 'higher', 1.0, -1.0)
        t = np.maximum(np.asarray(thrust, float), 0.0)
        for g in groups:
            ok = np.flatnonzero(g.fan >= 0)
            if not len(ok):
                continue
            c = g.centres[ok]
            r = np.hypot(c[:, 0], c[:, 1])
            fans = g.fan[ok]
            arc = self.drift * t[fans] / (t[fans] + self.thrust_ref) * spin[fans]
            turn = np.where(r > 0.05, arc / np.maximum(r, 0.05), 0.0)   # [rad]; the axis stays
            cos, sin = np.cos(turn), np.sin(turn)
            g.centres = g.centres.copy()
            g.centres[ok] = np.column_stack([cos * c[:, 0] - sin * c[:, 1], sin * c[:, 0] + cos * c[:, 1]])
        return groups


@dataclass(frozen=True)
class ContractionCore(HiddenEffect):
    """The contraction above the fans builds a broad core of fast air on the axis that grows
    with the square of the total flow: extra density

        gain * (sum_j T_j)^2 / thrust_ref   [N]   at the peak,

    a Gaussian of width ``width`` [m] about the axis. Twice the fans give four times the core,
    which a sum of the fans' own footprints (and a share spread evenly with their total)
    cannot give."""

    gain: float = 0.02
    thrust_ref: float = 20.0
    width: float = 0.25
    name: ClassVar[str] = 'contraction_core'
    priority: ClassVar[int] = 1
    bounds: ClassVar = {'gain': (0.0, 1.0), 'thrust_ref': (0.1, 1000.0), 'width': (0.05, 1.0)}

    def sources(self, groups, thrust, geometry):
        total = float(np.sum(np.maximum(np.asarray(thrust, float), 0.0)))
        if self.gain == 0 or total == 0:
            return groups
        amp = np.array([self.gain * total ** 2 / self.thrust_ref])
        return groups + [JetGroup(FlatTop(2.0), np.zeros((1, 2)), amp, np.array([self.width]),
                                  np.array([-1]))]


@dataclass(frozen=True)
class EscKink(HiddenEffect):
    """Each ESC maps the command with two slopes (an endpoint calibration done at one throttle
    and a second at another): up to ``knee`` the command is passed on, above it at a slope of
    1 + k_j, k_j a seeded draw within +-``spread`` per fan:

        U_eff = U + k_j * max(U - knee, 0),   clipped to [0, 1].

    A power curve bends a fan's thrust everywhere; this one has a corner, and differs between
    fans only above it."""

    knee: float = 0.35
    spread: float = 0.4
    seed: int = 0
    name: ClassVar[str] = 'esc_kink'
    bounds: ClassVar = {'knee': (0.05, 0.95), 'spread': (0.0, 1.0)}

    def slopes(self, n: int) -> np.ndarray:
        """k_j per fan (n,)."""
        return self.spread * np.random.default_rng([int(self.seed), 0xE5C]).uniform(-1.0, 1.0, n)

    def command(self, u, geometry):
        u = np.asarray(u, float)
        k = self.slopes(u.shape[-1])
        return np.clip(u + k * np.maximum(u - self.knee, 0.0), 0.0, 1.0)


register_effects(OwnSwirlDrift, ContractionCore, EscKink)
