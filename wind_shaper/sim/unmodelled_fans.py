"""Unmodelled effects on the fans' drive: commands and thrusts that depend on other fans or
follow a curve of their own, where the prior gives every fan its own fixed curve.

``PlenumStarvation`` (one inlet for all fans), ``EscCrosstalk`` (one fan's ESC hears another's
signal), ``NeighbourStarvation`` (neighbouring fans share their inflow) and ``UnequalCurves``
(a throttle curve per fan: a plant variation for benchmarks). Registered, with the others, by
``wind_shaper.sim.unmodelled_effects``.

Thrusts [N], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import neighbour_pairs
from .effects import HiddenEffect
from .errors import EffectError

__all__ = ['PlenumStarvation', 'UnequalCurves', 'EscCrosstalk', 'NeighbourStarvation']


@dataclass(frozen=True)
class PlenumStarvation(HiddenEffect):
    """All fans draw from one inlet plenum whose pressure drop grows with the total flow: each
    fan runs at the effective command

        U_eff,j = U_j / (1 + coupling * mean_k U_k),

    so a fan's thrust depends on what the others do. No family couples fans: a per-fan gain or
    curve fitted to it changes with the total command from sweep to sweep."""

    coupling: float = 0.6
    name: ClassVar[str] = 'plenum_starvation'
    priority: ClassVar[int] = 2  # after an ESC dead band: the plenum limits what the motor drives
    bounds: ClassVar = {'coupling': (0.0, 3.0)}

    def command(self, u, geometry):
        enabled = geometry.fans.enabled
        mean = float(np.mean(u[enabled])) if enabled.any() else 0.0
        return u / (1.0 + self.coupling * max(mean, 0.0))


@dataclass(frozen=True)
class UnequalCurves(HiddenEffect):
    """Every fan's ESC maps the command through its own throttle curve: fan j runs at
    U_j ** p_j, with p_j = exp(``spread`` x z_j) and z_j standard normal draws of ``seed``
    (clipped to +-2). At 50 % command a fan with p = 1.35 gives the thrust of 39 %, one with
    p = 0.75 that of 59 %. The prior's calibration fits one curve per fan group, so the per-fan
    shapes are model error the shaping loop must absorb. Used by the convergence benchmark as a
    plant whose fans differ; the workbench is not yet tested on it."""

    spread: float = 0.3
    seed: int = 11
    name: ClassVar[str] = 'unequal_curves'
    bounds: ClassVar = {'spread': (0.0, 1.0)}
    priority: ClassVar[int] = -1   # the throttle curve first, then a dead band acts on its output

    def exponents(self, n_fans: int) -> np.ndarray:
        z = np.clip(np.random.default_rng(int(self.seed)).standard_normal(n_fans), -2.0, 2.0)
        return np.exp(self.spread * z)

    def command(self, u, geometry):
        u = np.clip(np.asarray(u, dtype=float), 0.0, None)
        return u ** self.exponents(len(u))


@dataclass(frozen=True)
class EscCrosstalk(HiddenEffect):
    """Fan ``fan``'s ESC picks up part of fan ``source``'s PWM signal (a shared ground, cables
    bundled together): it runs at

        U_eff = min(U_fan + coupling * U_source, 1).

    Its thrust then depends on another fan's command; a gain of ``fan`` fitted to it changes
    with the ratio of the two commands from sweep to sweep."""

    fan: str = 'LM1'
    source: str = 'HM1'
    coupling: float = 0.25
    name: ClassVar[str] = 'esc_crosstalk'
    priority: ClassVar[int] = -2  # at the signal, before a throttle curve or a dead band
    bounds: ClassVar = {'coupling': (0.0, 1.0)}

    def validate(self, geometry):
        self._indices(geometry)

    def _indices(self, geometry) -> tuple[int, int]:
        try:
            return geometry.fans.index(self.fan), geometry.fans.index(self.source)
        except ConfigError as exc:
            raise EffectError(f'EscCrosstalk: {exc}') from None

    def command(self, u, geometry):
        j, k = self._indices(geometry)
        u = np.asarray(u, dtype=float).copy()
        u[j] = min(u[j] + self.coupling * max(u[k], 0.0), 1.0)
        return u


@dataclass(frozen=True)
class NeighbourStarvation(HiddenEffect):
    """Fans mounted close together draw their inflow from the same air: a fan's thrust falls
    with what its neighbours (hubs within ``reach`` times the closest hub spacing) deliver,

        T_j' = T_j / (1 + coupling * mean_{k near j} T_k / thrust_ref).

    Unlike a starved plenum it is local (a fan beside two idle neighbours runs free whatever
    the rest do), and unlike an ESC's crosstalk every fan is coupled to several others."""

    coupling: float = 0.3
    thrust_ref: float = 4.0
    reach: float = 1.2
    name: ClassVar[str] = 'neighbour_starvation'
    priority: ClassVar[int] = 2
    bounds: ClassVar = {'coupling': (0.0, 3.0), 'thrust_ref': (0.1, 100.0), 'reach': (1.0, 3.0)}

    def thrust(self, t, geometry):
        on = np.flatnonzero(geometry.fans.enabled)
        pairs = on[neighbour_pairs(np.asarray(geometry.fans.positions)[on], self.reach)]
        if len(pairs) == 0 or self.coupling == 0:
            return t
        near = np.zeros((len(t), len(t)), bool)
        near[pairs[:, 0], pairs[:, 1]] = near[pairs[:, 1], pairs[:, 0]] = True
        count = near.sum(axis=1)
        mean = np.where(count > 0, (near * np.maximum(t, 0.0)[None, :]).sum(axis=1) / np.maximum(count, 1), 0.0)
        return t / (1.0 + self.coupling * mean / self.thrust_ref)
