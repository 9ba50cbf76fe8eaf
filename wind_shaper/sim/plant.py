"""The simulated tunnel: the embedded default plant behind the ``Tunnel`` protocol.

Physics (see ``physics.py`` for the pieces, ``effects.py`` for the switchable extras):

* Each edge fan j at effective command U_j lays a flat-topped jet on the measurement plane:
  local force density T_j(U_j) * n_j * exp(-(d_j / w_j)^beta) [N], d_j the distance [m] to
  where its jet lands (hub + build offset), w_j its width (0.14 m lower, 0.15 m higher, times a
  build factor), beta = 2.4, n_j the factor that makes T_j the plate force right over a lone
  nominal fan.
* The central fan lays a ring: T_c(U_c) * n_c * (0.25 + (d/0.18)^2) exp(-(d/0.22)^2), weak on the
  axis and strongest ~0.2 m out, so raising it mostly raises the flow over the edge fans.
* Thrust curves per mount group T(U) = a U^2 + b U + c U^3, times a per-fan build gain.
* Jets superpose; the plate force at centre c is the mean of the density over the 20 cm square
  plate centred on c (Gauss-Legendre quadrature, axis-aligned plate).
* Measurements add turbulence and mocap noise (``noise.py``); sweeps move the plate along a
  smooth random path (``paths.py``).

Everything random is drawn from ``seed``: call number k of ``sweep``/``measure_at`` uses
``default_rng([seed, k])`` unless an explicit ``rng`` is passed. The build imperfections come from
a separate ``build_seed``, fixed by default, so the default tunnel is always the same lopsided one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import TunnelGeometry
from ..core.tunnel import Sweep
from .effects import HiddenEffect, effects_from_config
from .errors import CommandError
from .noise import NoiseModel
from .paths import TourPath, path_from_config
from .physics import (BUILD_SEED, Imperfections, JetGroup, PlantConstants, Ring, edge_profile,
                      footprint_norm, plate_nodes)

#: Plate-centre positions evaluated per block (x plate quadrature nodes) in ``true_field``.
_NODES_PER_BLOCK = 1 << 18


@dataclass(frozen=True)
class PlantState:
    """What the fans do at one command. applied: (n,) commands after clipping and disabling
    [fraction]; effective: (n,) after command effects; thrust: (n,) per-fan thrust [N] after
    thrust effects; groups: the jets to evaluate."""

    applied: np.ndarray
    effective: np.ndarray
    thrust: np.ndarray
    groups: tuple[JetGroup, ...]


class SimulatedTunnel:
    """A simulated multi-fan tunnel satisfying ``wind_shaper.core.tunnel.Tunnel``.

    geometry: fans, key points, plate and sweep radius; seed: seeds every sweep and measurement;
    effects: hidden effects (any subset of ``HIDDEN_EFFECTS``); noise: ``NoiseModel`` (None = the
    default turbulence, ``NoiseModel.zero()`` for none); sample_rate_hz: force/mocap rate [Hz];
    path: sweep path (default ``TourPath()``); constants: ``PlantConstants``; imperfections: fixed
    per-fan build errors (None = drawn from ``build_seed``; ``Imperfections.none(n)`` for a
    perfect build); plate_order: Gauss-Legendre order per plate axis (5 -> 25 nodes).
    """

    def __init__(self, geometry: TunnelGeometry, *, seed: int = 0,
                 effects: Sequence[HiddenEffect] = (), noise: NoiseModel | None = None,
                 sample_rate_hz: float = 50.0, path=None, constants: PlantConstants | None = None,
                 imperfections: Imperfections | None = None, build_seed: int = BUILD_SEED,
                 plate_order: int = 5):
        if not sample_rate_hz > 0:
            raise ConfigError(f'sample_rate_hz must be > 0; got {sample_rate_hz}')
        n = geometry.fans.n_fans
        self.geometry = geometry
        self.seed = int(seed)
        self.build_seed = int(build_seed)
        self.sample_rate_hz = float(sample_rate_hz)
        self.noise = NoiseModel() if noise is None else noise
        self.path = TourPath() if path is None else path
        self.constants = PlantConstants() if constants is None else constants
        self.imperfections = (Imperfections.draw(n, self.build_seed) if imperfections is None
                              else imperfections)
        if len(self.imperfections) != n:
            raise ConfigError(f'imperfections are for {len(self.imperfections)} fans; the tunnel has {n}')
        self.plate_order = int(plate_order)
        self.effects = tuple(effects)
        for effect in self.effects:
            if not isinstance(effect, HiddenEffect):
                raise ConfigError(f'{effect!r} is not a HiddenEffect; build effects with make_effect()')
            effect.validate(geometry)
        self._pipeline = sorted(self.effects, key=lambda e: e.priority)  # stable
        self._nodes, self._weights = plate_nodes(geometry.plate_side, self.plate_order)
        self._groups = np.array(geometry.fans.groups)
        self._enabled = geometry.fans.enabled
        self._setup_jets()
        self._pwm = np.zeros(n)
        self.call_count = 0
        # the recording clock [s] (sweeps' plate time end to end) and the last command change,
        # for faults in time (``unmodelled_sensing``: a drifting sensor zero, fans still settling)
        self.clock_s = 0.0
        self._previous = np.zeros(n)
        self._changed_at = 0.0
        self._bias = 0.0   # what ``bias_sensor`` zeroed [N]

    def _setup_jets(self):
        c, side = self.constants, self.geometry.plate_side
        self._edge = edge_profile(c)
        self._ring = Ring(c.ring_core, c.ring_rise / c.ring_width)
        norm = {g: footprint_norm(self._edge, c.width[g], side, self.plate_order, ring=False)
                for g in ('higher', 'lower')}
        norm['central'] = footprint_norm(self._ring, c.ring_width, side, self.plate_order, ring=True)
        width = {'higher': c.width['higher'], 'lower': c.width['lower'], 'central': c.ring_width}
        self._norm = np.array([norm[g] for g in self._groups])
        self._width = np.array([width[g] for g in self._groups]) * self.imperfections.width_scale
        self._landing = self.geometry.fans.positions + self.imperfections.offset

    # -- Tunnel protocol ---------------------------------------------------------------------------
    def apply(self, pwm) -> np.ndarray:
        """Command the fans [fraction per fan, fan order]; like the hardware, commands are clipped
        to [0, 1] and disabled fans held at 0. Returns what was applied."""
        new = self._hardware(pwm)
        if not np.array_equal(new, self._pwm):
            self._previous, self._changed_at = self._pwm, self.clock_s
        self._pwm = new
        return self._pwm.copy()

    @property
    def pwm(self) -> np.ndarray:
        """The commands in force (n_fans,) [fraction]."""
        return self._pwm.copy()

    def sweep(self, n_samples: int = 1000, *, rng: np.random.Generator | None = None,
              region=None) -> Sweep:
        """Move the plate along a smooth random path within ``geometry.sweep_radius`` at
        ``sample_rate_hz`` and record noisy force [N] and mocap position [m] (1000 samples = 20 s
        at 50 Hz, like the rig); ``region`` (a ``core.area.SweepArea``): keep the path to that
        part of the disc."""
        if int(n_samples) < 1:
            raise CommandError(f'a sweep needs n_samples >= 1; got {n_samples}')
        n = int(n_samples)
        rng = self._rng(rng)
        dt = 1.0 / self.sample_rate_hz
        state = self.state(self._pwm)
        true_pos = (self.path(n, dt, self.geometry.sweep_radius, rng) if region is None
                    else self.path(n, dt, self.geometry.sweep_radius, rng, region=region))
        clock = self.clock_s + np.arange(n) * dt
        forces = self.noise.forces(self._sweep_forces(state, true_pos, clock), dt, rng)
        for effect in self._pipeline:
            forces = forces + effect.sensor_zero(clock)
        forces = forces - self._bias
        paired = true_pos
        for effect in self._pipeline:
            paired = effect.recorded(paired, dt)
        self.clock_s += n * dt
        return Sweep(self.noise.positions(paired, rng), forces, np.arange(n) * dt, self._pwm.copy())

    def _sweep_forces(self, state: PlantState, positions: np.ndarray, clock: np.ndarray,
                      block_s: float = 0.1) -> np.ndarray:
        """Noise-free plate forces (n,) [N] along a sweep: at the settled ``state``, except where
        an effect has the fans still running toward the commands (``HiddenEffect.running``);
        there the state follows the commands block by block (``block_s`` [s] each)."""
        true = self._plate(state, positions)
        since = clock - self._changed_at
        for effect in self._pipeline:
            running = effect.running(self._previous, self._pwm, since)
            if running is None:
                continue
            moving = np.flatnonzero(np.max(np.abs(running - self._pwm[None]), axis=1) > 1e-4)
            step = max(1, int(round(block_s * self.sample_rate_hz)))
            for lo in range(0, len(moving), step):
                rows = moving[lo:lo + step]
                u = running[rows].mean(axis=0)
                true[rows] = self._plate(self.state(u), positions[rows])
        return true

    def sweep_chunks(self, max_samples: int = 1000, chunk_samples: int = 50, *,
                     rng: np.random.Generator | None = None, region=None):
        """One sweep of up to ``max_samples`` delivered ``chunk_samples`` at a time, along one
        continuous path, so the caller can end it early (``control.sweep_length``); the chunks
        joined are ``sweep(max_samples)`` with the same draws."""
        if int(chunk_samples) < 1:
            raise CommandError(f'chunk_samples must be >= 1; got {chunk_samples}')
        full = self.sweep(max_samples, rng=rng, region=region)
        step = int(chunk_samples)
        for i in range(0, len(full), step):
            part = slice(i, i + step)
            yield Sweep(full.positions[part], full.forces[part], full.times[part], full.pwm)

    def measure_at(self, positions, samples_per_point: int = 20, *,
                   rng: np.random.Generator | None = None) -> np.ndarray:
        """Hold the plate still at each position (K, 2) [m] for ``samples_per_point`` samples and
        return the mean measured force (K,) [N]."""
        pts = self._points(positions)
        if int(samples_per_point) < 1:
            raise CommandError(f'samples_per_point must be >= 1; got {samples_per_point}')
        rng = self._rng(rng)
        true = self._plate(self.state(self._pwm), pts)
        series = self.noise.forces(np.tile(true, (int(samples_per_point), 1)),
                                   1.0 / self.sample_rate_hz, rng)
        return series.mean(axis=0)

    def bias_sensor(self) -> float:
        """Zero the force sensor, like the rig's bias command: every later recorded force has this
        moment's reading taken off -- the sensor's zero at ``clock_s`` (``HiddenEffect.sensor_zero``)
        and the plate's noise-free force at the area's centre with the fans as commanded now (so
        a bias with a fan running zeroes its force too; with every fan off, a draft that still
        blows). Sweeps only, like the zero itself (``HiddenEffect.sensor_zero``): ``measure_at``
        reads as before. Returns that offset [N]."""
        now = np.array([self.clock_s])
        zero = sum(float(np.sum(effect.sensor_zero(now))) for effect in self._pipeline)
        here = float(self._plate(self.state(self._pwm), np.zeros((1, 2)))[0])
        self._bias = zero + here
        return self._bias

    # -- ground truth -------------------------------------------------------------------------------
    def true_field(self, pwm, points) -> np.ndarray:
        """Noise-free plate force (K,) [N] with the plate centred at each point (K, 2) [m], for
        commands ``pwm`` (clipped and disabled as by ``apply``; the tunnel state is unchanged)."""
        return self._plate(self.state(pwm), self._points(points))

    def point_field(self, pwm, points) -> np.ndarray:
        """Noise-free local force density (P,) [N] at points (P, 2) [m] (no plate averaging)."""
        return self._density(self.state(pwm), self._points(points))

    def thrust(self, pwm) -> np.ndarray:
        """Per-fan thrust (n_fans,) [N] (plate force over a lone nominal fan) after effects."""
        return self.state(pwm).thrust.copy()

    def state(self, pwm) -> PlantState:
        """Everything the fans do at commands ``pwm``: see ``PlantState``."""
        applied = self._hardware(pwm)
        u = applied
        for effect in self._pipeline:
            u = effect.command(u, self.geometry)
        t = np.zeros(len(u))
        for group, curve in self.constants.thrust.items():
            mask = self._groups == group
            t[mask] = curve(u[mask])
        t = t * self.imperfections.gain
        for effect in self._pipeline:
            t = effect.thrust(t, self.geometry)
        groups = self._jets(t)
        for effect in self._pipeline:
            groups = effect.sources(groups, t, self.geometry)
        return PlantState(applied, u, t, tuple(groups))

    # -- internals ----------------------------------------------------------------------------------
    def _jets(self, thrust: np.ndarray) -> list[JetGroup]:
        amp = thrust * self._norm
        out = []
        for profile, mask in ((self._edge, self._groups != 'central'), (self._ring, self._groups == 'central')):
            idx = np.nonzero(mask)[0]
            if len(idx):
                out.append(JetGroup(profile, self._landing[idx].copy(), amp[idx], self._width[idx], idx))
        return out

    def _density(self, state: PlantState, points: np.ndarray) -> np.ndarray:
        q = points
        for effect in self._pipeline:
            q = effect.warp(q, state.thrust, self.geometry)
        dens = np.zeros(len(points))
        for group in state.groups:
            dens += group.density(q)
        for effect in self._pipeline:
            dens = dens + effect.offset(points, self.geometry)
        for effect in self._pipeline:
            dens = dens * effect.scale(points, self.geometry)
        return np.broadcast_to(dens, (len(points),)).astype(float)

    def _plate(self, state: PlantState, centres: np.ndarray) -> np.ndarray:
        q = len(self._weights)
        block = max(1, _NODES_PER_BLOCK // q)
        out = np.empty(len(centres))
        for lo in range(0, len(centres), block):
            c = centres[lo:lo + block]
            nodes = (c[:, None, :] + self._nodes[None]).reshape(-1, 2)
            out[lo:lo + block] = self._density(state, nodes).reshape(len(c), q) @ self._weights
        for effect in self._pipeline:
            out = effect.reading(out, self.geometry)
        return out

    def _hardware(self, pwm) -> np.ndarray:
        n = self.geometry.fans.n_fans
        u = np.asarray(pwm, dtype=float)
        if u.shape != (n,):
            raise CommandError(f'expected {n} fan commands in order {list(self.geometry.fans.names)[:8]}'
                               f'{"..." if n > 8 else ""}; got shape {u.shape}')
        if not np.all(np.isfinite(u)):
            raise CommandError(f'fan commands must be finite; got {u}')
        return np.where(self._enabled, np.clip(u, 0.0, 1.0), 0.0)

    @staticmethod
    def _points(points) -> np.ndarray:
        p = np.asarray(points, dtype=float)
        if p.ndim == 1 and p.shape == (2,):
            p = p[None]
        if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
            raise CommandError(f'positions must be a finite (K, 2) array [m]; got shape {p.shape}')
        return p

    def _rng(self, rng) -> np.random.Generator:
        if rng is not None:
            return rng
        rng = np.random.default_rng([self.seed, self.call_count])
        self.call_count += 1
        return rng

    # -- construction ---------------------------------------------------------------------------------
    _CONFIG_KEYS = ('seed', 'build_seed', 'sample_rate_hz', 'noise', 'path', 'imperfections',
                    'constants', 'plate_order', 'effects')

    @classmethod
    def from_config(cls, geometry: TunnelGeometry, cfg: Mapping | None) -> 'SimulatedTunnel':
        """Build from the ``sim`` section of ``config/sim.yaml`` (or the whole file)."""
        cfg = dict(cfg or {})
        if set(cfg) == {'sim'}:
            cfg = dict(cfg['sim'] or {})
        unknown = set(cfg) - set(cls._CONFIG_KEYS)
        if unknown:
            raise ConfigError(f'unknown sim config keys {sorted(unknown)}; known: {list(cls._CONFIG_KEYS)}')
        n = geometry.fans.n_fans
        build_seed = int(cfg.get('build_seed', BUILD_SEED))
        return cls(geometry, seed=int(cfg.get('seed', 0)),
                   effects=effects_from_config(cfg.get('effects')),
                   noise=NoiseModel.from_config(cfg.get('noise')),
                   sample_rate_hz=float(cfg.get('sample_rate_hz', 50.0)),
                   path=path_from_config(cfg.get('path')),
                   constants=PlantConstants.from_config(cfg.get('constants')),
                   imperfections=Imperfections.from_config(cfg.get('imperfections'), n, build_seed),
                   build_seed=build_seed, plate_order=int(cfg.get('plate_order', 5)))

    def with_effects(self, effects: Sequence[HiddenEffect]) -> 'SimulatedTunnel':
        """The same tunnel (seed, build, noise, path) carrying ``effects`` instead."""
        return SimulatedTunnel(self.geometry, seed=self.seed, effects=effects, noise=self.noise,
                               sample_rate_hz=self.sample_rate_hz, path=self.path,
                               constants=self.constants, imperfections=self.imperfections,
                               build_seed=self.build_seed, plate_order=self.plate_order)

    def __repr__(self) -> str:
        return (f'SimulatedTunnel({self.geometry.fans.n_fans} fans, seed={self.seed}, '
                f'build_seed={self.build_seed}, effects={list(self.effects)}, noise={self.noise})')
