"""The simulated tunnel in real time: the fans as applied now, the plate where it is now, the force
on it now. Used by the ``sim_tunnel`` node; pure (no ROS), thread-safe.

Frames and units: positions [m] in the tunnel frame (origin on the axis at the fan plane, x/y
horizontal), forces [N] (vertical, positive up), times [s] on the caller's monotonic clock.

* ``LiveTunnel.apply(pwm)`` applies fan commands to the plant. The plate-averaged true field is
  then tabulated on a regular grid (``ForceGrid``, 1 cm by default: ~0.1 s of numpy on the paper
  rig), so a force lookup at 1 kHz is a bilinear interpolation of a few microseconds. Until the
  new grid is ready the old one answers (``field_current`` tells); with ``start_worker()`` the
  grid is recomputed on a background thread at most every ``min_refresh_s``, so a burst of
  per-channel commands (one DO_SET_SERVO per fan) or a slewing fan costs a few recomputations,
  not one per pulse.
* The plate rests at ``rest_position`` until ``start_sweep(duration_s)``: a transit from the rest
  position, the simulator's sweep path (``TourPath``/``RandomWalkPath``) sped up so that it
  covers the sweep disc in the requested time (``sweep_speed``), and a transit back, lasting
  ``duration_s`` in all (``plan_sweep``). The plate never moves faster than ``max_speed``
  (2.5 m/s by default, under the mocap relay's 3 m/s jump gate) unless a sweep is too short to
  fit the transits.
* ``force(t)`` is the true plate force at the plate's position at t, times (1 + relative xi_m),
  plus absolute xi_a, as in ``NoiseModel.forces``: xi are drawn in blocks of ``noise_block_s``
  and consumed one per call, so successive calls at 1 kHz form the model's correlated series
  (the AR(1) state restarts, stationary, at block boundaries).
* ``mocap_position(t)`` is the true position plus N(0, position_sd) per axis, or None for a
  dropout.

``MocapFrame`` turns a plate-centre position in the tunnel frame into the pose of the
tracked rigid body in the mocap frame: the exact inverse of the mocap relay's
``tunnel_from_mocap * body_pose * offset``.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..estimation import RigidTransform, quat_to_matrix
from .errors import CommandError
from .plant import SimulatedTunnel

__all__ = ['ForceGrid', 'Motion', 'LiveTunnel', 'MocapFrame', 'sweep_speed', 'transit_time',
           'plan_sweep']

#: Lane spacing [m] assumed for paths that have none (the random walk) when sizing their speed.
_DEFAULT_SPACING = 0.045


# ------------------------------------------------------------------------------------- field grid
class ForceGrid:
    """Plate force [N] tabulated on a square grid centred on the axis: ``values[i, j]`` is the
    force with the plate centred at (x0 + i step, x0 + j step) [m]. Lookups outside the grid are
    clamped to its edge."""

    def __init__(self, values: np.ndarray, x0: float, step: float):
        values = np.asarray(values, dtype=float)
        if values.ndim != 2 or values.shape[0] != values.shape[1] or values.shape[0] < 2:
            raise ValueError(f'grid values must be square (n, n), n >= 2; got {values.shape}')
        self.n = values.shape[0]
        self.x0 = float(x0)
        self.step = float(step)
        self.values = values
        self._flat = values.ravel().tolist()   # python floats: fast scalar lookups

    @classmethod
    def compute(cls, tunnel: SimulatedTunnel, pwm, half_width: float, step: float) -> 'ForceGrid':
        """Tabulate ``tunnel.true_field(pwm, .)`` over [-half_width, half_width]^2 [m]."""
        if not (step > 0 and half_width > step):
            raise ConfigError(f'force grid needs 0 < step < half_width; got step={step}, '
                              f'half_width={half_width}')
        n = int(math.ceil(2 * half_width / step)) + 1
        x0 = -0.5 * (n - 1) * step
        axis = x0 + step * np.arange(n)
        gx, gy = np.meshgrid(axis, axis, indexing='ij')
        values = tunnel.true_field(pwm, np.column_stack([gx.ravel(), gy.ravel()]))
        return cls(values.reshape(n, n), x0, step)

    def __call__(self, x: float, y: float) -> float:
        """Bilinear interpolation at (x, y) [m] -> force [N]."""
        last = self.n - 1
        u = min(max((x - self.x0) / self.step, 0.0), last)
        v = min(max((y - self.x0) / self.step, 0.0), last)
        i = min(int(u), last - 1)
        j = min(int(v), last - 1)
        fu, fv = u - i, v - j
        f, n = self._flat, self.n
        k = i * n + j
        return ((f[k] * (1 - fv) + f[k + 1] * fv) * (1 - fu)
                + (f[k + n] * (1 - fv) + f[k + n + 1] * fv) * fu)

    def many(self, points) -> np.ndarray:
        """Vectorised lookups at points (K, 2) [m] -> (K,) [N]."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        last = self.n - 1
        u = np.clip((p[:, 0] - self.x0) / self.step, 0, last)
        v = np.clip((p[:, 1] - self.x0) / self.step, 0, last)
        i = np.minimum(u.astype(int), last - 1)
        j = np.minimum(v.astype(int), last - 1)
        fu, fv = u - i, v - j
        g = self.values
        return ((g[i, j] * (1 - fv) + g[i, j + 1] * fv) * (1 - fu)
                + (g[i + 1, j] * (1 - fv) + g[i + 1, j + 1] * fv) * fu)


# ----------------------------------------------------------------------------------- plate motion
@dataclass(frozen=True)
class Motion:
    """A timed plate trajectory: positions (n, 2) [m, tunnel frame] at times t0 + k / rate_hz
    [s]. Before t0 the plate is at the first position, after ``end`` at the last."""

    t0: float
    rate_hz: float
    positions: np.ndarray

    def __post_init__(self):
        p = np.asarray(self.positions, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 1:
            raise ValueError(f'motion positions must be (n >= 1, 2); got {p.shape}')
        object.__setattr__(self, 'positions', p)
        object.__setattr__(self, '_xs', p[:, 0].tolist())
        object.__setattr__(self, '_ys', p[:, 1].tolist())

    @property
    def end(self) -> float:
        """Time the motion stops [s]."""
        return self.t0 + (len(self.positions) - 1) / self.rate_hz

    @property
    def duration(self) -> float:
        return self.end - self.t0

    @property
    def times(self) -> np.ndarray:
        return self.t0 + np.arange(len(self.positions)) / self.rate_hz

    def at(self, t: float) -> tuple[float, float]:
        """Position (x, y) [m] at time t [s], linear between samples."""
        u = (t - self.t0) * self.rate_hz
        last = len(self._xs) - 1
        if u <= 0 or last == 0:
            return self._xs[0], self._ys[0]
        if u >= last:
            return self._xs[last], self._ys[last]
        i = int(u)
        f = u - i
        xs, ys = self._xs, self._ys
        return xs[i] + f * (xs[i + 1] - xs[i]), ys[i] + f * (ys[i + 1] - ys[i])


def sweep_speed(path, duration_s: float, radius: float, max_speed: float = math.inf,
                share: float = 1.0) -> float:
    """Plate speed [m/s] for ``path`` to cover the disc of ``radius`` [m] (or ``share`` of it, a
    region sweep) in ``duration_s`` [s]: one serpentine tour at the path's lane spacing is about
    1.1 pi r^2 share / spacing + 2 r long. Never slower than the path's own speed, never faster
    than ``max_speed`` (then ``TourPath`` widens its lanes to still cross the whole area)."""
    if not duration_s > 0:
        raise CommandError(f'a sweep needs duration_s > 0; got {duration_s}')
    spacing = float(getattr(path, 'lane_spacing', _DEFAULT_SPACING))
    length = 1.1 * math.pi * radius ** 2 * share / spacing + 2 * radius
    base = float(getattr(path, 'speed', 0.0))
    return min(max(base, length / duration_s), max_speed)


def _transit(a, b, n: int) -> np.ndarray:
    """n >= 2 points from a to b with a smooth (cosine) velocity profile, both ends included."""
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n))
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a[None] + s[:, None] * (b - a)[None]


def transit_time(rest, radius: float, transit_s: float, max_speed: float) -> float:
    """Time [s] of one move between ``rest`` (2,) [m] and any point of the sweep disc of
    ``radius`` [m]: at least ``transit_s``, and long enough that the cosine velocity profile
    (peak pi/2 x mean speed) stays under ``max_speed`` [m/s] over the longest such move."""
    reach = float(np.hypot(*np.asarray(rest, dtype=float))) + radius
    return max(transit_s, 0.5 * math.pi * reach / max_speed)


def plan_sweep(path, duration_s: float, radius: float, rest, rng: np.random.Generator, t0: float,
               *, rate_hz: float = 200.0, transit_s: float = 0.3,
               max_speed: float = math.inf, region=None) -> Motion:
    """The plate's motion for one sweep of ``duration_s`` [s] starting at ``t0`` [s]: from
    ``rest`` (2,) [m] to the start of the path, along the sweep path within ``radius`` [m] (speed
    from ``sweep_speed``, at most ``max_speed`` [m/s]), back to ``rest``. Each transit takes
    ``transit_time`` but at most a quarter of the sweep (a very short sweep then moves faster);
    the whole motion lasts ``duration_s`` to one sample (1 / rate_hz). region: a
    ``core.area.SweepArea`` to keep the path to (its share of the disc sets the speed)."""
    if not duration_s > 0:
        raise CommandError(f'a sweep needs duration_s > 0; got {duration_s}')
    if not rate_hz > 0:
        raise CommandError(f'rate_hz must be > 0; got {rate_hz}')
    transit = min(transit_time(rest, radius, max(transit_s, 0.0), max_speed), 0.25 * duration_s)
    n_total = max(int(round(duration_s * rate_hz)) + 1, 4)
    n_transit = int(round(transit * rate_hz)) + 1 if transit > 0 else 0
    n_path = max(n_total - 2 * max(n_transit - 1, 0), 2)
    path_s = (n_path - 1) / rate_hz
    share = 1.0 if region is None else max(region.disc_share(radius), 0.02)
    if hasattr(path, 'speed'):
        path = replace(path, speed=sweep_speed(path, path_s, radius, max_speed, share))
    body = (path(n_path, 1.0 / rate_hz, radius, rng) if region is None
            else path(n_path, 1.0 / rate_hz, radius, rng, region=region))
    parts = [body]
    if n_transit >= 2:
        parts = [_transit(rest, body[0], n_transit)[:-1], body, _transit(body[-1], rest, n_transit)[1:]]
    return Motion(float(t0), float(rate_hz), np.vstack(parts))


# -------------------------------------------------------------------------------------- mocap frame
class MocapFrame:
    """Where the mocap sees the plate's rigid body, for a level plate (orientation = tunnel frame).

    tunnel_from_mocap: (tx, ty, tz [m], qx, qy, qz, qw), T_tunnel_mocap (maps mocap coordinates
    to tunnel coordinates; the mocap relay's parameter); plate_offset: (3,) [m] from the rigid
    body's origin to the plate centre, in the body frame. ``body_pose(p)`` is the body's pose in
    the mocap frame for a plate centred at p (3,) [m, tunnel frame]:
    inverse(T_tunnel_mocap) * plate * inverse(offset), so that the relay's
    ``T_tunnel_mocap * body * offset`` (``estimation.frames.PlateRelay``) gives the plate back exactly.
    """

    def __init__(self, tunnel_from_mocap: Sequence[float], plate_offset: Sequence[float]):
        off = np.asarray(plate_offset, dtype=float).reshape(-1)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise ConfigError(f'plate_offset is 3 finite numbers [m, body frame]; got {off.tolist()}')
        mocap_from_tunnel = RigidTransform.from_xyz_quat(tunnel_from_mocap).inverse()
        # body = mocap_from_tunnel * (plate translated by -offset): rotation only, precomputed
        self._rot = quat_to_matrix(mocap_from_tunnel.rotation).tolist()
        self._trans = mocap_from_tunnel.translation.tolist()
        self._offset = off.tolist()
        self.quaternion = tuple(float(v) for v in mocap_from_tunnel.rotation)

    def body_pose(self, plate_position) -> tuple[tuple[float, float, float], tuple[float, ...]]:
        """(position (x, y, z) [m, mocap frame], quaternion (x, y, z, w)) of the rigid body."""
        d = [float(plate_position[i]) - self._offset[i] for i in range(3)]
        r, t = self._rot, self._trans
        return (tuple(r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2] + t[i] for i in range(3)),
                self.quaternion)


# ------------------------------------------------------------------------------------ live tunnel
class LiveTunnel:
    """A ``SimulatedTunnel`` played in real time (see the module docstring).

    rest_position: (2,) [m] where the plate waits between sweeps; grid_step [m]: force grid
    pitch; force_rate_hz [Hz]: rate at which ``force`` is called (the noise's time step);
    noise_block_s [s]: length of each pre-drawn noise block; path_rate_hz [Hz]: sampling of sweep
    trajectories; transit_s [s]: shortest move between rest and the sweep path; max_speed
    [m/s]: fastest plate motion; min_refresh_s [s]: the worker recomputes the force grid at most
    this often (a fan slew sends new pulses every 50 ms; each grid costs ~0.1 s of CPU);
    clock: monotonic time source [s].
    """

    def __init__(self, tunnel: SimulatedTunnel, rest_position=(0.0, -0.34), *,
                 grid_step: float = 0.01, force_rate_hz: float = 1000.0,
                 noise_block_s: float = 10.0, path_rate_hz: float = 200.0,
                 transit_s: float = 0.3, max_speed: float = 2.5, min_refresh_s: float = 0.2,
                 clock: Callable[[], float] = time.monotonic):
        rest = np.asarray(rest_position, dtype=float)
        if rest.shape != (2,) or not np.all(np.isfinite(rest)):
            raise ConfigError(f'rest_position must be 2 finite numbers (x, y) [m]; '
                              f'got {rest_position!r}')
        if not (force_rate_hz > 0 and noise_block_s > 0 and path_rate_hz > 0 and max_speed > 0):
            raise ConfigError('force_rate_hz, noise_block_s, path_rate_hz and max_speed must be > 0')
        self.tunnel = tunnel
        self.geometry = tunnel.geometry
        self.rest_position = rest
        self.grid_step = float(grid_step)
        self.force_rate_hz = float(force_rate_hz)
        self.path_rate_hz = float(path_rate_hz)
        self.transit_s = float(transit_s)
        self.max_speed = float(max_speed)
        self.min_refresh_s = float(min_refresh_s)
        self.clock = clock
        # the grid covers every place the plate can be: the sweep disc and the rest position
        reach = max(self.geometry.sweep_radius, float(np.max(np.abs(rest))))
        self.half_width = reach + 2 * self.grid_step
        self._lock = threading.Lock()
        self._noise_lock = threading.Lock()
        self._motion = Motion(clock(), path_rate_hz, rest[None])
        self._grid_pwm = tunnel.pwm
        self._grid = ForceGrid.compute(tunnel, self._grid_pwm, self.half_width, self.grid_step)
        self.grid_computations = 1
        self._sweeps = 0
        noise = tunnel.noise
        self._noise = noise
        self._block_n = max(int(noise_block_s * force_rate_hz), 1)
        self._force_rng = np.random.default_rng([tunnel.seed, 1])
        self._mocap_rng = np.random.default_rng([tunnel.seed, 2])
        self._xi_m: list[float] = []
        self._xi_a: list[float] = []
        self._k = 0
        self.forces_served = 0
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._worker: threading.Thread | None = None

    # ------------------------------------------------------------------ fans
    def apply(self, pwm) -> np.ndarray:
        """Apply fan commands (n_fans,) [fraction, fan order] to the plant (clipped to 0..1,
        disabled fans held at 0) and bring the force grid up to date: at once, or on the worker
        thread if it runs. Returns what was applied."""
        with self._lock:
            applied = self.tunnel.apply(pwm)
        if self._worker is not None:
            self._dirty.set()
        else:
            self.refresh_field()
        return applied

    @property
    def pwm(self) -> np.ndarray:
        """Commands applied to the plant (n_fans,) [fraction]."""
        with self._lock:
            return self.tunnel.pwm

    @property
    def field_current(self) -> bool:
        """The force grid is that of the commands applied now."""
        with self._lock:
            return bool(np.array_equal(self._grid_pwm, self.tunnel.pwm))

    def refresh_field(self) -> bool:
        """Recompute the force grid if the commands changed since; True if it was recomputed."""
        with self._lock:
            pwm = self.tunnel.pwm
            if np.array_equal(pwm, self._grid_pwm):
                return False
        grid = ForceGrid.compute(self.tunnel, pwm, self.half_width, self.grid_step)
        with self._lock:
            self._grid, self._grid_pwm = grid, pwm
            self.grid_computations += 1
        return True

    def start_worker(self) -> None:
        """Recompute the force grid on a background thread after each ``apply``."""
        if self._worker is None:
            self._worker = threading.Thread(target=self._work, name='sim-force-grid', daemon=True)
            self._worker.start()

    def _work(self) -> None:
        while not self._stop.is_set():
            if self._dirty.wait(0.1):
                self._dirty.clear()
                t0 = time.monotonic()
                self.refresh_field()
                # while fans slew (a command every 50 ms) recompute at most every min_refresh_s
                self._stop.wait(max(0.0, self.min_refresh_s - (time.monotonic() - t0)))

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._worker is not None:
            self._worker.join(timeout_s)
            self._worker = None

    # ------------------------------------------------------------------ plate
    def position(self, t: float | None = None) -> tuple[float, float]:
        """True plate centre (x, y) [m, tunnel frame] at time t (default now)."""
        return self._motion.at(self.clock() if t is None else t)

    def sweeping(self, t: float | None = None) -> bool:
        t = self.clock() if t is None else t
        m = self._motion
        return m.t0 <= t < m.end

    @property
    def motion(self) -> Motion:
        """The current (or last) plate motion."""
        return self._motion

    def start_sweep(self, duration_s: float, seed: int = 0, t0: float | None = None,
                    region=None) -> Motion:
        """Plan and start a sweep of ``duration_s`` [s] now (or at ``t0``) from the rest position;
        ``seed`` 0 takes the next seed of this tunnel's sequence; ``region`` (a
        ``core.area.SweepArea``): sweep only that part of the disc. Refused (CommandError) while
        the plate moves (a sweep, or the way back to rest after ``stop_sweep``)."""
        now = self.clock()
        with self._lock:
            if self.sweeping(now):
                raise CommandError(f'a sweep is running until {self._motion.end - now:.1f} s from now; '
                                   f'wait for it to end')
            self._sweeps += 1
            key = [self.tunnel.seed, 3, self._sweeps] if not seed else [self.tunnel.seed, 4, int(seed)]
            motion = plan_sweep(self.tunnel.path, duration_s, self.geometry.sweep_radius,
                                self.rest_position, np.random.default_rng(key),
                                now if t0 is None else t0, rate_hz=self.path_rate_hz,
                                transit_s=self.transit_s, max_speed=self.max_speed, region=region)
            self._motion = motion
        return motion

    def place(self, x: float, y: float, t0: float | None = None) -> Motion:
        """Move the plate from where it is to (x, y) [m] (a transit of at least ``transit_s``
        within ``max_speed``) and hold it there. Refused (CommandError) while a sweep runs or
        when (x, y) lies outside the force grid (farther than the sweep disc)."""
        now = self.clock() if t0 is None else t0
        target = np.array([x, y], dtype=float)
        if not np.all(np.isfinite(target)) or np.max(np.abs(target)) > self.half_width - self.grid_step:
            raise CommandError(f'({x}, {y}) m lies outside the simulated area (|x|, |y| <= '
                               f'{self.half_width - self.grid_step:.2f} m)')
        with self._lock:
            if self.sweeping(now):
                raise CommandError(f'the plate moves until {self._motion.end - now:.1f} s from now; '
                                   f'wait for it to stop')
            here = np.asarray(self.position(now), float)
            duration = max(self.transit_s, 0.5 * math.pi * float(np.hypot(*(target - here))) / self.max_speed)
            n = max(int(round(duration * self.path_rate_hz)) + 1, 2)
            self._motion = Motion(now, self.path_rate_hz, _transit(here, target, n))
        return self._motion

    def stop_sweep(self) -> None:
        """Stop the plate where it is and send it straight back to rest (transit_s)."""
        now = self.clock()
        with self._lock:
            here = self.position(now)
            n = max(int(round(self.transit_s * self.path_rate_hz)) + 1, 2)
            self._motion = Motion(now, self.path_rate_hz, _transit(here, self.rest_position, n))

    # ------------------------------------------------------------------ measurements
    def true_force(self, t: float | None = None) -> float:
        """Noise-free plate force [N] at the plate's position at time t (from the grid)."""
        x, y = self.position(t)
        return self._grid(x, y)

    def force(self, t: float | None = None) -> float:
        """One measured plate force [N] at time t (default now): true + the noise model's next
        sample (one sample per call; calls are assumed ``1 / force_rate_hz`` apart)."""
        true = self.true_force(t)
        nm = self._noise
        if nm.relative == 0 and nm.absolute == 0:
            return true
        with self._noise_lock:
            k = self._k
            if k >= len(self._xi_m):
                self._draw_noise()
                k = 0
            self._k = k + 1
            xi_m, xi_a = self._xi_m[k], self._xi_a[k]
            self.forces_served += 1
        return true * (1.0 + nm.relative * xi_m) + nm.absolute * xi_a

    def _draw_noise(self) -> None:
        dt = 1.0 / self.force_rate_hz
        self._xi_m = self._noise.unit_series(self._block_n, dt, self._force_rng)[:, 0].tolist()
        self._xi_a = self._noise.unit_series(self._block_n, dt, self._force_rng)[:, 0].tolist()

    def mocap_position(self, t: float | None = None) -> tuple[float, float] | None:
        """The mocap's reading of the plate centre (x, y) [m, tunnel frame] at t: true position
        plus N(0, position_sd) per axis; None when the sample drops out."""
        x, y = self.position(t)
        nm = self._noise
        with self._noise_lock:
            if nm.dropout > 0 and self._mocap_rng.random() < nm.dropout:
                return None
            if nm.position_sd > 0:
                dx, dy = nm.position_sd * self._mocap_rng.standard_normal(2)
                x, y = x + float(dx), y + float(dy)
        return x, y
