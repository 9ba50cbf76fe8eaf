"""PWM update rules. Commands are fractions 0..1 of full PWM, one per fan.

``PaperUpdate`` is Algorithm 1 of the paper: U_{k+1} = clip(U_k + lambda_k pinv(J) Delta_k),
lambda_k = gain / (k + 1). Every rule keeps disabled fans at 0 and every command inside
[u_min, u_max]; nothing outside that range ever leaves a rule.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np

from ..core.errors import ConfigError


@dataclass(frozen=True)
class CommandBounds:
    """Feasible commands: u_min <= U <= u_max for enabled fans, 0 for disabled ones."""

    u_min: float = 0.0
    u_max: float = 0.65

    def __post_init__(self):
        if not (0.0 <= self.u_min < self.u_max <= 1.0):
            raise ConfigError(f'command bounds need 0 <= u_min < u_max <= 1; got '
                              f'u_min={self.u_min}, u_max={self.u_max}')

    def project(self, U: np.ndarray, enabled: np.ndarray) -> np.ndarray:
        """Clip into the bounds and zero the disabled fans; NaN is refused, never passed on."""
        U = np.asarray(U, dtype=float)
        if not np.all(np.isfinite(U)):
            raise ConfigError(f'commands contain NaN or inf: {U.tolist()}')
        return np.where(enabled, np.clip(U, self.u_min, self.u_max), 0.0)


@dataclass(frozen=True)
class PastIteration:
    """An earlier iteration as a rule may use it: U (n_fans,) commands [fraction]; mean (N,)
    estimated force at the key points [N]; std (N,) its GP standard deviation [N] (or None);
    info: what the rule answered at that iteration (``UpdateStep.info``; empty if none)."""

    U: np.ndarray
    mean: np.ndarray
    std: np.ndarray | None = None
    info: Mapping = field(default_factory=dict)


@dataclass(frozen=True)
class UpdateInput:
    """What a rule sees at iteration k.

    U: (n_fans,) commands the sweep was measured at; delta: (N,) F_des - F_k at the key
    points [N]; jacobian: (N, n_fans) model dPhi/dU at U [N per unit PWM], or None for rules
    that do not need it (``needs_jacobian = False``); enabled: (n_fans,) mask; std: (N,) GP
    standard deviation [N] (rules may weight by it).

    Optional, for rules that learn from the run (``PaperUpdate`` ignores them): model: the
    prior ``Term``; key_points: (N, 2) [m]; target: (N,) F_des [N]; history: the earlier
    iterations of this run, oldest first (``PastIteration``); prior_maps: field maps of this
    tunnel measured when the prior was commissioned (``PastIteration``, at the same key points):
    data for the rule's corrections of the prior, never a point to step from.
    """

    k: int
    U: np.ndarray
    delta: np.ndarray
    jacobian: np.ndarray | None
    enabled: np.ndarray
    std: np.ndarray | None = None
    model: Any = None
    key_points: np.ndarray | None = None
    target: np.ndarray | None = None
    history: tuple = ()
    prior_maps: tuple = ()


@dataclass(frozen=True)
class UpdateStep:
    """A rule's answer: the next commands, the step size used, and the raw (unbounded) step."""

    U_next: np.ndarray
    step_size: float
    raw_step: np.ndarray
    info: dict = field(default_factory=dict)


class UpdateRule(Protocol):
    bounds: CommandBounds

    def step(self, inp: UpdateInput) -> UpdateStep: ...


@dataclass(frozen=True)
class PaperUpdate:
    """The paper's Algorithm 1 update: pseudo-inverse Gauss-Newton step, decaying step size
    lambda_k = gain / (k + 1), then clipping into the bounds.

    rcond: singular values below rcond x the largest count as zero in the pseudo-inverse. A fan
    idling near PWM 0 has a nearly flat thrust curve, hence a nearly zero Jacobian column;
    inverting that tiny singular value throws the fan to full PWM, so the cut-off is 1e-3,
    not machine precision."""

    gain: float = 0.8
    bounds: CommandBounds = CommandBounds()
    rcond: float = 1e-3

    def __post_init__(self):
        if not self.gain > 0:
            raise ConfigError(f'step gain must be > 0, got {self.gain}')

    def step_size(self, k: int) -> float:
        return self.gain / (k + 1)

    def step(self, inp: UpdateInput) -> UpdateStep:
        on = np.asarray(inp.enabled, dtype=bool)
        raw = np.zeros_like(np.asarray(inp.U, dtype=float))
        if on.any():
            raw[on] = np.linalg.pinv(inp.jacobian[:, on], rcond=self.rcond) @ inp.delta
        lam = self.step_size(inp.k)
        U_next = self.bounds.project(inp.U + lam * raw, on)
        return UpdateStep(U_next, lam, raw)
