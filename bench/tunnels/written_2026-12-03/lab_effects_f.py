"""Two effects written on 2026-12-03, when the shaping started to bend one curve every fan
shares (``shared_curve_sd``), apart from the simulator's own and from the earlier written sets:
physics that looks like such a curve in some sweeps and is not one."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim import register_effects
from wind_shaper.sim.effects import HiddenEffect


@dataclass(frozen=True)
class MixedMakeDips(HiddenEffect):
    """The array was built from two makes of fan: the 'higher' fans stall at one command, the
    others (the 'lower' ring and the central fan) at another. Each fan runs at

        U_eff,j = U_j * (1 - d_j * exp(-((U_j - at_g) / width)^2)),

    at_g ``at_higher`` or ``at_others`` [PWM fraction] by the fan's group, d_j a seeded draw in
    [0.5, 1.5] x ``depth`` per fan. The library's stall dip sits at one command for every fan;
    here no single curve fits the array."""

    depth: float = 0.25
    at_higher: float = 0.38
    at_others: float = 0.58
    width: float = 0.05
    seed: int = 0
    name: ClassVar[str] = 'mixed_make_dips'
    priority: ClassVar[int] = 4
    bounds: ClassVar = {'depth': (0.0, 0.6), 'at_higher': (0.05, 0.95), 'at_others': (0.05, 0.95),
                        'width': (0.01, 0.5)}

    def depths(self, n: int) -> np.ndarray:
        """d_j per fan (n,)."""
        return self.depth * np.random.default_rng([int(self.seed), 0x2AE]).uniform(0.5, 1.5, n)

    def command(self, u, geometry):
        u = np.asarray(u, float)
        at = np.where(np.array(geometry.fans.groups) == 'higher', self.at_higher, self.at_others)
        return u * (1.0 - self.depths(u.shape[-1]) * np.exp(-((u - at) / self.width) ** 2))


@dataclass(frozen=True)
class FrameResonance(HiddenEffect):
    """The fans' frame has a resonance at the rotor speed of command ``at`` [PWM fraction]:
    every fan running near it shakes the frame, and the shaking costs every fan the same share
    of its speed,

        U_eff,j = U_j * (1 - loss * mean_i exp(-((U_i - at) / width)^2)).

    A level sweep at that command shows every fan weak, as a curve every fan shares would; but
    one fan at it costs the others too, and a fan far from it loses when the others sit there."""

    loss: float = 0.15
    at: float = 0.45
    width: float = 0.04
    name: ClassVar[str] = 'frame_resonance'
    priority: ClassVar[int] = 4
    bounds: ClassVar = {'loss': (0.0, 0.6), 'at': (0.05, 0.95), 'width': (0.01, 0.5)}

    def command(self, u, geometry):
        u = np.asarray(u, float)
        shaking = float(np.mean(np.exp(-((u - self.at) / self.width) ** 2)))
        return u * (1.0 - self.loss * shaking)


register_effects(MixedMakeDips, FrameResonance)
