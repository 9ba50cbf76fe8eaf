"""mocap_relay: tracked rigid body pose (mocap frame) -> plate centre pose (tunnel frame).

Subscribes ``input_topic`` (geometry_msgs/PoseStamped from the mocap driver, e.g. vrpn_mocap,
best-effort so it matches the driver's sensor-data QoS) and publishes on ``output_topic`` the
plate centre ``T_tunnel_mocap * T_mocap_body * plate_offset`` with the plate's orientation, in
frame ``tunnel``, with the input's stamp unchanged (the capture time the field estimator aligns
force with). The per-pose logic is ``wind_shaper.estimation.frames.PlateRelay``: poses with NaN or a
non-unit quaternion, poses not newer than the last accepted one, and jumps (faster than
``max_speed_m_s`` since the last accepted pose) are dropped and counted; poses outside
``max_radius_m`` from the tunnel axis are published and flagged. Dropouts (no accepted pose for
``dropout_timeout_s``) and everything above are reported in /diagnostics at 1 Hz.

The relay listens to the mocap driver only while someone listens to it: once ``output_topic``
has had no subscriber for ``pause_unheard_s`` it drops its input subscription, and it takes it
again at the next subscriber (a field estimator beginning a sweep, a bag, a plot). A mocap
system streams whatever anyone reads; a graph at rest then spends nothing on relaying it.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..estimation import PlateRelay, RelayStats, RigidTransform, Verdict
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import stamp_to_seconds
from ..ros.params import declare_parameters, param
from ..ros.runner import run

#: Best effort matches both best-effort (vrpn_mocap's default sensor-data QoS) and reliable
#: publishers. Depth 100 holds 1 s of poses at 100 Hz: with depth 10 the relay lost 10-40 % of
#: the poses whenever the machine was busy.
MOCAP_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT,
                       history=HistoryPolicy.KEEP_LAST)
#: After taking its input again, the relay waits this long for the first pose before it reports
#: a dropout (the middleware matches the new subscription with the driver first) [s].
RESUME_GRACE_S = 1.0


@dataclass(frozen=True)
class MocapRelayParams:
    input_topic: str = param(names.MOCAP_POSE, 'PoseStamped of the tracked rigid body, mocap '
                             'frame (the mocap driver output)')
    output_topic: str = param(names.PLATE_POSE, 'PoseStamped of the plate centre, tunnel frame')
    tunnel_from_mocap: tuple = param((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), 'calibrated transform '
                                     'T_tunnel_mocap: tx ty tz [m] qx qy qz qw (the mocap frame '
                                     'in the tunnel frame)', array_of=float)
    plate_offset: tuple = param((0.0, 0.0, 0.0), 'plate centre in the tracked rigid body frame '
                                '[m]', array_of=float)
    max_speed_m_s: float = param(6.0, 'a faster move since the last accepted pose is a jump and '
                                 'is dropped [m/s]', low=1e-3)
    dropout_timeout_s: float = param(0.2, 'no accepted pose for this long is a dropout [s]',
                                     low=1e-3)
    max_radius_m: float = param(0.40, 'plate centre farther than this from the tunnel axis is '
                                'flagged as outside the tunnel [m]', low=1e-3)
    pause_unheard_s: float = param(2.0, 'drop the input subscription once output_topic has had '
                                   'no subscriber for this long, and take it again at the next '
                                   'subscriber; 0 = relay always [s]', low=0.0, high=3600.0)

    def __post_init__(self):
        self.relay()

    def relay(self) -> PlateRelay:
        return PlateRelay(RigidTransform.from_xyz_quat(self.tunnel_from_mocap), self.plate_offset,
                          self.max_speed_m_s, self.max_radius_m)


class MocapRelayNode(Node):
    """PoseStamped [m, mocap frame] in, PoseStamped [m, tunnel frame] out; see the module doc."""

    def __init__(self, **kwargs):
        super().__init__(names.MOCAP_RELAY, **kwargs)
        self.params = p = declare_parameters(self, MocapRelayParams)
        self._relay = p.relay()
        self._received = 0
        self._input_frame = ''
        self._last_accepted: float | None = None   # time.monotonic() of the last accepted pose
        self._dropouts = 0
        self._longest_dropout = 0.0
        self._last_outside = False
        self._last_position = None
        self._reported = (time.monotonic(), RelayStats(), 0)
        self._input = None                    # the input subscription; None while paused
        self._resumed_at: float | None = None   # time.monotonic() the input was last taken again
        self._unheard_since: float | None = None
        self._pauses = 0
        # a subscriber's arrival takes the input again at once (the diagnostics timer pauses)
        self._pub = self.create_publisher(PoseStamped, p.output_topic, qos.STREAM,
                                          event_callbacks=PublisherEventCallbacks(
                                              matched=self._on_matched))
        self._pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self._listen()
        self.create_timer(1.0, self._on_diagnostics_timer)
        self.get_logger().info(f'{p.input_topic} -> {p.output_topic}; T_tunnel_mocap = '
                               f'{self._relay.tunnel_from_mocap!r}')

    # -- listening on demand ----------------------------------------------------------------
    def _listen(self) -> None:
        if self._input is None:
            self._input = self.create_subscription(PoseStamped, self.params.input_topic,
                                                   self._on_mocap_pose, MOCAP_QOS)
            self._resumed_at, self._unheard_since = time.monotonic(), None
            self._last_accepted = None    # the silence while paused is no dropout

    def _on_matched(self, status) -> None:
        if status.current_count > 0 and self._input is None:
            self._listen()
            self.get_logger().info(f'a subscriber to {self.params.output_topic}: relaying again')

    def _watch_listeners(self, now: float) -> None:
        """Drop the input once nobody has listened for ``pause_unheard_s``; take it again when
        someone does (the matched event does so at once; this is the backstop)."""
        if self.params.pause_unheard_s <= 0:
            return
        if self._pub.get_subscription_count() > 0:
            self._unheard_since = None
            self._listen()
            return
        if self._input is None:
            return
        if self._unheard_since is None:
            self._unheard_since = now
        elif now - self._unheard_since >= self.params.pause_unheard_s:
            self.destroy_subscription(self._input)
            self._input = None
            self._last_accepted = None    # the silence while paused is no dropout
            self._pauses += 1
            self.get_logger().info(f'nobody subscribes to {self.params.output_topic}: the relay '
                                   f'stops listening to {self.params.input_topic} until someone '
                                   f'does')

    def _on_mocap_pose(self, msg: PoseStamped) -> None:
        now = time.monotonic()
        self._received += 1
        if self._received == 1:   # tells a lab (and a restart) that the mocap stream is flowing
            self.get_logger().info(f'first pose received on {self.params.input_topic}')
        self._input_frame = msg.header.frame_id
        pos, q = msg.pose.position, msg.pose.orientation
        result = self._relay.process(stamp_to_seconds(msg.header.stamp), (pos.x, pos.y, pos.z),
                                     (q.x, q.y, q.z, q.w))
        if result.verdict is not Verdict.ACCEPTED:
            self.get_logger().warning(
                f'pose dropped ({result.verdict.value}'
                + (f', {result.speed:.1f} m/s' if result.speed is not None else '') + ')',
                throttle_duration_sec=2.0)
            return
        if self._last_accepted is not None:
            gap = now - self._last_accepted
            if gap > self.params.dropout_timeout_s:
                self._dropouts += 1
                self._longest_dropout = max(self._longest_dropout, gap)
        self._last_accepted = now
        self._last_outside = result.outside
        self._last_position = result.position
        out = PoseStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = names.TUNNEL_FRAME
        x, y, z = (float(v) for v in result.position)
        out.pose.position.x, out.pose.position.y, out.pose.position.z = x, y, z
        qx, qy, qz, qw = (float(v) for v in result.orientation)
        o = out.pose.orientation
        o.x, o.y, o.z, o.w = qx, qy, qz, qw
        self._pub.publish(out)

    def _on_diagnostics_timer(self) -> None:
        now = time.monotonic()
        self._watch_listeners(now)
        stats = self._relay.stats
        t_prev, prev, received_prev = self._reported
        self._reported = (now, stats, self._received)
        rate = (stats.accepted - prev.accepted) / max(now - t_prev, 1e-9)
        waiting = False
        if self._last_accepted is not None:
            age = now - self._last_accepted
        elif self._received and self._resumed_at is not None:
            # listening again: the middleware's matching with the driver is no dropout
            age = now - self._resumed_at
            waiting = age < RESUME_GRACE_S
        else:
            age = None
        in_dropout = self._input is not None and not waiting and (
            age is None or age > self.params.dropout_timeout_s)
        if in_dropout and age is not None and age > self._longest_dropout:
            self._longest_dropout = age
        values = dict(received=self._received, published=stats.accepted, rate_hz=rate,
                      invalid=stats.invalid, stale=stats.stale, jumps=stats.jumps,
                      outside=stats.outside, dropouts=self._dropouts + int(in_dropout and
                                                                           age is not None),
                      longest_dropout_s=self._longest_dropout,
                      last_pose_age_s=('never' if self._last_accepted is None
                                       else now - self._last_accepted),
                      input_frame=self._input_frame, paused=self._input is None,
                      pauses=self._pauses)
        if self._last_position is not None:
            x, y, z = self._last_position
            values.update(x_m=float(x), y_m=float(y), z_m=float(z),
                          radius_m=float((x * x + y * y) ** 0.5))
        fresh = {k: getattr(stats, k) - getattr(prev, k) for k in ('invalid', 'stale', 'jumps')}
        if self._input is None:
            level, message = diag.OK, (f'paused: nobody subscribes to {self.params.output_topic}; '
                                       f'relaying resumes at the first subscriber')
        elif waiting:
            level, message = diag.OK, 'resuming: waiting for the first pose'
        elif in_dropout:
            level, message = diag.ERROR, ('no pose received yet' if age is None else
                                          f'dropout: no good pose for {age:.2f} s')
        elif self._last_outside:
            level, message = diag.WARN, (f'plate outside the tunnel (radius > '
                                         f'{self.params.max_radius_m} m)')
        elif any(fresh.values()):
            level, message = diag.WARN, ', '.join(
                f'{v} {k}' for k, v in fresh.items() if v) + ' dropped in the last second'
        else:
            level, message = diag.OK, f'relaying at {rate:.0f} Hz'
        self._pub_diag.publish(diag.array(self, diag.status(
            f'{names.MOCAP_RELAY}: plate pose', level, message, values,
            hardware_id=self.params.input_topic)))


def main(args=None):
    # Single-threaded, as every node: the wait set looks at what is really queued. (A relay
    # restarted in fault tests on a busy machine now and then relayed no pose again; one such
    # relay, caught, was blocked in Fast DDS's shared-memory publish, which `wind-shaper up
    # --hang-after` now restarts.) Depth 100 (MOCAP_QOS) keeps the 100 Hz poses on a busy machine.
    return run(MocapRelayNode, args, executor='single')


if __name__ == '__main__':
    raise SystemExit(main())
