"""The live view as ROS messages for RViz2 (and anything else): the field as a
sensor_msgs/PointCloud2 (one point per key point; force, std, target and residual as fields), the
fans and the plate's sweep path as visualization_msgs/MarkerArray, all in the ``tunnel`` frame.
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from ..estimation.view import POINT_FIELDS, FanView, field_points
from . import names


def point_cloud(key_points, mean, std, target, stamp) -> PointCloud2:
    """The field at the key points, x y z float32 then force std target residual float32 [N]."""
    rows = field_points(key_points, mean, std, target)
    msg = PointCloud2(header=Header(stamp=stamp, frame_id=names.TUNNEL_FRAME))
    msg.height, msg.width = 1, len(rows)
    msg.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, n in enumerate(POINT_FIELDS)]
    msg.is_bigendian = False
    msg.point_step = 4 * len(POINT_FIELDS)
    msg.row_step = msg.point_step * len(rows)
    msg.is_dense = bool(np.all(np.isfinite(rows)))
    msg.data = rows.astype('<f4').tobytes()
    return msg


def read_point_cloud(msg: PointCloud2) -> dict[str, np.ndarray]:
    """{field name: (N,) values} of a point cloud written by ``point_cloud``."""
    names_ = [f.name for f in msg.fields]
    rows = np.frombuffer(bytes(msg.data), dtype='<f4').reshape(-1, len(names_))
    return {n: rows[:, i].astype(float) for i, n in enumerate(names_)}


def _color(command: float, enabled: bool) -> ColorRGBA:
    """Blue (0) to red (1); grey when disabled."""
    if not enabled:
        return ColorRGBA(r=0.5, g=0.5, b=0.5, a=0.6)
    c = float(np.clip(command, 0.0, 1.0))
    return ColorRGBA(r=c, g=0.2, b=1.0 - c, a=0.8)


def fan_markers(fans: list[FanView], stamp) -> MarkerArray:
    """Per fan a cylinder at its hub (height grows with the command, colour blue to red), an
    arrow for its spin (tangent, counter-clockwise for CCW) and a label "LM1 42 % CCW"."""
    header = Header(stamp=stamp, frame_id=names.TUNNEL_FRAME)
    out = MarkerArray()
    for i, f in enumerate(fans):
        height = 0.01 + 0.1 * f.command
        hub = Marker(header=header, ns='fans', id=i, type=Marker.CYLINDER, action=Marker.ADD)
        hub.pose.position.x, hub.pose.position.y, hub.pose.position.z = f.x, f.y, -height / 2
        hub.pose.orientation.w = 1.0
        hub.scale.x = hub.scale.y = 2 * f.radius
        hub.scale.z = height
        hub.color = _color(f.command, f.enabled)
        spin = Marker(header=header, ns='fan_spin', id=i, type=Marker.ARROW, action=Marker.ADD)
        spin.pose.orientation.w = 1.0
        a = np.array([f.x + f.radius, f.y])
        b = a + np.array([0.0, f.spin * f.radius])
        spin.points = [Point(x=float(a[0]), y=float(a[1]), z=0.0), Point(x=float(b[0]), y=float(b[1]), z=0.0)]
        spin.scale.x, spin.scale.y, spin.scale.z = 0.005, 0.012, 0.012
        spin.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=0.9 if f.enabled else 0.3)
        label = Marker(header=header, ns='fan_labels', id=i, type=Marker.TEXT_VIEW_FACING,
                       action=Marker.ADD, text=f.label())
        label.pose.position.x, label.pose.position.y, label.pose.position.z = f.x, f.y, 0.03
        label.pose.orientation.w = 1.0
        label.scale.z = 0.025
        label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        out.markers += [hub, spin, label]
    return out


def path_marker(points, stamp) -> MarkerArray:
    """The plate's path over the running sweep as one line strip (a DELETE when it is empty)."""
    header = Header(stamp=stamp, frame_id=names.TUNNEL_FRAME)
    m = Marker(header=header, ns='sweep_path', id=0, type=Marker.LINE_STRIP)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(pts) < 2:
        m.action = Marker.DELETE
    else:
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        m.points = [Point(x=float(x), y=float(y), z=0.0) for x, y in pts]
        m.scale.x = 0.004
        m.color = ColorRGBA(r=1.0, g=0.85, b=0.1, a=0.9)
    return MarkerArray(markers=[m])


__all__ = ['point_cloud', 'read_point_cloud', 'fan_markers', 'path_marker']
