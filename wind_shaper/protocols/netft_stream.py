"""Net F/T record streams over UDP: which records to use (``RdtSequenceTracker``, from their
rdt_sequence) and when each was sampled (``SampleClock``, from the sensor's fixed rate and the
arrival times). Pure logic on numbers, no sockets; the codec is ``protocols.netft``.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from .errors import ProtocolConfigError

_U32 = 1 << 32   # rdt_sequence is a uint32

__all__ = ['SequenceVerdict', 'RdtSequenceStats', 'RdtSequenceTracker', 'SampleClock']


class SequenceVerdict(Enum):
    """What a record's rdt_sequence says about its place in the stream."""

    FIRST = 'first'                # first record since reset
    IN_ORDER = 'in_order'          # newer than the newest seen (possibly after a gap)
    OUT_OF_ORDER = 'out_of_order'  # older than the newest, first time seen, inside the window
    STALE = 'stale'                # older than the newest by >= window: late or duplicate, unknown
    DUPLICATE = 'duplicate'        # this sequence number was already seen (inside the window)
    RESYNC = 'resync'              # jumped back by more than max_backstep: the stream restarted


@dataclass(frozen=True)
class RdtSequenceStats:
    """Counters of a tracker. lost: sequence numbers skipped over and not received (yet);
    out_of_order includes stale records; accepted: records the tracker said to use."""

    received: int = 0
    accepted: int = 0
    lost: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    stale: int = 0
    resyncs: int = 0


class RdtSequenceTracker:
    """Counts received, lost, out-of-order and duplicate records from their rdt_sequence.

    The counting rule (serial-number arithmetic on uint32, like RFC 1982 / an IPsec replay
    window):

    * d = (seq - newest) mod 2^32, read as a signed int32. d > 0: newer; d == 0: the newest
      again; d < 0: older. 2^32 - 1 followed by 0 is therefore d = 1, in order.
    * Newer by d: the d - 1 numbers jumped over count as **lost** right away.
    * Older by i = -d with i < window: if that number was already seen it is a **duplicate**;
      otherwise it is **out of order**, and if it had been counted lost, lost goes down by one
      (a reorder that fills a gap un-counts the loss). A number from before the first record
      is out of order but was never counted lost.
    * Older by window <= i <= max_backstep: **stale** (also counted out of order): it cannot be
      told from a duplicate any more, and a loss counted for it stays counted. A loss becomes
      final once its number falls out of the window.
    * Older by more than max_backstep: the sensor restarted its counter: **resync** (the record
      becomes the newest; losses counted so far stay).
    * Losses before the first record received are unknown and not counted.

    Use: FIRST, IN_ORDER and RESYNC records are used; OUT_OF_ORDER ones only with
    ``use_out_of_order=True``; duplicates and stale records never.
    """

    def __init__(self, window: int = 1024, max_backstep: int = 1 << 16,
                 use_out_of_order: bool = False):
        if not (isinstance(window, int) and 1 <= window <= 1 << 20):
            raise ProtocolConfigError(f'window must be an int in 1..2^20 records; got {window!r}')
        if not (isinstance(max_backstep, int) and window <= max_backstep < 1 << 31):
            raise ProtocolConfigError(f'max_backstep must be an int in window..2^31-1; got '
                                      f'{max_backstep!r} (window {window})')
        self.window = window
        self.max_backstep = max_backstep
        self.use_out_of_order = bool(use_out_of_order)
        self._mask = (1 << window) - 1
        self.reset()

    def reset(self) -> None:
        """Forget the stream and zero the counters (call when a new stream starts)."""
        self._newest: int | None = None
        self._seen = 0       # bit i: newest - i was received
        self._missing = 0    # bit i: newest - i was counted lost and is still missing
        self._received = self._accepted = self._lost = 0
        self._out_of_order = self._duplicates = self._stale = self._resyncs = 0

    def restart_stream(self) -> None:
        """Forget the stream's position but keep the counters: the next record starts a new
        stream, whatever its number. For a re-sent start request: a sensor that rebooted, or
        starts a new stream, numbers from 1 again, and without this those records would look
        stale (older than the newest seen) until the count passed the old one."""
        if self._newest is not None:
            self._resyncs += 1
        self._newest = None
        self._seen = self._missing = 0

    @property
    def newest(self) -> int | None:
        """The newest rdt_sequence seen, or None before the first record."""
        return self._newest

    @property
    def stats(self) -> RdtSequenceStats:
        return RdtSequenceStats(self._received, self._accepted, self._lost, self._out_of_order,
                                self._duplicates, self._stale, self._resyncs)

    def observe(self, seq: int) -> SequenceVerdict:
        """Count one record's rdt_sequence (uint32) and classify it."""
        if not 0 <= seq < _U32:
            raise ProtocolConfigError(f'rdt_sequence is a uint32; got {seq}')
        self._received += 1
        newest = self._newest
        if newest is None:
            self._start(seq)
            return self._verdict(SequenceVerdict.FIRST)
        d = (seq - newest) % _U32
        if d >= 1 << 31:
            d -= _U32
        if d > 0:
            if d > 1:
                self._lost += d - 1
            if d >= self.window:
                self._seen = 1
                self._missing = self._mask & ~1
            else:
                self._seen = ((self._seen << d) | 1) & self._mask
                self._missing = ((self._missing << d) | ((1 << d) - 2)) & self._mask
            self._newest = seq
            return self._verdict(SequenceVerdict.IN_ORDER)
        back = -d
        if back == 0:
            self._duplicates += 1
            return self._verdict(SequenceVerdict.DUPLICATE)
        if back > self.max_backstep or (back >= self.window and seq <= self.window):
            # far behind, or numbered from the start again while the newest is far ahead: a new
            # stream (a sensor numbers every stream from 1; records of the old one may still
            # have arrived after restart_stream())
            self._resyncs += 1
            self._start(seq)
            return self._verdict(SequenceVerdict.RESYNC)
        if back >= self.window:
            self._stale += 1
            self._out_of_order += 1
            return self._verdict(SequenceVerdict.STALE)
        bit = 1 << back
        if self._seen & bit:
            self._duplicates += 1
            return self._verdict(SequenceVerdict.DUPLICATE)
        self._seen |= bit
        self._out_of_order += 1
        if self._missing & bit:
            self._missing &= ~bit
            self._lost -= 1
        return self._verdict(SequenceVerdict.OUT_OF_ORDER)

    def should_use(self, verdict: SequenceVerdict) -> bool:
        """Whether a record with this verdict should be used as a measurement."""
        if verdict is SequenceVerdict.OUT_OF_ORDER:
            return self.use_out_of_order
        return verdict in (SequenceVerdict.FIRST, SequenceVerdict.IN_ORDER, SequenceVerdict.RESYNC)

    def accept(self, seq: int) -> bool:
        """observe() then should_use(): True if the record should be used."""
        return self.should_use(self.observe(seq))

    def _start(self, seq: int) -> None:
        self._newest = seq
        self._seen = 1
        self._missing = 0

    def _verdict(self, verdict: SequenceVerdict) -> SequenceVerdict:
        if self.should_use(verdict):
            self._accepted += 1
        return verdict

    def __repr__(self) -> str:
        s = self.stats
        return (f'RdtSequenceTracker(window={self.window}, newest={self._newest}, '
                f'received={s.received}, lost={s.lost}, out_of_order={s.out_of_order}, '
                f'duplicates={s.duplicates})')


class SampleClock:
    """Sample times of a fixed-rate stream, from its sequence numbers instead of arrival times.

    A Net F/T samples on its own crystal at ``rate_hz`` and numbers every record; the host
    receives them late by a delay that jumps whenever the host is busy. Stamping at arrival
    shifts each force sample by that delay, so a plate moving at 2 m/s is 20 cm off for every
    100 ms of lag. Here t_n = offset + n / rate_hz, with n the unwrapped rdt_sequence and offset
    the smallest (arrival - n / rate_hz) seen, i.e. the least-delayed record's. The offset may
    rise by at most ``max_drift`` seconds per second (the two crystals drift apart by ppm), so a
    lag spike never moves it. The clock starts over (the sensor restarted, or the stream was
    re-requested) when the sequence jumps forward by more than ``restart_s``, steps back by
    more than ``max_backstep_s``, or a record would be stamped more than ``max_lag_s`` before
    it arrived: no host lags that long, so the numbers no longer belong to the anchored stream,
    and keeping the anchor would stamp the new stream seconds in the past. Times are in the
    clock of ``arrival`` [s]; ``stamp_in`` keeps the anchor in a steady clock and stamps in
    another (a node's ROS clock), which may be stepped.
    """

    def __init__(self, rate_hz: float, max_drift: float = 200e-6, restart_s: float = 10.0,
                 max_backstep_s: float = 0.1, max_lag_s: float = 5.0):
        if not rate_hz > 0:
            raise ProtocolConfigError(f'SampleClock needs the sensor rate > 0 Hz, got {rate_hz}')
        if not (max_lag_s > 0 and max_backstep_s >= 0 and restart_s > 0):
            raise ProtocolConfigError(f'SampleClock needs restart_s > 0, max_backstep_s >= 0 and '
                                      f'max_lag_s > 0; got {restart_s}, {max_backstep_s}, '
                                      f'{max_lag_s}')
        self.rate_hz = float(rate_hz)
        self.max_drift = float(max_drift)
        self.restart_n = int(restart_s * rate_hz)
        self.max_backstep_n = int(max_backstep_s * rate_hz)
        self.max_lag_s = float(max_lag_s)
        self.restarts = 0
        self.reset()

    def reset(self) -> None:
        self._last_seq = None
        self._n = 0
        self._offset = None
        self._last_arrival = None
        self._clock_difference = None   # stamp_in: the other clock minus the steady one [s]
        self._step_seen = []
        self._last_out = None           # stamp_in: the last stamp given [s]

    def stamp(self, rdt_sequence: int, arrival: float) -> float:
        """Sample time [s] of record ``rdt_sequence`` that arrived at ``arrival`` [s]."""
        if self._last_seq is not None:
            step = ((rdt_sequence - self._last_seq + (1 << 31)) % (1 << 32)) - (1 << 31)
            lag = arrival - (self._offset + (self._n + step) / self.rate_hz)
            if step > self.restart_n or step < -self.max_backstep_n or lag > self.max_lag_s:
                self.reset()
                self.restarts += 1
            else:
                self._n += step
        self._last_seq = rdt_sequence
        lag_free = arrival - self._n / self.rate_hz
        if self._offset is None or lag_free < self._offset:
            self._offset = lag_free
        else:
            rise = self.max_drift * max(arrival - self._last_arrival, 0.0)
            self._offset = min(lag_free, self._offset + rise)
        self._last_arrival = arrival
        return self._offset + self._n / self.rate_hz

    #: the two clocks' difference is followed only when it moves by more than this [s] ...
    STEP_S = 0.005
    #: ... in this many arrivals in a row: one late reading of a clock is not a step
    STEP_CONFIRM = 3

    def stamp_in(self, rdt_sequence: int, arrival_steady: float, clock_at_arrival: float) -> float:
        """Sample time of record ``rdt_sequence`` in the clock that read ``clock_at_arrival`` [s]
        (the ROS clock the other streams are stamped in) when the steady clock (e.g.
        ``time.monotonic()``) read ``arrival_steady`` [s]; read the two one right after the other.

        The anchor is kept in the steady clock, which no clock step moves, and the stamps are
        moved into the other clock by the two clocks' difference. A lab host's system clock can
        be stepped (NTP or chrony correcting it, a virtual machine resumed): anchored in that
        clock, a step forward left every later stamp behind by the step until the drift
        allowance caught up (0.2 s took 17 min at 200 ppm), so the force no longer paired with
        the plate's pose, whose stamps follow the step. The difference is the smallest one read
        (the other clock is read after the steady one, so a delay between the readings can only
        add to it) and follows a change of more than ``STEP_S`` only once ``STEP_CONFIRM``
        arrivals in a row show it: a thread preempted between the two readings moves one
        reading by milliseconds, which at 1 kHz would put stamps out of order."""
        base = self.stamp(rdt_sequence, arrival_steady)   # may start the clock over (reset)
        difference = clock_at_arrival - arrival_steady
        stepped = False
        if self._clock_difference is None:
            self._clock_difference = difference
        elif abs(difference - self._clock_difference) > self.STEP_S:
            self._step_seen.append(difference)
            if len(self._step_seen) >= self.STEP_CONFIRM:
                self._clock_difference = float(sorted(self._step_seen)[len(self._step_seen) // 2])
                self._step_seen = []
                stepped = True
        else:
            self._step_seen = []
            # a reading delayed between the two clocks can only make the difference larger
            self._clock_difference = min(self._clock_difference, difference)
        out = base + self._clock_difference
        # While the stream starts, the first records may have waited in a busy host longer than
        # the later ones: a less-delayed record lowers the anchor (or the clocks' difference), and
        # its stamp would fall before those already given, by the correction. Consumers pair and
        # interpolate in stamp order, so the order is held (1 us apart) until the stamps catch
        # up; a step of the other clock itself is followed.
        if self._last_out is not None and not stepped and out <= self._last_out:
            out = self._last_out + 1e-6
        self._last_out = out
        return out
