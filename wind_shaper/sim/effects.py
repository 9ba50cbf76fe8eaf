"""Hidden effects: switchable physical hypotheses the simulated tunnel can carry.

Each effect is a small frozen dataclass: its parameters are set only in ``__init__`` and checked
against physical bounds (``bounds``); ``truth()`` returns the true parameter values (what a
diagnosis should recover) and ``spec()`` the config entry that rebuilds it. Any subset composes:
the plant applies every effect at each stage of its pipeline, in this order, whatever the order
of the list::

    command -> thrust -> sources (where and how jets land) -> warp (field coordinates)
            -> density = (sum of sources + offsets) * scales -> the plate's reading

and a sweep records each force with the positions ``recorded`` gives (the true path by default).

Within a stage effects run by ``priority`` (lower first): effects that move or reshape jets run
before effects that add sources between them (``JetInteraction`` uses where jets really land).

so calibration, sweeps and ``true_field`` all see the same physics. Hooks receive the tunnel
geometry; positions [m, tunnel frame], thrusts and densities [N], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import ClassVar, Mapping

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import TunnelGeometry, neighbour_pairs
from .errors import EffectError
from .physics import FlatTop, JetGroup

__all__ = ['HiddenEffect', 'WeakFan', 'Swirl', 'WallBoundaryLayer', 'JetInteraction', 'DeadBand',
           'TiltedFan', 'ElongatedFootprint', 'BackgroundDraft', 'HIDDEN_EFFECTS', 'make_effect',
           'effects_from_config']


@dataclass(frozen=True)
class HiddenEffect:
    """Base class: every hook is the identity. Subclasses override the hooks they need."""

    name: ClassVar[str] = ''
    #: order within a pipeline stage (lower first); see the module docstring.
    priority: ClassVar[int] = 0
    #: parameter -> (low, high) inclusive physical bounds; a scalar check for every number.
    bounds: ClassVar[Mapping[str, tuple[float, float]]] = {}

    def __post_init__(self):
        for key, (lo, hi) in self.bounds.items():
            value = getattr(self, key)
            if not (np.isfinite(value) and lo <= value <= hi):
                raise EffectError(f'{type(self).__name__}.{key} = {value!r} is outside its '
                                  f'physical bounds [{lo}, {hi}]; choose a value inside them')

    # -- what the diagnosis should recover -------------------------------------------------------
    def truth(self) -> dict:
        """The true parameter values, e.g. ``{'fan': 'HM2', 'gain': 0.8}``."""
        return asdict(self)

    def spec(self) -> dict:
        """The config entry that rebuilds this effect: ``{'name': ..., **truth()}``."""
        return {'name': self.name, **self.truth()}

    # -- pipeline hooks ----------------------------------------------------------------------------
    def validate(self, geometry: TunnelGeometry) -> None:
        """Raise EffectError if the effect cannot apply to this tunnel (e.g. unknown fan)."""

    def command(self, u: np.ndarray, geometry: TunnelGeometry) -> np.ndarray:
        """Applied PWM (n_fans,) -> the PWM the motors effectively run at."""
        return u

    def thrust(self, t: np.ndarray, geometry: TunnelGeometry) -> np.ndarray:
        """Per-fan thrust (n_fans,) [N] -> modified thrust."""
        return t

    def sources(self, groups: list[JetGroup], thrust: np.ndarray,
                geometry: TunnelGeometry) -> list[JetGroup]:
        """The jets (freshly built per command; may be edited in place) -> jets to evaluate."""
        return groups

    def warp(self, points: np.ndarray, thrust: np.ndarray, geometry: TunnelGeometry) -> np.ndarray:
        """Points (P, 2) [m] -> the points at which the un-warped jets are evaluated."""
        return points

    def offset(self, points: np.ndarray, geometry: TunnelGeometry):
        """Density added to the jets at points (P, 2) [N]; scalar or (P,)."""
        return 0.0

    def scale(self, points: np.ndarray, geometry: TunnelGeometry):
        """Factor multiplying the whole density at points (P, 2); scalar or (P,)."""
        return 1.0

    def reading(self, force: np.ndarray, geometry: TunnelGeometry) -> np.ndarray:
        """The plate's force (K,) [N] from the flow it sits in -> the force it takes up (the
        plate's own drag law; the identity for a plate whose drag follows the local force)."""
        return force

    def running(self, previous: np.ndarray, commanded: np.ndarray, since: np.ndarray):
        """The commands (K, n_fans) the fans run at ``since`` (K,) [s] after the command changed
        from ``previous`` to ``commanded`` (n_fans,) [fraction], or None when they follow it at
        once (the default). Sweeps only: a fault of the recording (see ``unmodelled_sensing``)."""
        return None

    def sensor_zero(self, clock: np.ndarray):
        """The force sensor's zero [N] (scalar or (K,)) at recording times ``clock`` (K,) [s]
        (the plant's clock: the sweeps' plate time laid end to end), added to every recorded
        force; 0 for a sensor whose zero holds. Sweeps only (see ``unmodelled_sensing``)."""
        return 0.0

    def recorded(self, positions: np.ndarray, dt: float) -> np.ndarray:
        """A sweep's true plate positions (n, 2) [m], sampled every ``dt`` [s] -> the positions
        the recording pairs with each force sample (motion capture and force sensor out of
        step); the identity when they are in step."""
        return positions

    # -- helpers ---------------------------------------------------------------------------------
    def _fan_index(self, geometry: TunnelGeometry) -> int:
        try:
            return geometry.fans.index(self.fan)
        except ConfigError as exc:
            raise EffectError(f'{type(self).__name__}: {exc}') from None


def fan_landings(groups, n_fans: int) -> tuple[np.ndarray, np.ndarray]:
    """Where each fan's jet lands (n_fans, 2) [m] and its width (n_fans,) [m], read from the
    jet groups (a fan with no source: at the origin, width 1)."""
    centre, width = np.zeros((n_fans, 2)), np.ones(n_fans)
    for g in groups:
        ok = g.fan >= 0
        centre[g.fan[ok]], width[g.fan[ok]] = g.centres[ok], g.width[ok]
    return centre, width


def _fan_rows(groups, fan):
    return [(g, g.index_of(fan)) for g in groups if len(g.index_of(fan))]


@dataclass(frozen=True)
class WeakFan(HiddenEffect):
    """One fan delivers only ``gain`` (0..1) of its nominal thrust: a worn or chipped
    propeller, or a tired ESC/motor. Its whole footprint scales by ``gain``; its shape does not
    change. Detect: the force right over that fan falls short by the factor ``gain``."""

    fan: str = 'HM2'
    gain: float = 0.8
    name: ClassVar[str] = 'weak_fan'
    bounds: ClassVar = {'gain': (0.0, 1.0)}

    def validate(self, geometry):
        self._fan_index(geometry)

    def thrust(self, t, geometry):
        t = t.copy()
        t[self._fan_index(geometry)] *= self.gain
        return t


@dataclass(frozen=True)
class Swirl(HiddenEffect):
    """Residual swirl the honeycomb does not remove: when CW and CCW thrusts are unbalanced
    the net angular momentum turns the whole field about the tunnel axis by

        theta = gain * (sum T_ccw - sum T_cw) / sum T   [rad, counter-clockwise seen from above]

    (thrusts T [N] after command and thrust effects). Balanced fans give no rotation; a lone
    CCW fan rotates its footprint by ``gain`` rad about the axis."""

    gain: float = 0.5
    name: ClassVar[str] = 'swirl'
    bounds: ClassVar = {'gain': (-1.5, 1.5)}

    def angle(self, thrust: np.ndarray, geometry: TunnelGeometry) -> float:
        """Rotation [rad, CCW] for per-fan thrusts (n_fans,) [N]."""
        total = float(np.sum(thrust))
        if total <= 0:
            return 0.0
        return self.gain * float(np.dot(geometry.fans.spin_sign, thrust)) / total

    def warp(self, points, thrust, geometry):
        theta = self.angle(thrust, geometry)
        c, s = np.cos(theta), np.sin(theta)
        # The rotated field at p is the un-rotated field at R(-theta) p.
        return np.column_stack([c * points[:, 0] + s * points[:, 1],
                                -s * points[:, 0] + c * points[:, 1]])


@dataclass(frozen=True)
class WallBoundaryLayer(HiddenEffect):
    """The flow slows near the tunnel wall (viscous boundary layer of ``thickness`` delta [m]):
    the density is multiplied by 1 - exp(-(R_wall - r)/delta), and is 0 outside the wall.
    r is the distance from the axis for a round wall, max(|x|, |y|) for a square one; shape
    None takes ``geometry.extra['wall_shape']`` (default round). Detect: a deficit that grows
    towards the wall, independent of which fan is near."""

    thickness: float = 0.06
    shape: str | None = None
    name: ClassVar[str] = 'wall_boundary_layer'
    bounds: ClassVar = {'thickness': (1e-3, 0.5)}

    def __post_init__(self):
        super().__post_init__()
        if self.shape not in (None, 'round', 'square'):
            raise EffectError(f'WallBoundaryLayer.shape must be round, square or None; got {self.shape!r}')

    def scale(self, points, geometry):
        shape = self.shape or geometry.extra.get('wall_shape', 'round')
        if shape == 'square':
            r = np.max(np.abs(points), axis=1)
        else:
            r = np.hypot(points[:, 0], points[:, 1])
        gap = geometry.wall_radius - r
        return np.where(gap > 0, -np.expm1(-np.maximum(gap, 0.0) / self.thickness), 0.0)


@dataclass(frozen=True)
class JetInteraction(HiddenEffect):
    """Neighbouring jets entrain each other and fill the gap between them: extra density

        kappa * sum_{neighbour pairs} sqrt(T_i T_j) exp(-|p - m_ij|^2 / w_ij^2)   [N]

    at the midpoints m_ij of where the two jets land, w_ij the mean of their widths (or
    ``width`` [m] if given). Neighbours: nominal hubs closer than ``reach`` x the nearest hub
    spacing. Detect: excess force between fans, growing with both fans' thrust."""

    strength: float = 0.3
    reach: float = 1.2
    width: float | None = None
    name: ClassVar[str] = 'jet_interaction'
    priority: ClassVar[int] = 1
    bounds: ClassVar = {'strength': (0.0, 2.0), 'reach': (1.0, 2.0)}

    def __post_init__(self):
        super().__post_init__()
        if self.width is not None and not (0.01 <= self.width <= 1.0):
            raise EffectError(f'JetInteraction.width must be in [0.01, 1] m or None; got {self.width}')

    def pairs(self, geometry: TunnelGeometry) -> np.ndarray:
        """(n_pairs, 2) fan indices of neighbouring hubs."""
        return neighbour_pairs(geometry.fans.positions, self.reach)

    def sources(self, groups, thrust, geometry):
        pairs = self.pairs(geometry)
        if self.strength == 0 or len(pairs) == 0:
            return groups
        centre, width = fan_landings(groups, geometry.fans.n_fans)
        i, j = pairs[:, 0], pairs[:, 1]
        w = np.full(len(pairs), self.width) if self.width else 0.5 * (width[i] + width[j])
        amp = self.strength * np.sqrt(np.maximum(thrust[i], 0) * np.maximum(thrust[j], 0))
        return groups + [JetGroup(FlatTop(2.0), 0.5 * (centre[i] + centre[j]), amp, w,
                                  np.full(len(pairs), -1))]


@dataclass(frozen=True)
class DeadBand(HiddenEffect):
    """ESC dead band and saturation: the effective command is 0 below ``threshold``, rises
    linearly from 0 at the threshold to ``saturation`` at ``saturation``, and stays flat above:

        U_eff = saturation * clip((U - threshold) / (saturation - threshold), 0, 1)

    Detect: no force at all for small commands, no gain in force above saturation."""

    threshold: float = 0.12
    saturation: float = 0.75
    name: ClassVar[str] = 'dead_band'
    bounds: ClassVar = {'threshold': (0.0, 0.5), 'saturation': (0.2, 1.0)}

    def __post_init__(self):
        super().__post_init__()
        if not self.saturation > self.threshold + 0.05:
            raise EffectError(f'DeadBand needs saturation > threshold + 0.05; got threshold '
                              f'{self.threshold}, saturation {self.saturation}')

    def command(self, u, geometry):
        span = self.saturation - self.threshold
        return self.saturation * np.clip((u - self.threshold) / span, 0.0, 1.0)


@dataclass(frozen=True)
class TiltedFan(HiddenEffect):
    """A mis-mounted (tilted) fan whose jet lands displaced by ``shift`` (dx, dy) [m] from its
    hub; its thrust and shape are unchanged. Detect: that fan's footprint peak is off its hub."""

    fan: str = 'LM2'
    shift: tuple[float, float] = (0.04, 0.0)
    name: ClassVar[str] = 'tilted_fan'
    bounds: ClassVar = {}

    def __post_init__(self):
        shift = tuple(float(v) for v in np.ravel(self.shift))
        if len(shift) != 2 or not np.all(np.isfinite(shift)) or np.hypot(*shift) > 0.15:
            raise EffectError(f'TiltedFan.shift must be (dx, dy) [m] with length <= 0.15; got {self.shift!r}')
        object.__setattr__(self, 'shift', shift)

    def validate(self, geometry):
        self._fan_index(geometry)

    def sources(self, groups, thrust, geometry):
        for g, rows in _fan_rows(groups, self._fan_index(geometry)):
            g.centres = g.centres.copy()
            g.centres[rows] += np.asarray(self.shift)
        return groups


@dataclass(frozen=True)
class ElongatedFootprint(HiddenEffect):
    """A fan whose jet spreads unevenly (bent guide vane, tilted mount): its footprint is
    stretched by sqrt(``ratio``) along the direction ``angle`` [rad from +x, CCW] and squeezed
    by 1/sqrt(ratio) across it, so the area, peak and total force stay the same. Detect: an
    elliptical footprint over that fan."""

    fan: str = 'LM2'
    ratio: float = 1.6
    angle: float = 0.0
    name: ClassVar[str] = 'elongated_footprint'
    bounds: ClassVar = {'ratio': (1.0, 4.0), 'angle': (-np.pi, np.pi)}

    def validate(self, geometry):
        self._fan_index(geometry)

    def metric(self) -> np.ndarray:
        """A = R diag(1/ratio, ratio) R^T: s = d^T A d / w^2."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        rot = np.array([[c, -s], [s, c]])
        return rot @ np.diag([1.0 / self.ratio, self.ratio]) @ rot.T

    def sources(self, groups, thrust, geometry):
        fan, out = self._fan_index(geometry), []
        for g in groups:
            rows = g.index_of(fan)
            if len(rows) == 0:
                out.append(g)
                continue
            rest, own = g.split(rows)
            out += [rest, own.stretched(self.metric(), np.sqrt(self.ratio))]
        return out


@dataclass(frozen=True)
class BackgroundDraft(HiddenEffect):
    """A constant ambient updraft (room ventilation, building stack effect) adds ``force`` [N]
    to the plate everywhere inside the tunnel, whatever the fans do. Detect: a uniform offset,
    present even with every fan off."""

    force: float = 0.3
    name: ClassVar[str] = 'background_draft'
    bounds: ClassVar = {'force': (-1.0, 3.0)}

    def offset(self, points, geometry):
        return self.force


#: Registry: config name -> effect class.
HIDDEN_EFFECTS: dict[str, type[HiddenEffect]] = {
    cls.name: cls for cls in (WeakFan, Swirl, WallBoundaryLayer, JetInteraction, DeadBand,
                              TiltedFan, ElongatedFootprint, BackgroundDraft)}


def register_effects(*classes: type[HiddenEffect]) -> None:
    """Add effect classes to ``HIDDEN_EFFECTS`` under their config names (a name already taken
    by another class is an EffectError)."""
    for cls in classes:
        if cls.name in HIDDEN_EFFECTS and HIDDEN_EFFECTS[cls.name] is not cls:
            raise EffectError(f'hidden effect name {cls.name!r} is taken')
        HIDDEN_EFFECTS[cls.name] = cls


def make_effect(name: str, **params) -> HiddenEffect:
    """Build a hidden effect by registry name (``weak_fan``) or class name (``WeakFan``)."""
    by_class = {cls.__name__: cls for cls in HIDDEN_EFFECTS.values()}
    cls = HIDDEN_EFFECTS.get(name) or by_class.get(name)
    if cls is None:
        raise EffectError(f'unknown hidden effect {name!r}; known effects: {sorted(HIDDEN_EFFECTS)}')
    try:
        return cls(**params)
    except TypeError:
        known = [f.name for f in fields(cls)]
        raise EffectError(f'{cls.__name__} got parameters {sorted(params)}; it takes {known}') from None


def effects_from_config(entries) -> tuple[HiddenEffect, ...]:
    """``[{name: weak_fan, fan: HM2, gain: 0.8}, ...]`` -> effects (``None`` -> none)."""
    out = []
    for entry in entries or ():
        if isinstance(entry, HiddenEffect):
            out.append(entry)
            continue
        entry = dict(entry)
        if 'name' not in entry:
            raise EffectError(f'effect entry {entry} needs a name; known effects: {sorted(HIDDEN_EFFECTS)}')
        out.append(make_effect(entry.pop('name'), **entry))
    return tuple(out)
