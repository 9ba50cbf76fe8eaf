"""Replay a bag onto the ROS graph (rclpy): the raw CDR bytes, with their original timing.

``Player(bag).play()`` publishes every message of the chosen topics at its recorded receive
time, relative to the first one, divided by ``rate`` (rate 2 plays twice as fast); ``loop``
repeats until stopped. Each topic is published with the QoS its publishers offered when it was
recorded (reliability and durability; a deeper history for streams), as ``ros2 bag play`` does,
or the graph's default for a known topic. ``restamp`` shifts the ``header.stamp`` of every
message that starts with a std_msgs/Header by (replay start - recording start), so nodes that
compare stamps with their own clock see a live stream; spacing between stamps is kept.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import importlib
from pathlib import Path
import struct
import threading
import time
from typing import Callable, Iterable

from .errors import BagContentError
from .storage import BagReader
from ..ros import names
from .topics import KNOWN_TOPICS, STREAM, TopicQos, bag_namespace, canonical, in_namespace
from .types import has_header, typestore

#: Volatile topics are published with at least this history depth, so a burst at a high
#: replay rate is not overwritten before a reliable subscriber has it.
MIN_STREAM_DEPTH = 1000
#: The longest single sleep [s] between two messages: Ctrl-C and stop() act within this.
MAX_SLEEP_S = 0.05


def message_class(msgtype: str):
    """The rclpy message class of 'pkg/msg/Type' (BagContentError if its package is not installed)."""
    try:
        pkg, kind, name = msgtype.split('/')
        return getattr(importlib.import_module(f'{pkg}.{kind}'), name)
    except (ValueError, ImportError, AttributeError):
        raise BagContentError(f'message type {msgtype!r} is not installed for Python: source the '
                              f'workspace that provides it, or leave its topic out (--topics)') from None


def rclpy_qos(qos: TopicQos, min_depth: int = 1):
    """The rclpy QoSProfile of a TopicQos (KEEP_LAST; depth raised to min_depth for volatile)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    depth = qos.depth if qos.transient_local else max(qos.depth, min_depth)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=(ReliabilityPolicy.RELIABLE if qos.reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if qos.transient_local
                                  else DurabilityPolicy.VOLATILE))


def shift_header_stamp(raw: bytes, offset_ns: int) -> bytes:
    """CDR bytes of a message whose first field is a std_msgs/Header, with header.stamp moved by
    offset_ns [ns] (the stamp sits right after the 4-byte encapsulation header)."""
    if len(raw) < 12 or offset_ns == 0:
        return raw
    endian = '<' if raw[1] & 1 else '>'
    sec, nanosec = struct.unpack_from(endian + 'iI', raw, 4)
    total = sec * 1_000_000_000 + nanosec + int(offset_ns)
    out = bytearray(raw)
    struct.pack_into(endian + 'iI', out, 4, total // 1_000_000_000, total % 1_000_000_000)
    return bytes(out)


@dataclass
class PlayStats:
    """What a replay did: messages published per topic, passes over the bag, the wall time it
    took [s], and how late each publish was behind its schedule [s] (the first LATE_KEPT)."""

    LATE_KEPT = 200_000  # lateness samples kept for the percentiles (a looped replay goes on)

    published: dict[str, int] = field(default_factory=dict)
    passes: int = 0
    wall_s: float = 0.0
    max_late_s: float = 0.0
    late_s: list[float] = field(default_factory=list, repr=False)

    @property
    def total(self) -> int:
        return sum(self.published.values())

    def record_late(self, late_s: float) -> None:
        self.max_late_s = max(self.max_late_s, late_s)
        if len(self.late_s) < self.LATE_KEPT:
            self.late_s.append(late_s)

    def late_percentile(self, q: float) -> float:
        """The q-th percentile [0, 100] of publish lateness [s]; 0 before any publish."""
        if not self.late_s:
            return 0.0
        ordered = sorted(self.late_s)
        return ordered[min(int(round(q / 100 * (len(ordered) - 1))), len(ordered) - 1)]


class Player:
    """Publishes a bag's messages on the graph. bag_path: the bag; rate: speed factor (> 0);
    topics: the topics to play (None: all); loop: repeat until stopped; restamp: shift header
    stamps to the replay time; context: the rclpy context (None: the default one, already
    initialised); wait_for_subscribers_s [s]: before playing, wait up to this long until every
    played topic has a subscriber (then play anyway)."""

    def __init__(self, bag_path: Path | str, *, rate: float = 1.0, topics: Iterable[str] | None = None,
                 loop: bool = False, restamp: bool = False, context=None,
                 wait_for_subscribers_s: float = 0.0, node_name: str = 'wind_shaper_player'):
        if not rate > 0:
            raise ValueError(f'replay rate must be > 0 (1 = real time); got {rate}')
        self.bag_path = Path(bag_path)
        self.rate = float(rate)
        self.loop = bool(loop)
        self.restamp = bool(restamp)
        self.wait_for_subscribers_s = float(wait_for_subscribers_s)
        self._stop = threading.Event()
        with BagReader(self.bag_path) as bag:
            infos = bag.topics
            self.duration_s = bag.duration_s
        # a graph name (wind_shaper/force) means the bag's topic of that name, in whatever
        # namespace it was recorded
        ns = bag_namespace(infos)
        wanted = (list(infos) if topics is None
                  else [t if t.startswith('/') else in_namespace(names.resolve(t, '/'), ns) for t in topics])
        unknown = [t for t in wanted if t not in infos]
        if unknown:
            raise BagContentError(f'bag {self.bag_path} has no topic {", ".join(unknown)}; it has '
                                  f'{", ".join(infos) or "none"}')
        wanted = [t for t in wanted if infos[t].count]
        if not wanted:
            raise BagContentError(f'bag {self.bag_path} has no messages on the topics to play')
        self.topics = {t: infos[t] for t in wanted}
        store = typestore()
        self._stamped = {t for t, info in self.topics.items() if has_header(info.msgtype, store)}
        import rclpy
        self._node = rclpy.create_node(node_name, context=context)
        self._publishers = {}
        try:
            for topic, info in self.topics.items():
                cls = message_class(info.msgtype)
                qos = (TopicQos.from_rosbags(info.qos[0]) if info.qos
                       else KNOWN_TOPICS[canonical(topic)].qos if canonical(topic) in KNOWN_TOPICS else STREAM)
                self._publishers[topic] = self._node.create_publisher(
                    cls, topic, rclpy_qos(qos, MIN_STREAM_DEPTH))
        except Exception:
            self.destroy()
            raise

    @property
    def node(self):
        return self._node

    def stop(self) -> None:
        """Ask a running play() to return (from another thread or a signal handler)."""
        self._stop.set()

    def _wait_for_subscribers(self) -> list[str]:
        deadline = time.monotonic() + self.wait_for_subscribers_s
        while True:
            lonely = [t for t, p in self._publishers.items() if p.get_subscription_count() == 0]
            if not lonely or time.monotonic() >= deadline or self._stop.is_set():
                return lonely
            time.sleep(0.02)

    def play(self, on_pass: Callable[[int], None] | None = None) -> PlayStats:
        """Publish the bag (once, or until stop() with loop); returns PlayStats. Blocks; a
        KeyboardInterrupt ends it cleanly."""
        stats = PlayStats(published={t: 0 for t in self.topics})
        if self.wait_for_subscribers_s > 0:
            self._wait_for_subscribers()
        t_start = time.monotonic()
        try:
            while not self._stop.is_set():
                self._play_once(stats)
                stats.passes += 1
                if on_pass is not None:
                    on_pass(stats.passes)
                if not self.loop:
                    break
        except KeyboardInterrupt:
            pass
        finally:
            stats.wall_s = time.monotonic() - t_start
            self._flush()
        return stats

    def _play_once(self, stats: PlayStats) -> None:
        first_ns = None
        wall0 = 0
        offset_ns = 0
        with BagReader(self.bag_path) as bag:
            for topic, t_ns, raw in bag.messages(self.topics):
                if first_ns is None:
                    first_ns, wall0 = t_ns, time.monotonic_ns()
                    offset_ns = time.time_ns() - t_ns if self.restamp else 0
                due = wall0 + (t_ns - first_ns) / self.rate
                while True:
                    if self._stop.is_set():
                        return
                    wait = due - time.monotonic_ns()
                    if wait <= 0:
                        break
                    time.sleep(min(wait * 1e-9, MAX_SLEEP_S))
                if topic in self._stamped and offset_ns:
                    raw = shift_header_stamp(raw, offset_ns)
                self._publishers[topic].publish(bytes(raw))
                stats.published[topic] += 1
                stats.record_late((time.monotonic_ns() - due) * 1e-9)

    def _flush(self, timeout_s: float = 2.0) -> None:
        """Give reliable subscribers up to timeout_s [s] to acknowledge what was published."""
        from rclpy.duration import Duration
        deadline = time.monotonic() + timeout_s
        for pub in self._publishers.values():
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
            except Exception:  # best effort publishers, or a context already shut down
                pass

    def destroy(self) -> None:
        for pub in self._publishers.values():
            try:
                self._node.destroy_publisher(pub)
            except Exception:
                pass
        self._publishers = {}
        try:
            self._node.destroy_node()
        except Exception:
            pass
