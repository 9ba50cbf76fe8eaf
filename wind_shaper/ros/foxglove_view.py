"""The live view served to the Foxglove app through the foxglove-sdk WebSocket server: the same
field, fans and sweep path as the RViz topics, in Foxglove's own schemas (``foxglove.PointCloud``,
``foxglove.SceneUpdate``), on channels named like the ROS topics. Open Foxglove, "Open
connection", ``ws://HOST:PORT`` (``config/foxglove_layout.json`` arranges the panels).
"""
from __future__ import annotations

import time

import numpy as np

from ..estimation.view import POINT_FIELDS, FanView, field_points

FIELD_CHANNEL = '/wind_shaper/live/field'
FANS_CHANNEL = '/wind_shaper/live/fans'
PATH_CHANNEL = '/wind_shaper/live/sweep_path'


def _stamp(t_s: float):
    from foxglove.messages import Timestamp
    sec = int(t_s)
    return Timestamp(sec, int(round((t_s - sec) * 1e9)) % 1_000_000_000)


class FoxgloveView:
    """A foxglove-sdk WebSocket server on ``host``:``port`` (0: a free port, see ``port``) with
    the live view's three channels. A client may connect and drop at any time: the server
    keeps serving, and logging with no client costs next to nothing."""

    def __init__(self, host: str = '127.0.0.1', port: int = 8765, name: str = 'wind_shaper'):
        import foxglove
        from foxglove.channels import PointCloudChannel, SceneUpdateChannel
        self._server = foxglove.start_server(name=name, host=host, port=int(port))
        self._field = PointCloudChannel(FIELD_CHANNEL)
        self._fans = SceneUpdateChannel(FANS_CHANNEL)
        self._path = SceneUpdateChannel(PATH_CHANNEL)

    @property
    def port(self) -> int:
        return int(self._server.port)

    def close(self) -> None:
        for channel in (self._field, self._fans, self._path):
            channel.close()
        self._server.stop()

    def field(self, key_points, mean, std, target, frame_id: str, t_s: float | None = None) -> None:
        from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud
        rows = field_points(key_points, mean, std, target)
        fields = [PackedElementField(name=n, offset=4 * i, type=PackedElementFieldNumericType.Float32)
                  for i, n in enumerate(POINT_FIELDS)]
        self._field.log(PointCloud(timestamp=_stamp(time.time() if t_s is None else t_s),
                                   frame_id=frame_id, pose=_identity(), point_stride=4 * len(POINT_FIELDS),
                                   fields=fields, data=rows.astype('<f4').tobytes()))

    def fans(self, fans: list[FanView], frame_id: str, t_s: float | None = None) -> None:
        from foxglove.messages import (Color, CylinderPrimitive, SceneEntity, SceneUpdate,
                                       TextPrimitive, Vector3)
        stamp = _stamp(time.time() if t_s is None else t_s)
        entities = []
        for f in fans:
            height = 0.01 + 0.1 * f.command
            c = float(np.clip(f.command, 0, 1))
            color = Color(r=c, g=0.2, b=1 - c, a=0.8) if f.enabled else Color(r=0.5, g=0.5, b=0.5, a=0.6)
            entities.append(SceneEntity(
                timestamp=stamp, frame_id=frame_id, id=f.name,
                cylinders=[CylinderPrimitive(pose=_identity(f.x, f.y, -height / 2),
                                             size=Vector3(x=2 * f.radius, y=2 * f.radius, z=height),
                                             bottom_scale=1.0, top_scale=1.0, color=color)],
                texts=[TextPrimitive(pose=_identity(f.x, f.y, 0.03), billboard=True, font_size=14,
                                     scale_invariant=True, color=Color(r=1, g=1, b=1, a=1),
                                     text=f.label())]))
        self._fans.log(SceneUpdate(entities=entities))

    def path(self, points, frame_id: str, t_s: float | None = None) -> None:
        from foxglove.messages import (Color, LinePrimitive, LinePrimitiveLineType, Point3,
                                       SceneEntity, SceneUpdate)
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        line = LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=_identity(), thickness=3,
                             scale_invariant=True, color=Color(r=1, g=0.85, b=0.1, a=0.9),
                             points=[Point3(x=float(x), y=float(y), z=0.0) for x, y in pts])
        self._path.log(SceneUpdate(entities=[SceneEntity(
            timestamp=_stamp(time.time() if t_s is None else t_s), frame_id=frame_id,
            id='sweep_path', lines=[line] if len(pts) >= 2 else [])]))


def _identity(x: float = 0.0, y: float = 0.0, z: float = 0.0):
    from foxglove.messages import Pose, Quaternion, Vector3
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(w=1.0))


__all__ = ['FoxgloveView', 'FIELD_CHANNEL', 'FANS_CHANNEL', 'PATH_CHANNEL']
