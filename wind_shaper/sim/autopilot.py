"""A simulated autopilot: a MAVLink 2 peer on UDP that applies fan outputs like the real ones.

``SimAutopilot`` binds a UDP socket (port 0 = a free port; ``port`` tells which) and learns its
client's address from every valid MAVLink packet it receives (or sends to a fixed ``peer``, for
clients that listen with 'udpin:'). It understands every fan flavour at once:

* COMMAND_LONG MAV_CMD_DO_SET_SERVO: param1 servo 1..n_channels, param2 pulse within
  [pulse_min_us, pulse_max_us]: applied and held, COMMAND_ACK ACCEPTED; otherwise DENIED.
* COMMAND_LONG MAV_CMD_DO_SET_ACTUATOR: params 1..6 in -1..1 (NaN = unchanged), param7 the set
  index; actuator n drives servo n, value -1..1 maps to pwm_min_us..pwm_max_us. ACCEPTED, or
  DENIED (nothing applied) for a value outside -1..1 or an actuator beyond n_channels.
* RC_CHANNELS_OVERRIDE: overrides servo n with channel n (RC passthrough). Channels 1..8: 0
  releases, UINT16_MAX ignores; channels 9..18: 0 and UINT16_MAX ignore, UINT16_MAX-1 releases.
  When no override arrives for ``rc_override_timeout_s``, every override is dropped and the
  servos go back to what DO_SET_SERVO last set (the safe value by default).
* other COMMAND_LONGs: ACK UNSUPPORTED.

It sends HEARTBEAT at ``heartbeat_hz`` and SERVO_OUTPUT_RAW (port 0, servos 1..16) at
``servo_output_hz`` with the pulses really applied. ``pause_heartbeat()`` stops heartbeats only;
``cut_link()`` drops everything in and out, like a pulled cable. Times are monotonic [s].
"""
from __future__ import annotations

import logging
import math
import os
import threading
import time
from typing import Callable

os.environ.setdefault('MAVLINK20', '1')
from .udp_peer import UdpPeer
from ..protocols.errors import ProtocolConfigError  # noqa: E402
from ..protocols.mavlink_fans import UINT16_MAX, mavlink  # noqa: E402

__all__ = ['SimAutopilot']

_log = logging.getLogger(__name__)
_AUTOPILOTS = {'ardupilot': mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 'px4': mavlink.MAV_AUTOPILOT_PX4}
_EPOCH_2015 = 1420070400  # MAVLink signing timestamps count 10 us units since 2015-01-01


class _Writer:
    """File-like object pymavlink's encoder writes to: one datagram to the current peer."""

    def __init__(self, owner: 'SimAutopilot'):
        self._owner = owner

    def write(self, buf: bytes) -> None:
        owner = self._owner
        if owner._peer is None or owner._cut:
            return
        try:
            owner._sock.sendto(buf, owner._peer)
        except OSError as exc:
            _log.debug('sim autopilot send failed: %s', exc)


class SimAutopilot(UdpPeer):
    """MAVLink 2 autopilot on UDP loopback for tests and the simulated tunnel.

    flavour: 'ardupilot' / 'px4' or a fan flavour name (``ardupilot_*`` / ``px4_*``), which only
    picks the HEARTBEAT autopilot field; n_channels: servo outputs (<= 16); safe_us: pulse [us]
    every servo starts at and falls back to; on_outputs({channel: us}): called on the
    simulator's thread whenever an applied pulse changes.
    """

    thread_name = 'sim-autopilot'

    def __init__(self, host: str = '127.0.0.1', port: int = 0, *, flavour: str = 'ardupilot',
                 n_channels: int = 16,
                 on_outputs: Callable[[dict[int, int]], None] | None = None,
                 safe_us: int = 1000, pwm_min_us: int = 1000, pwm_max_us: int = 2000,
                 pulse_min_us: int = 800, pulse_max_us: int = 2200,
                 rc_override_timeout_s: float = 1.0, heartbeat_hz: float = 1.0,
                 servo_output_hz: float = 10.0, system_id: int = 1, component_id: int = 1,
                 peer: tuple[str, int] | None = None, signing_key: bytes | None = None,
                 vehicle_type: int = mavlink.MAV_TYPE_GENERIC):
        family = 'px4' if str(flavour).startswith('px4') else (
            'ardupilot' if str(flavour).startswith('ardupilot') else None)
        if family is None:
            raise ProtocolConfigError(f"flavour must be 'ardupilot', 'px4' or a fan flavour name; "
                                      f'got {flavour!r}')
        if not 1 <= n_channels <= 16:
            raise ProtocolConfigError(f'n_channels must be 1..16 (SERVO_OUTPUT_RAW port 0); got '
                                      f'{n_channels}')
        self.autopilot = _AUTOPILOTS[family]
        self.vehicle_type = vehicle_type
        self.n_channels = n_channels
        self.on_outputs = on_outputs
        self.safe_us = int(safe_us)
        self.pwm_min_us, self.pwm_max_us = int(pwm_min_us), int(pwm_max_us)
        self.pulse_min_us, self.pulse_max_us = int(pulse_min_us), int(pulse_max_us)
        self.rc_override_timeout_s = float(rc_override_timeout_s)
        self._hb_period = 1.0 / heartbeat_hz
        self._so_period = 1.0 / servo_output_hz

        self._open(host, port)
        self._peer = tuple(peer) if peer is not None else None
        self._mav = mavlink.MAVLink(_Writer(self), srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        if signing_key is not None:
            if len(signing_key) != 32:
                raise ProtocolConfigError('signing_key must be 32 bytes, the same as the client')
            self._mav.signing.secret_key = bytes(signing_key)
            self._mav.signing.sign_outgoing = True
            self._mav.signing.allow_unsigned_callback = None
            self._mav.signing.timestamp = int((time.time() - _EPOCH_2015) * 100_000)

        self._lock = threading.Lock()
        self._servo = {ch: self.safe_us for ch in range(1, n_channels + 1)}
        self._override: dict[int, int] = {}
        self._override_time: float | None = None
        self._applied = dict(self._servo)
        self._hb_paused = False
        self._cut = False
        self._t0 = time.monotonic()
        self.counts = dict(set_servo=0, set_actuator=0, rc_override=0, denied=0, unsupported=0,
                           bad_data=0, override_timeouts=0, heartbeats_sent=0, servo_outputs_sent=0)
        self._start()

    # ---------------------------------------------------------------- public
    @property
    def url(self) -> str:
        """pymavlink URL a client uses to reach this autopilot."""
        host, port = self.address
        return f'udpout:{host}:{port}'

    @property
    def peer(self) -> tuple[str, int] | None:
        return self._peer

    def outputs(self) -> dict[int, int]:
        """Applied pulses {channel: us}."""
        with self._lock:
            return dict(self._applied)

    def pause_heartbeat(self) -> None:
        self._hb_paused = True

    def resume_heartbeat(self) -> None:
        self._hb_paused = False

    def cut_link(self) -> None:
        """Drop every packet in and out until ``restore_link()``."""
        self._cut = True

    def restore_link(self) -> None:
        self._cut = False

    def reboot(self) -> None:
        """Forget every servo setting and override, as an autopilot that restarted (faster than
        a heartbeat timeout): all outputs back to the safe pulse."""
        with self._lock:
            self._servo = {ch: self.safe_us for ch in self._servo}
            self._override.clear()
            self._override_time = None
        self._update_applied()

    # ---------------------------------------------------------------- loop
    def _run(self) -> None:
        next_hb = next_so = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + self._hb_period
                self._send_heartbeat()
            if now >= next_so:
                next_so = now + self._so_period
                self._send_servo_output()
            self._expire_override(now)
            timeout = min(max(0.0, min(next_hb, next_so) - time.monotonic()), 0.05)
            ready = self._wait_readable(timeout)
            if ready is None:
                break
            if ready:
                self._receive()

    def _receive(self) -> None:
        got = self._recv(65535)
        if got is None:
            return
        data, addr = got
        if self._cut:
            return
        try:
            messages = self._mav.parse_buffer(data) or []
        except Exception as exc:
            self.counts['bad_data'] += 1
            _log.debug('sim autopilot parse error: %s', exc)
            return
        for m in messages:
            if m.get_type() == 'BAD_DATA':
                self.counts['bad_data'] += 1
                continue
            if self._peer != addr:
                self._peer = addr
                self._send_heartbeat()   # a new client hears from us at once, not within 1 s
            self._handle(m)

    def _handle(self, m) -> None:
        kind = m.get_type()
        if kind == 'COMMAND_LONG':
            if m.target_system not in (0, self._mav.srcSystem):
                return
            if m.command == mavlink.MAV_CMD_DO_SET_SERVO:
                self.counts['set_servo'] += 1
                self._ack(m, self._do_set_servo(m.param1, m.param2))
            elif m.command == mavlink.MAV_CMD_DO_SET_ACTUATOR:
                self.counts['set_actuator'] += 1
                self._ack(m, self._do_set_actuator(
                    (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6), m.param7))
            else:
                self.counts['unsupported'] += 1
                self._ack(m, mavlink.MAV_RESULT_UNSUPPORTED)
        elif kind == 'RC_CHANNELS_OVERRIDE':
            if m.target_system not in (0, self._mav.srcSystem):
                return
            self.counts['rc_override'] += 1
            self._rc_override(m)

    def _do_set_servo(self, channel: float, pulse: float) -> int:
        if not (math.isfinite(channel) and math.isfinite(pulse) and channel.is_integer()
                and 1 <= channel <= self.n_channels
                and self.pulse_min_us <= pulse <= self.pulse_max_us):
            self.counts['denied'] += 1
            return mavlink.MAV_RESULT_DENIED
        with self._lock:
            self._servo[int(channel)] = int(round(pulse))
        self._update_applied()
        return mavlink.MAV_RESULT_ACCEPTED

    def _do_set_actuator(self, values, index: float) -> int:
        if not (math.isfinite(index) and index.is_integer() and index >= 0):
            self.counts['denied'] += 1
            return mavlink.MAV_RESULT_DENIED
        updates = {}
        for slot, v in enumerate(values):
            if math.isnan(v):
                continue
            channel = int(index) * 6 + slot + 1
            if not (-1.0 <= v <= 1.0 and channel <= self.n_channels):
                self.counts['denied'] += 1
                return mavlink.MAV_RESULT_DENIED
            updates[channel] = int(round(self.pwm_min_us
                                         + (v + 1.0) / 2.0 * (self.pwm_max_us - self.pwm_min_us)))
        with self._lock:
            self._servo.update(updates)
        self._update_applied()
        return mavlink.MAV_RESULT_ACCEPTED

    def _rc_override(self, m) -> None:
        with self._lock:
            for ch in range(1, 19):
                value = getattr(m, f'chan{ch}_raw')
                if ch <= 8:
                    release, ignore = value == 0, value == UINT16_MAX
                else:
                    release, ignore = value == UINT16_MAX - 1, value in (0, UINT16_MAX)
                if ignore or ch > self.n_channels:
                    continue
                if release:
                    self._override.pop(ch, None)
                else:
                    self._override[ch] = int(value)
            self._override_time = time.monotonic()
        self._update_applied()

    def _expire_override(self, now: float) -> None:
        with self._lock:
            expired = (self._override and self._override_time is not None
                       and now - self._override_time > self.rc_override_timeout_s)
            if expired:
                self._override.clear()
                self.counts['override_timeouts'] += 1
        if expired:
            self._update_applied()

    def _update_applied(self) -> None:
        with self._lock:
            applied = dict(self._servo)
            applied.update(self._override)
            changed = applied != self._applied
            self._applied = applied
        if changed and self.on_outputs is not None:
            try:
                self.on_outputs(dict(applied))
            except Exception:
                _log.exception('sim autopilot on_outputs callback raised')

    def _send_heartbeat(self) -> None:
        if self._hb_paused or self._peer is None or self._cut:
            return
        self._send(mavlink.MAVLink_heartbeat_message(
            self.vehicle_type, self.autopilot, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
        self.counts['heartbeats_sent'] += 1

    def _ack(self, m, result: int) -> None:
        self._send(mavlink.MAVLink_command_ack_message(
            m.command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()))

    def _send_servo_output(self) -> None:
        with self._lock:
            pulses = [self._applied.get(ch, 0) for ch in range(1, 17)]
        t_us = int((time.monotonic() - self._t0) * 1e6) % (1 << 32)
        self._send(mavlink.MAVLink_servo_output_raw_message(t_us, 0, *pulses))
        self.counts['servo_outputs_sent'] += 1

    def _send(self, msg) -> None:
        if self._peer is None or self._cut:
            return
        self._mav.send(msg)

    def __repr__(self) -> str:
        return f'SimAutopilot(port={self.port}, channels={self.n_channels}, peer={self._peer})'
