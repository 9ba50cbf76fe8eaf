"""mocap_relay in-process: transform, stamps, dropped NaN and jumps, dropout and outside flags."""
import math
import threading
import time
from dataclasses import fields
from pathlib import Path

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from wind_shaper.core.errors import ConfigError  # noqa: E402
from wind_shaper.estimation.frames import quat_to_yaw  # noqa: E402
from wind_shaper.nodes.mocap_relay import MocapRelayNode, MocapRelayParams  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402

from waiting import wait_for  # noqa: E402

pytestmark = pytest.mark.ros
CONFIG = Path(__file__).resolve().parents[2] / 'config' / 'mocap_relay.yaml'
S = math.sqrt(0.5)
# tunnel = mocap turned +90 deg about z and shifted; the plate centre 5 cm below the body origin
CALIBRATION = dict(tunnel_from_mocap=[0.1, -0.2, 0.0, 0.0, 0.0, S, S],
                   plate_offset=[0.0, 0.0, -0.05], max_speed_m_s=3.0, dropout_timeout_s=0.3,
                   max_radius_m=0.4)


def pose(t, xyz, q=(0.0, 0.0, 0.0, 1.0), frame='mocap'):
    msg = PoseStamped()
    msg.header.stamp = Time(sec=int(t), nanosec=int(round((t % 1) * 1e9)))
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, xyz)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = map(float, q)
    return msg


def relay_status(diagnostics):
    """The values of the relay's newest status among ``diagnostics``, with its level and
    message (None: none yet)."""
    for msg in reversed(diagnostics):
        for status in msg.status:
            if status.name.startswith(names.MOCAP_RELAY):
                return {kv.key: kv.value for kv in status.values} | {
                    '_level': status.level, '_message': status.message}
    return None


@pytest.fixture
def relay(ros_context):
    """(node, send(msg), received list, diag() -> next diagnostics values)."""
    executor = SingleThreadedExecutor(context=ros_context)
    client = rclpy.create_node('mocap_relay_test_client', context=ros_context)
    node = MocapRelayNode(context=ros_context, parameter_overrides=[
        Parameter(k, value=v) for k, v in CALIBRATION.items()])
    received, diagnostics = [], []
    pub = client.create_publisher(PoseStamped, names.MOCAP_POSE, 10)
    client.create_subscription(PoseStamped, names.PLATE_POSE, received.append, qos.STREAM)
    client.create_subscription(DiagnosticArray, names.DIAGNOSTICS, diagnostics.append, 10)
    for n in (client, node):
        executor.add_node(n)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    assert wait_for(lambda: pub.get_subscription_count() >= 1
                    and node._pub.get_subscription_count() >= 1)

    def diag(timeout_s=2.5):
        diagnostics.clear()
        return wait_for(lambda: relay_status(diagnostics), timeout_s)
    try:
        yield node, pub.publish, received, diag
    finally:
        executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=5.0)
        node.destroy_node()
        client.destroy_node()


def test_plate_centre_in_the_tunnel_frame_with_the_stamp_kept(relay):
    node, send, received, _ = relay
    send(pose(100.25, (0.5, 0.0, 1.0)))
    assert wait_for(lambda: len(received) == 1)
    out = received[0]
    p = out.pose.position
    # (0.5, 0, 1) - 5 cm in z -> turned +90 deg about z: (0, 0.5, 0.95) -> + (0.1, -0.2, 0)
    assert (p.x, p.y, p.z) == pytest.approx((0.1, 0.3, 0.95), abs=1e-12)
    o = out.pose.orientation
    assert quat_to_yaw((o.x, o.y, o.z, o.w)) == pytest.approx(math.pi / 2)
    assert out.header.frame_id == names.TUNNEL_FRAME
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == (100, 250_000_000)
    # the body rolled +90 deg about x: the offset points along mocap +y
    send(pose(100.35, (0.5, 0.0, 1.0), (S, 0.0, 0.0, S)))
    assert wait_for(lambda: len(received) == 2)
    p = received[1].pose.position
    assert (p.x, p.y, p.z) == pytest.approx((0.05, 0.3, 1.0), abs=1e-12)
    assert (received[1].header.stamp.sec, received[1].header.stamp.nanosec) == (100, 350_000_000)


@pytest.mark.fault
def test_nan_and_jumps_are_dropped_and_counted(relay, fault_row):
    node, send, received, diag = relay
    send(pose(10.00, (0.0, 0.0, 1.0)))
    assert wait_for(lambda: len(received) == 1)
    send(pose(10.01, (math.nan, 0.0, 1.0)))          # NaN
    send(pose(10.02, (0.0, 0.0, 1.0), (0, 0, 0, 0)))  # no rotation
    send(pose(10.03, (0.2, 0.0, 1.0)))               # 0.2 m in 30 ms = 6.7 m/s: a jump
    send(pose(10.03, (0.0, 0.0, 1.0)))               # same stamp as the jump, no move: good
    send(pose(10.00, (0.0, 0.0, 1.0)))               # older than the last accepted: stale
    send(pose(10.05, (0.01, 0.0, 1.0)))              # 0.2 m/s: good
    assert wait_for(lambda: len(received) == 3)
    time.sleep(0.1)
    assert len(received) == 3
    stamps = [(m.header.stamp.sec, m.header.stamp.nanosec) for m in received]
    assert stamps == [(10, 0), (10, 30_000_000), (10, 50_000_000)]
    values = diag()
    assert (values['invalid'], values['jumps'], values['stale'], values['published'],
            values['received']) == ('2', '1', '1', '3', '7')
    fault_row('mocap pose with NaN, or a plate that jumps',
              'dropped and counted; never reaches the estimator', True)


class Streamer:
    """Publishes the body at ``xyz`` at ~100 Hz with increasing stamps while in a with-block."""

    def __init__(self, send, t0):
        self.send, self.t = send, t0
        self._stop = threading.Event()
        self._thread = None

    def at(self, xyz):
        self.xyz = xyz
        return self

    def __enter__(self):
        self._stop.clear()
        self._thread = threading.Thread(target=self._run)
        self._thread.start()
        time.sleep(0.1)
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def _run(self):
        while not self._stop.is_set():
            self.t += 0.01
            self.send(pose(self.t, self.xyz))
            time.sleep(0.01)


@pytest.mark.fault
def test_dropout_and_outside_are_flagged(relay, fault_row):
    node, send, received, diag = relay
    streamer = Streamer(send, 50.0)
    with streamer.at((0.2, 0.0, 1.0)):                # (0.1, 0.0) in the tunnel
        values = diag()
    assert values['_level'] == b'\x00', values
    assert values['dropouts'] == '0' and float(values['rate_hz']) > 30
    values = wait_for(lambda: (v := diag()) and v['_level'] == b'\x02' and v, 3.0)  # silence
    # one silence was made; a busy machine may add a second gap, never none
    assert values and 'dropout' in values['_message'] and int(values['dropouts']) >= 1
    streamer.t += 2.0
    with streamer.at((0.7, -0.1, 1.0)):               # (0.2, 0.5): r = 0.54 m, outside
        values = diag()
    assert int(values['dropouts']) >= 1 and int(values['outside']) >= 5
    assert 'outside' in values['_message'] and values['_level'] == b'\x01'
    assert float(values['radius_m']) == pytest.approx(math.hypot(0.2, 0.5))
    assert float(values['longest_dropout_s']) > CALIBRATION['dropout_timeout_s']
    last = received[-1].pose.position
    assert (last.x, last.y) == pytest.approx((0.2, 0.5))   # outside poses are still published
    fault_row('mocap dropout; plate outside the tunnel',
              'flagged in /diagnostics, poses outside not published', True)


def test_bad_parameters_are_refused(ros_context):
    for overrides, match in (
            ([Parameter('tunnel_from_mocap', value=[0.0] * 7)], 'norm'),
            ([Parameter('tunnel_from_mocap', value=[0.0, 0.0, 0.0, 1.0])], '7 numbers'),
            ([Parameter('plate_offset', value=[0.0, 0.0])], 'plate_offset')):
        with pytest.raises(ConfigError, match=match):
            MocapRelayNode(context=ros_context, parameter_overrides=overrides)


def test_config_file_lists_every_parameter(ros_context):
    listed = yaml.safe_load(CONFIG.read_text())['mocap_relay']['ros__parameters']
    assert set(listed) == {f.name for f in fields(MocapRelayParams)}
    node = MocapRelayNode(context=ros_context, cli_args=['--ros-args', '--params-file',
                                                         str(CONFIG)])
    try:
        assert node.params == MocapRelayParams()
    finally:
        node.destroy_node()


def test_the_relay_stops_listening_while_nobody_listens_to_it_and_starts_at_a_subscriber(
        ros_context):
    """With no subscriber to the plate pose the relay drops its subscription to the mocap
    driver (the driver's publisher then has no reader); a subscriber brings it back at once,
    and the pause is no dropout."""
    executor = SingleThreadedExecutor(context=ros_context)
    driver = rclpy.create_node('mocap_relay_test_driver', context=ros_context)
    node = MocapRelayNode(context=ros_context, parameter_overrides=[
        # a dropout only after 1 s of silence, so that a loaded machine delaying the 50 Hz poses
        # is none; the pause below lasts longer than that, so counting it would still show
        Parameter(k, value=v) for k, v in (CALIBRATION | {'pause_unheard_s': 0.3,
                                                          'dropout_timeout_s': 1.0}).items()])
    diagnostics, received = [], []
    pub = driver.create_publisher(PoseStamped, names.MOCAP_POSE, 10)
    driver.create_subscription(DiagnosticArray, names.DIAGNOSTICS, diagnostics.append, 10)
    for n in (driver, node):
        executor.add_node(n)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    streamer = Streamer(pub.publish, 50.0)
    try:
        with streamer.at((0.2, 0.0, 1.0)):
            assert wait_for(lambda: node._received >= 5, 3.0), 'the relay never listened'
            # nobody listens to the relay: within a diagnostics period or two it lets go
            assert wait_for(lambda: pub.get_subscription_count() == 0, 4.0), 'still subscribed'
            diagnostics.clear()
            # a report on its way when the relay let go may still say unpaused
            values = wait_for(lambda: (v := relay_status(diagnostics)) and v['paused'] == 'true'
                              and v, 3.5) or relay_status(diagnostics)
            assert values and values['paused'] == 'true' and values['_level'] == b'\x00', values
            got = node._received
            time.sleep(1.5)
            assert node._received == got                 # paused: nothing taken in
            asked = time.monotonic()
            driver.create_subscription(PoseStamped, names.PLATE_POSE, received.append, qos.STREAM)
            assert wait_for(lambda: len(received) >= 10, 3.0), 'no pose relayed after resuming'
            resumed_after = time.monotonic() - asked
            diagnostics.clear()
            values = wait_for(lambda: (v := relay_status(diagnostics))
                              and v['paused'] == 'false' and v, 3.0)
    finally:
        executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=5.0)
        node.destroy_node()
        driver.destroy_node()
    assert resumed_after < 1.5, resumed_after
    assert values['_level'] == b'\x00' and values['dropouts'] == '0', values
    assert int(values['pauses']) == 1
