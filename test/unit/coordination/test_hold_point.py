"""coordination.hold_point: one held-plate calibration point, checked and recorded over plain
asyncio ports on simulated pairs (no rclpy): the mean force near the point, and every way a
point fails."""
import asyncio
from types import SimpleNamespace

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination import FAILED, FieldAnswer, IterationStopped
from wind_shaper.coordination.hold_point import (DEFAULT_SAMPLES, DEFAULT_TIMEOUT_S,
                                                 DEFAULT_TOLERANCE_M, FORCE_CATCH_UP_S,
                                                 MIN_POSE_HZ, PointRecorder, check_point,
                                                 hold_point, point_result)
from wind_shaper.core.errors import WindShaperError
from wind_shaper.core.limits import Limits
from wind_shaper.core.tunnel import Sweep


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


def a_point(setup, **kw):
    names = list(setup.geometry.fans.names)
    pwm = [0.0] * len(names)
    pwm[0] = 0.5
    return check_point(Limits(), setup, kw.pop('names', names), kw.pop('pwm', pwm),
                       kw.pop('x', 0.1), kw.pop('y', -0.05), **kw)


def test_a_point_is_checked_and_zeros_mean_the_defaults(setup):
    point = a_point(setup)
    assert point.U[0] == 0.5 and np.count_nonzero(point.U) == 1
    assert (point.tolerance_m, point.samples, point.wait_s) == (DEFAULT_TOLERANCE_M, DEFAULT_SAMPLES,
                                                                DEFAULT_TIMEOUT_S)
    assert point.where == '(+0.100, -0.050) m'
    own = a_point(setup, tolerance_m=0.02, samples=5, timeout_s=30.0)
    assert (own.tolerance_m, own.samples, own.wait_s) == (0.02, 5, 30.0)
    assert own.time_limit(10.0, 10.0, 2.0) == pytest.approx(30.0 + 5 / MIN_POSE_HZ + FORCE_CATCH_UP_S
                                                            + 40.0 + 12.0)


def test_a_bad_point_is_refused_before_any_fan_moves(setup):
    with pytest.raises(WindShaperError, match='not finite'):
        a_point(setup, x=float('nan'))
    with pytest.raises((WindShaperError, ValueError, IndexError)):
        a_point(setup, names=['NOPE'] + list(setup.geometry.fans.names)[1:])
    with pytest.raises((WindShaperError, ValueError, IndexError)):
        a_point(setup, pwm=[2.0] + [0.0] * (setup.geometry.fans.n_fans - 1))
    with pytest.raises(WindShaperError):   # more names than limits.fans allows
        a_point(setup, names=[f'F{i}' for i in range(Limits().fans + 1)])


def test_the_recorder_counts_poses_and_strays_only_while_recording(setup):
    rec = PointRecorder()
    rec.start(a_point(setup))
    for k in range(60):
        rec.on_pose(0.02 * k, 0.1, -0.05)
    assert rec.poses == 0 and rec.verdict(1.0) == ''
    rec.begin_recording()
    rec.on_pose(1.3, 0.1, -0.05)
    rec.on_pose(1.32, 0.1 + 2 * DEFAULT_TOLERANCE_M, -0.05)
    assert (rec.poses, rec.strays) == (2, 1)


def pairs_around(x, y, n=40, spread=0.02, seed=0):
    rng = np.random.default_rng(seed)
    P = np.column_stack([x + rng.uniform(-spread, spread, n), y + rng.uniform(-spread, spread, n)])
    return Sweep(P, 2.0 + P[:, 0], np.arange(n) * 0.01, np.zeros(3))


class Ports:
    """The rig for one point: poses as ``poses(t)`` gives them, pairs from ``sweep``."""

    def __init__(self, recorder, poses, sweep, placed=None):
        self.recorder, self.poses, self.sweep, self.placed = recorder, poses, sweep, placed
        self.t, self.log, self.held = 0.0, [], []

    def hold(self, U):
        self.held.append(np.array(U))

    async def command_fans(self, U):
        self.log.append('commanded')

    def check_boundary(self):
        pass

    async def place(self, x, y, timeout_s):
        self.log.append(('place', x, y))
        return self.placed

    def info(self, message):
        self.log.append(message)

    async def wait_for(self, predicate, timeout_s):
        end = self.t + timeout_s
        while not predicate() and self.t < end:
            self.t += 0.01
            self.recorder.on_pose(self.t, *self.poses(self.t))
        return predicate()

    async def begin_sweep(self):
        self.log.append('begin')

    async def estimate(self, k, U):
        return FieldAnswer(False, 'too few samples for a field', sweep=self.sweep)


def run_point(point, recorder, ports):
    recorder.start(point)
    return asyncio.run(hold_point(point, recorder, ports, still_s=0.5, service_timeout_s=2.0))


def test_a_held_point_records_the_mean_force_of_the_pairs_within_the_tolerance(setup):
    point, rec = a_point(setup), PointRecorder()
    ports = Ports(rec, lambda t: (0.1, -0.05), pairs_around(0.1, -0.05))
    result = run_point(point, rec, ports)
    near = np.hypot(ports.sweep.positions[:, 0] - 0.1, ports.sweep.positions[:, 1] + 0.05) <= 0.01
    assert result.n == int(near.sum()) > 0
    assert result.force_mean == pytest.approx(np.mean(ports.sweep.forces[near]))
    assert result.force_std == pytest.approx(np.std(ports.sweep.forces[near]))
    assert result.x_mean == pytest.approx(np.mean(ports.sweep.positions[near, 0]))
    assert result.message.startswith(f'{result.n} poses at (+0.100, -0.050) m: ')
    assert rec.poses >= DEFAULT_SAMPLES and rec.strays == 0
    # no placement service: the operator is told where to hold the plate
    assert any(isinstance(e, str) and e.startswith('hold the plate at (+0.100, -0.050) m')
               for e in ports.log)
    assert np.allclose(ports.held[0], point.U)


def test_a_placement_that_fails_fails_the_point(setup):
    point, rec = a_point(setup), PointRecorder()
    ports = Ports(rec, lambda t: (0.1, -0.05), pairs_around(0.1, -0.05),
                  placed=SimpleNamespace(success=False, message='stage jammed'))
    with pytest.raises(IterationStopped, match='could not be placed: stage jammed') as stop:
        run_point(point, rec, ports)
    assert stop.value.state == FAILED and ('place', 0.1, -0.05) in ports.log


def test_a_plate_that_is_never_still_at_the_point_fails_it(setup):
    point, rec = a_point(setup, timeout_s=2.0), PointRecorder()
    ports = Ports(rec, lambda t: (0.3, 0.0), pairs_around(0.1, -0.05))
    with pytest.raises(IterationStopped, match='not held still at .* within 2 s: the plate is'):
        run_point(point, rec, ports)
    assert 'begin' not in ports.log


def test_a_plate_that_leaves_the_point_while_recording_fails_it(setup):
    point, rec = a_point(setup), PointRecorder()

    def poses(t):   # still until the recording, then pushed away
        return (0.1, -0.05) if not rec.recording else (0.15, -0.05)

    ports = Ports(rec, poses, pairs_around(0.1, -0.05))
    with pytest.raises(IterationStopped, match='left the point while recording'):
        run_point(point, rec, ports)


def test_no_pairs_fail_the_point_with_the_estimators_words(setup):
    point, rec = a_point(setup), PointRecorder()
    empty = Sweep(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(3))
    ports = Ports(rec, lambda t: (0.1, -0.05), empty)
    with pytest.raises(IterationStopped, match='no \\(force, pose\\) pairs at .*too few samples'):
        run_point(point, rec, ports)


def test_point_result_keeps_only_pairs_near_the_point(setup):
    point = a_point(setup)
    far = Sweep(np.array([[0.1, -0.05], [0.5, 0.5]]), np.array([1.0, 9.0]), np.zeros(2), np.zeros(3))
    result = point_result(point, far)
    assert result.n == 1 and result.force_mean == 1.0 and result.force_std == 0.0
