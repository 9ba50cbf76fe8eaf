"""UDP client of an ATI Net F/T sensor's RDT stream, read by a background thread (no rclpy).

``NetFtClient`` sends RDT requests to the sensor and decodes the records it streams back. A
reader thread receives datagrams with a bounded timeout, accepts them only from the sensor's
address and port, decodes them, tracks rdt_sequence and calls ``on_sample(sample, stats)`` for
each record the tracker says to use, on the reader thread: keep the callback short (hand the
sample to a queue or publish it). Samples whose status word is nonzero are delivered with
``sample.ok`` False and counted as faulted: check ``ok`` before using a sample as a measurement.
"""
from __future__ import annotations

import logging
import math
import socket
import threading
from dataclasses import dataclass
from typing import Callable

from ..protocols.errors import NetFtPacketError
from ..protocols.netft import (RDT_PORT, NetFtCalibration, NetFtSample, RdtCommand,
                                    RdtSequenceTracker, decode_records, encode_request)
from .errors import LinkConfigError, TransportError

__all__ = ['NetFtClient', 'NetFtStreamStats']

_log = logging.getLogger(__name__)
_MAX_DATAGRAM = 65535


@dataclass(frozen=True)
class NetFtStreamStats:
    """Counters of a client since its last ``start()``.

    datagrams: datagrams from the sensor; rejected: datagrams from any other address (dropped
    unread); malformed: sensor datagrams that were not whole records; received / accepted / lost /
    out_of_order / duplicates / stale / resyncs: see ``RdtSequenceTracker``; faulted: delivered
    samples with a nonzero status word; callback_errors: exceptions raised by ``on_sample``.
    """

    datagrams: int = 0
    rejected: int = 0
    malformed: int = 0
    received: int = 0
    accepted: int = 0
    lost: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    stale: int = 0
    resyncs: int = 0
    faulted: int = 0
    callback_errors: int = 0


class NetFtClient:
    """RDT over UDP from one sensor.

    sensor_host / port: the sensor's address (port 49152 on real sensors); calibration: counts
    per N and per N m; on_sample(sample, stats): called on the reader thread; local_host /
    local_port: where to bind (port 0 = any free port); use_out_of_order: deliver records that
    arrive late instead of dropping them; poll_interval_s: the reader's longest blocking wait,
    which bounds how long ``close()`` takes.
    """

    def __init__(self, sensor_host: str, port: int = RDT_PORT, *,
                 calibration: NetFtCalibration | None = None,
                 on_sample: Callable[[NetFtSample, NetFtStreamStats], None] | None = None,
                 local_host: str = '0.0.0.0', local_port: int = 0,
                 use_out_of_order: bool = False, window: int = 1024,
                 poll_interval_s: float = 0.05, receive_buffer_bytes: int = 1 << 20):
        if not (isinstance(port, int) and 0 < port < 65536):
            raise LinkConfigError(f'sensor port must be 1..65535; got {port!r} (Net F/T: 49152)')
        if not (isinstance(poll_interval_s, (int, float)) and 0 < poll_interval_s <= 1.0
                and math.isfinite(poll_interval_s)):
            raise LinkConfigError(f'poll_interval_s must be in (0, 1] s; got {poll_interval_s!r}')
        try:
            infos = socket.getaddrinfo(sensor_host, port, socket.AF_INET, socket.SOCK_DGRAM)
        except (socket.gaierror, UnicodeError) as exc:
            raise LinkConfigError(f'cannot resolve sensor host {sensor_host!r} ({exc}): give the '
                                  f'sensor IPv4 address or a name in /etc/hosts') from None
        self._sensor = infos[0][4][:2]
        self.calibration = calibration or NetFtCalibration()
        self.on_sample = on_sample
        self._tracker = RdtSequenceTracker(window=window, use_out_of_order=use_out_of_order)
        self._poll = float(poll_interval_s)
        self._lock = threading.Lock()
        self._counts = dict(datagrams=0, rejected=0, malformed=0, faulted=0, callback_errors=0)
        self.last_error: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, int(receive_buffer_bytes))
            self._sock.bind((local_host, int(local_port)))
            self._sock.settimeout(self._poll)
        except OSError as exc:
            self._sock.close()
            raise LinkConfigError(f'cannot bind the RDT client socket to {local_host}:{local_port} '
                                  f'({exc}): choose a free local port or 0') from None

    # ---------------------------------------------------------------- properties
    @property
    def sensor_address(self) -> tuple[str, int]:
        """(ip, port) that datagrams must come from."""
        return self._sensor

    @property
    def local_address(self) -> tuple[str, int]:
        """(ip, port) the client is bound to."""
        return self._sock.getsockname()[:2]

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def stats(self) -> NetFtStreamStats:
        with self._lock:
            return self._stats_locked()

    def _stats_locked(self) -> NetFtStreamStats:
        t = self._tracker.stats
        c = self._counts
        return NetFtStreamStats(c['datagrams'], c['rejected'], c['malformed'], t.received,
                                t.accepted, t.lost, t.out_of_order, t.duplicates, t.stale,
                                t.resyncs, c['faulted'], c['callback_errors'])

    # ---------------------------------------------------------------- commands
    def start(self, sample_count: int = 0) -> None:
        """Zero the counters, start the reader thread and ask the sensor to stream
        (sample_count records, 0 = until ``stop()``)."""
        self._check_open()
        with self._lock:
            self._tracker.reset()
            for key in self._counts:
                self._counts[key] = 0
            self.last_error = None
        if not self.running:
            self._stop.clear()
            self._thread = threading.Thread(target=self._read_loop, name='netft-reader',
                                            daemon=True)
            self._thread.start()
        self._send(RdtCommand.START_REALTIME, sample_count)

    def request_stream(self, sample_count: int = 0) -> None:
        """Send the start-streaming request again without touching the counters (a sensor
        that booted after us, or rebooted, never got the first one). The records that follow
        start a new stream: a rebooted sensor numbers them from 1 again."""
        with self._lock:
            self._tracker.restart_stream()
        self._send(RdtCommand.START_REALTIME, sample_count)

    def bias(self) -> None:
        """Ask the sensor to zero its current reading (software bias)."""
        self._send(RdtCommand.SET_SOFTWARE_BIAS)

    def stop(self) -> None:
        """Ask the sensor to stop streaming; the reader keeps draining late datagrams."""
        self._send(RdtCommand.STOP_STREAMING)

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop streaming (best effort), stop the reader thread and close the socket. Idempotent."""
        if self._closed:
            return
        try:
            self._send(RdtCommand.STOP_STREAMING)
        except TransportError:
            pass
        self._stop.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout_s)
            if thread.is_alive():
                _log.warning('netft reader thread did not stop within %.1f s', timeout_s)
        self._closed = True
        self._sock.close()

    def __enter__(self) -> 'NetFtClient':
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._closed:
            raise TransportError('the Net F/T client is closed: create a new NetFtClient')

    def _send(self, command: int, sample_count: int = 0) -> None:
        self._check_open()
        try:
            self._sock.sendto(encode_request(command, sample_count), self._sensor)
        except OSError as exc:
            raise TransportError(f'cannot send RDT command 0x{int(command):x} to '
                                 f'{self._sensor[0]}:{self._sensor[1]} ({exc}): check the '
                                 f'network route to the sensor') from None

    # ---------------------------------------------------------------- reader thread
    def _read_loop(self) -> None:
        buf = bytearray(_MAX_DATAGRAM)
        view = memoryview(buf)
        sock = self._sock
        while not self._stop.is_set():
            try:
                n, addr = sock.recvfrom_into(buf)
            except socket.timeout:
                continue
            except OSError as exc:
                if self._stop.is_set():
                    break
                _log.warning('netft socket error: %s', exc)
                self._stop.wait(self._poll)
                continue
            self._handle_datagram(view[:n], addr)

    def _handle_datagram(self, data, addr) -> None:
        deliver = []
        with self._lock:
            if addr[:2] != self._sensor:
                self._counts['rejected'] += 1
                return
            self._counts['datagrams'] += 1
            try:
                records = decode_records(data)
            except NetFtPacketError as exc:
                self._counts['malformed'] += 1
                self.last_error = str(exc)
                return
            for record in records:
                if self._tracker.accept(record.rdt_sequence):
                    if record.status:
                        self._counts['faulted'] += 1
                    deliver.append((self.calibration.to_sample(record), self._stats_locked()))
        callback = self.on_sample
        if callback is None:
            return
        for sample, stats in deliver:
            try:
                callback(sample, stats)
            except Exception:  # a consumer's bug must not kill the reader
                with self._lock:
                    self._counts['callback_errors'] += 1
                _log.exception('on_sample callback raised')

    def __repr__(self) -> str:
        return (f'NetFtClient(sensor={self._sensor[0]}:{self._sensor[1]}, '
                f'local={self.local_address if not self._closed else "closed"})')
