"""The base physics of the simulated tunnel: thrust curves, jet footprints, plate averaging.

Units and frame: positions [m] in the tunnel frame (origin on the axis, x and y horizontal);
forces [N] of vertical force on the square force plate; PWM commands as fractions 0..1.

The local *force density* f(p) [N] is defined so that the force on the plate centred at c is the
mean of f over the plate square: F(c) = mean_{q in plate(c)} f(q). A uniform flow of density f
therefore pushes the plate with f newtons.

This plant is deliberately *not* the project's prior model (isotropic Gaussian footprints times a
quadratic PWM curve): footprints are flat-topped, thrust curves have a cubic term, and every fan
carries its own fixed imperfections.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from scipy.spatial import cKDTree

from ..core.errors import ConfigError

#: Relative footprint value below which a fan/point pair is skipped (sets the cutoff radius).
CUTOFF_TOLERANCE = 1e-4
#: Target number of fan/point pairs evaluated at once (bounds memory to a few tens of MB).
PAIRS_PER_CHUNK = 1 << 20
#: Edge-jet footprint forms ``PlantConstants.profile`` may name.
EDGE_PROFILES = ('flat_top', 'heavy_tail')
#: Default seed of the fixed per-fan build imperfections: the default tunnel is always the same
#: lopsided tunnel.
BUILD_SEED = 7


@dataclass(frozen=True)
class ThrustCurve:
    """PWM-to-force curve T(U) = a U^2 + b U + c U^3 [N], clipped at 0.

    T is the force on the plate centred right above a lone fan of nominal width; U is the
    effective PWM fraction 0..1. The cubic term makes the curve deliberately not quadratic.
    """

    a: float
    b: float = 0.0
    c: float = 0.0

    def __call__(self, u) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        return np.maximum(u * (self.b + u * (self.a + u * self.c)), 0.0)


def _default_thrust() -> dict:
    # Lone nominal fan over its hub: higher 3.64 N at U = 0.5 and 6.38 N at 0.65, lower 3.28 N
    # and 5.75 N (CCW ~11 % stronger than CW); the central fan's ring peak 2.93 N and 5.16 N.
    # With these, the bounded least-squares optimum for the paper's parabola has the central fan
    # at 0 and the edge fans at 0.53-0.63, as the paper found.
    return {'higher': ThrustCurve(a=10.6, b=0.6, c=5.5),
            'lower': ThrustCurve(a=9.6, b=0.5, c=5.0),
            'central': ThrustCurve(a=8.6, b=0.4, c=4.6)}


@dataclass(frozen=True)
class PlantConstants:
    """Nominal constants of the base plant.

    thrust: group -> ThrustCurve [N]; width: group -> nominal footprint width w [m] of the
    edge-fan jets (``higher``/``lower``); profile: the edge jets' footprint form, ``flat_top``
    exp(-(d/w)^beta) with beta = ``flatness``, or ``heavy_tail`` (1 + (d/w)^2 / nu)^-nu with
    nu = ``tail`` (a jet that entrains the air around it: a rounder top and a far slower fall
    than any exponential, so the prior's Gaussian footprints differ in form, not only in size);
    ring_core, ring_rise [m], ring_width [m]: the central fan's ring footprint
    (ring_core + (d/ring_rise)^2) exp(-(d/ring_width)^2).
    """

    thrust: Mapping[str, ThrustCurve] = field(default_factory=_default_thrust)
    width: Mapping[str, float] = field(default_factory=lambda: {'higher': 0.15, 'lower': 0.14})
    flatness: float = 2.4
    profile: str = 'flat_top'
    tail: float = 3.0
    ring_core: float = 0.25
    ring_rise: float = 0.18
    ring_width: float = 0.22

    def __post_init__(self):
        thrust = {g: c if isinstance(c, ThrustCurve) else ThrustCurve(**dict(c))
                  for g, c in dict(self.thrust).items()}
        missing = {'higher', 'lower', 'central'} - set(thrust)
        if missing:
            raise ConfigError(f'plant constants need a thrust curve for groups {sorted(missing)}')
        width = {g: float(w) for g, w in dict(self.width).items()}
        if {'higher', 'lower'} - set(width) or min(width.values()) <= 0:
            raise ConfigError(f'plant constants need positive widths for higher and lower; got {width}')
        if not (1.0 <= self.flatness <= 8.0):
            raise ConfigError(f'footprint flatness must be in [1, 8]; got {self.flatness}')
        if self.profile not in EDGE_PROFILES:
            raise ConfigError(f'footprint profile {self.profile!r} is unknown; choose one of '
                              f'{sorted(EDGE_PROFILES)}')
        if not (1.5 <= self.tail <= 50.0):
            raise ConfigError(f'footprint tail exponent must be in [1.5, 50]; got {self.tail}')
        if not (self.ring_core >= 0 and self.ring_rise > 0 and self.ring_width > 0):
            raise ConfigError('ring constants need ring_core >= 0 and positive ring_rise, ring_width')
        object.__setattr__(self, 'thrust', thrust)
        object.__setattr__(self, 'width', width)

    @classmethod
    def from_config(cls, cfg: Mapping | None) -> 'PlantConstants':
        try:
            return cls(**dict(cfg or {}))
        except TypeError as exc:
            raise ConfigError(f'bad plant constants: {exc}; keys are thrust, width, flatness, '
                              f'profile, tail, ring_core, ring_rise, ring_width') from None


@dataclass(frozen=True)
class Imperfections:
    """Fixed per-fan build imperfections, in fan order.

    gain: (n,) thrust multipliers (1 = nominal); offset: (n, 2) hub offsets [m] of where the jet
    lands relative to the nominal hub; width_scale: (n,) multipliers of the footprint width.
    """

    gain: np.ndarray
    offset: np.ndarray
    width_scale: np.ndarray

    def __post_init__(self):
        gain = np.asarray(self.gain, dtype=float).ravel()
        offset = np.asarray(self.offset, dtype=float).reshape(-1, 2)
        width = np.asarray(self.width_scale, dtype=float).ravel()
        if not (len(gain) == len(offset) == len(width)):
            raise ConfigError(f'imperfections disagree in length: gain {len(gain)}, offset '
                              f'{len(offset)}, width_scale {len(width)}')
        if np.any(gain < 0) or np.any(width <= 0) or not np.all(np.isfinite(offset)):
            raise ConfigError('imperfections need gain >= 0, width_scale > 0 and finite offsets')
        for name, arr in (('gain', gain), ('offset', offset), ('width_scale', width)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return len(self.gain)

    @classmethod
    def none(cls, n_fans: int) -> 'Imperfections':
        """A perfect build: unit gains and widths, no offsets."""
        return cls(np.ones(n_fans), np.zeros((n_fans, 2)), np.ones(n_fans))

    @classmethod
    def draw(cls, n_fans: int, seed: int = BUILD_SEED, *, gain_sd: float = 0.08,
             offset_sd: float = 0.008, width_sd: float = 0.06) -> 'Imperfections':
        """Random build: gain 1 +- gain_sd, hub offset N(0, offset_sd) per axis [m] (mean
        magnitude ~1 cm for the default), width 1 +- width_sd; normal draws clipped at 2.5 sd."""
        if min(gain_sd, offset_sd, width_sd) < 0:
            raise ConfigError('imperfection spreads must be >= 0')
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
        z = np.clip(rng.standard_normal((n_fans, 4)), -2.5, 2.5)
        return cls(1.0 + gain_sd * z[:, 0], offset_sd * z[:, 1:3], 1.0 + width_sd * z[:, 3])

    @classmethod
    def from_config(cls, cfg, n_fans: int, seed: int = BUILD_SEED) -> 'Imperfections':
        """``'none'`` / ``False`` for a perfect build, or a mapping of draw spreads
        (gain_sd, offset_sd, width_sd); ``None`` or ``{}`` for the default spreads."""
        if cfg in ('none', False):
            return cls.none(n_fans)
        try:
            return cls.draw(n_fans, seed, **dict(cfg or {}))
        except TypeError as exc:
            raise ConfigError(f'bad imperfections config: {exc}; use none or a mapping of '
                              f'gain_sd, offset_sd, width_sd') from None

    def as_dict(self, names) -> dict:
        """{fan name: {gain, offset [m], width_scale}} for reports and tests."""
        return {n: {'gain': float(g), 'offset': (float(o[0]), float(o[1])), 'width_scale': float(w)}
                for n, g, o, w in zip(names, self.gain, self.offset, self.width_scale)}


# -- footprint profiles -------------------------------------------------------------------------
class Profile:
    """A footprint shape g(s) of the scaled squared distance s = d^2 / w^2 (d [m], w [m]).

    ``cutoff`` is the scaled distance d/w beyond which g stays below CUTOFF_TOLERANCE of its peak.
    """

    cutoff: float = 3.0

    def __call__(self, s: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _find_cutoff(self) -> float:
        u = np.linspace(0.0, 12.0, 24001)
        g = self(u * u)
        above = np.nonzero(g > CUTOFF_TOLERANCE * g.max())[0]
        return float(u[above[-1] + 1])


class FlatTop(Profile):
    """Flat-topped generalised Gaussian exp(-(d/w)^beta), beta > 2 flattens the top and
    sharpens the shoulder compared with a Gaussian (beta = 2 is a Gaussian)."""

    def __init__(self, beta: float = 2.0):
        self.beta = float(beta)
        self.cutoff = self._find_cutoff()

    def __call__(self, s):
        if self.beta == 2.0:
            return np.exp(-s)
        return np.exp(-np.power(s, 0.5 * self.beta))

    def __repr__(self):
        return f'exp(-(d/w)^{self.beta:g})'


class HeavyTail(Profile):
    """Student-t-like footprint (1 + (d/w)^2 / nu)^-nu: a Gaussian as nu grows, far heavier
    tails for small nu (at d = 2w, nu = 3: 0.08 of the peak against a Gaussian's 0.018)."""

    def __init__(self, nu: float = 3.0):
        self.nu = float(nu)
        self.cutoff = self._find_cutoff()

    def __call__(self, s):
        return np.power(1.0 + s / self.nu, -self.nu)

    def __repr__(self):
        return f'(1 + (d/w)^2/{self.nu:g})^-{self.nu:g}'


def edge_profile(constants: 'PlantConstants') -> Profile:
    """The edge jets' footprint profile that ``constants`` name."""
    if constants.profile == 'heavy_tail':
        return HeavyTail(constants.tail)
    return FlatTop(constants.flatness)


class Ring(Profile):
    """The central fan's ring (core + (d/rise)^2) exp(-(d/w)^2): weak on the axis, strongest
    on a ring at d = w sqrt(1 - core rise^2/w^2) (~0.2 m for the defaults)."""

    def __init__(self, core: float, rise_ratio: float):
        self.core = float(core)
        self.rise_ratio = float(rise_ratio)  # rise / w
        self.cutoff = self._find_cutoff()

    def __call__(self, s):
        return (self.core + s / self.rise_ratio ** 2) * np.exp(-s)

    def __repr__(self):
        return f'({self.core:g} + (d/{self.rise_ratio:g}w)^2) exp(-(d/w)^2)'


@dataclass
class JetGroup:
    """Sources sharing one footprint profile.

    centres: (n, 2) where each jet lands [m]; amplitude: (n,) peak density scale [N];
    width: (n,) w [m]; fan: (n,) index of the fan behind each source (-1 for sources that are
    not a fan, e.g. interaction terms); metric: optional (n, 2, 2) symmetric matrices A with
    s = d^T A d / w^2 (identity when None) for stretched footprints; stretch: (n,) largest
    semi-axis factor of A (sets the cutoff radius).
    """

    profile: Profile
    centres: np.ndarray
    amplitude: np.ndarray
    width: np.ndarray
    fan: np.ndarray
    metric: np.ndarray | None = None
    stretch: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.amplitude)

    def index_of(self, fan: int) -> np.ndarray:
        return np.nonzero(self.fan == fan)[0]

    def split(self, rows: np.ndarray) -> tuple['JetGroup', 'JetGroup']:
        """(the group without ``rows``, a group of just ``rows``)."""
        keep = np.ones(len(self), dtype=bool)
        keep[rows] = False
        return _subset(self, np.nonzero(keep)[0]), _subset(self, np.asarray(rows))

    def stretched(self, metric: np.ndarray, stretch: float) -> 'JetGroup':
        """A copy whose every source has the footprint metric ``metric`` (2, 2)."""
        out = _subset(self, np.arange(len(self)))
        out.metric = np.tile(np.asarray(metric, dtype=float), (len(self), 1, 1))
        out.stretch = np.full(len(self), float(stretch))
        return out

    def density(self, points: np.ndarray) -> np.ndarray:
        """Summed density of the group's sources at points (P, 2) [m] -> (P,) [N]."""
        points = np.asarray(points, dtype=float)
        out = np.zeros(len(points))
        live = np.nonzero(self.amplitude != 0)[0]
        if len(live) == 0 or len(points) == 0:
            return out
        g = _subset(self, live)
        if len(g) <= 64:
            step = max(1, PAIRS_PER_CHUNK // len(g))
            for lo in range(0, len(points), step):
                out[lo:lo + step] = _block(points[lo:lo + step], g)
            return out
        return _tiled_density(points, g)


def _subset(group: JetGroup, rows: np.ndarray) -> JetGroup:
    return JetGroup(group.profile, group.centres[rows], group.amplitude[rows], group.width[rows],
                    group.fan[rows],
                    None if group.metric is None else group.metric[rows],
                    None if group.stretch is None else group.stretch[rows])


def _block(points: np.ndarray, g: JetGroup) -> np.ndarray:
    """Density of every source of g at every point (dense). Pairs beyond the profile cutoff
    are zeroed, so the result does not depend on how points and sources were blocked."""
    dx = points[:, 0:1] - g.centres[:, 0]
    dy = points[:, 1:2] - g.centres[:, 1]
    inv_w2 = 1.0 / g.width ** 2
    if g.metric is None:
        s = (dx * dx + dy * dy) * inv_w2
    else:
        m = g.metric
        s = (m[:, 0, 0] * dx * dx + 2.0 * m[:, 0, 1] * dx * dy + m[:, 1, 1] * dy * dy) * inv_w2
    cut2 = g.profile.cutoff ** 2
    val = g.profile(np.minimum(s, cut2))
    val[s > cut2] = 0.0
    return val @ g.amplitude


def _tiled_density(points: np.ndarray, g: JetGroup) -> np.ndarray:
    """Many sources (a fan wall): cut the plane into square tiles, find the sources within
    reach of each tile once (cKDTree) and evaluate tile points x those sources densely. Cost
    and memory grow with the number of sources within the cutoff radius, not sources x points."""
    stretch = np.ones(len(g)) if g.stretch is None else g.stretch
    rmax = float(np.max(g.profile.cutoff * g.width * stretch))
    tile = 0.25 * rmax
    cells = np.floor(points / tile).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    order = np.argsort(key, kind='stable')
    uniq, first = np.unique(key[order], return_index=True)
    bounds = np.append(first, len(order))
    lo_pts = order[first]
    centres = (np.floor(points[lo_pts] / tile) + 0.5) * tile
    candidates = cKDTree(g.centres).query_ball_point(centres, rmax + tile * np.sqrt(0.5))
    out = np.zeros(len(points))
    for k, cand in enumerate(candidates):
        if not cand:
            continue
        rows = order[bounds[k]:bounds[k + 1]]
        sub = _subset(g, np.asarray(cand))
        step = max(1, PAIRS_PER_CHUNK // len(sub))
        for lo in range(0, len(rows), step):
            r = rows[lo:lo + step]
            out[r] = _block(points[r], sub)
    return out


# -- plate averaging ----------------------------------------------------------------------------
def plate_nodes(side: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes (Q, 2) [m, relative to the plate centre] and weights (Q,) summing
    to 1 over the axis-aligned square plate of ``side`` [m]; Q = order^2."""
    if order < 1:
        raise ConfigError(f'plate quadrature order must be >= 1; got {order}')
    x, w = np.polynomial.legendre.leggauss(int(order))
    xx, yy = np.meshgrid(0.5 * side * x, 0.5 * side * x)
    ww = np.outer(w, w) / 4.0
    return np.column_stack([xx.ravel(), yy.ravel()]), ww.ravel()


def footprint_norm(profile: Profile, width: float, side: float, order: int, ring: bool) -> float:
    """1 / (plate-averaged footprint at its peak) for a source of amplitude 1 and ``width`` [m]:
    the factor that makes a jet's amplitude equal to the plate force at its peak (over the hub
    for a flat top, on the ring for the central fan)."""
    nodes, weights = plate_nodes(side, order)
    radii = np.linspace(0.0, 3.0 * width, 301) if ring else np.zeros(1)
    centres = np.column_stack([radii, np.zeros_like(radii)])
    q = (centres[:, None, :] + nodes[None]).reshape(-1, 2)
    g = profile(np.sum(q * q, axis=1) / width ** 2).reshape(len(radii), -1) @ weights
    return float(1.0 / g.max())

