"""wind_shaper_msgs as built by tools/dev.sh: importable, serialisable, and usable across processes."""
from pathlib import Path
import time

from ament_index_python.packages import get_package_share_directory
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_types_from_msg, get_typestore, Stores
from wind_shaper_msgs.msg import FanCommand, FieldEstimate

pytestmark = pytest.mark.ros

PUBLISHER = Path(__file__).with_name('fan_command_publisher.py')
DISCOVERY_TIMEOUT_S = 20.0  # discovery takes 0.05-3 s on one machine; this bounds a broken graph
PUBLISHER_LIFETIME_S = 60.0  # the child ends by itself after this even if nobody stops it


def make_fan_command():
    msg = FanCommand(names=['fan_00', 'fan_01', 'fan_02'], pwm=[0.0, 0.5, 1.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000, 250_000_000
    msg.header.frame_id = 'tunnel'
    return msg


def make_field_estimate():
    msg = FieldEstimate(
        x=[-0.2, 0.0, 0.2], y=[0.1, 0.1, 0.1],
        mean=[0.8, 1.1, 0.8], std=[0.05, 0.04, 0.05], pwm=[0.3, 0.6, 0.3])
    msg.header.stamp.sec = 42
    msg.header.frame_id = 'tunnel'
    return msg


def test_fan_command_reaches_another_process(ros_context, ros_process):
    topic = '/test_interfaces/fan_command'
    names = ['fan_00', 'fan_01', 'fan_02']
    received = []
    node = rclpy.create_node('test_interfaces_listener', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    try:
        node.create_subscription(FanCommand, topic, received.append, 10)
        executor.add_node(node)
        publisher = ros_process(PUBLISHER, topic, PUBLISHER_LIFETIME_S, *names)
        deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
        while len(received) < 3 and time.monotonic() < deadline and publisher.poll() is None:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        node.destroy_node()

    assert len(received) >= 3, (
        f'got {len(received)} FanCommand messages from the publisher process in '
        f'{DISCOVERY_TIMEOUT_S} s (its exit code: {publisher.poll()}); its output:\n'
        + publisher.log_path.read_text())
    for msg in received:
        assert list(msg.names) == names
        assert list(msg.pwm) == pytest.approx([0.25, 0.5, 0.75])
    counts = [int(msg.header.frame_id) for msg in received]
    assert counts == sorted(counts), 'messages arrived out of order on a reliable topic'
    stamps = [(msg.header.stamp.sec, msg.header.stamp.nanosec) for msg in received]
    assert stamps[0] > (0, 0) and stamps == sorted(stamps)


@pytest.mark.parametrize('make', [make_fan_command, make_field_estimate])
def test_serialisation_round_trip(make):
    msg = make()
    data = serialize_message(msg)
    assert data[:2] == b'\x00\x01', 'expected a little-endian CDR encapsulation header'
    assert deserialize_message(data, type(msg)) == msg


def test_interface_files_are_in_the_ament_index():
    share = Path(get_package_share_directory('wind_shaper_msgs'))
    assert (share / 'msg' / 'FanCommand.msg').is_file()
    assert (share / 'msg' / 'FieldEstimate.msg').is_file()


@pytest.mark.parametrize('make', [make_fan_command, make_field_estimate])
def test_rosbags_reads_and_writes_the_same_bytes_as_rclpy(make):
    """Bags are written with rosbags from the installed .msg text: both sides must agree on CDR."""
    share = Path(get_package_share_directory('wind_shaper_msgs'))
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for path in sorted((share / 'msg').glob('*.msg')):
        typestore.register(get_types_from_msg(path.read_text(), f'wind_shaper_msgs/msg/{path.stem}'))
    msg = make()
    typename = f'wind_shaper_msgs/msg/{type(msg).__name__}'

    from_rclpy = typestore.deserialize_cdr(serialize_message(msg), typename)
    for field in msg.get_fields_and_field_types():
        if field == 'header':
            assert from_rclpy.header.frame_id == msg.header.frame_id
            assert from_rclpy.header.stamp.sec == msg.header.stamp.sec
            assert from_rclpy.header.stamp.nanosec == msg.header.stamp.nanosec
        else:
            np.testing.assert_array_equal(getattr(from_rclpy, field), getattr(msg, field))

    from_rosbags = bytes(typestore.serialize_cdr(from_rclpy, typename))
    assert deserialize_message(from_rosbags, type(msg)) == msg
