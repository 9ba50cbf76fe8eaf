"""Bags in one process: the player's messages all arrive, in order, byte for byte, at the bag's
rate; the recorder keeps what live publishers send (latched messages included) byte for byte.
How closely each message keeps its recorded offset is measured by bench/replay_timing.py."""
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from wind_shaper.bag import topics as bt  # noqa: E402
from wind_shaper_msgs.msg import FanCommand  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402

from wind_shaper.bag import BagReader, read_sweeps, write_sweep_bag  # noqa: E402
from wind_shaper.bag.player import Player, message_class  # noqa: E402
from wind_shaper.bag.recorder import Recorder  # noqa: E402
from wind_shaper.core.geometry import TunnelGeometry  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402
from wind_shaper.sim import SimulatedTunnel  # noqa: E402

pytestmark = pytest.mark.ros

WAIT_S = 10.0  # bound on discovery and delivery waits


def wait_until(condition, timeout_s=WAIT_S, step_s=0.01):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step_s)
    return condition()


@pytest.fixture(scope='module')
def sweep_bag(tmp_path_factory):
    """One 1.5 s sweep: force 1 kHz, plate and mocap pose 100 Hz, commands, status (~2.3 s)."""
    geometry = TunnelGeometry.paper_rig()
    sim = SimulatedTunnel(geometry, seed=3, sample_rate_hz=100.0)
    sim.apply(np.full(geometry.fans.n_fans, 0.5))
    return write_sweep_bag(tmp_path_factory.mktemp('bags') / 'sweep', [sim.sweep(150)],
                           settle_s=0.2, idle_streams=False)


class Listener:
    """Raw subscriptions to every topic of a bag, spun by an events executor in a thread;
    records (topic, arrival time [s, monotonic], raw bytes)."""

    def __init__(self, context, topics: dict):
        self.node = rclpy.create_node('bag_replay_listener', context=context)
        self.received = []
        deep = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
        for topic, info in topics.items():
            self.node.create_subscription(message_class(info.msgtype), topic, self._callback(topic),
                                          deep, raw=True)
        self.executor = EventsExecutor(context=context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _callback(self, topic):
        def on_message(raw):
            self.received.append((topic, time.monotonic(), raw))
        return on_message

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self._stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.mark.slow
@pytest.mark.parametrize('rate', [1.0, 4.0])
def test_replay_delivers_every_message_in_order_at_the_bags_rate(ros_context, sweep_bag, rate):
    with BagReader(sweep_bag) as bag:
        topics = bag.topics
        recorded = list(bag.messages())
    listener = Listener(ros_context, topics)
    player = Player(sweep_bag, rate=rate, context=ros_context, wait_for_subscribers_s=WAIT_S)
    try:
        stats = player.play()
        assert wait_until(lambda: len(listener.received) >= len(recorded))
    finally:
        player.destroy()
        listener.close()

    assert stats.total == len(recorded) and stats.passes == 1
    got = listener.received
    counts = {t: sum(1 for tt, _, _ in got if tt == t) for t in topics}
    assert len(got) == len(recorded), f'got {counts} of {[(t, i.count) for t, i in topics.items()]}'
    for topic in topics:  # per topic: same bytes, same order
        assert [r for t, _, r in got if t == topic] == [bytes(r) for t, _, r in recorded if t == topic]
    # The rate is honoured: the replay never runs ahead of the bag's time / rate, and a faster
    # rate is clearly faster than the bag's own time. No tight upper bound: a loaded host stalls
    # processes (a run beside a benchmark took 3.4 s for 1.9 s of bag at rate 1); how closely
    # each message keeps its offset is bench/replay_timing.py's figure, not a pass/fail bound.
    t_bag = np.array([t for _, t, _ in recorded], dtype=float) * 1e-9
    duration = t_bag[-1] - t_bag[0]
    expected = duration / rate
    arrivals = sorted(a for _, a, _ in got)
    span = arrivals[-1] - arrivals[0]
    assert span > 0.8 * expected, f'replay took {span:.3f} s for {expected:.3f} s of bag at rate {rate}'
    if rate > 1:
        assert span < 0.75 * duration, \
            f'replay at rate {rate} took {span:.3f} s, not faster than the bag\'s {duration:.3f} s'
    late = np.asarray(stats.late_s)
    assert len(late) == min(stats.total, stats.LATE_KEPT) and np.all(np.isfinite(late))


def test_restamp_moves_header_stamps_to_the_replay_time_and_keeps_their_spacing(
        ros_context, sweep_bag):
    with BagReader(sweep_bag) as bag:
        topics = {bt.PLATE_POSE: bag.topics[bt.PLATE_POSE]}
        recorded = [msg.header.stamp for _, _, msg in bag.decoded([bt.PLATE_POSE])]
    listener = Listener(ros_context, topics)
    player = Player(sweep_bag, rate=8.0, topics=[bt.PLATE_POSE], restamp=True,
                    context=ros_context, wait_for_subscribers_s=WAIT_S)
    try:
        started = time.time()
        player.play()
        assert wait_until(lambda: len(listener.received) >= len(recorded))
    finally:
        player.destroy()
        listener.close()
    from rclpy.serialization import deserialize_message
    from geometry_msgs.msg import PoseStamped
    got = [deserialize_message(raw, PoseStamped).header.stamp for _, _, raw in listener.received]
    ns = np.array([s.sec * 10**9 + s.nanosec for s in got], dtype=np.int64)
    ns0 = np.array([s.sec * 10**9 + s.nanosec for s in recorded], dtype=np.int64)
    assert abs(ns[0] * 1e-9 - started) < 1.0  # now, not 2023
    np.testing.assert_array_equal(np.diff(ns), np.diff(ns0))  # spacing kept to the nanosecond


def test_loop_repeats_until_stopped(ros_context, sweep_bag):
    with BagReader(sweep_bag) as bag:
        n_status = bag.topics[bt.STATUS].count
    player = Player(sweep_bag, rate=20.0, topics=[bt.STATUS], loop=True, context=ros_context)
    passes = []

    def on_pass(n):
        passes.append(n)
        if n == 3:
            player.stop()
    try:
        stats = player.play(on_pass=on_pass)
    finally:
        player.destroy()
    assert stats.passes == 3 and stats.published == {bt.STATUS: 3 * n_status}


def test_player_refuses_topics_the_bag_does_not_have(ros_context, sweep_bag):
    with pytest.raises(Exception, match='has no topic /not/there; it has /wind_shaper/force'):
        Player(sweep_bag, topics=['/not/there'], context=ros_context)
    with pytest.raises(ValueError, match='rate must be > 0'):
        Player(sweep_bag, rate=0.0, context=ros_context)


@pytest.mark.slow
def test_recorder_keeps_live_messages_byte_for_byte_including_a_latched_one(ros_context, tmp_path):
    node = rclpy.create_node('bag_record_talker', context=ros_context)
    latched = node.create_publisher(FanCommand, bt.FAN_COMMAND, qos.LATCHED)
    force = node.create_publisher(WrenchStamped, bt.FORCE, qos.STREAM)
    first = FanCommand(names=['fan_00'], pwm=[0.25])
    latched.publish(first)  # before the recorder exists: only transient local gets it
    recorder = Recorder(tmp_path / 'rec', [bt.FAN_COMMAND, bt.FORCE, bt.FIELD],
                        context=ros_context, discovery_period_s=0.05)
    thread = threading.Thread(target=recorder.record, daemon=True)
    thread.start()
    sent = []
    try:
        assert wait_until(lambda: force.get_subscription_count() == 1
                          and latched.get_subscription_count() == 1), 'recorder never subscribed'
        for k in range(300):
            msg = WrenchStamped()
            msg.header.stamp.sec, msg.header.frame_id = k, names.SENSOR_FRAME
            msg.wrench.force.z = 0.01 * k
            force.publish(msg)
            sent.append(msg)
            time.sleep(0.001)
        latched.publish(FanCommand(names=['fan_00'], pwm=[0.75]))
        assert wait_until(lambda: recorder.stats.counts.get(bt.FORCE, 0) == len(sent)
                          and recorder.stats.counts.get(bt.FAN_COMMAND, 0) == 2)
    finally:
        recorder.stop()
        thread.join(timeout=WAIT_S)
        node.destroy_node()
    assert not thread.is_alive()
    stats = recorder.stats
    assert stats.missing == [bt.FIELD] and stats.counts[bt.FORCE] == len(sent)
    with BagReader(tmp_path / 'rec') as bag:
        topics = bag.topics
        rows = list(bag.decoded([bt.FORCE, bt.FAN_COMMAND]))
    assert topics[bt.FORCE].msgtype == 'geometry_msgs/msg/WrenchStamped'
    offered = topics[bt.FAN_COMMAND].qos[0]  # as DDS reports it (no history/depth), like ros2 bag
    assert (offered.durability.name, offered.reliability.name) == ('TRANSIENT_LOCAL', 'RELIABLE')
    assert topics[bt.FORCE].qos[0].durability.name == 'VOLATILE'
    assert [m.pwm[0] for t, _, m in rows if t == bt.FAN_COMMAND] == [0.25, 0.75]
    forces = [m for t, _, m in rows if t == bt.FORCE]
    assert [m.header.stamp.sec for m in forces] == list(range(300))
    assert [m.wrench.force.z for m in forces] == [0.01 * k for k in range(300)]
    times = [t for _, t, _ in rows]
    assert times == sorted(times) and abs(times[-1] * 1e-9 - time.time()) < 30


def test_a_recorder_stopped_at_once_leaves_a_readable_empty_bag(ros_context, tmp_path):
    recorder = Recorder(tmp_path / 'empty', [bt.FORCE], context=ros_context)
    stats = recorder.record(duration_s=0.2)
    assert stats.total == 0 and stats.missing == [bt.FORCE]
    with BagReader(tmp_path / 'empty') as bag:
        assert bag.message_count == 0
    with pytest.raises(Exception, match='no messages on /wind_shaper/force'):
        read_sweeps(tmp_path / 'empty')
