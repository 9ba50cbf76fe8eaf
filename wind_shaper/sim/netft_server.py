"""A simulated ATI Net F/T sensor: answers RDT requests on UDP and streams records from a thread.

``SimNetFtServer`` binds a UDP socket (port 0 = a free port; ``port`` tells which) and behaves
like the sensor: a start request (command 2) streams ``sample_count`` records (0 = until stopped)
to the address the request came from at ``rate_hz``, paced by a monotonic clock (when the
thread is late it sends the records it owes back to back, at most ``max_batch`` at once; beyond
that it skips ahead and counts ``late_skips``), one record per datagram or, with
``records_per_datagram`` > 1, that many back to back in each datagram, as a Net F/T does with
RDT buffering (a datagram leaves when its last record is due); a stop request (command 0)
stops; a bias request (0x42) zeroes the current reading.

The wrench comes from ``force_source(t)`` -> (Fx, Fy, Fz [N], Tx, Ty, Tz [N m]), with t [s] the
ideal sample time k / rate_hz since the stream started (k counts skipped records too, so a
record's t always matches its sequence number). Readings beyond int32 counts (or NaN)
saturate and set status bits 31 and 30, like a saturated transducer.

Fault injection (``NetFtFaults``, seeded, so runs repeat): drops, reorders (a record is held
back and sent right after the next one sent), duplicates, truncated datagrams, status fault
bits, and overflowed (saturated) readings. ``fault_log()`` tells which rdt_sequence numbers
were hit, to compare with what a client counted.
"""
from __future__ import annotations

import logging
import random
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

from .udp_peer import UdpPeer
from ..protocols.errors import NetFtPacketError, ProtocolConfigError
from ..protocols.netft import (INT32_MAX, NetFtCalibration, RdtCommand, RdtRecord,
                                    decode_request)

__all__ = ['SimNetFtServer', 'NetFtFaults', 'NetFtFaultLog', 'SATURATION_STATUS']

_log = logging.getLogger(__name__)
_U32 = 1 << 32
SATURATION_STATUS = (1 << 31) | (1 << 30)     # error + force/torque out of range
SOURCE_ERROR_STATUS = (1 << 31) | (1 << 5)    # error + other error


@dataclass(frozen=True)
class NetFtFaults:
    """Seeded fault injection. Probabilities are per record, in 0..1.

    drop: never sent; reorder: sent after the next record that is sent; duplicate: sent twice;
    truncate: sent cut to 1..35 bytes (malformed at the client); status_fault: status |=
    status_bits; overflow: readings replaced by full-scale counts with SATURATION_STATUS.
    """

    drop_probability: float = 0.0
    reorder_probability: float = 0.0
    duplicate_probability: float = 0.0
    truncate_probability: float = 0.0
    status_fault_probability: float = 0.0
    status_bits: int = (1 << 31) | (1 << 2)   # error + broken gage
    overflow_probability: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name in ('drop_probability', 'reorder_probability', 'duplicate_probability',
                     'truncate_probability', 'status_fault_probability', 'overflow_probability'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
                raise ProtocolConfigError(f'{name} must be in 0..1; got {value!r}')
        if not 0 < int(self.status_bits) < _U32:
            raise ProtocolConfigError(f'status_bits must be a nonzero uint32; got '
                                      f'{self.status_bits!r}')


@dataclass(frozen=True)
class NetFtFaultLog:
    """rdt_sequence numbers the server generated and what it did to them."""

    generated: int = 0
    datagrams_sent: int = 0
    dropped: tuple[int, ...] = ()
    reordered: tuple[int, ...] = ()
    duplicated: tuple[int, ...] = ()
    truncated: tuple[int, ...] = ()
    status_faults: tuple[int, ...] = ()
    overflows: tuple[int, ...] = ()
    unsent: tuple[int, ...] = ()
    late_skips: int = 0


@dataclass
class _Log:
    generated: int = 0
    datagrams_sent: int = 0
    dropped: list = field(default_factory=list)
    reordered: list = field(default_factory=list)
    duplicated: list = field(default_factory=list)
    truncated: list = field(default_factory=list)
    status_faults: list = field(default_factory=list)
    overflows: list = field(default_factory=list)
    unsent: list = field(default_factory=list)
    late_skips: int = 0


class SimNetFtServer(UdpPeer):
    """Simulated Net F/T on UDP: force_source(t [s]) -> 6 floats [N, N m]."""

    thread_name = 'sim-netft'

    def __init__(self, force_source: Callable[[float], Sequence[float]], host: str = '127.0.0.1',
                 port: int = 0, rate_hz: float = 1000.0, counts_per_force: float = 1_000_000.0,
                 counts_per_torque: float = 1_000_000.0, *, faults: NetFtFaults | None = None,
                 initial_rdt_sequence: int = 1, initial_ft_sequence: int = 0,
                 max_batch: int = 100, records_per_datagram: int = 1):
        if not (isinstance(rate_hz, (int, float)) and 0 < rate_hz <= 10_000):
            raise ProtocolConfigError(f'rate_hz must be in (0, 10000]; got {rate_hz!r} '
                                      f'(Net F/T: up to 7000 Hz)')
        if not 0 <= initial_rdt_sequence < _U32 or not 0 <= initial_ft_sequence < _U32:
            raise ProtocolConfigError('initial sequence numbers are uint32')
        self.force_source = force_source
        self.rate_hz = float(rate_hz)
        self.calibration = NetFtCalibration(counts_per_force, counts_per_torque)
        self.faults = faults or NetFtFaults()
        if not (isinstance(records_per_datagram, int) and 1 <= records_per_datagram <= 40):
            raise ProtocolConfigError(f'records_per_datagram must be a whole number in 1..40; got '
                                      f'{records_per_datagram!r}')
        #: any fault configured: the per-record draws are only made then (they cost CPU at kHz)
        self._faulty = any(getattr(self.faults, name) > 0 for name in (
            'drop_probability', 'reorder_probability', 'duplicate_probability',
            'truncate_probability', 'status_fault_probability', 'overflow_probability'))
        if self._faulty and records_per_datagram > 1:
            raise ProtocolConfigError('fault injection works on datagrams of one record: use '
                                      'records_per_datagram 1 with faults')
        self.records_per_datagram = records_per_datagram
        self._buffered: list[bytes] = []    # records of the datagram being filled
        self.max_batch = int(max_batch)
        self._rng = random.Random(self.faults.seed)
        self._first_rdt_sequence = int(initial_rdt_sequence)
        self._rdt_seq = self._first_rdt_sequence
        self._ft_seq = int(initial_ft_sequence)
        self._bias = (0.0,) * 6
        self._lock = threading.Lock()
        self._log = _Log()
        self._client: tuple[str, int] | None = None
        self._streaming = False
        self._remaining = 0
        self._k = 0
        self._t_start = 0.0
        self._held: tuple[int, bytes] | None = None
        self.requests = dict(start=0, stop=0, bias=0, unknown=0, malformed=0)
        self.source_errors = 0
        self._open(host, port, send_buffer=1 << 20)
        self._start()

    # ---------------------------------------------------------------- public
    @property
    def streaming(self) -> bool:
        return self._streaming

    @property
    def client(self) -> tuple[str, int] | None:
        """Address the last start request came from."""
        return self._client

    @property
    def stream_start(self) -> float:
        """time.monotonic() [s] of the current stream's t = 0: record t is taken at
        ``stream_start + t``; t stays in step with the sequence number, skipped records included."""
        return self._t_start

    def fault_log(self) -> NetFtFaultLog:
        with self._lock:
            g = self._log
            return NetFtFaultLog(g.generated, g.datagrams_sent, tuple(g.dropped),
                                 tuple(g.reordered), tuple(g.duplicated), tuple(g.truncated),
                                 tuple(g.status_faults), tuple(g.overflows), tuple(g.unsent),
                                 g.late_skips)

    def wait_idle(self, timeout_s: float = 5.0, min_generated: int = 1) -> bool:
        """Wait until at least ``min_generated`` records were generated and streaming has ended
        (a finite stream sent completely, or stopped). False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if not self._streaming and self._log.generated >= min_generated:
                return True
            time.sleep(0.005)
        return False

    def _on_close(self) -> None:
        with self._lock:  # a record held back for reordering, or buffered, was never sent
            if self._held is not None:
                self._log.unsent.append(self._held[0])
                self._held = None
            self._log.unsent.extend(int.from_bytes(r[:4], 'big') for r in self._buffered)
            self._buffered = []

    # ---------------------------------------------------------------- loop
    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        while not self._stop.is_set():
            timeout = 0.05
            if self._streaming:
                self._emit_due(time.monotonic())
                if self._streaming:
                    last = self._k + self.records_per_datagram - len(self._buffered) - 1
                    timeout = min(timeout, max(0.0, self._t_start + last * period
                                               - time.monotonic()))
            ready = self._wait_readable(timeout)
            if ready is None:
                break
            if ready:
                self._receive()

    def _receive(self) -> None:
        got = self._recv(2048)
        if got is None:
            return
        data, addr = got
        try:
            request = decode_request(data)
        except NetFtPacketError as exc:
            self.requests['malformed'] += 1
            _log.debug('sim netft: %s', exc)
            return
        if request.command == RdtCommand.START_REALTIME:
            self.requests['start'] += 1
            self._flush()   # the old stream's last records, to the address that asked for them
            self._client = addr[:2]
            self._remaining = request.sample_count
            self._k = 0
            self._t_start = time.monotonic()
            # rdt_sequence is a record's place within its output stream: a new stream numbers
            # from the first again (ft_sequence, the sensor's own count, carries on). Numbers
            # carried over the silence before it would date every new record that long ago.
            self._rdt_seq = self._first_rdt_sequence
            self._streaming = True
        elif request.command == RdtCommand.STOP_STREAMING:
            self.requests['stop'] += 1
            self._finish()
        elif request.command == RdtCommand.SET_SOFTWARE_BIAS:
            self.requests['bias'] += 1
            self._bias = self._raw_wrench(self._k / self.rate_hz) or self._bias
        else:
            self.requests['unknown'] += 1

    def _finish(self) -> None:
        self._flush()
        if self._held is not None:
            # nothing intact was sent after it, so it arrives in order after all: not reordered
            with self._lock:
                self._log.reordered.remove(self._held[0])
            self._sendto(self._held[1])
            self._held = None
        self._streaming = False

    def _emit_due(self, now: float) -> None:
        due = int((now - self._t_start) * self.rate_hz) + 1 - self._k
        if due > self.max_batch:
            # Far behind (the host stalled): skip those records. A real sensor samples on its
            # own clock, so their sequence numbers are used up and the client counts them lost;
            # numbers stay in step with sample time, which the client's SampleClock relies on.
            skip = due - self.max_batch
            self._k += skip          # the skipped samples' times are used up too
            self._rdt_seq = (self._rdt_seq + skip) % _U32
            self._ft_seq = (self._ft_seq + skip) % _U32
            with self._lock:
                self._log.late_skips += skip
            due = self.max_batch
        for _ in range(max(0, due)):
            self._emit_one()
            if self._remaining:
                self._remaining -= 1
                if self._remaining == 0:
                    self._finish()
                    return

    def _raw_wrench(self, t: float) -> tuple[float, ...] | None:
        """force_source(t), or None (counted in source_errors) if it raised or gave not 6 values."""
        try:
            w = tuple(float(x) for x in self.force_source(t))
        except Exception:
            w = None
            if self.source_errors == 0:
                _log.exception('sim netft force_source raised')
        if w is None or len(w) != 6:
            self.source_errors += 1
            return None
        return w

    def _next_sample(self) -> tuple:
        """(rdt_sequence, ft_sequence, status, counts) of the next sample, its sequence numbers
        and sample time used up."""
        seq, ft_seq = self._rdt_seq, self._ft_seq
        self._rdt_seq = (seq + 1) % _U32
        self._ft_seq = (ft_seq + 1) % _U32
        t = self._k / self.rate_hz
        self._k += 1
        raw = self._raw_wrench(t)
        status = 0
        if raw is None:
            counts, status = (0,) * 6, SOURCE_ERROR_STATUS
        else:
            counts, saturated = self.calibration.to_counts(
                [a - b for a, b in zip(raw, self._bias)])
            if saturated:
                status |= SATURATION_STATUS
        return seq, ft_seq, status, counts

    def _emit_one(self) -> None:
        if not self._faulty:
            self._emit_clean()
            return
        f = self.faults
        r_overflow, r_status, r_drop, r_trunc, r_reorder, r_dup = (self._rng.random()
                                                                    for _ in range(6))
        cut = self._rng.randint(1, 35)
        seq, ft_seq, status, counts = self._next_sample()
        log = self._log
        with self._lock:
            log.generated += 1
            if r_overflow < f.overflow_probability:
                counts, status = (INT32_MAX,) * 6, status | SATURATION_STATUS
                log.overflows.append(seq)
            if r_status < f.status_fault_probability:
                status |= f.status_bits
                log.status_faults.append(seq)
            data = RdtRecord(seq, ft_seq, status, *counts).encode()
            if r_drop < f.drop_probability:
                log.dropped.append(seq)
                return
            if r_trunc < f.truncate_probability:
                # a held record waits for the next intact datagram, so it still arrives late
                log.truncated.append(seq)
                self._sendto(data[:cut])
                return
            if self._held is None and r_reorder < f.reorder_probability:
                log.reordered.append(seq)
                self._held = (seq, data)
                return
            if r_dup < f.duplicate_probability:
                log.duplicated.append(seq)
                self._sendto(data)
            held, self._held = self._held, None
        self._sendto(data)
        if held is not None:
            self._sendto(held[1])

    def _emit_clean(self) -> None:
        """``_emit_one`` without faults: the record goes into the datagram being filled, which
        leaves once it holds ``records_per_datagram`` records."""
        seq, ft_seq, status, counts = self._next_sample()
        with self._lock:
            self._log.generated += 1
        self._buffered.append(RdtRecord(seq, ft_seq, status, *counts).encode())
        if len(self._buffered) >= self.records_per_datagram:
            self._flush()

    def _flush(self) -> None:
        """Send the records of the datagram being filled, if any."""
        if self._buffered:
            data, self._buffered = b''.join(self._buffered), []
            self._sendto(data)

    def _sendto(self, data: bytes) -> None:
        if self._client is None:
            return
        try:
            self._sock.sendto(data, self._client)
            self._log.datagrams_sent += 1
        except OSError as exc:
            _log.debug('sim netft send failed: %s', exc)

    def __repr__(self) -> str:
        return (f'SimNetFtServer(port={self.port}, rate_hz={self.rate_hz}, '
                f'streaming={self._streaming})')
