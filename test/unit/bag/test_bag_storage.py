"""BagWriter / BagReader: raw round trips, metadata a real rosbag2 reads, and clear errors."""
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from wind_shaper.bag import (BagContentError, BagNotFoundError, BagReadError, BagReader,
                             BagWriteError, BagWriter, TopicQos, read_sweeps, write_sweep_bag)
from wind_shaper.bag.types import has_header, msg_dir, typestore
from wind_shaper.bag import topics as bt


def fan_command(bag, k):
    T = typestore().types
    return bag.message('wind_shaper_msgs/msg/FanCommand', header=T['std_msgs/msg/Header'](
        stamp=T['builtin_interfaces/msg/Time'](sec=100 + k, nanosec=k), frame_id=str(k)),
        names=['fan_00', 'fan_01'], pwm=np.array([0.1 * k, 0.5]))


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_raw_bytes_round_trip_in_order_with_their_times(tmp_path, storage):
    path = tmp_path / 'bag'
    with BagWriter(path, storage=storage) as bag:
        bag.add_topic(bt.FAN_COMMAND)
        bag.add_topic('/other', 'std_msgs/msg/String', TopicQos(reliable=False, depth=5))
        sent = []
        for k in range(5):
            raw = bytes(typestore().serialize_cdr(fan_command(bag, k), 'wind_shaper_msgs/msg/FanCommand'))
            bag.write_raw(bt.FAN_COMMAND, 1_000 + 10 * k, raw)
            sent.append((bt.FAN_COMMAND, 1_000 + 10 * k, raw))
        bag.write('/other', 1_025, bag.message('std_msgs/msg/String', data='hello'))
    with BagReader(path) as bag:
        topics = bag.topics
        got = list(bag.messages())
        decoded = list(bag.decoded(['/other']))
    assert [m for m in got if m[0] == bt.FAN_COMMAND] == sent
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert topics[bt.FAN_COMMAND].count == 5 and topics['/other'].msgtype == 'std_msgs/msg/String'
    assert decoded[0][2].data == 'hello'
    assert TopicQos.from_rosbags(topics['/other'].qos[0]) == TopicQos(reliable=False, depth=5)
    assert TopicQos.from_rosbags(topics[bt.FAN_COMMAND].qos[0]).transient_local


def test_metadata_is_rosbag2_version_9_with_jazzy_hashes_and_string_qos(tmp_path):
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        bag.add_topic(bt.FORCE)
        bag.add_topic(bt.STATUS)
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['bag.mcap'] and (path / 'bag.mcap').is_file()
    topics = {t['topic_metadata']['name']: t['topic_metadata'] for t in meta['topics_with_message_count']}
    force = topics[bt.FORCE]
    assert force['type'] == 'geometry_msgs/msg/WrenchStamped' and force['serialization_format'] == 'cdr'
    qos = force['offered_qos_profiles'][0]
    assert (qos['reliability'], qos['durability'], qos['history'], qos['depth']) == \
        ('reliable', 'volatile', 'keep_last', 100)
    assert qos['deadline'] == {'sec': 9223372036, 'nsec': 854775807}  # RMW_DURATION_INFINITE
    assert topics[bt.STATUS]['offered_qos_profiles'][0]['durability'] == 'transient_local'
    # rosidl writes the type hashes next to the installed .msg files; rosbags must agree
    share = msg_dir()
    hashes = share / 'IterationStatus.json'
    if hashes.is_file():
        want = next(h['hash_string'] for h in json.loads(hashes.read_text())['type_hashes']
                    if h['type_name'] == 'wind_shaper_msgs/msg/IterationStatus')
        assert topics[bt.STATUS]['type_description_hash'] == want
    assert force['type_description_hash'].startswith('RIHS01_')


def test_the_msg_files_are_found_in_the_source_tree_without_an_install(monkeypatch):
    monkeypatch.setenv('AMENT_PREFIX_PATH', '/nonexistent')
    monkeypatch.setattr('sys.prefix', '/nonexistent')
    assert msg_dir() == Path(__file__).resolve().parents[3] / 'msg_defs' / 'msg'


def test_header_detection_and_unknown_types(tmp_path):
    assert has_header('geometry_msgs/msg/WrenchStamped') and has_header('wind_shaper_msgs/msg/FanCommand')
    assert not has_header('std_msgs/msg/String') and not has_header('no_pkg/msg/Nothing')
    with BagWriter(tmp_path / 'bag') as bag:
        with pytest.raises(BagContentError, match="'no_pkg/msg/Nothing' is unknown"):
            bag.add_topic('/x', 'no_pkg/msg/Nothing')
        with pytest.raises(BagWriteError, match='give its message type'):
            bag.add_topic('/not/a/graph/topic')
        with pytest.raises(BagWriteError, match='add_topic'):
            bag.write_raw('/never/added', 0, b'')


def test_an_existing_folder_is_never_overwritten(tmp_path):
    (tmp_path / 'bag').mkdir()
    with pytest.raises(BagWriteError, match='exists already'):
        BagWriter(tmp_path / 'bag')


def test_a_missing_bag_says_which_path_and_what_to_give(tmp_path):
    with pytest.raises(BagNotFoundError, match=r'does not exist: give the bag folder'):
        read_sweeps(tmp_path / 'nowhere')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagNotFoundError, match='not a rosbag2 bag'):
        read_sweeps(tmp_path / 'empty')


@pytest.fixture
def good_bag(tmp_path, sim_sweeps):
    return write_sweep_bag(tmp_path / 'good', sim_sweeps[:1], idle_streams=False)


def test_a_bag_never_closed_is_reported_as_such(good_bag):
    (good_bag / 'metadata.yaml').unlink()
    with pytest.raises(BagReadError, match='without closing the bag') as err:
        read_sweeps(good_bag)
    assert 'Ctrl-C' in str(err.value)


@pytest.mark.parametrize('cut', [0.5, 0.98])
@pytest.mark.fault
def test_a_truncated_bag_gives_a_clear_error(good_bag, cut, fault_row):
    data = (good_bag / 'good.mcap').read_bytes()
    (good_bag / 'good.mcap').write_bytes(data[:int(len(data) * cut)])
    with pytest.raises(BagReadError, match='cannot read bag .*damaged or truncated'):
        read_sweeps(good_bag)
    fault_row('a truncated bag',
              'clear error naming the file; nothing else read wrongly', True)


def test_corrupted_metadata_gives_a_clear_error(good_bag):
    (good_bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: {version: [')
    with pytest.raises(BagReadError, match='cannot read bag .*damaged'):
        read_sweeps(good_bag)


@pytest.mark.fault
def test_a_storage_file_of_garbage_gives_a_clear_error(good_bag, fault_row):
    (good_bag / 'good.mcap').write_bytes(b'\x89MCAP0\r\n' + bytes(range(256)) * 4)
    with pytest.raises(BagReadError, match='cannot read bag'):
        read_sweeps(good_bag)
    fault_row('a bag whose storage file is garbage',
              'clear error naming the file', True)


def pose(sec):
    T = typestore().types
    return T['geometry_msgs/msg/PoseStamped'](
        header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=sec, nanosec=0),
                                        frame_id='tunnel'),
        pose=T['geometry_msgs/msg/Pose'](
            position=T['geometry_msgs/msg/Point'](x=0.1, y=0.2, z=0.0),
            orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)))


def test_a_bag_without_force_names_what_is_missing_and_what_it_has(tmp_path):
    path = tmp_path / 'poses_only'
    with BagWriter(path) as bag:
        bag.add_topic(bt.PLATE_POSE)
        bag.add_topic(bt.FORCE)  # declared but empty: as good as missing
        for k in range(3):
            bag.write(bt.PLATE_POSE, k * 10_000_000, pose(k))
    with pytest.raises(BagContentError, match=r'no messages on /wind_shaper/force, needed to rebuild') as err:
        read_sweeps(path)
    assert '/wind_shaper/plate/pose (3)' in str(err.value)


def test_a_bag_with_only_the_raw_mocap_pose_points_to_the_relay(tmp_path):
    path = tmp_path / 'mocap_only'
    with BagWriter(path) as bag:
        bag.add_topic(bt.MOCAP_POSE)
        bag.write(bt.MOCAP_POSE, 0, pose(0))
    with pytest.raises(BagContentError, match='mocap frame.*pose_topic'):
        read_sweeps(path)


@pytest.mark.parametrize('little_endian', [True, False])
@pytest.mark.parametrize('offset_ns', [1_500_000_000, -700_000_000, 0])
def test_shifting_a_header_stamp_in_cdr_bytes(little_endian, offset_ns):
    from wind_shaper.bag.player import shift_header_stamp  # pure: no rclpy at import
    store = typestore()
    msg = pose(41)
    msg.header.stamp.nanosec = 600_000_000
    raw = bytes(store.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped', little_endian=little_endian))
    out = store.deserialize_cdr(shift_header_stamp(raw, offset_ns), 'geometry_msgs/msg/PoseStamped')
    total = out.header.stamp.sec * 10**9 + out.header.stamp.nanosec
    assert total == 41_600_000_000 + offset_ns and 0 <= out.header.stamp.nanosec < 10**9
    assert out.pose.position.y == 0.2 and out.header.frame_id == 'tunnel'
