"""fan_output: FanCommand -> fan PWMs on an autopilot over MAVLink 2 (a lifecycle node).

Subscribes ``/wind_shaper/fans/command`` (FanCommand, PWM fractions 0..1). A command must name
every configured fan exactly once with a finite value; anything else (unknown fan, length
mismatch, missing fan, NaN/inf) is refused with a warning and counted in /diagnostics, and
changes nothing. Values outside [u_min, u_max] are clipped into it and the clip is reported.
A timer at ``send_rate_hz`` moves the outputs toward the command at no more than
``slew_rate_per_s`` and sends them (``wind_shaper.io.MavlinkFanLink``) when the pulses change,
and at least every ``refresh_s`` while a command is held (an autopilot that restarted between
two heartbeat checks gets the commands back).

Publishes ``/wind_shaper/fans/applied`` (FanCommand, latched) from the autopilot's
SERVO_OUTPUT_RAW read-back: the fractions really applied. Services
``/wind_shaper/fans/emergency_stop`` (every fan to its safe pulse at once, bypassing the slew
limit; latched, commands refused until ``/wind_shaper/fans/reset_stop``). /diagnostics at 1 Hz.

The fans go to their safe pulse on: link loss (no autopilot heartbeat for
``heartbeat_timeout_s``), the watchdog (no FanCommand for ``command_timeout_s``; the coordinator
republishes at 2 Hz), e-stop, deactivate / cleanup / shutdown / destroy_node (SIGINT and SIGTERM
go through the runner's destroy_node), and any exception in a callback. After any of these the
fans stay safe until a new command arrives (and, after e-stop, reset_stop), then ramp up from
the safe value through the slew limit. When the link comes back while no command is held, the
safe pulse is sent again (the one sent at the loss may never have arrived).

Lifecycle: configure opens the MAVLink link (heartbeats start, read-back is published);
activate sends the safe pulse and enables commands; deactivate makes safe and refuses commands;
cleanup / shutdown make safe and close the link. With ``autostart`` (default) the node
configures and activates itself at start.
"""
from __future__ import annotations

import functools
import math
import threading
import time
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from std_srvs.srv import Trigger
from wind_shaper_msgs.msg import FanCommand

from ..core.errors import ConfigError
from ..protocols.mavlink_fans import FanChannel, FanChannelMap, Flavour, SlewLimiter
from ..io import LinkConfigError, MavlinkFanLink
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import fan_command, pwm_from_command
from ..ros.params import declare_parameters, param
from ..ros.runner import run

#: A read-back off the sent command by more than this [fraction] (2 us in 1000 us) for RESYNC_S
#: [s] makes fan_output send the command again.
RESYNC_TOLERANCE = 0.002
RESYNC_S = 1.0
PAPER_FANS = ('LM1', 'HM1', 'LM2', 'HM2', 'LM3', 'HM3', 'CM')


@dataclass(frozen=True)
class FanOutputParams:
    fan_names: tuple = param(PAPER_FANS, 'fan names, as in the tunnel configuration',
                             array_of=str)
    channels: tuple = param(tuple(range(1, 8)), 'autopilot servo output of each fan, 1-based, '
                            'in fan_names order', array_of=int)
    pwm_min_us: int = param(1000, 'pulse at PWM fraction 0 [us]', low=1, high=5000)
    pwm_max_us: int = param(2000, 'pulse at PWM fraction 1 [us]', low=1, high=5000)
    safe_us: int = param(1000, 'pulse that stops a fan [us], within pwm_min_us..pwm_max_us',
                         low=1, high=5000)
    u_min: float = param(0.0, 'lowest PWM fraction a command may set [1]; lower is clipped',
                         low=0.0, high=1.0)
    u_max: float = param(1.0, 'highest PWM fraction a command may set [1]; higher is clipped',
                         low=0.0, high=1.0)
    flavour: str = param('ardupilot_servo', 'how outputs are driven: ardupilot_servo | '
                         'ardupilot_rc_override | px4_actuator')
    mavlink_url: str = param('udpout:127.0.0.1:14550', 'pymavlink connection to the autopilot '
                             '(udpout:HOST:PORT, udpin:HOST:PORT, tcp:..., a serial device)')
    heartbeat_timeout_s: float = param(3.0, 'no autopilot heartbeat for this long = link lost, '
                                       'fans safe [s]', low=0.05, high=60.0)
    slew_rate_per_s: float = param(0.5, 'largest change of a fan PWM fraction per second [1/s]',
                                   low=1e-3, high=1e6)
    command_timeout_s: float = param(2.0, 'watchdog: no FanCommand for this long = fans safe [s]',
                                     low=0.05, high=3600.0)
    send_rate_hz: float = param(20.0, 'rate of the slew-limited send timer [Hz]', low=1.0,
                                high=200.0)
    refresh_s: float = param(1.0, 'while a command is held, send it again at least this often '
                             '[s], changed or not: an autopilot that restarted (its outputs back '
                             'at safe) gets it back; 0 = only when the pulses change', low=0.0,
                             high=3600.0)
    signing_key_hex: str = param('', "MAVLink 2 signing key, 64 hex digits ('' = signing off); "
                                 'the autopilot must hold the same key')
    autostart: bool = param(True, 'configure and activate at start (else wait for lifecycle '
                            'transitions)')

    def __post_init__(self):
        if len(self.fan_names) != len(self.channels):
            raise ConfigError(f'fan_names has {len(self.fan_names)} entries but channels has '
                              f'{len(self.channels)}: give one servo output per fan')
        Flavour.parse(self.flavour)
        self.channel_map()
        self.signing_key()

    def channel_map(self) -> FanChannelMap:
        return FanChannelMap(FanChannel(name, ch, self.pwm_min_us, self.pwm_max_us, self.safe_us,
                                        self.u_min, self.u_max)
                             for name, ch in zip(self.fan_names, self.channels))

    def signing_key(self) -> bytes | None:
        if not self.signing_key_hex:
            return None
        try:
            key = bytes.fromhex(self.signing_key_hex)
        except ValueError:
            key = b''
        if len(key) != 32:
            raise ConfigError('signing_key_hex must be 64 hex digits (a 32-byte key) or empty '
                              'for no signing')
        return key


def _guarded(callback):
    """Run a callback; on any exception log it, make the fans safe, and (for a service) answer
    with success False instead of raising into the executor."""
    @functools.wraps(callback)
    def wrapper(self, *args):
        try:
            return callback(self, *args)
        except Exception as exc:  # noqa: BLE001 - any failure must end with the fans safe
            self._counts['exceptions'] += 1
            self.get_logger().error(f'{callback.__name__} raised {exc!r}: fans made safe')
            try:
                self._make_safe(f'exception in {callback.__name__}')
            except Exception as inner:  # noqa: BLE001
                self.get_logger().error(f'making the fans safe failed too: {inner!r}')
            if args and isinstance(args[-1], Trigger.Response):
                args[-1].success = False
                args[-1].message = f'failed: {exc!r}; fans made safe'
                return args[-1]
            return None
    return wrapper


class FanOutputNode(LifecycleNode):
    """PWM fractions [1] in, MAVLink out; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__(names.FAN_OUTPUT, **kwargs)
        self.params = p = declare_parameters(self, FanOutputParams)
        self._map = p.channel_map()
        self._names = list(p.fan_names)
        self._lo = np.array([f.u_min for f in self._map])
        self._hi = np.array([f.u_max for f in self._map])
        # where a ramp starts after "safe": the safe pulse's fraction, brought into range
        self._rest = np.clip([f.safe_fraction for f in self._map], self._lo, self._hi)
        self._lock = threading.RLock()
        self._link: MavlinkFanLink | None = None
        self._state = 'unconfigured'
        self._configure_error = ''
        self._estop = False
        self._target: np.ndarray | None = None
        self._last_command: float | None = None     # time.monotonic() of the last good command
        self._limiter = SlewLimiter(p.slew_rate_per_s, self._rest)
        self._last_sent: dict[int, int] | None = None
        self._last_value: np.ndarray | None = None     # fractions of _last_sent, fan order
        self._last_send_at = 0.0                       # time.monotonic() of the last send
        self._off_since: float | None = None           # read-back off _last_value since [s]
        self._counts = dict(commands=0, rejected=0, clipped=0, watchdog_trips=0, link_losses=0,
                            estops=0, exceptions=0, resyncs=0)
        self._reported = dict(self._counts)
        self._last_reject = ''
        self._last_clipped: tuple[str, ...] = ()

        self._pub_applied = self.create_publisher(FanCommand, names.FAN_APPLIED, qos.LATCHED)
        self._pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.create_subscription(FanCommand, names.FAN_COMMAND, self._on_fans_command,
                                 qos.COMMAND)
        self.create_service(Trigger, names.EMERGENCY_STOP, self._handle_emergency_stop)
        self.create_service(Trigger, names.RESET_STOP, self._handle_reset_stop)
        self.create_timer(1.0 / p.send_rate_hz, self._on_send_timer)
        self.create_timer(1.0, self._on_diagnostics_timer)

        if p.autostart:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError(f'fan_output could not open the MAVLink link: '
                                  f'{self._configure_error or "see the log"}')
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError('fan_output could not activate: see the log')

    # ---------------------------------------------------------------- lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        p = self.params
        key = p.signing_key()
        try:
            link = MavlinkFanLink(p.mavlink_url, p.flavour, self._map,
                                  heartbeat_timeout_s=p.heartbeat_timeout_s,
                                  signing=key is not None, signing_key=key,
                                  on_link_lost=self._on_link_lost, on_link_up=self._on_link_up,
                                  on_outputs=self._on_servo_outputs)
        except (LinkConfigError, ConfigError) as exc:
            self._configure_error = str(exc)
            self.get_logger().error(f'cannot configure: {exc}')
            return TransitionCallbackReturn.FAILURE
        with self._lock:
            self._link = link
            self._state = 'inactive'
        self.get_logger().info(f'MAVLink link open: {p.mavlink_url} ({p.flavour}), fans '
                               + ', '.join(f'{f.name}->servo{f.channel}' for f in self._map))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        with self._lock:
            self._make_safe('activating')
            self._state = 'active'
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        with self._lock:
            self._state = 'inactive'
            self._make_safe('deactivating')
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close_link('cleanup')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close_link('shutdown')
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close_link('lifecycle error')
        return TransitionCallbackReturn.SUCCESS

    def destroy_node(self):
        self._close_link('node destroyed')
        super().destroy_node()

    # ---------------------------------------------------------------- safety
    def _make_safe(self, reason: str) -> None:
        """Forget the command and send every fan its safe pulse now (no slew limit)."""
        with self._lock:
            self._target = None
            self._limiter.reset(self._rest)
            self._last_sent = self._last_value = None
            if self._link is not None:
                self._link.go_safe()
        self.get_logger().info(f'fans safe ({reason})')

    def _close_link(self, reason: str) -> None:
        with self._lock:
            self._state = 'unconfigured'
            self._target = None
            link, self._link = self._link, None
        if link is not None:
            link.close()   # sends the safe pulse first; joins the link threads (not under _lock)
            self.get_logger().info(f'fans safe, MAVLink link closed ({reason})')

    # ---------------------------------------------------------------- callbacks
    @_guarded
    def _on_fans_command(self, msg: FanCommand) -> None:
        try:
            if len(set(msg.names)) != len(msg.names):
                raise ValueError(f'FanCommand names a fan twice: {list(msg.names)}')
            u = pwm_from_command(msg, self._names)
            bad = [n for n, v in zip(self._names, u) if not math.isfinite(v)]
            if bad:
                raise ValueError(f'FanCommand has non-finite PWM for {bad}')
        except ValueError as exc:
            self._reject(f'{exc}; the command was ignored')
            return
        with self._lock:
            if self._state != 'active':
                self._reject(f'fan_output is {self._state}, not active: the command was ignored')
                return
            if self._estop:
                self._reject('emergency stop is latched: the command was ignored; call '
                             f'{self.resolve_service_name(names.RESET_STOP)} first')
                return
            target = np.clip(u, self._lo, self._hi)
            clipped = tuple(n for n, a, b in zip(self._names, u, target) if a != b)
            if clipped:
                self._counts['clipped'] += 1
                self._last_clipped = clipped
                self.get_logger().warning(
                    f'FanCommand clipped into [{self.params.u_min}, {self.params.u_max}] for '
                    f'{list(clipped)}', throttle_duration_sec=5.0)
            self._target = target
            self._last_command = time.monotonic()
            self._counts['commands'] += 1

    def _reject(self, reason: str) -> None:
        self._counts['rejected'] += 1
        self._last_reject = reason
        self.get_logger().warning(reason, throttle_duration_sec=2.0)

    @_guarded
    def _on_send_timer(self) -> None:
        now = time.monotonic()
        with self._lock:
            link = self._link
            if self._state != 'active' or link is None:
                return
            if (self._target is not None
                    and now - self._last_command > self.params.command_timeout_s):
                self._counts['watchdog_trips'] += 1
                self.get_logger().warning(
                    f'no FanCommand for {self.params.command_timeout_s:.1f} s (command_timeout_s):'
                    f' fans made safe until the next command')
                self._make_safe('watchdog')
                return
            if self._estop or self._target is None:
                return
            if not link.link_up:
                self._limiter.reset(self._limiter.value)   # no time passes while not sending
                return
            value = self._limiter.step(now, self._target)
            pulses = self._map.command(value).pulses
            refresh = self.params.refresh_s
            if pulses != self._last_sent or (refresh > 0 and now - self._last_send_at >= refresh):
                link.send(value)
                self._last_sent, self._last_value = pulses, np.array(value, dtype=float)
                self._last_send_at = now

    @_guarded
    def _on_link_lost(self) -> None:
        # on the link's reader thread; the link has already sent the safe pulse
        with self._lock:
            self._counts['link_losses'] += 1
            self._target = None
            self._limiter.reset(self._rest)
            self._last_sent = self._last_value = None
        self.get_logger().error(
            f'no autopilot heartbeat for {self.params.heartbeat_timeout_s} s: link lost, fans '
            f'safe; they stay safe until the link is back and a new command arrives')

    @_guarded
    def _on_link_up(self) -> None:
        # on the link's reader thread. The safe pulse sent when the link was lost may never
        # have arrived (a pulled cable): while no command is held, send it again now.
        with self._lock:
            self._last_sent = self._last_value = None
            if self._target is None and self._link is not None:
                self._link.go_safe()
        self.get_logger().info(f'autopilot heartbeat received: link up ({self.params.mavlink_url})')

    @_guarded
    def _on_servo_outputs(self, fractions: dict) -> None:
        # on the link's reader thread, for every SERVO_OUTPUT_RAW
        self._check_outputs(fractions)
        present = [n for n in self._names if n in fractions]
        self._pub_applied.publish(fan_command(present, [fractions[n] for n in present],
                                              self.get_clock().now().to_msg()))

    def _check_outputs(self, fractions: dict) -> None:
        """An autopilot that restarted (or lost a command) reports outputs other than the ones
        sent, and pulses are sent only when they change: after RESYNC_S [s] of a mismatch, send
        them again."""
        now = time.monotonic()
        with self._lock:
            sent = self._last_value
            if (sent is None or self._estop or self._target is None
                    or np.max(np.abs(sent - self._target)) > 1e-9):   # still slewing
                self._off_since = None
                return
            off = any(abs(fractions[n] - u) > RESYNC_TOLERANCE
                      for n, u in zip(self._names, sent) if n in fractions)
            if not off:
                self._off_since = None
                return
            if self._off_since is None:
                self._off_since = now
                return
            if now - self._off_since < RESYNC_S:
                return
            self._off_since = None
            self._last_sent = self._last_value = None    # the send timer sends them again
            self._counts['resyncs'] += 1
        self.get_logger().warning(f'the autopilot reports outputs other than the commands for '
                                  f'{RESYNC_S:g} s (did it restart?): sending them again')

    @_guarded
    def _handle_emergency_stop(self, request: Trigger.Request,
                               response: Trigger.Response) -> Trigger.Response:
        with self._lock:
            self._estop = True
            self._counts['estops'] += 1
            self._make_safe('emergency stop')
            link_open = self._link is not None
        self.get_logger().warning(f'EMERGENCY STOP: fans safe; commands refused until '
                                  f'{self.resolve_service_name(names.RESET_STOP)}')
        response.success = True
        response.message = ('fans at their safe pulse; latched until reset_stop' if link_open else
                            'latched; no MAVLink link is open, so nothing was sent')
        return response

    @_guarded
    def _handle_reset_stop(self, request: Trigger.Request,
                           response: Trigger.Response) -> Trigger.Response:
        with self._lock:
            was = self._estop
            self._estop = False
        if was:
            self.get_logger().info('emergency stop reset: fans stay safe until the next command')
        response.success = True
        response.message = ('emergency stop reset; fans stay safe until the next command' if was
                            else 'no emergency stop was latched')
        return response

    @_guarded
    def _on_diagnostics_timer(self) -> None:
        now = time.monotonic()
        with self._lock:
            link = self._link
            counts = dict(self._counts)
            fresh = {k: counts[k] - self._reported[k] for k in counts}
            self._reported = counts
            values = dict(state=self._state, estop=self._estop,
                          last_command_age_s=(now - self._last_command
                                              if self._last_command is not None else 'never'),
                          commanding=self._target is not None, **counts,
                          last_rejected=self._last_reject,
                          last_clipped=','.join(self._last_clipped))
        hb_age = link.heartbeat_age_s if link is not None else None
        values['link'] = 'closed' if link is None else ('up' if link.link_up else 'down')
        values['heartbeat_age_s'] = 'never' if hb_age is None else hb_age
        if link is not None:
            values['commanded_us'] = ' '.join(
                f'{o.name}={o.pulse_us}' for o in link.commanded.outputs)
            values['applied'] = ' '.join(f'{n}={u:.3f}' for n, u in link.applied.items())
            stats = link.stats
            values.update(acks_denied=stats.denied, bad_data=stats.bad_data)
        if link is None:
            level, message = diag.ERROR, f'MAVLink link closed ({values["state"]})'
        elif not link.link_up:
            level, message = diag.ERROR, 'no autopilot heartbeat: fans safe'
        elif values['estop']:
            level, message = diag.WARN, 'emergency stop latched: fans safe'
        elif values['state'] != 'active':
            level, message = diag.WARN, f'{values["state"]}: commands refused'
        elif fresh['rejected'] or fresh['clipped'] or fresh['watchdog_trips'] or \
                fresh['exceptions']:
            level, message = diag.WARN, ', '.join(
                f'{k} {fresh[k]}' for k in ('rejected', 'clipped', 'watchdog_trips', 'exceptions')
                if fresh[k]) + ' in the last second'
        elif not values['commanding']:
            level, message = diag.OK, 'idle: fans safe, waiting for a command'
        else:
            level, message = diag.OK, 'commanding'
        self._pub_diag.publish(diag.array(self, diag.status(
            f'{names.FAN_OUTPUT}: MAVLink fans', level, message, values,
            hardware_id=self.params.mavlink_url)))


def main(args=None):
    return run(FanOutputNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
