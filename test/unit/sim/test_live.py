"""The simulated tunnel in real time (wind_shaper.sim.live): force grid, sweep motion, noise,
mocap frame. A fake clock drives time, so nothing here sleeps."""
import math
import threading
import time

import numpy as np
import pytest
from scipy.spatial import cKDTree

from wind_shaper.core.errors import ConfigError
from wind_shaper.estimation.frames import PlateRelay, RigidTransform
from wind_shaper.sim import NoiseModel, RandomWalkPath, SimulatedTunnel, TourPath
from wind_shaper.sim.errors import CommandError
from wind_shaper.sim.live import (ForceGrid, LiveTunnel, MocapFrame, Motion, plan_sweep,
                                  sweep_speed, transit_time)


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def speeds(motion):
    return np.hypot(*np.diff(motion.positions, axis=0).T) * motion.rate_hz


def test_force_grid_matches_the_plant(tunnel, rig):
    pwm = np.linspace(0.2, 0.6, rig.fans.n_fans)
    grid = ForceGrid.compute(tunnel, pwm, 0.36, 0.01)
    pts = np.random.default_rng(0).uniform(-0.34, 0.34, (300, 2))
    true = tunnel.true_field(pwm, pts)
    assert np.max(np.abs(grid.many(pts) - true)) < 0.01 * true.max()   # bilinear, 1 cm pitch
    assert [grid(x, y) for x, y in pts[:20]] == pytest.approx(grid.many(pts[:20]), abs=1e-12)
    # on a node the table is exact; outside it is clamped to the edge
    node = (grid.x0 + 3 * grid.step, grid.x0 + 5 * grid.step)
    assert grid(*node) == pytest.approx(tunnel.true_field(pwm, [node])[0], rel=1e-9)
    assert grid(5.0, 0.0) == pytest.approx(grid(grid.x0 + (grid.n - 1) * grid.step, 0.0))


def test_motion_interpolates_and_holds_its_ends():
    m = Motion(10.0, 2.0, np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 2.0]]))
    assert m.end == 11.0 and m.duration == 1.0
    assert m.at(9.0) == (0.0, 0.0)
    assert m.at(10.25) == pytest.approx((0.5, 1.0))
    assert m.at(10.75) == pytest.approx((2.0, 2.0))
    assert m.at(50.0) == (3.0, 2.0)


def test_sweep_speed_covers_the_disc_in_time_and_respects_limits():
    tour = TourPath()
    fast = sweep_speed(tour, 3.0, 0.34)
    assert fast * 3.0 == pytest.approx(1.1 * math.pi * 0.34 ** 2 / tour.lane_spacing + 0.68)
    assert sweep_speed(tour, 1000.0, 0.34) == tour.speed        # never slower than configured
    assert sweep_speed(tour, 3.0, 0.34, max_speed=2.5) == 2.5
    with pytest.raises(CommandError, match='duration_s'):
        sweep_speed(tour, 0.0, 0.34)


@pytest.mark.parametrize('duration', [3.0, 10.0, 20.0])
def test_a_sweep_covers_the_key_points_in_the_requested_time(rig, duration):
    rest = (0.0, -0.34)
    m = plan_sweep(TourPath(), duration, rig.sweep_radius, rest, np.random.default_rng(1), 5.0,
                   rate_hz=200.0, max_speed=2.5)
    assert m.t0 == 5.0 and m.duration == pytest.approx(duration, abs=1 / 200)
    assert np.allclose(m.positions[0], rest) and np.allclose(m.positions[-1], rest)
    assert np.max(np.hypot(*m.positions.T)) <= rig.sweep_radius + 1e-9
    assert speeds(m).max() <= 2.5 + 1e-6                    # under the relay's jump gate
    gap, _ = cKDTree(m.positions[::2]).query(rig.key_points)   # at the mocap's 100 Hz
    assert gap.max() < 0.06                                 # every key point has a sample nearby


def test_transit_time_keeps_the_rest_moves_under_the_speed_limit():
    assert transit_time((0.0, -0.34), 0.34, 0.3, 2.5) == pytest.approx(0.5 * math.pi * 0.68 / 2.5)
    assert transit_time((0.0, 0.0), 0.1, 0.3, 2.5) == 0.3
    m = plan_sweep(RandomWalkPath(), 1.0, 0.34, (0.0, -0.34), np.random.default_rng(2), 0.0,
                   max_speed=2.5)   # too short for the limit: transits take a quarter each
    assert m.duration == pytest.approx(1.0, abs=0.01)


def test_live_tunnel_plate_moves_only_during_a_sweep(tunnel):
    clock = FakeClock()
    live = LiveTunnel(tunnel, (0.0, -0.34), clock=clock)
    assert live.position() == (0.0, -0.34) and not live.sweeping()
    m = live.start_sweep(4.0)
    with pytest.raises(CommandError, match='sweep is running'):
        live.start_sweep(4.0)
    clock.t += 2.0
    assert live.sweeping() and np.hypot(*live.position()) < tunnel.geometry.sweep_radius + 1e-9
    clock.t = m.end + 0.01
    assert not live.sweeping() and live.position() == pytest.approx((0.0, -0.34))
    # seeds: 0 takes the next of the sequence; an explicit seed repeats its path
    a = live.start_sweep(4.0, seed=7).positions
    clock.t += 10
    b = live.start_sweep(4.0, seed=7).positions
    clock.t += 10
    c = live.start_sweep(4.0).positions
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_stop_sweep_returns_to_rest_smoothly(tunnel):
    clock = FakeClock()
    live = LiveTunnel(tunnel, (0.0, -0.34), clock=clock)
    live.start_sweep(10.0)
    clock.t += 5.0
    here = live.position()
    live.stop_sweep()
    assert live.position() == pytest.approx(here)
    clock.t += live.transit_s + 0.01
    assert live.position() == pytest.approx((0.0, -0.34))


def test_force_is_the_true_field_where_the_plate_is_plus_the_noise_model(rig):
    clock = FakeClock()
    quiet = SimulatedTunnel(rig, noise=NoiseModel.zero())
    live = LiveTunnel(quiet, (0.1, 0.0), clock=clock)
    pwm = np.full(rig.fans.n_fans, 0.5)
    assert np.array_equal(live.apply(pwm), pwm) and live.field_current
    assert live.force() == pytest.approx(quiet.true_field(pwm, [(0.1, 0.0)])[0], rel=1e-3)

    noisy = SimulatedTunnel(rig, noise=NoiseModel(relative=0.04, absolute=0.03))
    live = LiveTunnel(noisy, (0.1, 0.0), clock=clock)
    live.apply(pwm)
    true = noisy.true_field(pwm, [(0.1, 0.0)])[0]
    f = np.array([live.force() for _ in range(20000)])     # two noise blocks at 1 kHz
    expected_sd = float(NoiseModel(relative=0.04, absolute=0.03).sd(true))
    assert abs(f.mean() - true) < 0.2 * expected_sd       # AR(1) makes the mean wander a little
    assert f.std() == pytest.approx(expected_sd, rel=0.15)
    # successive samples at 1 kHz are correlated (gusts last ~0.1 s), as the model says
    assert np.corrcoef(f[:-1], f[1:])[0, 1] > 0.3


def test_mocap_noise_and_dropouts(rig):
    clock = FakeClock()
    tunnel = SimulatedTunnel(rig, noise=NoiseModel(position_sd=0.001, dropout=0.2))
    live = LiveTunnel(tunnel, (0.0, -0.34), clock=clock)
    readings = [live.mocap_position() for _ in range(4000)]
    kept = np.array([r for r in readings if r is not None])
    assert len(kept) / len(readings) == pytest.approx(0.8, abs=0.03)
    assert kept.std(axis=0) == pytest.approx([0.001, 0.001], rel=0.1)
    assert kept.mean(axis=0) == pytest.approx([0.0, -0.34], abs=1e-4)


def test_worker_recomputes_the_grid_in_the_background(rig):
    live = LiveTunnel(SimulatedTunnel(rig), min_refresh_s=0.0)
    live.start_worker()
    try:
        before = live.grid_computations
        for u in np.linspace(0.1, 0.5, 10):          # a burst: one channel at a time
            live.apply(np.full(rig.fans.n_fans, u))
        deadline = time.monotonic() + 5.0
        while not live.field_current and time.monotonic() < deadline:
            time.sleep(0.01)
        assert live.field_current
        assert 1 <= live.grid_computations - before <= 10
    finally:
        live.close()
    assert not any(t.name == 'sim-force-grid' for t in threading.enumerate())


def test_mocap_frame_is_undone_exactly_by_the_relay():
    q = np.array([0.1, -0.3, 0.2, 0.9])
    tunnel_from_mocap = (0.4, -0.2, 1.5, *(q / np.linalg.norm(q)))
    offset = (0.01, 0.02, -0.05)
    frame = MocapFrame(tunnel_from_mocap, offset)
    relay = PlateRelay(RigidTransform.from_xyz_quat(tunnel_from_mocap), offset)
    for plate in [(0.1, 0.2, 0.35), (-0.3, 0.0, 0.0)]:
        pos, quat = frame.body_pose(plate)
        back = relay.plate_pose(pos, quat)
        assert back.translation == pytest.approx(plate, abs=1e-12)
        assert abs(back.rotation[3]) == pytest.approx(1.0, abs=1e-12)   # level plate
    # identity: the body is the plate, minus the offset
    pos, quat = MocapFrame((0, 0, 0, 0, 0, 0, 1), (0.0, 0.0, 0.1)).body_pose((0.1, 0.2, 0.3))
    assert pos == pytest.approx((0.1, 0.2, 0.2)) and quat == (0.0, 0.0, 0.0, 1.0)


def test_bad_settings_are_refused(tunnel):
    with pytest.raises(ConfigError, match='rest_position'):
        LiveTunnel(tunnel, (0.0,))
    with pytest.raises(ConfigError, match='7 numbers'):
        MocapFrame((0, 0, 0, 1), (0, 0, 0))
    with pytest.raises(ConfigError, match='norm'):
        MocapFrame((0, 0, 0, 0, 0, 0, 2), (0, 0, 0))
    with pytest.raises(ConfigError, match='plate_offset'):
        MocapFrame((0, 0, 0, 0, 0, 0, 1), (0, 0))
