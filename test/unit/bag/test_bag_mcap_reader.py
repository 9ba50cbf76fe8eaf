"""The bags wind_shaper writes open in other tools: the mcap library's ROS 2 decoder (what
Foxglove uses) reads every message back, wind_shaper's own types included, from the message
definitions stored in the MCAP file alone (no ROS install, no wind_shaper_msgs)."""
from pathlib import Path

import numpy as np
import pytest

mcap_ros2 = pytest.importorskip('mcap_ros2.reader', reason='mcap-ros2-support (tools/requirements.txt)')

from wind_shaper.app import Setup  # noqa: E402
from wind_shaper.bag.storage import BagReader  # noqa: E402
from wind_shaper.bag.sweeps import write_sweep_bag  # noqa: E402
from wind_shaper.bag import topics as bt  # noqa: E402
from wind_shaper.workbench.commands import simulated_sweeps  # noqa: E402


def test_a_sweep_bag_reads_back_with_the_mcap_ros2_decoder(tmp_path):
    setup = Setup.load()
    data = simulated_sweeps(setup.make_sim(seed=1), 2, seed=1, n_samples=100)
    bag = write_sweep_bag(tmp_path / 'bag', data.sweeps, fan_names=setup.geometry.fans.names,
                          force_rate_hz=100.0, idle_streams=False, settle_s=0.1, gap_s=0.1)
    (mcap_file,) = Path(bag).glob('*.mcap')
    got = {}
    for m in mcap_ros2.read_ros2_messages(str(mcap_file)):
        got.setdefault(m.channel.topic, []).append(m)
    # the same messages, in the same order and with the same values, as wind_shaper's own
    # (rosbags-based) reader gives
    with BagReader(bag) as reader:
        ours = {}
        for topic, t_ns, msg in reader.decoded():
            ours.setdefault(topic, []).append((t_ns, msg))
    assert {t: len(v) for t, v in got.items()} == {t: len(v) for t, v in ours.items()}
    assert len(got[bt.PLATE_POSE]) >= 100 and len(got[bt.FORCE]) >= 200
    xy = np.array([[m.ros_msg.pose.position.x, m.ros_msg.pose.position.y] for m in got[bt.PLATE_POSE]])
    xy_ours = np.array([[msg.pose.position.x, msg.pose.position.y] for _, msg in ours[bt.PLATE_POSE]])
    np.testing.assert_array_equal(xy, xy_ours)
    fz = [m.ros_msg.wrench.force.z for m in got[bt.FORCE]]
    assert fz == [msg.wrench.force.z for _, msg in ours[bt.FORCE]]
    assert [m.log_time_ns for m in got[bt.FORCE]] == [t for t, _ in ours[bt.FORCE]]
    # a wind_shaper type, decoded from the definition stored in the file
    status = got[bt.STATUS][0]
    assert status.schema.name == 'wind_shaper_msgs/msg/IterationStatus'
    assert status.ros_msg.state in ('idle', 'commanding', 'sweeping', 'estimating', 'updating', 'done')
    command = got[bt.FAN_COMMAND][0].ros_msg
    assert list(command.names) == list(setup.geometry.fans.names)
