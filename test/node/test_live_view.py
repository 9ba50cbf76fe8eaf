"""live_view in-process: the field as PointCloud2 (force, std, target, residual), the fans and the
sweep path as MarkerArray, and the same view served to a real Foxglove WebSocket client (the
foxglove.sdk.v1 WebSocket protocol, over the websockets library) that connects, subscribes, receives
the field, and drops without harm."""
import json
import socket
import struct
import threading
import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
websockets_client = pytest.importorskip('websockets.sync.client')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402
from wind_shaper_msgs.msg import FanCommand, FieldEstimate, IterationStatus  # noqa: E402

from wind_shaper.app import Setup  # noqa: E402
from wind_shaper.nodes.live_view import LIVE_FANS, LIVE_FIELD, LIVE_PATH, LiveViewNode, LiveViewParams  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402
from wind_shaper.ros.convert import fan_command  # noqa: E402
from wind_shaper.ros.foxglove_view import FIELD_CHANNEL  # noqa: E402
from wind_shaper.ros.live import read_point_cloud  # noqa: E402

from waiting import wait_for as _wait_for  # noqa: E402

pytestmark = pytest.mark.ros
CONFIG = Path(__file__).resolve().parents[2] / 'config' / 'live_view.yaml'


def wait_for(predicate, timeout_s=5.0, interval_s=0.02):
    return _wait_for(predicate, timeout_s, interval_s)


def free_tcp_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.fixture
def view(ros_context):
    port = free_tcp_port()
    node = LiveViewNode(context=ros_context, parameter_overrides=[
        Parameter('foxglove_port', value=port), Parameter('path_rate_hz', value=20.0)])
    peer = rclpy.create_node('live_view_test_peer', context=ros_context)
    got = {'field': [], 'fans': [], 'path': [], 'diag': []}
    peer.create_subscription(PointCloud2, LIVE_FIELD, got['field'].append, qos.LATCHED)
    peer.create_subscription(MarkerArray, LIVE_FANS, got['fans'].append, qos.LATCHED)
    peer.create_subscription(MarkerArray, LIVE_PATH, got['path'].append, qos.COMMAND)
    peer.create_subscription(DiagnosticArray, names.DIAGNOSTICS, got['diag'].append, 10)
    pubs = {'field': peer.create_publisher(FieldEstimate, names.FIELD, qos.LATCHED),
            'status': peer.create_publisher(IterationStatus, names.STATUS, qos.LATCHED),
            'applied': peer.create_publisher(FanCommand, names.FAN_APPLIED, qos.LATCHED),
            'pose': peer.create_publisher(PoseStamped, names.PLATE_POSE, qos.STREAM),
            'partial': peer.create_publisher(FieldEstimate, names.FIELD_PARTIAL, qos.COMMAND)}
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(peer)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield node, pubs, got, port
    finally:
        executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=5.0)  # the spin thread ends before its nodes go
        node.destroy_node()
        peer.destroy_node()


def field_msg(kp, mean, std, k=0):
    msg = FieldEstimate(iteration=k, x=kp[:, 0].tolist(), y=kp[:, 1].tolist(), mean=list(map(float, mean)),
                        std=list(map(float, std)))
    msg.header.frame_id = names.TUNNEL_FRAME
    return msg


def test_config_file_lists_every_parameter():
    doc = yaml.safe_load(CONFIG.read_text())['live_view']['ros__parameters']
    assert set(doc) == {f.name for f in fields(LiveViewParams)}
    text = CONFIG.read_text()
    for name in doc:
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f'{name}:'))
        assert '#' in line, f'{name} has no comment'


def test_the_field_fans_and_sweep_path_for_rviz(view):
    node, pubs, got, _ = view
    setup = Setup.load()
    kp = setup.geometry.key_points
    mean = 2.0 + 0.5 * kp[:, 0]
    pubs['status'].publish(IterationStatus(iteration=0, state='sweeping', target='uniform:2.5'))
    pubs['field'].publish(field_msg(kp, mean, np.full(len(kp), 0.05)))
    assert wait_for(lambda: got['field'] and
                    np.isfinite(read_point_cloud(got['field'][-1])['target']).all())
    cloud = got['field'][-1]
    values = read_point_cloud(cloud)
    assert cloud.header.frame_id == 'tunnel' and cloud.width == len(kp)
    assert list(values) == ['x', 'y', 'z', 'force', 'std', 'target', 'residual']
    np.testing.assert_allclose(values['x'], kp[:, 0], atol=1e-6)
    np.testing.assert_allclose(values['force'], mean, atol=1e-5)
    np.testing.assert_allclose(values['target'], 2.5, atol=1e-5)
    np.testing.assert_allclose(values['residual'], mean - 2.5, atol=1e-5)
    # the field of a sweep under way (each peek of the coordinator) replaces it as it forms
    assert wait_for(lambda: pubs['partial'].get_subscription_count() > 0)
    pubs['partial'].publish(field_msg(kp, mean + 1.0, np.full(len(kp), 0.3), k=1))
    assert wait_for(lambda: abs(read_point_cloud(got['field'][-1])['force'][0] - (mean[0] + 1.0)) < 1e-4)
    # the fans: hub, spin and label per fan, the command in the label and the hub's height
    pwm = np.linspace(0.1, 0.6, 7)
    pubs['applied'].publish(fan_command(list(setup.geometry.fans.names), pwm))
    assert wait_for(lambda: any('60 %' in m.text for m in got['fans'][-1].markers) if got['fans'] else False)
    markers = got['fans'][-1].markers
    assert len(markers) == 3 * 7
    hubs = [m for m in markers if m.ns == 'fans']
    assert [round(m.scale.z, 4) for m in hubs] == [round(0.01 + 0.1 * u, 4) for u in pwm]
    labels = [m.text for m in markers if m.ns == 'fan_labels']
    assert labels[0].startswith('LM1 10 %') and ('CW' in labels[0] or 'CCW' in labels[0])
    # the sweep path follows the plate and starts over with the next iteration
    for i in range(30):
        pose = PoseStamped()
        pose.header.frame_id = 'tunnel'
        pose.pose.position.x, pose.pose.position.y = 0.01 * i, -0.01 * i
        pubs['pose'].publish(pose)
        time.sleep(0.005)
    assert wait_for(lambda: got['path'] and got['path'][-1].markers[0].action == Marker.ADD
                    and len(got['path'][-1].markers[0].points) == 30)
    pubs['status'].publish(IterationStatus(iteration=1, state='commanding', target='uniform:2.5'))
    assert wait_for(lambda: got['path'][-1].markers[0].action == Marker.DELETE)


def test_a_target_it_cannot_build_is_shown_as_nan_and_reported(view):
    node, pubs, got, _ = view
    kp = Setup.load().geometry.key_points
    pubs['status'].publish(IterationStatus(iteration=0, state='sweeping', target='csv:/no/such.csv'))
    pubs['field'].publish(field_msg(kp, np.ones(len(kp)), np.full(len(kp), 0.1)))
    assert wait_for(lambda: got['field'])
    assert np.isnan(read_point_cloud(got['field'][-1])['target']).all()
    assert wait_for(lambda: any(kv.key == 'target_errors' and kv.value == '1'
                                for a in got['diag'] for s in a.status if 'live_view' in s.name
                                for kv in s.values))


def _foxglove_client(port):
    return websockets_client.connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'],
                                     open_timeout=5)


def _advertised(ws, topic, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = ws.recv(timeout=max(0.05, deadline - time.monotonic()))
        if isinstance(msg, str):
            doc = json.loads(msg)
            if doc.get('op') == 'advertise':
                for ch in doc['channels']:
                    if ch['topic'] == topic:
                        return ch
    raise AssertionError(f'{topic} was not advertised')


def _first_message(ws, sub_id, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = ws.recv(timeout=max(0.05, deadline - time.monotonic()))
        if isinstance(msg, bytes) and msg[0] == 1:
            sub, t_ns = struct.unpack_from('<IQ', msg, 1)
            if sub == sub_id:
                return t_ns, msg[13:]
    raise AssertionError('no message on the subscription')


def test_a_foxglove_client_subscribes_receives_the_field_and_may_drop(view):
    node, pubs, got, port = view
    kp = Setup.load().geometry.key_points
    with _foxglove_client(port) as ws:
        channel = _advertised(ws, FIELD_CHANNEL)
        assert channel['schemaName'] == 'foxglove.PointCloud'
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 7, 'channelId': channel['id']}]}))
        time.sleep(0.3)   # the subscription reaches the server
        pubs['field'].publish(field_msg(kp, np.full(len(kp), 3.0), np.full(len(kp), 0.05), k=4))
        t_ns, payload = _first_message(ws, 7)
        # one point per key point, 7 float32 each, inside the encoded message
        assert len(payload) >= 28 * len(kp) and abs(t_ns / 1e9 - time.time()) < 60
        assert struct.pack('<f', 3.0) in payload
    # the client dropped: the node goes on, and the next client is served
    pubs['field'].publish(field_msg(kp, np.full(len(kp), 2.0), np.full(len(kp), 0.05), k=5))
    assert wait_for(lambda: got['field'] and read_point_cloud(got['field'][-1])['force'][0] == 2.0)
    with _foxglove_client(port) as ws:
        channel = _advertised(ws, FIELD_CHANNEL)
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 1, 'channelId': channel['id']}]}))
        time.sleep(0.3)
        pubs['field'].publish(field_msg(kp, np.full(len(kp), 1.5), np.full(len(kp), 0.05), k=6))
        _, payload = _first_message(ws, 1)
        assert struct.pack('<f', 1.5) in payload
