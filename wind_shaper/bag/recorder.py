"""Record graph topics into a rosbag2 bag (rclpy): raw CDR bytes with their reception time.

``Recorder(out, topics).record(duration_s)`` subscribes to each topic as soon as a publisher
appears (the graph is polled every ``discovery_period_s``), with a QoS adapted to what the
publishers offer, like ``ros2 bag record``: reliable if all of them are reliable, transient
local (so a latched message is recorded too) if all of them are. Messages are written as
received (``raw=True``: no deserialisation), stamped with the node clock's time of reception.
The bag is closed (index + metadata.yaml written) when the duration is over, on Ctrl-C /
SIGTERM, or on ``stop()``; a recorder killed with SIGKILL leaves an unreadable bag.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import threading
import time
from typing import Iterable

from .player import message_class, rclpy_qos
from .storage import BagWriter
from ..ros import names
from .topics import SWEEP_TOPICS, TopicQos, in_namespace, qos_time
from .types import typestore


def rosbags_qos(profile):
    """The rosbags Qos of an rclpy QoSProfile (as reported for a live publisher)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)

    def enum(kind, value):
        try:
            return kind(int(value))
        except ValueError:
            return kind.UNKNOWN

    return Qos(enum(QosHistory, profile.history), int(profile.depth),
               enum(QosReliability, profile.reliability), enum(QosDurability, profile.durability),
               QosTime(*qos_time(profile.deadline.nanoseconds)),
               QosTime(*qos_time(profile.lifespan.nanoseconds)),
               enum(QosLiveliness, profile.liveliness),
               QosTime(*qos_time(profile.liveliness_lease_duration.nanoseconds)),
               bool(profile.avoid_ros_namespace_conventions))


def adapted_request(profiles) -> TopicQos:
    """The subscription QoS that connects to every offered profile: reliable only if all
    publishers are, transient local only if all are; a deep history for bursts."""
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
    profiles = list(profiles)
    reliable = bool(profiles) and all(p.reliability == ReliabilityPolicy.RELIABLE for p in profiles)
    latched = bool(profiles) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
    return TopicQos(reliable=reliable, transient_local=latched, depth=1000)


@dataclass
class RecordStats:
    """What a recording holds: messages per topic, topics never seen (no publisher appeared),
    topics skipped (with the reason), and how long it ran [s]."""

    path: Path
    counts: dict[str, int] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    wall_s: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.counts.values())


class Recorder:
    """Records ``topics`` (default: the sweep topics, ``SWEEP_TOPICS``, under the namespace in
    ``$WIND_SHAPER_NAMESPACE``) into a new bag at
    ``out``. storage: 'mcap' or 'sqlite3'; context: the rclpy context (None: the default one,
    already initialised); discovery_period_s [s]: how often the graph is polled for new
    publishers."""

    def __init__(self, out: Path | str, topics: Iterable[str] | None = None, *, storage: str = 'mcap',
                 context=None, discovery_period_s: float = 0.2, node_name: str = 'wind_shaper_recorder'):
        import rclpy
        from rclpy.experimental import EventsExecutor
        if topics is None:   # the sweep topics, in the command line's namespace
            ns = names.namespace_from_env()
            topics = [in_namespace(t, ns) for t in SWEEP_TOPICS]
        self.topics = list(dict.fromkeys(topics))
        if not self.topics:
            raise ValueError('give at least one topic to record')
        self._store = typestore()
        self._bag = BagWriter(out, storage=storage,
                              custom_data={'wind_shaper': 'wind-shaper record'}).open()
        self.stats = RecordStats(self._bag.path)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._subscriptions = {}
        self._node = self._executor = None
        try:
            # in the command line's namespace: a graph name (wind_shaper/force) given by the
            # user resolves where the graph is, and is recorded under its absolute name
            self._node = rclpy.create_node(node_name, context=context,
                                           namespace=names.namespace_from_env())
            self.topics = list(dict.fromkeys(self._node.resolve_topic_name(t) for t in self.topics))
            self._clock = self._node.get_clock()
            # The events executor keeps up with several kHz of raw messages (the default
            # executor lost messages above ~2 kHz in our runs).
            self._executor = EventsExecutor(context=context)
            self._executor.add_node(self._node)
            self._timer = self._node.create_timer(discovery_period_s, self._discover)
            self._discover()
        except BaseException:
            self.close()
            raise

    @property
    def node(self):
        return self._node

    @property
    def subscribed(self) -> list[str]:
        """The topics being recorded so far (a publisher was found)."""
        return list(self._subscriptions)

    def stop(self) -> None:
        """Ask a running record() to close the bag and return (thread- and signal-safe)."""
        self._stop.set()

    def _discover(self) -> None:
        for topic in self.topics:
            if topic in self._subscriptions or topic in self.stats.skipped:
                continue
            infos = self._node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            msgtypes = sorted({i.topic_type for i in infos})
            if len(msgtypes) > 1:
                self._skip(topic, f'publishers disagree on its type ({", ".join(msgtypes)})')
                continue
            msgtype = msgtypes[0]
            if msgtype not in self._store.fielddefs:
                self._skip(topic, f'type {msgtype} is unknown to the bag typestore')
                continue
            expected = self._store.hash_rihs01(msgtype)
            offered = {str(getattr(i, 'topic_type_hash', '') or '') for i in infos} - {''}
            if offered and not any(expected in h for h in offered):
                self._node.get_logger().warning(
                    f'{topic}: the publishers\' {msgtype} hash {offered} differs from the bag '
                    f'typestore\'s {expected}: the recorded definition may not match the data')
            try:
                cls = message_class(msgtype)
            except Exception as exc:
                self._skip(topic, str(exc))
                continue
            profiles = [i.qos_profile for i in infos]
            request = adapted_request(profiles)
            with self._lock:
                self._bag.add_topic(topic, msgtype, [rosbags_qos(p) for p in profiles])
                self.stats.counts[topic] = 0
            self._subscriptions[topic] = self._node.create_subscription(
                cls, topic, self._callback(topic), rclpy_qos(request), raw=True)

    def _skip(self, topic: str, why: str) -> None:
        self.stats.skipped[topic] = why
        self._node.get_logger().warning(f'not recording {topic}: {why}')

    def _callback(self, topic: str):
        def on_message(raw: bytes) -> None:
            t_ns = self._clock.now().nanoseconds
            with self._lock:
                if self._bag.is_open:
                    self._bag.write_raw(topic, t_ns, raw)
                    self.stats.counts[topic] += 1
        return on_message

    def record(self, duration_s: float | None = None) -> RecordStats:
        """Record until ``duration_s`` [s] has passed (None: until stop() or Ctrl-C), then close
        the bag and return RecordStats. KeyboardInterrupt (Ctrl-C, SIGINT) closes it cleanly."""
        from rclpy.executors import ExternalShutdownException
        start = time.monotonic()
        end = None if duration_s is None else start + float(duration_s)
        try:
            while not self._stop.is_set() and (end is None or time.monotonic() < end):
                timeout = 0.1 if end is None else max(0.0, min(0.1, end - time.monotonic()))
                self._executor.spin_once(timeout_sec=timeout)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            self.stats.wall_s = time.monotonic() - start
            self.close()
        return self.stats

    def close(self) -> None:
        """Close the bag (idempotent) and release the node."""
        with self._lock:
            self._bag.close()
        self.stats.counts = dict(self._bag.counts)
        self.stats.missing = [t for t in self.topics
                              if t not in self._subscriptions and t not in self.stats.skipped]
        for part, release in ((self._executor, lambda e: e.shutdown(timeout_sec=1.0)),
                              (self._node, lambda n: n.destroy_node())):
            if part is not None:
                try:
                    release(part)
                except Exception:  # already released, or the context is shut down
                    pass
