"""live_view: the field forming live, for RViz2 and the Foxglove app.

Subscribes the field estimate (``wind_shaper/field``, and while a sweep runs the estimate of the
sweep so far, ``wind_shaper/field/partial``, so the field forms as the plate moves), the
coordinator's status (its target and
state), the fans' read-back (``wind_shaper/fans/applied``) and the plate pose
(``wind_shaper/plate/pose``), and publishes, in frame ``tunnel``:

- ``wind_shaper/live/field`` (sensor_msgs/PointCloud2, latched): one point per key point with
  fields force, std, target and residual [N] (colour by any of them in RViz2);
- ``wind_shaper/live/fans`` (visualization_msgs/MarkerArray, latched): per fan its hub, its
  command (height and colour) and its spin, with a label;
- ``wind_shaper/live/sweep_path`` (visualization_msgs/MarkerArray): the plate's path over the
  running sweep, cleared when the next iteration starts commanding.

The plate's pose itself is ``wind_shaper/plate/pose``; node health is on /diagnostics. With
``foxglove_port`` > 0 the same view is served to the Foxglove app over the foxglove-sdk
WebSocket server (``ros/foxglove_view.py``). ``config/rviz/wind_shaper.rviz`` and
``config/foxglove_layout.json`` arrange the panels. The target's values come from the status's
target spec and this node's ``config_dir`` (a target the node cannot build is shown as NaN,
with a warning).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray
from sensor_msgs.msg import PointCloud2
from wind_shaper_msgs.msg import FanCommand, FieldEstimate, IterationStatus

from ..app import Setup
from ..core.errors import WindShaperError
from ..estimation.view import SweepTrail, fan_views
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import pwm_from_command
from ..ros.live import fan_markers, path_marker, point_cloud
from ..ros.params import declare_parameters, param
from ..ros.runner import run

LIVE_FIELD = 'wind_shaper/live/field'
LIVE_FANS = 'wind_shaper/live/fans'
LIVE_PATH = 'wind_shaper/live/sweep_path'


@dataclass(frozen=True)
class LiveViewParams:
    config_dir: str = param('', 'folder with tunnel.yaml, shaping.yaml, model.yaml ("" = the '
                            'shipped config): the fans and the targets')
    path_rate_hz: float = param(2.0, 'how often the sweep path is republished while the plate '
                                'moves [Hz]', low=0.1, high=50.0)
    path_points: int = param(2000, 'longest sweep path kept (every other point dropped beyond)',
                             low=2, high=100000)
    foxglove_port: int = param(0, 'serve the view to the Foxglove app on this WebSocket port '
                               '(0 = off)', low=0, high=65535)
    foxglove_host: str = param('127.0.0.1', 'address the Foxglove server listens on (0.0.0.0: '
                               'every interface)')


class LiveViewNode(Node):
    """Field, fans and sweep path for RViz2 and Foxglove; see the module doc."""

    def __init__(self, **kwargs):
        super().__init__(names.LIVE_VIEW, **kwargs)
        self.params = p = declare_parameters(self, LiveViewParams)
        self._setup = Setup.load(p.config_dir or None)
        self._fans = self._setup.geometry.fans
        self._lock = threading.Lock()
        self._trail = SweepTrail(p.path_points)
        self._target_spec, self._target = None, None
        self._last_field: FieldEstimate | None = None
        self._state = ''
        self._counts = dict(fields=0, fan_updates=0, poses=0, target_errors=0)
        self._trail_dirty = False
        self._foxglove = None
        if p.foxglove_port:
            from ..ros.foxglove_view import FoxgloveView
            self._foxglove = FoxgloveView(p.foxglove_host, p.foxglove_port)
            self.get_logger().info(f'Foxglove: open ws://{p.foxglove_host}:{self._foxglove.port} '
                                   f'in the Foxglove app')
        self._field_pub = self.create_publisher(PointCloud2, LIVE_FIELD, qos.LATCHED)
        self._fans_pub = self.create_publisher(MarkerArray, LIVE_FANS, qos.LATCHED)
        self._path_pub = self.create_publisher(MarkerArray, LIVE_PATH, qos.COMMAND)
        self._diag_pub = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.create_subscription(FieldEstimate, names.FIELD, self._on_field, qos.LATCHED)
        self.create_subscription(FieldEstimate, names.FIELD_PARTIAL, self._on_field, qos.COMMAND)
        self.create_subscription(IterationStatus, names.STATUS, self._on_status, qos.LATCHED)
        self.create_subscription(FanCommand, names.FAN_APPLIED, self._on_applied, qos.LATCHED)
        self.create_subscription(PoseStamped, names.PLATE_POSE, self._on_pose, qos.STREAM)
        self.create_timer(1.0 / p.path_rate_hz, self._on_path_timer)
        self.create_timer(1.0, self._on_diagnostics)
        self._publish_fans(np.zeros(self._fans.n_fans))

    # -- inputs --------------------------------------------------------------------------------
    def _target_values(self, spec: str, key_points):
        """The target at ``key_points`` for a status's target spec (None if it cannot be built)."""
        if not spec:
            return None
        if spec != self._target_spec:
            self._target_spec = spec
            try:
                self._target = self._setup.make_target(spec)
            except (WindShaperError, OSError, ValueError) as exc:
                self._target = None
                self._counts['target_errors'] += 1
                self.get_logger().warning(f'target {spec!r} cannot be shown: {exc}')
        return None if self._target is None else self._target.values(key_points)

    def _on_field(self, msg: FieldEstimate) -> None:
        self._last_field = msg
        self._publish_field()

    def _publish_field(self) -> None:
        msg = self._last_field
        if msg is None:
            return
        kp = np.column_stack([msg.x, msg.y])
        target = self._target_values(self._target_spec or '', kp) if self._target_spec else None
        try:
            cloud = point_cloud(kp, msg.mean, msg.std, target, msg.header.stamp)
        except ValueError as exc:
            self.get_logger().warning(f'field estimate not shown: {exc}')
            return
        self._field_pub.publish(cloud)
        self._counts['fields'] += 1
        if self._foxglove is not None:
            self._foxglove.field(kp, msg.mean, msg.std, target, names.TUNNEL_FRAME)

    def _on_status(self, msg: IterationStatus) -> None:
        changed = msg.target and msg.target != self._target_spec
        if changed:
            self._target_values(msg.target, self._setup.geometry.key_points)
            self._publish_field()
        if msg.state == 'commanding' and self._state != 'commanding':
            with self._lock:   # a new iteration: a new sweep path
                self._trail.clear()
                self._trail_dirty = True
        self._state = msg.state

    def _on_applied(self, msg: FanCommand) -> None:
        try:
            pwm = pwm_from_command(msg, list(self._fans.names))
        except ValueError as exc:
            self.get_logger().warning(f'fan read-back not shown: {exc}', throttle_duration_sec=10)
            return
        self._publish_fans(pwm)

    def _publish_fans(self, pwm) -> None:
        views = fan_views(self._fans, pwm)
        self._fans_pub.publish(fan_markers(views, self.get_clock().now().to_msg()))
        self._counts['fan_updates'] += 1
        if self._foxglove is not None:
            self._foxglove.fans(views, names.TUNNEL_FRAME)

    def _on_pose(self, msg: PoseStamped) -> None:
        with self._lock:
            self._trail.add(msg.pose.position.x, msg.pose.position.y)
            self._trail_dirty = True
        self._counts['poses'] += 1

    def _on_path_timer(self) -> None:
        with self._lock:
            if not self._trail_dirty:
                return
            self._trail_dirty = False
            points = self._trail.points
        self._path_pub.publish(path_marker(points, self.get_clock().now().to_msg()))
        if self._foxglove is not None:
            self._foxglove.path(points, names.TUNNEL_FRAME)

    def _on_diagnostics(self) -> None:
        values = dict(self._counts)
        if self._foxglove is not None:
            values['foxglove_port'] = self._foxglove.port
        level = diag.WARN if self._counts['target_errors'] else diag.OK
        self._diag_pub.publish(diag.array(self, diag.status(
            f'{names.LIVE_VIEW}: live view', level,
            'showing' if self._counts['fields'] else 'waiting for a field estimate', values)))

    def destroy_node(self):
        if self._foxglove is not None:
            self._foxglove.close()
            self._foxglove = None
        return super().destroy_node()


def main(args=None) -> int:
    return run(LiveViewNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
