"""Tunnel geometry: fans, their mounting groups, and the key points.

Frame: the tunnel frame has its origin on the tunnel axis at the fan plane, x and y horizontal,
z up. Every position here is [m] in that frame. PWM commands are fractions 0..1 of full PWM.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, replace
from typing import Iterable, Mapping, Sequence

import numpy as np

from .errors import ConfigError
from .limits import DEFAULT_LIMITS, excerpt

#: Mount groups. The paper's rig has CCW fans mounted higher ("higher"), CW fans lower ("lower")
#: and a low central fan ("central"); each group gets its own PWM-to-force curve.
GROUPS = ('higher', 'lower', 'central')
SPINS = ('cw', 'ccw')
#: Most fans and key points a tunnel config may describe (a 36 x 36 wall has 1296 fans; the
#: paper's disc 317 key points): a config beyond these is a typo or a damaged file, refused
#: before any array is built.
MAX_FANS = 10_000
MAX_KEY_POINTS = 200_000
#: Where a refused tunnel config sends the reader.
CONFIG_HINT = 'see the shipped config/tunnel.yaml for the form'


def config_mapping(value, where: str) -> dict:
    """``value`` (a YAML mapping, or None / absent: empty) as a dict; ConfigError naming
    ``where`` for anything else."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ConfigError(f'{where} must be a mapping (key: value lines), not the '
                          f'{type(value).__name__} {excerpt(value)}; {CONFIG_HINT}')
    return dict(value)


def config_number(value, where: str, *, positive: bool = False, integer: bool = False):
    """``value`` as a finite float (``integer``: an int), > 0 when ``positive``; ConfigError
    naming ``where`` otherwise (a string, a list, NaN, an integer too large for a float)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ConfigError(f'{where} must be a number, not the {type(value).__name__} '
                          f'{excerpt(value)}; {CONFIG_HINT}')
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number) or (positive and not number > 0):
        raise ConfigError(f'{where} must be a finite{" positive" if positive else ""} number; '
                          f'got {excerpt(value)}; {CONFIG_HINT}')
    if integer:
        if number != int(number):
            raise ConfigError(f'{where} must be a whole number; got {excerpt(value)}')
        return int(number)
    return number


@dataclass(frozen=True)
class Fan:
    """One fan.

    name: unique label (e.g. ``LM1``); x, y: hub position [m, tunnel frame];
    spin: ``cw`` or ``ccw`` seen from above; group: mount group (see ``GROUPS``);
    enabled: a disabled fan is held at PWM 0 and never commanded.
    """

    name: str
    x: float
    y: float
    spin: str = 'cw'
    group: str = 'lower'
    enabled: bool = True

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f'a fan name must be a non-empty text, not {excerpt(self.name)}')
        if len(self.name) > DEFAULT_LIMITS.name_chars:
            raise ConfigError(f'a fan name has {len(self.name)} characters, more than '
                              f'{DEFAULT_LIMITS.name_chars}: {excerpt(self.name)}')
        for axis in ('x', 'y'):
            object.__setattr__(self, axis, config_number(getattr(self, axis),
                                                         f'fan {self.name!r}: {axis}'))
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise ConfigError(f'fan {self.name!r}: enabled must be true or false, not '
                              f'{excerpt(self.enabled)}')
        if self.spin not in SPINS:
            raise ConfigError(f'fan {self.name!r}: spin {excerpt(self.spin)} is not one of {SPINS}')
        if self.group not in GROUPS:
            raise ConfigError(f'fan {self.name!r}: group {excerpt(self.group)} is not one of '
                              f'{GROUPS}')


@dataclass(frozen=True)
class FanArray:
    """An ordered set of fans; the order is the order of every PWM vector."""

    fans: tuple[Fan, ...]

    def __post_init__(self):
        if not self.fans:
            raise ConfigError('a fan array needs at least one fan')
        names = [f.name for f in self.fans]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ConfigError(f'fan names must be unique; repeated: {dup}')

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def paper_rig(cls, hex_radius: float = 0.25, disabled: Iterable[str] = ()) -> 'FanArray':
        """The paper's rig: 6 fans on a regular hexagon, alternating CW-lower (LM) and
        CCW-higher (HM), and one central fan (CM). ``hex_radius`` [m] is hub-to-axis distance."""
        fans = []
        for k in range(6):
            angle = np.pi / 2 - k * np.pi / 3  # LM1 at 12 o'clock, then clockwise
            lower = k % 2 == 0
            idx = k // 2 + 1
            fans.append(Fan(
                name=f'LM{idx}' if lower else f'HM{idx}',
                x=float(hex_radius * np.cos(angle)), y=float(hex_radius * np.sin(angle)),
                spin='cw' if lower else 'ccw', group='lower' if lower else 'higher'))
        fans.append(Fan(name='CM', x=0.0, y=0.0, spin='cw', group='central'))
        return cls(tuple(fans)).with_disabled(disabled)

    @classmethod
    def grid(cls, rows: int, cols: int, pitch: float) -> 'FanArray':
        """A rectangular fan wall (e.g. 36 x 36) centred on the axis, ``pitch`` [m] apart.
        Spin alternates in a checkerboard; CCW fans are the 'higher' group, CW the 'lower'."""
        if rows < 1 or cols < 1 or not pitch > 0:
            raise ConfigError(f'grid needs rows, cols >= 1 and pitch > 0; got {rows}, {cols}, {pitch}')
        fans = []
        for r in range(rows):
            for c in range(cols):
                ccw = (r + c) % 2 == 1
                fans.append(Fan(
                    name=f'F{r:02d}_{c:02d}',
                    x=(c - (cols - 1) / 2) * pitch, y=(r - (rows - 1) / 2) * pitch,
                    spin='ccw' if ccw else 'cw', group='higher' if ccw else 'lower'))
        return cls(tuple(fans))

    @classmethod
    def from_config(cls, cfg: Mapping) -> 'FanArray':
        """Build from a config mapping: ``{layout: paper_rig, hex_radius: 0.25, disabled: [CM]}``,
        ``{layout: grid, rows: 36, cols: 36, pitch: 0.08}`` or ``{fans: [{name, x, y, spin,
        group, enabled}, ...]}``."""
        cfg = config_mapping(cfg, 'tunnel.fans')
        disabled = cfg.pop('disabled', []) or []
        if not isinstance(disabled, list) or not all(isinstance(n, str) for n in disabled):
            raise ConfigError(f'tunnel.fans.disabled must be a list of fan names, not '
                              f'{excerpt(disabled)}; {CONFIG_HINT}')
        if 'fans' in cfg:
            entries = cfg['fans']
            if not isinstance(entries, list) or not entries:
                raise ConfigError(f'tunnel.fans.fans must be a list of fans, not '
                                  f'{excerpt(entries)}; {CONFIG_HINT}')
            if len(entries) > MAX_FANS:
                raise ConfigError(f'tunnel.fans.fans lists {len(entries)} fans, more than '
                                  f'{MAX_FANS}: check the file')
            fans = []
            for i, entry in enumerate(entries):
                entry = config_mapping(entry, f'tunnel.fans.fans[{i}]')
                if not all(isinstance(k, str) for k in entry):
                    raise ConfigError(f'tunnel.fans.fans[{i}]: keys must be names; got '
                                      f'{excerpt(list(entry))}')
                try:
                    fans.append(Fan(**entry))
                except TypeError as exc:
                    raise ConfigError(f'bad fan entry tunnel.fans.fans[{i}]: {exc}; each fan '
                                      f'needs name, x, y and optionally spin, group, '
                                      f'enabled') from None
            return cls(tuple(fans)).with_disabled(disabled)
        layout = cfg.get('layout', 'paper_rig')
        if layout == 'paper_rig':
            return cls.paper_rig(config_number(cfg.get('hex_radius', 0.25), 'tunnel.fans.hex_radius',
                                               positive=True), disabled)
        if layout == 'grid':
            try:
                rows, cols, pitch = (config_number(cfg[k], f'tunnel.fans.{k}', positive=True,
                                                   integer=k != 'pitch')
                                     for k in ('rows', 'cols', 'pitch'))
            except KeyError as exc:
                raise ConfigError(f'grid layout needs {exc.args[0]!r}') from None
            if rows * cols > MAX_FANS:
                raise ConfigError(f'a grid of {rows} x {cols} fans is more than {MAX_FANS} fans: '
                                  f'check tunnel.fans.rows and cols')
            return cls.grid(rows, cols, pitch).with_disabled(disabled)
        raise ConfigError(f'unknown fan layout {excerpt(layout)}; use paper_rig, grid or a list '
                          f'of fans')

    def with_disabled(self, names: Iterable[str]) -> 'FanArray':
        """A copy with the named fans disabled (unknown names are an error)."""
        names = set(names)
        unknown = names - set(self.names)
        if unknown:
            raise ConfigError(f'cannot disable unknown fans {sorted(unknown)}; fans are {list(self.names)}')
        return FanArray(tuple(replace(f, enabled=f.enabled and f.name not in names) for f in self.fans))

    # -- views ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.fans)

    @property
    def n_fans(self) -> int:
        return len(self.fans)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fans)

    @property
    def positions(self) -> np.ndarray:
        """(n_fans, 2) hub positions [m, tunnel frame]."""
        return np.array([[f.x, f.y] for f in self.fans], dtype=float)

    @property
    def enabled(self) -> np.ndarray:
        """(n_fans,) bool mask of fans that may be commanded."""
        return np.array([f.enabled for f in self.fans], dtype=bool)

    @property
    def groups(self) -> tuple[str, ...]:
        return tuple(f.group for f in self.fans)

    def group_mask(self, group: str) -> np.ndarray:
        return np.array([f.group == group for f in self.fans], dtype=bool)

    @property
    def spin_sign(self) -> np.ndarray:
        """(n_fans,) +1 for CCW, -1 for CW (seen from above)."""
        return np.array([1.0 if f.spin == 'ccw' else -1.0 for f in self.fans])

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(f'no fan named {name!r}; fans are {list(self.names)}') from None

    @property
    def radius(self) -> float:
        """Largest hub distance from the axis [m]."""
        return float(np.max(np.hypot(*self.positions.T)))


def disc_key_points(radius: float = 0.30, spacing: float = 0.03) -> np.ndarray:
    """Key points on a square grid of ``spacing`` [m] inside a disc of ``radius`` [m].

    The defaults give 317 points, the paper's count: the lattice points within 10 spacings of
    the axis (any radius/spacing ratio of 10 gives 317). A 0.30 m disc covers the hexagon's
    hubs (0.25 m) and one plate half-width beyond.
    Returns (N, 2) [m, tunnel frame], ordered row by row.
    """
    radius = config_number(radius, 'key_points.radius', positive=True)
    spacing = config_number(spacing, 'key_points.spacing', positive=True)
    if math.pi * (radius / spacing) ** 2 > MAX_KEY_POINTS:
        raise ConfigError(f'a disc of radius {radius:g} m at a spacing of {spacing:g} m has more '
                          f'than {MAX_KEY_POINTS} key points: check key_points.radius and spacing')
    n = int(np.floor(radius / spacing + 1e-9))
    ticks = np.arange(-n, n + 1) * spacing
    xx, yy = np.meshgrid(ticks, ticks)
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    inside = np.hypot(pts[:, 0], pts[:, 1]) <= radius + 1e-9
    return pts[inside]


def rect_key_points(half_width: float, half_height: float, nx: int, ny: int) -> np.ndarray:
    """Key points on an nx x ny grid over the rectangle [-hw, hw] x [-hh, hh] [m]."""
    nx = config_number(nx, 'key_points.nx', positive=True, integer=True)
    ny = config_number(ny, 'key_points.ny', positive=True, integer=True)
    half_width = config_number(half_width, 'key_points.half_width', positive=True)
    half_height = config_number(half_height, 'key_points.half_height', positive=True)
    if nx * ny > MAX_KEY_POINTS:
        raise ConfigError(f'{nx} x {ny} key points are more than {MAX_KEY_POINTS}: check '
                          f'key_points.nx and ny')
    xx, yy = np.meshgrid(np.linspace(-half_width, half_width, nx),
                         np.linspace(-half_height, half_height, ny))
    return np.column_stack([xx.ravel(), yy.ravel()])


@dataclass(frozen=True)
class TunnelGeometry:
    """Everything spatial about a tunnel.

    fans: the fan array; key_points: (N, 2) [m] where the field is shaped;
    wall_radius: inner radius of the tunnel wall [m] (a square wall for grid arrays uses
    half its side); plate_side: side of the square force plate [m]; sweep_radius: the plate
    centre stays within this radius during sweeps [m].
    """

    fans: FanArray
    key_points: np.ndarray
    wall_radius: float = 0.40
    plate_side: float = 0.20
    sweep_radius: float = 0.34
    extra: Mapping = field(default_factory=dict)

    def __post_init__(self):
        kp = np.asarray(self.key_points, dtype=float)
        if kp.ndim != 2 or kp.shape[1] != 2 or len(kp) == 0 or not np.all(np.isfinite(kp)):
            raise ConfigError(f'key points must be a non-empty finite (N, 2) array; got shape {kp.shape}')
        object.__setattr__(self, 'key_points', kp)

    @classmethod
    def paper_rig(cls, disabled: Sequence[str] = ()) -> 'TunnelGeometry':
        return cls(fans=FanArray.paper_rig(disabled=disabled), key_points=disc_key_points())

    @classmethod
    def from_config(cls, cfg: Mapping) -> 'TunnelGeometry':
        """From the ``tunnel`` section of a YAML config (see ``config/tunnel.yaml``)."""
        cfg = config_mapping(cfg, 'the tunnel section')
        fans = FanArray.from_config(cfg.get('fans', {}))
        kp_cfg = config_mapping(cfg.get('key_points', {}), 'tunnel.key_points')
        kind = kp_cfg.pop('kind', 'disc')
        if not all(isinstance(k, str) for k in kp_cfg):
            raise ConfigError(f'tunnel.key_points: keys must be names; got {excerpt(list(kp_cfg))}')
        try:
            if kind == 'disc':
                kp = disc_key_points(**kp_cfg)
            elif kind == 'rect':
                kp = rect_key_points(**kp_cfg)
            else:
                raise ConfigError(f'unknown key point kind {excerpt(kind)}; use disc or rect')
        except TypeError as exc:
            raise ConfigError(f'bad key_points config: {exc}; {CONFIG_HINT}') from None
        known = ('wall_radius', 'plate_side', 'sweep_radius')
        return cls(fans=fans, key_points=kp, **{k: config_number(cfg[k], f'tunnel.{k}',
                                                                 positive=True)
                                                for k in known if k in cfg})

    def with_disabled(self, names: Iterable[str]) -> 'TunnelGeometry':
        return replace(self, fans=self.fans.with_disabled(names))


def neighbour_pairs(hubs: np.ndarray, reach: float) -> np.ndarray:
    """(n_pairs, 2) indices into ``hubs`` (n, 2) [m] of the hubs at most ``reach`` times the
    closest spacing apart: neighbouring fans."""
    hubs = np.asarray(hubs, dtype=float)
    if len(hubs) < 2:
        return np.zeros((0, 2), dtype=int)
    from scipy.spatial import cKDTree   # here: the nodes that read the geometry skip SciPy's load
    tree = cKDTree(hubs)
    dist, _ = tree.query(hubs, k=2)
    spacing = float(np.min(dist[:, 1]))
    if spacing <= 0:
        return np.zeros((0, 2), dtype=int)
    return tree.query_pairs(reach * spacing * (1 + 1e-9), output_type='ndarray')
