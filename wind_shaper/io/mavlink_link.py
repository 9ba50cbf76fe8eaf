"""MAVLink 2 link that drives fans on an autopilot (pymavlink; threads, no rclpy).

``MavlinkFanLink`` opens a pymavlink connection ('udpout:HOST:PORT' sends to an autopilot that
listens; 'udpin:HOST:PORT' listens and answers whoever sends first) and runs two threads:

* a reader that watches the autopilot's HEARTBEAT (no heartbeat for ``heartbeat_timeout_s``:
  the link is lost, the fans are commanded safe and ``on_link_lost()`` is called), collects
  COMMAND_ACKs, and turns SERVO_OUTPUT_RAW into applied fractions (``on_outputs({name: u})``);
* a timer that sends our own GCS HEARTBEAT (1 Hz) and, for ``ardupilot_rc_override``, resends
  the override at ``rc_refresh_hz`` because the autopilot drops an override it stops hearing.

``send(fractions)`` converts, clips (and reports clipping) and sends with the chosen flavour;
``go_safe()`` sends every fan its safe pulse; ``close()`` goes safe first. Callbacks run on the
link's threads: keep them short. Optional MAVLink 2 signing: ``signing=True`` with a 32-byte
``signing_key``; unsigned or badly signed messages are then dropped.

Limits, on purpose: ``send`` is not refused while the link is down (after a loss the held
command is the safe one; sending again is the caller's decision). ACKs are matched by command
id only (MAVLink has no request id), so a late ACK of an earlier command with the same id can
answer a wait. After ``close()`` an RC override is no longer refreshed: the autopilot drops it
after its timeout and falls back to its RC input, so its own failsafe/trim must also be safe.
"""
from __future__ import annotations

import collections
import logging
import math
import os
import select
import threading
import time
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

os.environ.setdefault('MAVLINK20', '1')
from pymavlink import mavutil  # noqa: E402

from ..protocols.mavlink_fans import (FanChannelMap, FanCommand, Flavour,  # noqa: E402
                                           applied_fractions, build_fan_messages, mavlink,
                                           servo_output_pulses)
from .errors import LinkConfigError, TransportError  # noqa: E402

__all__ = ['MavlinkFanLink', 'SendResult', 'LinkStats']

_log = logging.getLogger(__name__)
_COMMAND_FLAVOURS = (Flavour.ARDUPILOT_SERVO, Flavour.PX4_ACTUATOR)
_URL_PREFIXES = ('udpout:', 'udpin:', 'udp:', 'udpbcast:', 'tcp:', 'tcpin:', '/dev/', 'COM')


@dataclass(frozen=True)
class SendResult:
    """What one ``send`` / ``go_safe`` did.

    command: the outputs sent (pulses [us], fractions, which were clipped); messages: how many
    MAVLink messages went out; acks: MAV_RESULT of each COMMAND_ACK waited for (empty when not
    waiting or for RC override, which has no ACK); round_trip_s: send to last ACK [s].
    """

    command: FanCommand
    messages: int
    acks: tuple[int, ...] = ()
    round_trip_s: float | None = None

    @property
    def clipped(self) -> tuple[str, ...]:
        return self.command.clipped

    @property
    def accepted(self) -> bool:
        """Every message was ACKed with MAV_RESULT_ACCEPTED (False if not waited for)."""
        return len(self.acks) == self.messages and all(
            a == mavlink.MAV_RESULT_ACCEPTED for a in self.acks)


@dataclass(frozen=True)
class LinkStats:
    """heartbeats: autopilot heartbeats seen; link_losses: times the link was declared lost;
    acks / denied: COMMAND_ACKs seen / not ACCEPTED; servo_outputs: SERVO_OUTPUT_RAW seen;
    bad_data: messages pymavlink could not decode or whose signature was rejected;
    callback_errors: exceptions raised by user callbacks."""

    heartbeats: int = 0
    link_losses: int = 0
    acks: int = 0
    denied: int = 0
    servo_outputs: int = 0
    bad_data: int = 0
    callback_errors: int = 0


class MavlinkFanLink:
    """Fan outputs on one autopilot over one MAVLink 2 connection.

    url: pymavlink connection string; flavour: 'ardupilot_servo', 'ardupilot_rc_override' or
    'px4_actuator'; channel_map: fans -> outputs; target_system / target_component: the
    autopilot (target_system None: learn it from the first autopilot heartbeat);
    heartbeat_timeout_s [s]; rc_refresh_hz [Hz]; signing / signing_key: MAVLink 2 signing.
    """

    def __init__(self, url: str, flavour: Flavour | str, channel_map: FanChannelMap, *,
                 target_system: int | None = 1, target_component: int = 1,
                 source_system: int = 255, source_component: int = 190,
                 heartbeat_timeout_s: float = 3.0, heartbeat_rate_hz: float = 1.0,
                 rc_refresh_hz: float = 10.0, signing: bool = False,
                 signing_key: bytes | None = None, safe_on_link_loss: bool = True,
                 on_link_lost: Callable[[], None] | None = None,
                 on_link_up: Callable[[], None] | None = None,
                 on_outputs: Callable[[dict[str, float]], None] | None = None,
                 on_ack: Callable[[int, int], None] | None = None,
                 poll_interval_s: float = 0.02):
        self.flavour = Flavour.parse(flavour)
        if not isinstance(channel_map, FanChannelMap):
            raise LinkConfigError('channel_map must be a FanChannelMap')
        self.channel_map = channel_map
        if not isinstance(url, str) or not url.startswith(_URL_PREFIXES):
            raise LinkConfigError(f'MAVLink URL {url!r} is not understood: use '
                                  f"'udpout:HOST:PORT' or 'udpin:HOST:PORT' (or tcp:, a serial "
                                  f'device)')
        for name, value, lo, hi in (('heartbeat_timeout_s', heartbeat_timeout_s, 0.05, 60.0),
                                    ('heartbeat_rate_hz', heartbeat_rate_hz, 0.1, 50.0),
                                    ('rc_refresh_hz', rc_refresh_hz, 1.0, 100.0),
                                    ('poll_interval_s', poll_interval_s, 0.001, 0.5)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
                raise LinkConfigError(f'{name} must be in {lo}..{hi}; got {value!r}')
        if target_system is not None and not 1 <= int(target_system) <= 255:
            raise LinkConfigError(f'target_system must be 1..255 or None; got {target_system}')
        if signing:
            if not isinstance(signing_key, (bytes, bytearray)) or len(signing_key) != 32:
                raise LinkConfigError('MAVLink 2 signing needs a 32-byte secret key (bytes); the '
                                      'autopilot must hold the same key (SETUP_SIGNING)')
        self.target_system = None if target_system is None else int(target_system)
        self.target_component = int(target_component)
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.safe_on_link_loss = bool(safe_on_link_loss)
        self.on_link_lost, self.on_link_up = on_link_lost, on_link_up
        self.on_outputs, self.on_ack = on_outputs, on_ack
        self._poll = float(poll_interval_s)
        self._hb_period = 1.0 / heartbeat_rate_hz
        self._rc_period = 1.0 / rc_refresh_hz

        try:
            self._conn = mavutil.mavlink_connection(
                url, source_system=source_system, source_component=source_component,
                dialect='ardupilotmega', autoreconnect=False)
        except Exception as exc:
            raise LinkConfigError(f'cannot open MAVLink connection {url!r} ({exc}): check the '
                                  f'address and that the port is free') from None
        if signing:
            self._conn.setup_signing(bytes(signing_key), sign_outgoing=True,
                                     allow_unsigned_callback=None)

        self._io_lock = threading.Lock()      # pymavlink's MAVLink object is not thread-safe
        self._state_lock = threading.Lock()
        self._ack_cond = threading.Condition(self._state_lock)
        self._ack_counts: collections.Counter[int] = collections.Counter()
        self._ack_results: dict[int, collections.deque] = {}
        self._commanded: FanCommand = channel_map.safe_command()
        self._refresh_active = False
        self._last_heartbeat: float | None = None
        self._link_up = False
        self._applied: dict[str, float] = {}
        self._applied_pulses: dict[int, int] = {}
        self._applied_time: float | None = None
        self._stats = dict(heartbeats=0, link_losses=0, acks=0, denied=0, servo_outputs=0,
                           bad_data=0, callback_errors=0)
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._closed = False
        self._reader = threading.Thread(target=self._read_loop, name='mavlink-fan-reader',
                                        daemon=True)
        self._timer = threading.Thread(target=self._timer_loop, name='mavlink-fan-timer',
                                       daemon=True)
        self._reader.start()
        self._timer.start()

    # ---------------------------------------------------------------- properties
    @property
    def link_up(self) -> bool:
        """True while autopilot heartbeats arrive within heartbeat_timeout_s."""
        return self._link_up

    @property
    def local_address(self) -> tuple[str, int] | None:
        """(ip, port) of the UDP socket, or None for other transports."""
        port = getattr(self._conn, 'port', None)
        try:
            return port.getsockname()[:2]
        except (AttributeError, OSError):
            return None

    @property
    def applied(self) -> dict[str, float]:
        """Last applied fractions from SERVO_OUTPUT_RAW, {fan name: fraction}."""
        with self._state_lock:
            return dict(self._applied)

    @property
    def applied_pulses(self) -> dict[int, int]:
        """Last SERVO_OUTPUT_RAW pulses, {channel: us}."""
        with self._state_lock:
            return dict(self._applied_pulses)

    @property
    def heartbeat_age_s(self) -> float | None:
        """Time since the last autopilot heartbeat [s], or None before the first."""
        with self._state_lock:
            last = self._last_heartbeat
        return None if last is None else time.monotonic() - last

    @property
    def commanded(self) -> FanCommand:
        """What the link last sent (or holds for the RC override refresh), every fan."""
        with self._state_lock:
            return self._commanded

    @property
    def stats(self) -> LinkStats:
        with self._state_lock:
            return LinkStats(**self._stats)

    @property
    def signing_stats(self) -> dict[str, int]:
        s = self._conn.mav.signing
        return dict(good=s.goodsig_count, bad=s.badsig_count, unsigned_rejected=s.reject_count)

    def wait_heartbeat(self, timeout_s: float = 5.0) -> bool:
        """Block until the link is up (an autopilot heartbeat arrived); False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._link_up:
                return True
            if self._stop.wait(min(self._poll, max(0.0, deadline - time.monotonic()))):
                return False
        return self._link_up

    # ---------------------------------------------------------------- commands
    def send(self, fractions: Mapping[str, float] | Sequence[float], *,
             wait_ack_s: float | None = None) -> SendResult:
        """Command fans: {name: fraction} (any subset) or one fraction per fan in map order.

        Fractions outside a fan's [u_min, u_max] are clipped and listed in ``clipped``; NaN or an
        unknown fan raises FanCommandError and nothing is sent. With ``wait_ack_s``, waits that
        long [s] for the COMMAND_ACKs (command flavours only).
        """
        self._check_open()
        command = self.channel_map.command(fractions)
        with self._state_lock:
            self._commanded = self._commanded.merged(command)
            full = self._commanded
        return self._transmit(full if self.flavour is Flavour.ARDUPILOT_RC_OVERRIDE else command,
                              command, wait_ack_s)

    def go_safe(self, *, wait_ack_s: float | None = None) -> SendResult:
        """Send every fan its safe pulse (and keep refreshing it for RC override)."""
        self._check_open()
        safe = self.channel_map.safe_command()
        with self._state_lock:
            self._commanded = safe
        return self._transmit(safe, safe, wait_ack_s)

    def close(self, timeout_s: float = 2.0) -> None:
        """Go safe (best effort), stop the threads and close the connection. Idempotent."""
        if self._closed:
            return
        try:
            self.go_safe()
        except Exception as exc:  # closing must not fail because the link is already broken
            _log.warning('go_safe on close failed: %s', exc)
        self._closed = True
        self._stop.set()
        self._wake.set()
        for thread in (self._reader, self._timer):
            if thread is not threading.current_thread():
                thread.join(timeout_s)
                if thread.is_alive():
                    _log.warning('%s did not stop within %.1f s', thread.name, timeout_s)
        with self._io_lock:
            self._conn.close()

    def __enter__(self) -> 'MavlinkFanLink':
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._closed:
            raise TransportError('the MAVLink fan link is closed: create a new MavlinkFanLink')

    def _transmit(self, to_send: FanCommand, reported: FanCommand,
                  wait_ack_s: float | None) -> SendResult:
        target = self.target_system if self.target_system is not None else 1
        messages = build_fan_messages(self.flavour, to_send, self.channel_map, target,
                                      self.target_component)
        expect = self.flavour in _COMMAND_FLAVOURS and wait_ack_s is not None
        cmd_id = messages[0].command if expect else None
        with self._state_lock:
            base = self._ack_counts[cmd_id] if expect else 0
            if self.flavour is Flavour.ARDUPILOT_RC_OVERRIDE:
                self._refresh_active = True
        t0 = time.perf_counter()
        self._send_messages(messages)
        if not expect:
            return SendResult(reported, len(messages))
        deadline = time.monotonic() + float(wait_ack_s)
        with self._ack_cond:
            while self._ack_counts[cmd_id] < base + len(messages):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    break
                self._ack_cond.wait(min(remaining, self._poll))
            got = self._ack_counts[cmd_id] - base
            results = tuple(list(self._ack_results.get(cmd_id, ()))[-got:]) if got else ()
        rtt = time.perf_counter() - t0 if got >= len(messages) else None
        return SendResult(reported, len(messages), results, rtt)

    def _send_messages(self, messages) -> None:
        try:
            with self._io_lock:
                for msg in messages:
                    self._conn.mav.send(msg)
        except OSError as exc:
            raise TransportError(f'cannot send to the autopilot ({exc}): check the link') from None

    # ---------------------------------------------------------------- threads
    def _timer_loop(self) -> None:
        next_hb = next_rc = time.monotonic()
        heartbeat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3)
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_hb:
                    self._send_messages([heartbeat])
                    next_hb = now + self._hb_period
                if self.flavour is Flavour.ARDUPILOT_RC_OVERRIDE and now >= next_rc:
                    next_rc = now + self._rc_period
                    with self._state_lock:
                        active, full = self._refresh_active, self._commanded
                    if active:
                        target = self.target_system if self.target_system is not None else 1
                        self._send_messages(build_fan_messages(
                            self.flavour, full, self.channel_map, target, self.target_component))
            except TransportError as exc:
                _log.warning('%s', exc)
            if self.flavour is Flavour.ARDUPILOT_RC_OVERRIDE:
                wait = min(next_hb, next_rc) - time.monotonic()
            else:
                wait = next_hb - time.monotonic()
            self._wake.wait(max(0.0, min(wait, 0.5)))
            self._wake.clear()

    def _read_loop(self) -> None:
        fd = getattr(self._conn, 'fd', None)
        while not self._stop.is_set():
            if fd is not None:
                try:
                    select.select([fd], [], [], self._poll)
                except (OSError, ValueError):
                    if self._stop.is_set():
                        break
                    self._stop.wait(self._poll)
            else:
                self._stop.wait(self._poll)
            if self._stop.is_set():
                break
            messages = []
            try:
                with self._io_lock:
                    while True:
                        m = self._conn.recv_msg()
                        if m is None:
                            break
                        messages.append(m)
            except Exception as exc:  # a decode error must not kill the reader
                with self._state_lock:
                    self._stats['bad_data'] += 1
                _log.debug('MAVLink receive error: %s', exc)
            for m in messages:
                self._handle(m)
            self._check_heartbeat()

    def _handle(self, m) -> None:
        kind = m.get_type()
        if kind == 'BAD_DATA':
            with self._state_lock:
                self._stats['bad_data'] += 1
            return
        src = m.get_srcSystem()
        if self.target_system is not None and src != self.target_system:
            return
        if kind == 'HEARTBEAT':
            if m.type == mavlink.MAV_TYPE_GCS:
                return
            if self.target_system is None:
                self.target_system = src
            came_up = False
            with self._state_lock:
                self._stats['heartbeats'] += 1
                self._last_heartbeat = time.monotonic()
                if not self._link_up:
                    self._link_up = came_up = True
            if came_up:
                self._call(self.on_link_up)
        elif kind == 'COMMAND_ACK':
            with self._ack_cond:
                self._stats['acks'] += 1
                if m.result != mavlink.MAV_RESULT_ACCEPTED:
                    self._stats['denied'] += 1
                self._ack_counts[m.command] += 1
                self._ack_results.setdefault(m.command,
                                             collections.deque(maxlen=256)).append(m.result)
                self._ack_cond.notify_all()
            self._call(self.on_ack, m.command, m.result)
        elif kind == 'SERVO_OUTPUT_RAW':
            pulses = servo_output_pulses(m)
            fractions = applied_fractions(m, self.channel_map)
            with self._state_lock:
                self._stats['servo_outputs'] += 1
                self._applied_pulses.update(pulses)
                self._applied.update(fractions)
                self._applied_time = time.monotonic()
            if fractions:
                self._call(self.on_outputs, fractions)

    def _check_heartbeat(self) -> None:
        with self._state_lock:
            lost = (self._link_up and self._last_heartbeat is not None
                    and time.monotonic() - self._last_heartbeat > self.heartbeat_timeout_s)
            if lost:
                self._link_up = False
                self._stats['link_losses'] += 1
        if not lost:
            return
        _log.warning('no autopilot heartbeat for %.1f s: link lost', self.heartbeat_timeout_s)
        if self.safe_on_link_loss and not self._closed:
            try:
                self.go_safe()
            except Exception as exc:
                _log.warning('go_safe after link loss failed: %s', exc)
        self._call(self.on_link_lost)

    def _call(self, callback, *args) -> None:
        if callback is None:
            return
        try:
            callback(*args)
        except Exception:
            with self._state_lock:
                self._stats['callback_errors'] += 1
            _log.exception('MAVLink link callback raised')

    def __repr__(self) -> str:
        return (f'MavlinkFanLink(flavour={self.flavour.value}, fans={len(self.channel_map)}, '
                f'link_up={self._link_up})')
