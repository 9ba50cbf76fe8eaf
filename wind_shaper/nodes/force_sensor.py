"""force_sensor: ATI Net F/T RDT stream -> geometry_msgs/WrenchStamped (a lifecycle node).

``wind_shaper.io.NetFtClient`` reads the sensor's UDP stream on its own thread; every good
sample is published from that thread on ``/wind_shaper/force`` (QoS STREAM), stamped in the
node clock with its sample time (from its sequence number, ``sample_rate_hz``; 0: at reception),
in ``frame_id`` [N, N m]. The same samples also go out in blocks
of ``block_samples`` on ``/wind_shaper/force/block`` (wind_shaper_msgs/ForceBlock: stamps and
the vertical force), at the latest ``block_max_s`` after a block's first sample (when the
stream stops, within half a second): the field estimator takes those, tens of messages a
second instead of a thousand. Samples whose status word is nonzero (saturation, broken gage,
...) are not published but counted and logged. Service
``/wind_shaper/force_sensor/bias`` (std_srvs/Trigger) zeroes the sensor's current reading.
/diagnostics at 1 Hz: received / lost / out-of-order / duplicates / rejected-source / faulted /
malformed counts and the measured publish rate.

``force_sign`` -1 turns the readings 180 deg about the sensor's x axis (Fy, Fz, Ty, Tz change
sign), for a sensor mounted upside down: the published +Fz is then up and the frame stays
right-handed.

Lifecycle: configure opens the UDP socket; activate asks the sensor to stream (and biases it
with ``bias_on_start``); deactivate asks it to stop; cleanup / shutdown / destroy_node stop the
stream and close the socket. With ``autostart`` (default) it configures and activates at start.
The stream does not go through the executor at all; the executor (single-threaded) runs the
services and timers only.

While active, the stream runs only while someone listens: once neither topic has had a
subscriber for ``pause_unheard_s``, the node asks the sensor to stop streaming, and it asks
again at the next subscriber (a field estimator beginning a sweep, a bag, a plot). A graph at
rest then spends nothing on a thousand records a second that nobody reads. The new stream is
stamped from its own start (as after any silence); /diagnostics says the stream is paused.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from std_srvs.srv import Trigger
from wind_shaper_msgs.msg import ForceBlock

from ..core.errors import ConfigError
from ..protocols.netft import RDT_PORT, NetFtCalibration, NetFtSample, SampleClock
from ..io import LinkConfigError, NetFtClient, NetFtStreamStats, TransportError
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import seconds_to_stamp, stamp_to_seconds
from ..ros.params import declare_parameters, param
from ..ros.runner import run


@dataclass(frozen=True)
class ForceSensorParams:
    sensor_host: str = param('127.0.0.1', 'IP address or host name of the Net F/T sensor '
                             '(ATI factory default 192.168.1.1)')
    sensor_port: int = param(RDT_PORT, 'UDP port of the sensor RDT server', low=1, high=65535)
    counts_per_force: float = param(1_000_000.0, 'counts per N (calcpf in the sensor '
                                    'netftcalapi.xml) [counts/N]', low=1e-9)
    counts_per_torque: float = param(1_000_000.0, 'counts per N m (calcpt) [counts/(N m)]',
                                     low=1e-9)
    frame_id: str = param(names.SENSOR_FRAME, 'frame_id of the published wrenches')
    force_sign: int = param(1, '+1: sensor +z is up; -1: turn the readings 180 deg about x so '
                            'the published +Fz is up', low=-1, high=1)
    bias_on_start: bool = param(False, 'zero the sensor reading when streaming starts (only '
                                'with the plate at rest and the fans off)')
    autostart: bool = param(True, 'configure and activate at start (else wait for lifecycle '
                            'transitions)')
    sample_rate_hz: float = param(1000.0, 'the sensor\'s RDT output rate (its configuration); '
                                  'samples are stamped from their sequence numbers at this rate, '
                                  'anchored on the least-delayed packet, so host lag does not '
                                  'shift them; 0 = stamp at arrival [Hz]', low=0.0, high=10000.0)
    block_samples: int = param(20, 'samples per ForceBlock on wind_shaper/force/block (0 = '
                               'no blocks, only the per-sample wrenches)', low=0, high=100000)
    block_max_s: float = param(0.05, 'a block goes out at the latest this long after its first '
                               'sample, full or not (a slow stream; a stalled one within 0.5 s) '
                               '[s]',
                               low=0.001, high=10.0)
    restart_after_s: float = param(1.0, 'while active with no sample for this long, send the '
                                   'start request again (sensor booted late or rebooted) [s]',
                                   low=0.1, high=60.0)
    pause_unheard_s: float = param(2.0, 'ask the sensor to stop streaming once neither force '
                                   'topic has had a subscriber for this long, and to start '
                                   'again at the next subscriber; 0 = stream whenever active '
                                   '[s]', low=0.0, high=3600.0)

    def __post_init__(self):
        if self.force_sign not in (-1, 1):
            raise ConfigError(f'force_sign must be +1 or -1; got {self.force_sign}')
        if not self.sensor_host:
            raise ConfigError('sensor_host is empty: give the sensor IP address')
        self.calibration()

    def calibration(self) -> NetFtCalibration:
        return NetFtCalibration(self.counts_per_force, self.counts_per_torque)


_COUNTERS = ('received', 'lost', 'out_of_order', 'duplicates', 'rejected', 'faulted', 'malformed')


class ForceSensorNode(LifecycleNode):
    """Net F/T RDT in, WrenchStamped [N, N m, sensor frame] out; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__(names.FORCE_SENSOR, **kwargs)
        self.params = p = declare_parameters(self, ForceSensorParams)
        self._sign = float(p.force_sign)
        self._client: NetFtClient | None = None
        self._sample_clock = SampleClock(p.sample_rate_hz) if p.sample_rate_hz > 0 else None
        self._clock_restart = False   # set on a re-sent start request, applied by the reader thread
        self._lock = threading.Lock()
        self._state = 'unconfigured'
        self._configure_error = ''
        self._published = 0
        self._last_sample: float | None = None        # time.monotonic() of the last good sample
        self._last_fault = ''
        self._reported = (time.monotonic(), 0, NetFtStreamStats())
        self._paused = False                  # active, but the sensor asked to stop: nobody listens
        self._unheard_since: float | None = None   # time.monotonic() since no subscriber
        self._pauses = 0
        # a subscriber's arrival resumes a paused stream at once (the watch timer is the backstop)
        heard = PublisherEventCallbacks(matched=self._on_matched)
        self._pub = self.create_publisher(WrenchStamped, names.FORCE, qos.STREAM,
                                          event_callbacks=heard)
        self._block_pub = (self.create_publisher(ForceBlock, names.FORCE_BLOCK, qos.STREAM,
                                                 event_callbacks=heard)
                           if p.block_samples > 0 else None)
        self._block_lock = threading.Lock()   # the reader thread fills it, a timer flushes it
        self._block_t: list[float] = []
        self._block_fz: list[float] = []
        self._block_began = 0.0               # time.monotonic() of the block's first sample
        self._pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.create_service(Trigger, names.FORCE_BIAS, self._handle_bias)
        self.create_timer(1.0, self._on_diagnostics_timer)
        self._last_request = time.monotonic()
        self._rerequests = 0
        self.create_timer(min(p.restart_after_s, 1.0) / 2, self._on_stream_watch_timer)
        if p.autostart:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError(f'force_sensor could not open its socket: '
                                  f'{self._configure_error or "see the log"}')
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError(f'force_sensor could not start the stream from '
                                  f'{p.sensor_host}:{p.sensor_port}: see the log')

    # ---------------------------------------------------------------- lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        p = self.params
        try:
            client = NetFtClient(p.sensor_host, p.sensor_port, calibration=p.calibration(),
                                 on_sample=self._on_sample)
        except LinkConfigError as exc:
            self._configure_error = str(exc)
            self.get_logger().error(f'cannot configure: {exc}')
            return TransitionCallbackReturn.FAILURE
        with self._lock:
            self._client = client
            self._state = 'inactive'
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        p = self.params
        try:
            with self._lock:
                self._state = 'active'
                self._paused, self._unheard_since = False, None
                self._published = 0
                self._reported = (time.monotonic(), 0, NetFtStreamStats())
                self._client.start()
                self._last_request = time.monotonic()
                if self._sample_clock is not None:
                    self._sample_clock.reset()
                if p.bias_on_start:
                    self._client.bias()
        except TransportError as exc:
            self.get_logger().error(f'cannot start the stream: {exc}')
            self._state = 'inactive'
            return TransitionCallbackReturn.FAILURE
        self.get_logger().info(f'streaming from {p.sensor_host}:{p.sensor_port}'
                               + (' (biased)' if p.bias_on_start else ''))
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._flush_block()
        with self._lock:
            self._state = 'inactive'
            self._paused = False
            client = self._client
        try:
            client.stop()
        except TransportError as exc:
            self.get_logger().warning(f'stop request not sent: {exc}')
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close('cleanup')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close('shutdown')
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close('lifecycle error')
        return TransitionCallbackReturn.SUCCESS

    def destroy_node(self):
        self._close('node destroyed')
        super().destroy_node()

    def _close(self, reason: str) -> None:
        with self._lock:
            self._state = 'unconfigured'
            client, self._client = self._client, None
        if client is not None:
            client.close()     # stop request, reader thread joined, socket closed
            self._flush_block()
            self.get_logger().info(f'Net F/T stream closed ({reason})')

    # ---------------------------------------------------------------- stream
    def _on_sample(self, sample: NetFtSample, stats: NetFtStreamStats) -> None:
        """On the client's reader thread, once per accepted record."""
        if self._state != 'active':
            return
        if not sample.ok:
            self._last_fault = sample.status_info.describe()
            self.get_logger().warning(f'sensor fault, sample not published: {self._last_fault}',
                                      throttle_duration_sec=2.0)
            return
        steady = time.monotonic()
        now = self.get_clock().now()
        if self._sample_clock is None:
            stamp = now.to_msg()
        else:
            if self._clock_restart:
                self._clock_restart = False
                self._sample_clock.reset()
            stamp = seconds_to_stamp(self._sample_clock.stamp_in(
                sample.rdt_sequence, steady, now.nanoseconds * 1e-9))
        (fx, fy, fz), (tx, ty, tz) = sample.force, sample.torque
        s = self._sign
        # The wrench is built and sent only while someone subscribes (a bag, the lab's stack):
        # at 1 kHz that costs 5 % of a core; the field estimator reads the blocks. A new
        # subscriber is seen at its first matched sample (the count is the middleware's).
        if self._pub.get_subscription_count() > 0:
            msg = WrenchStamped()
            msg.header.stamp = stamp
            msg.header.frame_id = self.params.frame_id
            f, t = msg.wrench.force, msg.wrench.torque
            f.x, f.y, f.z = fx, s * fy, s * fz
            t.x, t.y, t.z = tx, s * ty, s * tz
            self._pub.publish(msg)
        self._published += 1
        self._last_sample = time.monotonic()
        if self._block_pub is not None:
            self._add_to_block(stamp_to_seconds(stamp), s * fz, self._last_sample)

    def _add_to_block(self, t: float, fz: float, now: float) -> None:
        with self._block_lock:
            if not self._block_t:
                self._block_began = now
            self._block_t.append(t)
            self._block_fz.append(fz)
            due = (len(self._block_t) >= self.params.block_samples
                   or now - self._block_began >= self.params.block_max_s)
        if due:
            self._flush_block()

    def _flush_block(self) -> None:
        """Publish the samples collected since the last block (none: nothing is sent)."""
        with self._block_lock:
            stamps, forces = self._block_t, self._block_fz
            self._block_t, self._block_fz = [], []
        if not stamps or self._block_pub is None:
            return
        block = ForceBlock()
        block.header.stamp = seconds_to_stamp(stamps[-1])
        block.header.frame_id = self.params.frame_id
        block.stamp, block.force_z = stamps, forces
        self._block_pub.publish(block)

    # ---------------------------------------------------------------- services, diagnostics
    def _handle_bias(self, request: Trigger.Request, response: Trigger.Response
                     ) -> Trigger.Response:
        client = self._client
        if client is None or self._state != 'active':
            response.success = False
            response.message = f'force_sensor is {self._state}: activate it first'
            return response
        try:
            client.bias()
        except TransportError as exc:
            response.success, response.message = False, str(exc)
            return response
        self.get_logger().info('bias request sent: the current reading is the new zero')
        response.success = True
        response.message = 'bias request sent to the sensor'
        return response

    def _on_stream_watch_timer(self) -> None:
        """Send a block the stream left unfinished; re-send the start request while streaming
        should run but nothing arrives."""
        client, now = self._client, time.monotonic()
        with self._block_lock:
            stalled = bool(self._block_t) and now - self._block_began >= self.params.block_max_s
        if stalled:
            self._flush_block()
        if self._state != 'active' or client is None:
            return
        if self._watch_listeners(client, now):
            return
        last = max(self._last_sample or 0.0, self._last_request)
        if now - last < self.params.restart_after_s:
            return
        try:
            client.request_stream()
            # the new stream's numbers start over on the sensor's clock of that moment; the
            # reader thread, which stamps, starts the clock again at its next sample
            self._clock_restart = True
        except TransportError as exc:
            self.get_logger().warning(f'cannot re-send the start request: {exc}',
                                      throttle_duration_sec=10.0)
            return
        self._last_request = now
        self._rerequests += 1
        self.get_logger().warning(
            f'no samples from {self.params.sensor_host}:{self.params.sensor_port} for '
            f'{self.params.restart_after_s} s: start request sent again ({self._rerequests})',
            throttle_duration_sec=5.0)

    # ---------------------------------------------------------------- streaming on demand
    def _listeners(self) -> int:
        """Subscribers to either force topic (as the middleware has matched them)."""
        count = self._pub.get_subscription_count()
        return count + (self._block_pub.get_subscription_count() if self._block_pub else 0)

    def _on_matched(self, status) -> None:
        if status.current_count > 0 and self._paused:
            self._resume()

    def _watch_listeners(self, client: NetFtClient, now: float) -> bool:
        """Pause the stream once nobody has listened for ``pause_unheard_s``, resume it when
        someone does; True while paused (there is no stream to watch)."""
        if self.params.pause_unheard_s <= 0:
            return False
        if self._listeners() > 0:
            self._unheard_since = None
            if self._paused:
                self._resume()
            return False
        if self._paused:
            return True
        if self._unheard_since is None:
            self._unheard_since = now
            return False
        if now - self._unheard_since < self.params.pause_unheard_s:
            return False
        try:
            client.stop()
        except TransportError as exc:
            self.get_logger().warning(f'cannot ask the sensor to stop: {exc}',
                                      throttle_duration_sec=10.0)
            return False
        self._paused = True
        self._pauses += 1
        self._flush_block()
        self.get_logger().info("nobody subscribes to the force topics: the sensor's stream is "
                               'paused until someone does')
        return True

    def _resume(self) -> None:
        client = self._client
        if client is None or self._state != 'active':
            return
        try:
            client.request_stream()
        except TransportError as exc:
            self.get_logger().warning(f'cannot ask the sensor to stream again: {exc}',
                                      throttle_duration_sec=10.0)
            return
        # a new stream numbers its records from 1 on the sensor's clock of now: stamp it afresh
        self._clock_restart = True
        self._last_request = time.monotonic()
        self._paused, self._unheard_since = False, None
        self.get_logger().info('a subscriber to the force topics: the sensor streams again')

    def _on_diagnostics_timer(self) -> None:
        now = time.monotonic()
        client = self._client
        stats = client.stats if client is not None else NetFtStreamStats()
        published = self._published
        t_prev, published_prev, stats_prev = self._reported
        self._reported = (now, published, stats)
        rate = (published - published_prev) / max(now - t_prev, 1e-9)
        fresh = {k: getattr(stats, k) - getattr(stats_prev, k) for k in _COUNTERS}
        age = None if self._last_sample is None else now - self._last_sample
        values = {k: getattr(stats, k) for k in _COUNTERS}
        values.update(state=self._state, published=published, rate_hz=rate,
                      rejected_source=stats.rejected, stale=stats.stale, resyncs=stats.resyncs,
                      last_sample_age_s='never' if age is None else age,
                      start_requests_resent=self._rerequests,
                      paused=self._paused, stream_pauses=self._pauses,
                      last_fault=self._last_fault)
        del values['rejected']
        p = self.params
        where = f'{p.sensor_host}:{p.sensor_port}'
        if self._state != 'active':
            level, message = diag.WARN, f'{self._state}: not streaming'
        elif self._paused:
            level, message = diag.OK, ('paused: nobody subscribes to the force topics; the sensor '
                                       'streams again at the first subscriber')
        elif age is None or age > 1.0:
            level, message = diag.ERROR, (f'no good samples from {where} for over 1 s: check the '
                                          f'sensor address, network and status')
        elif any(fresh[k] for k in ('lost', 'faulted', 'malformed', 'duplicates', 'rejected')):
            level, message = diag.WARN, ', '.join(
                f'{k} {fresh[k]}' for k in ('lost', 'faulted', 'malformed', 'duplicates',
                                            'rejected') if fresh[k]) + ' in the last second'
        else:
            level, message = diag.OK, f'streaming at {rate:.0f} Hz'
        self._pub_diag.publish(diag.array(self, diag.status(
            f'{names.FORCE_SENSOR}: Net F/T', level, message, values, hardware_id=where)))


def main(args=None):
    return run(ForceSensorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
