"""Sweeps recorded as rosbag2 bags, and replayed.

Pure part (no rclpy; rosbags only): ``BagWriter`` / ``BagReader`` (MCAP or sqlite3 rosbag2
bags, metadata version 9 as written by ROS 2 Jazzy), ``read_sweeps`` (the sweeps of a recording
as core ``Sweep`` objects) and ``write_sweep_bag`` (synthetic sweeps written as the graph would
record them). The ROS part, ``wind_shaper.bag.recorder`` (``Recorder``) and
``wind_shaper.bag.player`` (``Player``), imports rclpy and is loaded only when asked for.
"""
from .errors import BagContentError, BagError, BagNotFoundError, BagReadError, BagWriteError
from .storage import BagReader, BagWriter, TopicInfo, bag_summary
from .sweeps import SweepRecord, read_sweep_records, read_sweeps, write_sweep_bag
from .topics import KNOWN_TOPICS, SWEEP_TOPICS, TopicQos, TopicSpec
from .types import msg_dir, typestore

__all__ = [
    'BagWriter', 'BagReader', 'TopicInfo', 'bag_summary',
    'read_sweeps', 'read_sweep_records', 'SweepRecord', 'write_sweep_bag',
    'SWEEP_TOPICS', 'KNOWN_TOPICS', 'TopicSpec', 'TopicQos', 'typestore', 'msg_dir',
    'BagError', 'BagNotFoundError', 'BagReadError', 'BagContentError', 'BagWriteError',
]
