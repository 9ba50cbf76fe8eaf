"""The static sensor grid: a Tunnel whose 'sweep' is every sensor recording at once."""
import numpy as np
import pytest

from wind_shaper.estimation.field import FieldEstimator
from wind_shaper.control import ShapingConfig, ShapingLoop
from wind_shaper.model import CentralRing, FanJets
from wind_shaper.core.tunnel import Tunnel
from wind_shaper.sim import NoiseModel, SimulatedTunnel
from wind_shaper.sim.static_grid import StaticSensorGrid


def test_it_is_a_tunnel_and_its_plates_tile_the_area(rig):
    grid = StaticSensorGrid(SimulatedTunnel(rig))
    assert isinstance(grid, Tunnel)
    assert grid.pitch == pytest.approx(0.04)
    assert np.all(np.hypot(*grid.plate_centres.T) <= rig.sweep_radius + 1e-12)
    # every key point has a virtual plate within half a diagonal of the sensor pitch
    d = np.min(np.linalg.norm(rig.key_points[:, None] - grid.plate_centres[None], axis=2), axis=1)
    assert d.max() <= grid.pitch / np.sqrt(2) + 1e-9


def test_noise_free_plates_equal_the_plants_plate_force(perfect, rng):
    grid = StaticSensorGrid(perfect)
    U = rng.uniform(0.2, 0.6, 7)
    grid.apply(U)
    sweep = grid.sweep(200)
    np.testing.assert_allclose(sweep.forces, perfect.true_field(U, grid.plate_centres), atol=3e-3)
    np.testing.assert_allclose(sweep.pwm, U)
    assert len(sweep) == len(grid.plate_centres)


def test_recording_averages_the_turbulence_away(tunnel):
    grid = StaticSensorGrid(tunnel)
    U = np.full(7, 0.5)
    grid.apply(U)
    static = grid.sweep(1000)
    static_err = static.forces - tunnel.true_field(U, static.positions)
    plate = tunnel.sweep(1000)
    plate_err = plate.forces - tunnel.true_field(U, plate.positions)
    assert np.std(static_err) < 0.1 * np.std(plate_err)
    again = grid.sweep(1000)
    assert not np.array_equal(again.forces, static.forces)  # each recording draws new noise


def test_disabled_fans_stay_off_and_calibration_uses_the_plant(rig):
    off = rig.with_disabled(['CM'])
    plant = SimulatedTunnel(off, noise=NoiseModel.zero())
    grid = StaticSensorGrid(plant)
    applied = grid.apply(np.full(7, 0.5))
    assert applied[6] == 0.0
    pts = np.array([[0.0, 0.25], [0.1, 0.0]])
    np.testing.assert_allclose(grid.measure_at(pts), plant.true_field(applied, pts))


def test_the_loop_shapes_the_field_with_the_static_grid(rig):
    plant = SimulatedTunnel(rig, seed=3)
    grid = StaticSensorGrid(plant)
    kp = rig.key_points
    prior = (FanJets(rig.fans, thrust_higher=(0.12, 0.0, 16.3), thrust_lower=(0.18, 0.0, 12.9), sigma=0.163)
             + CentralRing(rig.fans, thrust=(0.0, 0.0, 12.2), offset=0.65, sigma=0.25))
    target = np.full(len(kp), 2.5)
    rule = ShapingConfig(update={'method': 'adaptive'}).make_rule()
    loop = ShapingLoop(grid, prior, target, rule, FieldEstimator(), u0=0.5,
                       truth=lambda U: plant.true_field(U, kp))
    history = loop.run(3)
    errors = [r.true_error for r in history]
    assert errors[-1] < 0.05 * errors[0]
    # the static grid's estimate tracks the truth far better than a 0.1 N plate sweep would
    assert abs(np.sqrt(history[-1].error) - np.sqrt(history[-1].true_error)) < 0.03
