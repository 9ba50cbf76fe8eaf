"""diagnostic_msgs plumbing: one status with key/values, wrapped in a stamped array."""
from __future__ import annotations

from typing import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE


def _text(value) -> str:
    if isinstance(value, float):
        return f'{value:.6g}'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    return str(value)


def status(name: str, level: bytes, message: str, values: Mapping[str, object] = (),
           hardware_id: str = '') -> DiagnosticStatus:
    """A DiagnosticStatus; ``values`` become KeyValues (floats with 6 significant digits)."""
    items = values.items() if isinstance(values, Mapping) else values
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=_text(v)) for k, v in items])


def array(node, *statuses: DiagnosticStatus) -> DiagnosticArray:
    """The statuses in a DiagnosticArray stamped with ``node``'s clock. /diagnostics is shared by
    the whole ROS domain: a node in a namespace prefixes its statuses' names with it
    ("/tunnel_b fan_output: MAVLink fans"), so two tunnels' statuses stay apart."""
    ns = node.get_namespace()
    if ns not in ('', '/'):
        for st in statuses:
            st.name = f'{ns} {st.name}'
    msg = DiagnosticArray(status=list(statuses))
    msg.header.stamp = node.get_clock().now().to_msg()
    return msg
