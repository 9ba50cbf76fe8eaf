"""The graph's topics a sweep bag carries, with their types and the QoS their publishers offer.

Names come from ``wind_shaper.ros.names`` (the graph contract; that module imports no rclpy).
The QoS here mirrors ``wind_shaper.ros.qos`` without importing rclpy: it is written into a bag's
metadata as the offered QoS of bags made by ``write_sweep_bag``, and the player uses it for a
topic whose bag metadata has none. The recorder stores what the live publishers really offer.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..ros import names
from . import types


#: RMW_DURATION_INFINITE as (sec, nsec), the way Jazzy's rosbag2 writes an infinite
#: deadline / lifespan / lease duration into metadata.yaml.
INFINITE_TIME = (9223372036, 854775807)


def qos_time(nanoseconds: int) -> tuple[int, int]:
    """(sec, nsec) of a QoS duration [ns]; infinite (>= 2**63 - 1 ns) as INFINITE_TIME."""
    ns = int(nanoseconds)
    return INFINITE_TIME if ns >= 2 ** 63 - 1 else (ns // 1_000_000_000, ns % 1_000_000_000)


@dataclass(frozen=True)
class TopicQos:
    """A QoS profile in plain terms: reliable (else best effort), transient_local (latched;
    else volatile), depth (KEEP_LAST history depth)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def to_rosbags(self):
        """The rosbags ``Qos`` of this profile (infinite deadline/lifespan/lease, automatic
        liveliness: what rclpy publishers offer by default)."""
        from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                        QosReliability, QosTime)
        infinite = QosTime(*INFINITE_TIME)
        return Qos(QosHistory.KEEP_LAST, int(self.depth),
                   QosReliability.RELIABLE if self.reliable else QosReliability.BEST_EFFORT,
                   QosDurability.TRANSIENT_LOCAL if self.transient_local else QosDurability.VOLATILE,
                   infinite, infinite, QosLiveliness.AUTOMATIC, infinite, False)

    @classmethod
    def from_rosbags(cls, qos) -> 'TopicQos':
        from rosbags.interfaces import QosDurability, QosReliability
        return cls(reliable=qos.reliability != QosReliability.BEST_EFFORT,
                   transient_local=qos.durability == QosDurability.TRANSIENT_LOCAL,
                   depth=max(int(qos.depth), 1))


STREAM = TopicQos(reliable=True, transient_local=False, depth=100)
COMMAND = TopicQos(reliable=True, transient_local=False, depth=10)
LATCHED = TopicQos(reliable=True, transient_local=True, depth=1)


@dataclass(frozen=True)
class TopicSpec:
    """A topic of the graph: name, registered type name ('pkg/msg/Type') and offered QoS."""

    name: str
    msgtype: str
    qos: TopicQos


# The graph's topics as a bag names them: absolute, resolved in the root namespace (a graph
# started in a namespace records them under it; ``bag_namespace`` finds it back).
FORCE, PLATE_POSE, MOCAP_POSE = (names.resolve(n, '/') for n in (names.FORCE, names.PLATE_POSE,
                                                                    names.MOCAP_POSE))
FAN_COMMAND, FAN_APPLIED, FIELD = (names.resolve(n, '/') for n in (names.FAN_COMMAND, names.FAN_APPLIED,
                                                                      names.FIELD))
STATUS, EXPERIMENT_STATUS, EXPERIMENT_SWEEPS = (names.resolve(n, '/') for n in (
    names.STATUS, names.EXPERIMENT_STATUS, names.EXPERIMENT_SWEEPS))
DIAGNOSTICS = names.DIAGNOSTICS

#: The topics of a sweep, in the order a bag lists them.
SWEEP_TOPICS: dict[str, TopicSpec] = {spec.name: spec for spec in (
    TopicSpec(FORCE, types.WRENCH_STAMPED, STREAM),
    TopicSpec(PLATE_POSE, types.POSE_STAMPED, STREAM),
    TopicSpec(MOCAP_POSE, types.POSE_STAMPED, STREAM),
    TopicSpec(FAN_COMMAND, types.FAN_COMMAND, LATCHED),
    TopicSpec(FAN_APPLIED, types.FAN_COMMAND, LATCHED),
    TopicSpec(FIELD, types.FIELD_ESTIMATE, LATCHED),
    TopicSpec(STATUS, types.ITERATION_STATUS, LATCHED),
    TopicSpec(EXPERIMENT_STATUS, types.EXPERIMENT_STATUS, LATCHED),
    TopicSpec(EXPERIMENT_SWEEPS, types.SWEEP_SAMPLES, COMMAND),
)}

#: Other graph topics the recorder and player know the type of.
KNOWN_TOPICS: dict[str, TopicSpec] = {
    **SWEEP_TOPICS,
    DIAGNOSTICS: TopicSpec(DIAGNOSTICS, types.DIAGNOSTIC_ARRAY, COMMAND),
}

_GRAPH_PREFIX = '/' + names.FORCE.split('/')[0] + '/'   # '/wind_shaper/'


def in_namespace(topic: str, namespace: str = '/') -> str:
    """A graph topic as a bag names it (``/wind_shaper/...``) for a graph in ``namespace``
    (``/tunnel_b/wind_shaper/...``); other topics (the raw mocap, /diagnostics) unchanged."""
    ns = names.check_namespace(namespace)
    if ns == '/' or not topic.startswith(_GRAPH_PREFIX):
        return topic
    return ns + topic


def bag_namespace(topics) -> str:
    """The namespace a bag's graph topics were recorded in: '/' for ``/wind_shaper/...``,
    ``/tunnel_b`` for ``/tunnel_b/wind_shaper/...`` (the first graph topic found decides)."""
    for topic in topics:
        at = topic.find(_GRAPH_PREFIX)
        if at > 0 and topic[at:] in SWEEP_TOPICS:
            return topic[:at]
        if at == 0 and topic in SWEEP_TOPICS:
            return '/'
    return '/'


def canonical(topic: str) -> str:
    """A bag topic's name in the root namespace (the key of ``KNOWN_TOPICS``)."""
    at = topic.find(_GRAPH_PREFIX)
    return topic[at:] if at > 0 and topic[at:] in KNOWN_TOPICS else topic
