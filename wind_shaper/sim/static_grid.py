"""A fixed grid of static force sensors as the measurement source (the paper's suggested upgrade).

Instead of sweeping one 20 cm plate through the tunnel, a grid of small square force sensors of
side ``pitch`` [m] tiles the measurement plane (sensor centres ``pitch`` apart). All sensors
record at once for the length of a "sweep" (``n_samples`` at ``sample_rate_hz``) and report
their time-averaged force. Because the sensors tile the plane and the plate side is ``m`` x
``pitch``, the force on a virtual plate centred on any sensor is the mean of the ``m`` x ``m``
block of sensors around it: exactly the plate's area average, no interpolation. The source
returns those virtual plates as an ordinary ``Sweep`` (plate centres [m, tunnel frame], plate
forces [N]), so ``FieldEstimator`` and ``ShapingLoop`` use it unchanged.

Differences from the moving plate: no motion capture (positions are exact), every sensor
averages the whole recording (turbulence averages out over ~duration / correlation time
samples), and the covered area is fixed by the grid. ``measure_at`` (held-plate calibration)
is passed to the underlying plant: the calibration batch still uses a plate.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import TunnelGeometry
from ..core.tunnel import Sweep
from .errors import CommandError
from .physics import plate_nodes


class StaticSensorGrid:
    """Satisfies ``wind_shaper.core.tunnel.Tunnel`` over a simulated plant.

    plant: a ``SimulatedTunnel`` (its ``point_field``, ``noise``, ``state`` and seeding are
    used); sensors_per_side m: sensors along one side of the virtual plate (pitch =
    plate_side / m [m]); radius [m]: virtual plate centres lie within this distance of the axis
    (default: the plant's sweep radius; a square wall uses |x|, |y| <= radius);
    sensor_order: quadrature order per axis over one sensor's face.
    """

    def __init__(self, plant, sensors_per_side: int = 5, radius: float | None = None,
                 sensor_order: int = 2):
        if not (isinstance(sensors_per_side, (int, np.integer)) and sensors_per_side >= 1):
            raise ConfigError(f'sensors_per_side must be a whole number >= 1; got {sensors_per_side!r}')
        self.plant = plant
        self.geometry: TunnelGeometry = plant.geometry
        self.m = int(sensors_per_side)
        self.pitch = self.geometry.plate_side / self.m
        self.radius = float(plant.geometry.sweep_radius if radius is None else radius)
        if not self.radius > 0:
            raise ConfigError(f'static grid radius must be > 0 m; got {self.radius}')
        square = self.geometry.extra.get('wall_shape', 'round') == 'square'
        # virtual plate centres on the sensor lattice (odd m: on sensor centres; even m: on corners)
        offset = 0.0 if self.m % 2 else 0.5 * self.pitch
        n = int(np.floor(self.radius / self.pitch)) + 1
        ticks = (np.arange(-n, n + 1) * self.pitch) + offset
        cx, cy = np.meshgrid(ticks, ticks)
        centres = np.column_stack([cx.ravel(), cy.ravel()])
        inside = (np.max(np.abs(centres), axis=1) if square else np.hypot(*centres.T)) <= self.radius + 1e-12
        self.plate_centres = centres[inside]
        # sensors: every lattice cell under some virtual plate
        half = 0.5 * (self.m - 1) * self.pitch
        s_ticks = np.arange(ticks[0] - half - self.pitch, ticks[-1] + half + 1.5 * self.pitch, self.pitch)
        sx, sy = np.meshgrid(s_ticks, s_ticks)
        lattice = np.column_stack([sx.ravel(), sy.ravel()])
        # block membership: sensor k is under plate p if |sensor - centre| <= half (per axis)
        idx_x = np.rint((self.plate_centres[:, 0:1] - s_ticks[0] - half) / self.pitch).astype(int)
        idx_y = np.rint((self.plate_centres[:, 1:2] - s_ticks[0] - half) / self.pitch).astype(int)
        steps = np.arange(self.m)
        ix = (idx_x + steps[None, :])[:, None, :]          # (P, 1, m)
        iy = (idx_y + steps[None, :])[:, :, None]          # (P, m, 1)
        flat = (iy * len(s_ticks) + ix).reshape(len(self.plate_centres), -1)
        used, inverse = np.unique(flat, return_inverse=True)
        self.sensor_positions = lattice[used]
        self._blocks = inverse.reshape(flat.shape)         # (P, m*m) rows into sensor_positions
        self._nodes, self._weights = plate_nodes(self.pitch, int(sensor_order))
        self.call_count = 0

    @property
    def n_sensors(self) -> int:
        return len(self.sensor_positions)

    # -- Tunnel protocol -----------------------------------------------------------------------
    def apply(self, pwm) -> np.ndarray:
        return self.plant.apply(pwm)

    def sensor_true(self, pwm=None) -> np.ndarray:
        """Noise-free force on each sensor (its face-averaged density) (K,) [N]."""
        pwm = self.plant.pwm if pwm is None else pwm
        q = len(self._weights)
        nodes = (self.sensor_positions[:, None, :] + self._nodes[None]).reshape(-1, 2)
        return self.plant.point_field(pwm, nodes).reshape(-1, q) @ self._weights

    def sweep(self, n_samples: int = 1000, *, rng: np.random.Generator | None = None) -> Sweep:
        """Record every sensor for ``n_samples`` samples at the plant's rate and return the
        virtual plates: centres (P, 2) [m], forces (P,) [N] (block means of the sensors' time
        averages), times all equal to the recording length [s]."""
        if int(n_samples) < 1:
            raise CommandError(f'a recording needs n_samples >= 1; got {n_samples}')
        n = int(n_samples)
        if rng is None:
            rng = np.random.default_rng([self.plant.seed, 1_000_003, self.call_count])
            self.call_count += 1
        dt = 1.0 / self.plant.sample_rate_hz
        true = self.sensor_true()
        mean = np.empty(len(true))
        step = max(1, (1 << 22) // n)  # bound the (n, sensors) noise array to ~32 MB
        for lo in range(0, len(true), step):
            block = np.broadcast_to(true[lo:lo + step], (n, len(true[lo:lo + step])))
            mean[lo:lo + step] = self.plant.noise.forces(block, dt, rng).mean(axis=0)
        forces = mean[self._blocks].mean(axis=1)
        times = np.full(len(forces), n * dt)
        return Sweep(self.plate_centres.copy(), forces, times, self.plant.pwm)

    def true_plates(self, pwm=None) -> np.ndarray:
        """Noise-free virtual plate forces (P,) [N] (equal to the plant's plate force up to the
        sensor quadrature)."""
        return self.sensor_true(pwm)[self._blocks].mean(axis=1)

    def measure_at(self, positions, samples_per_point: int = 20, **kw) -> np.ndarray:
        """Held-plate measurements (calibration) come from the plant's plate."""
        return self.plant.measure_at(positions, samples_per_point, **kw)

    def __repr__(self):
        return (f'StaticSensorGrid({self.n_sensors} sensors of {100 * self.pitch:.1f} cm, '
                f'{len(self.plate_centres)} virtual {100 * self.geometry.plate_side:.0f} cm plates)')
