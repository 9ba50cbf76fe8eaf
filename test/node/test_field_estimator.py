"""field_estimator in-process: sweeps of simulated-tunnel force and pose -> the core's field."""
import shutil
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from wind_shaper_msgs.msg import FieldEstimate, ForceBlock  # noqa: E402
from wind_shaper_msgs.srv import EstimateField, QueryField  # noqa: E402

from wind_shaper.app import Setup  # noqa: E402
from wind_shaper.core.config import default_config_dir  # noqa: E402
from wind_shaper.estimation.align import align_sweep  # noqa: E402
from wind_shaper.storage.journal import load_sweep_samples  # noqa: E402
from wind_shaper.nodes.field_estimator import FieldEstimatorNode  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402
from wind_shaper.ros.convert import estimate_from_msg, seconds_to_stamp, sweep_from_msg  # noqa: E402
from wind_shaper.sim.paths import TourPath  # noqa: E402

pytestmark = pytest.mark.ros

WAIT_S = 10.0          # bound on every wait: a broken node fails the test in seconds
FORCE_PER_POSE = 4     # force samples per pose period (400 Hz force for 100 Hz poses)
HOLD_S = 60.0          # longest a test holds an estimate at its gate [s]
POSE_DT = 0.01         # pose period [s]
U = np.array([0.5, 0.45, 0.55, 0.5, 0.4, 0.6, 0.3])


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


@pytest.fixture(scope='module')
def sim(setup):
    return setup.make_sim(seed=5)


def sweep_streams(sim, n_poses=400, t_start=1000.0, half_disc=False, seed=0):
    """Force (400 Hz) and plate pose (100 Hz) of a sweep over the simulated tunnel at U.

    The plate follows a tour of the sweep disc (sped up so 4 s of stamps cover it); the force at
    each force stamp is the simulator's true plate force at the plate's position then, plus
    noise. Pose stamps sit in the middle of their 4 force samples."""
    rng = np.random.default_rng(seed)
    dt = POSE_DT / FORCE_PER_POSE
    n = n_poses * FORCE_PER_POSE
    xy = TourPath(speed=3.0)(n, dt, sim.geometry.sweep_radius, rng)
    if half_disc:
        xy[:, 0] = -np.abs(xy[:, 0])  # the plate never crosses to x > 0
    force_t = t_start + np.arange(n) * dt
    force = sim.true_field(U, xy) + rng.normal(0, 0.03, n)
    idx = np.arange(n_poses) * FORCE_PER_POSE + 1
    pose_t = force_t[idx] + dt / 2
    return force_t, force, pose_t, xy[idx]


class Harness:
    """The node under test and a helper node (publishers, clients) on one spinning executor."""

    def __init__(self, context, journal_dir, overrides=(), per_sample=False):
        """per_sample: the force as one WrenchStamped per sample (force_block_topic ''), else
        in ForceBlocks as force_sensor sends it."""
        self.per_sample = per_sample
        if per_sample:
            overrides = [*overrides, Parameter('force_block_topic', value='')]
        self.node = FieldEstimatorNode(context=context, parameter_overrides=[
            Parameter('journal_dir', value=str(journal_dir)), *overrides])
        self.peer = rclpy.create_node('field_estimator_test_peer', context=context)
        self.force_pub = (self.peer.create_publisher(WrenchStamped, names.FORCE, qos.STREAM)
                          if per_sample else
                          self.peer.create_publisher(ForceBlock, names.FORCE_BLOCK, qos.STREAM))
        self.pose_pub = self.peer.create_publisher(PoseStamped, names.PLATE_POSE, qos.STREAM)
        self.begin = self.peer.create_client(Trigger, names.BEGIN_SWEEP)
        self.estimate = self.peer.create_client(EstimateField, names.ESTIMATE_FIELD)
        self.query = self.peer.create_client(QueryField, names.QUERY_FIELD)
        self.fields = []
        self.peer.create_subscription(FieldEstimate, names.FIELD, self.fields.append, qos.LATCHED)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, args=(context,), daemon=True)
        self.thread.start()
        assert self.begin.wait_for_service(timeout_sec=WAIT_S)
        assert self.estimate.wait_for_service(timeout_sec=WAIT_S)

    def _spin(self, context):
        while not self.stop.is_set() and context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def call(self, client, request):
        future = client.call_async(request)
        assert wait_until(future.done), f'{client.srv_name} did not answer within {WAIT_S} s'
        return future.result()

    def begin_sweep(self):
        """The node subscribes to the streams at begin_sweep and answers once both publishers
        send to it: what is published after the answer is collected."""
        answer = self.call(self.begin, Trigger.Request())
        assert (self.force_pub.get_subscription_count(), self.pose_pub.get_subscription_count()) == (1, 1)
        return answer

    def listening(self):
        """(force, pose) subscriptions of the node that the peer's publishers send to."""
        return self.force_pub.get_subscription_count(), self.pose_pub.get_subscription_count()

    def estimate_field(self, iteration=0, fan_names=None, pwm=U, peek=False, required=()):
        names_ = list(fan_names if fan_names is not None else self.node._fan_names)
        return self.call(self.estimate, EstimateField.Request(
            iteration=iteration, fan_names=names_, pwm=[float(u) for u in pwm], peek=peek,
            required=[bool(v) for v in required]))

    def query_field(self, x, y):
        return self.call(self.query, QueryField.Request(x=[float(v) for v in x], y=[float(v) for v in y]))

    def publish(self, force_t, force, pose_t, pose_xy, expect_buffered=True):
        """Publish the streams in time order, in chunks the node keeps up with (KEEP_LAST
        queues drop what a subscriber has not taken yet, and this test counts every sample)."""
        rows = sorted([(t, 0, f, 0.0) for t, f in zip(force_t, force)]
                      + [(t, 1, x, y) for t, (x, y) in zip(pose_t, pose_xy)])
        n_force = n_pose = 0
        block = ForceBlock()

        def send_block():
            if len(block.stamp):
                self.force_pub.publish(block)
            block.stamp, block.force_z = [], []
        for start in range(0, len(rows), 50):
            for t, kind, a, b in rows[start:start + 50]:
                if kind == 0 and not self.per_sample:
                    block.stamp.append(float(t))
                    block.force_z.append(float(a))
                    n_force += 1
                elif kind == 0:
                    msg = WrenchStamped()
                    msg.header.stamp = seconds_to_stamp(t)
                    msg.wrench.force.z = float(a)
                    self.force_pub.publish(msg)
                    n_force += 1
                else:
                    send_block()
                    msg = PoseStamped()
                    msg.header.stamp = seconds_to_stamp(t)
                    msg.header.frame_id = names.TUNNEL_FRAME
                    msg.pose.position.x, msg.pose.position.y = float(a), float(b)
                    msg.pose.orientation.w = 1.0
                    self.pose_pub.publish(msg)
                    n_pose += 1
            send_block()
            if expect_buffered:
                have = lambda: (len(self.node._force), len(self.node._pose))   # noqa: E731
                assert wait_until(lambda: have() == (n_force, n_pose)), \
                    f'the node has (forces, poses) {have()} of {(n_force, n_pose)} published'

    def close(self):
        self.stop.set()  # stop spinning before the shutdown (rclpy races otherwise)
        self.thread.join(timeout=WAIT_S)
        self.executor.shutdown(timeout_sec=WAIT_S)
        self.node.destroy_node()
        self.peer.destroy_node()


def wait_until(predicate, timeout=WAIT_S, period=0.005):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return bool(predicate())


@pytest.fixture
def harness(ros_context, tmp_path):
    h = Harness(ros_context, tmp_path / 'journal')
    yield h
    h.close()



def stamp_seconds(stamp):
    return stamp.sec + 1e-9 * stamp.nanosec


def test_estimate_is_the_core_estimate_of_the_aligned_pairs(harness, sim, setup):
    streams = sweep_streams(sim)
    assert harness.begin_sweep().success
    harness.publish(*streams)
    resp = harness.estimate_field(iteration=3)
    assert resp.success, resp.message
    force_t, force, pose_t, pose_xy = streams
    # the pairs are estimation.align's pairs of exactly what was published: one per pose
    expected = align_sweep(force_t, force, pose_t, pose_xy[:, 0], pose_xy[:, 1], U)
    got = sweep_from_msg(resp.samples)
    assert len(got) == len(pose_t) == 400
    np.testing.assert_array_equal(got.positions, expected.positions)
    np.testing.assert_allclose(got.forces, expected.forces, rtol=0, atol=1e-12)
    # stamps survive the message round trip to well under a microsecond
    np.testing.assert_allclose(got.times, expected.times, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(got.pwm, U)
    # and the field is the core FieldEstimator's on those pairs (computed in the node's worker
    # process on one BLAS thread: the rounding, and so where the hyperparameter fit stops,
    # differs from this process's, the std by a few 1e-7 with the length scale at its bound),
    # with the GP's length scale bounded by the prior's fan footprints, as the node reads the
    # prior from its config folder
    estimator = setup.shaping.make_estimator(setup.load_model())
    core = estimator.estimate(got, setup.geometry.key_points)
    kp, mean, std = estimate_from_msg(resp.estimate)
    np.testing.assert_array_equal(kp, setup.geometry.key_points)
    np.testing.assert_allclose(mean, core.mean, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(std, core.std, rtol=1e-5, atol=1e-9)
    # the bound matters on this sweep: without it the fit takes a longer length and another std
    free = replace(estimator, max_length_scale=None).estimate(got, setup.geometry.key_points)
    assert free.gp.params_.length_scale > core.gp.params_.length_scale
    assert not np.allclose(std, free.std, rtol=1e-3)
    assert resp.estimate.n_used == core.n_used and resp.estimate.n_samples == 400
    assert resp.estimate.iteration == resp.samples.iteration == 3
    assert list(resp.estimate.pwm) == list(U)
    assert resp.estimate.header.frame_id == names.TUNNEL_FRAME
    assert stamp_seconds(resp.samples.header.stamp) == pytest.approx(pose_t[0], abs=1e-6)
    assert stamp_seconds(resp.estimate.header.stamp) == pytest.approx(pose_t[-1], abs=1e-6)
    # a real field: close to the simulator's truth at the key points
    truth = sim.true_field(U, setup.geometry.key_points)
    assert np.sqrt(np.mean((mean - truth) ** 2)) < 0.1
    # published latched on /wind_shaper/field
    assert wait_until(lambda: len(harness.fields) == 1)
    np.testing.assert_array_equal(harness.fields[0].mean, resp.estimate.mean)


def test_the_force_per_sample_gives_the_same_pairs_and_field_as_in_blocks(
        ros_context, tmp_path, sim):
    """force_block_topic '' reads one WrenchStamped per sample (a lab's own force driver, a
    bag replayed): the same samples give the same pairs and field as the blocks do."""
    streams = sweep_streams(sim, seed=7)
    answers = []
    for per_sample in (False, True):
        h = Harness(ros_context, tmp_path / f'journal-{per_sample}', per_sample=per_sample)
        try:
            assert h.begin_sweep().success
            h.publish(*streams)
            resp = h.estimate_field(iteration=1)
            assert resp.success, resp.message
            answers.append(resp)
        finally:
            h.close()
    blocks, samples = (sweep_from_msg(r.samples) for r in answers)
    assert len(blocks) == len(samples) == 400
    # the per-sample stamps pass through integer nanoseconds, the blocks' do not
    np.testing.assert_allclose(samples.forces, blocks.forces, rtol=0, atol=1e-9)
    np.testing.assert_allclose(answers[1].estimate.mean, answers[0].estimate.mean, atol=1e-6)


def test_a_force_block_with_unequal_columns_is_dropped_and_collection_goes_on(harness, sim):
    assert harness.begin_sweep().success
    bad = ForceBlock(stamp=[1000.0, 1000.001], force_z=[1.0])
    harness.force_pub.publish(bad)
    good = ForceBlock(stamp=[1000.002, 1000.003], force_z=[1.0, 2.0])
    harness.force_pub.publish(good)
    assert wait_until(lambda: len(harness.node._force) == 2)
    time.sleep(0.2)
    assert len(harness.node._force) == 2
    np.testing.assert_array_equal(harness.node._force.arrays()[1], [1.0, 2.0])


def test_collection_stops_at_estimate_and_restarts_at_begin(harness, sim):
    # between sweeps the node takes neither stream (it would cost it a sixth of a core)
    assert wait_until(lambda: harness.listening() == (0, 0)), harness.listening()
    streams = sweep_streams(sim, seed=1)
    harness.begin_sweep()
    harness.publish(*streams)
    assert harness.estimate_field().success
    assert wait_until(lambda: harness.listening() == (0, 0)), harness.listening()
    later = sweep_streams(sim, n_poses=50, t_start=2000.0, seed=2)
    harness.publish(*later, expect_buffered=False)
    time.sleep(0.2)
    assert (len(harness.node._force), len(harness.node._pose)) == (1600, 400)  # nothing added
    harness.begin_sweep()
    # cleared: whatever is buffered now can only be late deliveries of the second batch
    assert harness.node._collecting
    for buffer in (harness.node._force, harness.node._pose):
        assert np.all(buffer.arrays()[0] >= 2000.0)


def test_every_sample_is_journaled_and_a_new_node_takes_an_unfinished_sweep_back(
        ros_context, tmp_path, sim, setup):
    journal_dir = tmp_path / 'journal'
    streams = sweep_streams(sim, seed=4)
    force_t, force, pose_t, pose_xy = streams
    first = Harness(ros_context, journal_dir)
    try:
        assert first.begin_sweep().success
        half_force, half_pose = len(force_t) // 2, len(pose_t) // 2
        first.publish(force_t[:half_force], force[:half_force], pose_t[:half_pose],
                      pose_xy[:half_pose])
        (folder,) = [p.parent for p in journal_dir.glob('sweep-*/OPEN')]
        on_disk_force, on_disk_pose = load_sweep_samples(folder)
        np.testing.assert_array_equal(on_disk_force[:, 0], force_t[:half_force])
        np.testing.assert_array_equal(on_disk_pose[:, 1:], pose_xy[:half_pose])
    finally:
        first.close()                               # the node goes away mid-sweep
    second = Harness(ros_context, journal_dir)       # ... and a new one starts
    try:
        assert second.node._collecting and len(second.node._force) == half_force
        # a node that takes a sweep back listens from its start
        assert wait_until(lambda: second.listening() == (1, 1)), second.listening()
        second.publish(force_t[half_force:], force[half_force:], pose_t[half_pose:],
                       pose_xy[half_pose:], expect_buffered=False)
        assert wait_until(lambda: len(second.node._force) == len(force_t)
                          and len(second.node._pose) == len(pose_t))
        resp = second.estimate_field()
        assert resp.success, resp.message
        expected = align_sweep(force_t, force, pose_t, pose_xy[:, 0], pose_xy[:, 1], U)
        np.testing.assert_array_equal(sweep_from_msg(resp.samples).positions, expected.positions)
        assert (folder / 'outcome').read_text() == 'estimated\n'
        assert len(load_sweep_samples(folder)[0]) == len(force_t)
    finally:
        second.close()


def test_estimate_without_a_sweep_says_to_begin_one(harness):
    resp = harness.estimate_field()
    assert not resp.success and 'call begin_sweep' in resp.message


@pytest.mark.fault
def test_no_samples_fails_and_collection_goes_on(harness, sim, fault_row):
    harness.begin_sweep()
    resp = harness.estimate_field()
    assert not resp.success
    assert 'no finite force sample' in resp.message and '0 force and 0 pose' in resp.message
    # state unchanged: still collecting, so the sweep can go on and the estimate be asked again
    harness.publish(*sweep_streams(sim, n_poses=250, seed=3))
    resp = harness.estimate_field()
    assert resp.success, resp.message
    fault_row('a sweep with too few samples',
              'refused with the counts; collection goes on', True)


@pytest.mark.fault
def test_poor_coverage_fails_with_the_gap_and_publishes_nothing(harness, sim, fault_row):
    harness.begin_sweep()
    harness.publish(*sweep_streams(sim, n_poses=250, half_disc=True, seed=4))
    resp = harness.estimate_field()
    assert not resp.success
    assert 'missed' in resp.message and 'sweep the plate over the whole area' in resp.message
    time.sleep(0.2)
    assert harness.fields == []  # the latched field is not replaced by a failed estimate
    fault_row('sweep with poor coverage of the key points',
              'refused with the largest gap; nothing published; the coordinator sweeps again', True)


def test_a_region_sweep_needs_only_its_key_points_passed(harness, sim):
    """The same half-disc sweep the previous test refuses is estimated when only the key points
    of that half are required (a region sweep); a malformed flag list is refused first and
    leaves the sweep to estimate."""
    kp = harness.node._key_points
    harness.begin_sweep()
    harness.publish(*sweep_streams(sim, n_poses=250, half_disc=True, seed=4))
    resp = harness.estimate_field(required=[True, False])
    assert not resp.success and 'flags 2 key points' in resp.message, resp.message
    resp = harness.estimate_field(required=[False] * len(kp))
    assert not resp.success and 'no key point' in resp.message, resp.message
    half = kp[:, 0] < -0.05
    resp = harness.estimate_field(peek=True, required=half)
    assert resp.success, resp.message
    resp = harness.estimate_field(required=half)
    assert resp.success, resp.message
    std = np.asarray(resp.estimate.std)
    assert np.max(std[half]) < np.max(std[kp[:, 0] > 0.2])


def test_a_peek_publishes_the_field_so_far_for_the_live_view(harness, sim):
    """While the plate has covered half the disc, a peek is refused for the gaps, but the field
    of the sweep so far goes out on wind_shaper/field/partial: the live view shows it forming,
    with a large std where the plate has not been."""
    partial = []
    harness.peer.create_subscription(FieldEstimate, names.FIELD_PARTIAL, partial.append, qos.COMMAND)
    time.sleep(0.3)
    harness.begin_sweep()
    harness.publish(*sweep_streams(sim, n_poses=250, half_disc=True, seed=4))
    resp = harness.estimate_field(peek=True)
    assert not resp.success and 'missed' in resp.message
    assert wait_until(lambda: partial, 3.0), 'no partial field published'
    kp = harness.node._key_points
    std = np.asarray(partial[-1].std)
    assert len(std) == len(kp)
    assert np.median(std[kp[:, 0] < -0.1]) < 0.5 * np.median(std[kp[:, 0] > 0.15])
    time.sleep(0.2)
    assert harness.fields == []   # the estimate of a finished sweep is not replaced


@pytest.mark.fault
def test_streams_out_of_step_are_reported(harness, sim, fault_row):
    force_t, force, pose_t, pose_xy = sweep_streams(sim, n_poses=200, seed=5)
    harness.begin_sweep()
    harness.publish(force_t + 30.0, force, pose_t, pose_xy)
    resp = harness.estimate_field()
    assert not resp.success and 'out of step' in resp.message
    fault_row('force and pose streams out of step in time',
              'estimate refused with both time spans; buffers kept', True)


def test_a_request_for_other_fans_is_refused(harness, sim):
    harness.begin_sweep()
    harness.publish(*sweep_streams(sim, n_poses=100, seed=6))
    resp = harness.estimate_field(fan_names=['LM1', 'XX'], pwm=[0.5, 0.5])
    assert not resp.success and "['XX']" in resp.message and 'config_dir' in resp.message
    resp = harness.estimate_field(fan_names=['LM1'], pwm=[0.5, 0.5])
    assert not resp.success and 'one per fan' in resp.message


def test_buffers_keep_only_max_buffer_s(ros_context, sim, tmp_path):
    h = Harness(ros_context, tmp_path / 'journal', [Parameter('max_buffer_s', value=2.0)])
    try:
        h.begin_sweep()
        force_t, force, pose_t, pose_xy = sweep_streams(sim, seed=7)  # 4 s of stamps
        h.publish(force_t, force, pose_t, pose_xy, expect_buffered=False)
        assert wait_until(lambda: h.node._force.dropped > 0 and len(h.node._pose) > 0)
        t, _ = h.node._force.arrays()
        assert t.max() - t.min() <= 2.0 and len(t) <= 801
    finally:
        h.close()


def test_a_sweep_nobody_asks_about_lets_go_of_the_streams_and_keeps_its_samples(
        ros_context, sim, tmp_path):
    """An iteration cancelled mid-sweep never calls estimate: after max_buffer_s with no call
    the node takes neither stream (the force sensor and the relay may rest), and what it had
    collected still gives the estimate."""
    h = Harness(ros_context, tmp_path / 'journal', [Parameter('max_buffer_s', value=5.0)])
    try:
        h.begin_sweep()
        h.publish(*sweep_streams(sim, seed=8))
        assert h.estimate_field(peek=True).success           # a call: the sweep goes on
        assert h.listening() == (1, 1)
        assert wait_until(lambda: h.listening() == (0, 0)), h.listening()
        assert h.estimate_field().success                     # nothing collected was lost
    finally:
        h.close()


def test_a_peek_estimates_what_is_collected_so_far_and_collection_goes_on(harness, sim):
    first = sweep_streams(sim, n_poses=400, seed=3)
    assert harness.begin_sweep().success
    half = 800   # the first half of the force samples, and the poses among them
    poses = first[2] < first[0][half]
    harness.publish(first[0][:half], first[1][:half], first[2][poses], first[3][poses])
    early = harness.estimate_field(peek=True)
    assert not early.success and 'missed' in early.message   # half the tour: gaps left
    assert len(early.samples.t) == int(poses.sum())          # its pairs, for the coverage
    harness.publish(first[0][half:], first[1][half:], first[2][~poses], first[3][~poses],
                    expect_buffered=False)
    assert wait_until(lambda: (len(harness.node._force), len(harness.node._pose)) == (1600, 400))
    peek = harness.estimate_field(peek=True)
    assert peek.success, peek.message
    assert harness.node._collecting and harness.fields == []  # nothing published, still collecting
    final = harness.estimate_field()
    assert final.success and not harness.node._collecting
    np.testing.assert_array_equal(peek.estimate.mean, final.estimate.mean)


def test_the_field_can_be_queried_anywhere_in_the_measured_disc(harness, sim, setup, fault_row):
    refused = harness.query_field([0.0], [0.0])
    assert not refused.success and 'no field has been estimated' in refused.message
    harness.begin_sweep()
    harness.publish(*sweep_streams(sim, seed=4))
    est = harness.estimate_field(iteration=7)
    assert est.success
    # between the key points too: the GP of that estimate, close to the simulator's truth
    rng = np.random.default_rng(0)
    r, a = 0.3 * np.sqrt(rng.uniform(0, 1, 40)), rng.uniform(0, 2 * np.pi, 40)
    x, y = r * np.cos(a), r * np.sin(a)
    got = harness.query_field(x, y)
    assert got.success, got.message
    assert got.iteration == 7 and stamp_seconds(got.stamp) == pytest.approx(
        stamp_seconds(est.estimate.header.stamp), abs=1e-6)
    truth = sim.true_field(U, np.column_stack([x, y]))
    assert np.sqrt(np.mean((np.asarray(got.force) - truth) ** 2)) < 0.12
    assert np.all(np.asarray(got.std) > 0) and np.all(np.asarray(got.std) < 0.2)
    # at a key point it is the published estimate
    kp = setup.geometry.key_points[[0, 150]]
    at_kp = harness.query_field(kp[:, 0], kp[:, 1])
    np.testing.assert_allclose(at_kp.force, np.asarray(est.estimate.mean)[[0, 150]], atol=1e-9)
    # bad requests: refused with the reason, the node keeps answering
    outside = harness.query_field([0.0, 0.5], [0.0, 0.0])
    assert not outside.success and 'outside the measured disc' in outside.message
    uneven = harness.query_field([0.0, 0.1], [0.0])
    assert not uneven.success and 'one (x, y) pair per position' in uneven.message
    nan = harness.query_field([float('nan')], [0.0])
    assert not nan.success and 'not a finite number' in nan.message
    assert harness.query_field([0.1], [0.1]).success
    fault_row('a field query outside the tunnel, uneven or NaN, or before any estimate',
              'refused with the reason; the estimator keeps answering', True)


@pytest.mark.parametrize('in_worker', [True, False], ids=['worker', 'executor'])
def test_samples_and_calls_are_taken_while_an_estimate_is_computed(ros_context, sim, tmp_path,
                                                                   in_worker, monkeypatch):
    """With the estimate in the worker process the executor goes on during a long estimate: a
    parameter call is answered and new samples are buffered before the peek's answer (on the
    executor thread, the old way, neither happens until the estimate is done).

    The estimate is held at a gate the test opens, so "long" does not depend on the machine's
    speed: the real estimate runs once the gate opens."""
    import wind_shaper.nodes.field_estimator as fe_module
    gate, entered = threading.Event(), threading.Event()

    def held(compute):
        def wrapper(*args):
            entered.set()
            gate.wait(timeout=HOLD_S)
            return compute(*args)
        return wrapper

    h = Harness(ros_context, tmp_path / 'journal', overrides=[
        Parameter('estimate_worker', value=in_worker)])
    try:
        if in_worker:
            monkeypatch.setattr(h.node._worker, 'run', held(h.node._worker.run))
        else:
            monkeypatch.setattr(fe_module, 'align_and_estimate', held(fe_module.align_and_estimate))
        from rcl_interfaces.srv import ListParameters
        params = h.peer.create_client(ListParameters, f'/{names.FIELD_ESTIMATOR}/list_parameters')
        assert params.wait_for_service(timeout_sec=WAIT_S)
        assert h.begin_sweep().success
        force_t, force, pose_t, pose_xy = sweep_streams(sim, n_poses=6000, seed=9)
        cut = 5800 * FORCE_PER_POSE
        h.publish(force_t[:cut], force[:cut], pose_t[:5800], pose_xy[:5800])
        peek = h.estimate.call_async(EstimateField.Request(
            iteration=1, fan_names=list(h.node._fan_names), pwm=[float(u) for u in U], peek=True))
        assert entered.wait(timeout=WAIT_S), 'the peek never reached the estimate'
        answered = params.call_async(ListParameters.Request())
        h.publish(force_t[cut:], force[cut:], pose_t[5800:], pose_xy[5800:], expect_buffered=False)
        # the worker's executor answers within WAIT_S; the blocked one cannot before the gate
        # opens itself after HOLD_S
        during = wait_until(lambda: answered.done() and len(h.node._pose) == 6000,
                            timeout=WAIT_S if in_worker else 3.0)
        during = during and not peek.done()
        gate.set()
        assert wait_until(peek.done, timeout=60.0) and peek.result().success, peek.result().message
        assert wait_until(lambda: answered.done() and len(h.node._pose) == 6000, timeout=WAIT_S)
        if in_worker:
            assert during, 'the call or the samples waited for the estimate'
        else:
            assert not during, 'the executor answered during its own estimate'
    finally:
        h.close()


def test_without_a_prior_the_length_scale_is_fitted_within_its_bounds_alone(ros_context, sim, tmp_path):
    # a config folder with no model file yet (commissioning): the node starts, says so, and
    # estimates with the length scale bounded by length_scale_bounds only
    config = tmp_path / 'config'
    shutil.copytree(default_config_dir(), config)
    (config / 'model.yaml').unlink()
    h = Harness(ros_context, tmp_path / 'journal', [Parameter('config_dir', value=str(config))])
    try:
        assert h.node._estimator.max_length_scale is None
        h.begin_sweep()
        h.publish(*sweep_streams(sim, seed=8))
        resp = h.estimate_field(iteration=1)
        assert resp.success, resp.message
    finally:
        h.close()
    # with the shipped prior the same node bounds it by the jets' footprints
    h = Harness(ros_context, tmp_path / 'journal2')
    try:
        assert h.node._estimator.max_length_scale == pytest.approx(
            Setup.load().load_model().k1.sigma, rel=0.03)
    finally:
        h.close()
