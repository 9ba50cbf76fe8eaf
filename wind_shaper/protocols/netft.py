"""ATI Net F/T Raw Data Transfer (RDT): requests, records, status word and sequence tracking.

Pure codec: bytes in, values out, no sockets. The sensor listens on UDP port 49152 and answers
the address a request came from. All fields are big-endian:

* request, 8 bytes: ``uint16 header (0x1234), uint16 command, uint32 sample_count``
  (command 0 stops streaming, 2 starts real-time streaming, 0x42 sets the software bias;
  sample_count 0 means "until stopped").
* record, 36 bytes: ``uint32 rdt_sequence, uint32 ft_sequence, uint32 status,
  int32 Fx, Fy, Fz, Tx, Ty, Tz`` with forces and torques in counts (sensor frame). One datagram
  may carry several records back to back.

Counts become SI units with the calibration's counts per force [counts/N] and counts per torque
[counts/(N m)] (the sensor serves them as ``calcpf`` / ``calcpt``), see ``NetFtCalibration``.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import Iterable, NamedTuple, Sequence

from .errors import NetFtPacketError, ProtocolConfigError

__all__ = [
    'RDT_PORT', 'RDT_HEADER', 'REQUEST_SIZE', 'RECORD_SIZE', 'RdtCommand', 'RdtRequest',
    'encode_request', 'decode_request', 'RdtRecord', 'encode_records', 'decode_records',
    'RdtStatus', 'NetFtCalibration', 'NetFtSample', 'SequenceVerdict', 'RdtSequenceStats',
    'RdtSequenceTracker', 'SampleClock',
]

RDT_PORT = 49152
RDT_HEADER = 0x1234
_REQUEST = struct.Struct('>HHI')
_RECORD = struct.Struct('>III6i')
REQUEST_SIZE = _REQUEST.size    # 8 bytes
RECORD_SIZE = _RECORD.size      # 36 bytes
_U32 = 1 << 32
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1


class RdtCommand(IntEnum):
    """RDT request commands (the uint16 after the header)."""

    STOP_STREAMING = 0x0000
    START_REALTIME = 0x0002
    SET_SOFTWARE_BIAS = 0x0042


# --------------------------------------------------------------------------------------------
# requests

@dataclass(frozen=True)
class RdtRequest:
    """One RDT request: a command and a sample count (0 = stream until stopped)."""

    command: int
    sample_count: int = 0

    def __post_init__(self):
        if not 0 <= int(self.command) <= 0xFFFF:
            raise ProtocolConfigError(f'RDT command must fit in uint16; got {self.command}')
        if not 0 <= int(self.sample_count) < _U32:
            raise ProtocolConfigError(f'RDT sample_count must be 0..2^32-1 (0 = until stopped); '
                                      f'got {self.sample_count}')

    def encode(self) -> bytes:
        """The 8 request bytes, big-endian."""
        return _REQUEST.pack(RDT_HEADER, int(self.command), int(self.sample_count))

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> 'RdtRequest':
        """Parse 8 request bytes; raises NetFtPacketError on a wrong length or header."""
        if len(data) != REQUEST_SIZE:
            raise NetFtPacketError(
                f'an RDT request is exactly {REQUEST_SIZE} bytes; got {len(data)}: the sender is '
                f'not speaking RDT or the datagram was cut; send header 0x1234, a uint16 command '
                f'and a uint32 sample count, big-endian')
        header, command, count = _REQUEST.unpack(data)
        if header != RDT_HEADER:
            raise NetFtPacketError(
                f'RDT request header is 0x{header:04x}, expected 0x{RDT_HEADER:04x}: check the '
                f'byte order (RDT is big-endian) and that the sender speaks RDT')
        return cls(command, count)


def encode_request(command: int, sample_count: int = 0) -> bytes:
    """Bytes of an RDT request (command: an ``RdtCommand``; sample_count 0 = until stopped)."""
    return RdtRequest(command, sample_count).encode()


def decode_request(data: bytes | bytearray | memoryview) -> RdtRequest:
    """Parse an RDT request datagram; raises NetFtPacketError if malformed."""
    return RdtRequest.decode(data)


# --------------------------------------------------------------------------------------------
# records

class RdtRecord(NamedTuple):
    """One RDT record as sent: sequence numbers, status word, and six int32 readings [counts].

    rdt_sequence counts RDT packets the sensor sent; ft_sequence counts its internal samples;
    status is the sensor's status word (0 = healthy, see ``RdtStatus``); fx..tz are the
    force [counts] and torque [counts] components in the sensor frame.
    """

    rdt_sequence: int
    ft_sequence: int
    status: int
    fx: int
    fy: int
    fz: int
    tx: int
    ty: int
    tz: int

    @property
    def counts(self) -> tuple[int, int, int, int, int, int]:
        """(Fx, Fy, Fz, Tx, Ty, Tz) [counts]."""
        return (self.fx, self.fy, self.fz, self.tx, self.ty, self.tz)

    def encode(self) -> bytes:
        """The 36 record bytes, big-endian; ProtocolConfigError if a field is out of range."""
        try:
            return _RECORD.pack(*self)
        except struct.error as exc:
            raise ProtocolConfigError(
                f'RDT record {tuple(self)} cannot be encoded ({exc}): sequence numbers and '
                f'status are uint32 and readings int32 counts; saturate readings before '
                f'encoding') from None


def encode_records(records: Iterable[RdtRecord]) -> bytes:
    """Several records back to back, as one datagram."""
    return b''.join(RdtRecord(*r).encode() for r in records)


def decode_records(data: bytes | bytearray | memoryview) -> list[RdtRecord]:
    """Every record of a datagram; raises NetFtPacketError unless its length is k * 36, k >= 1."""
    n = len(data)
    if n == 0 or n % RECORD_SIZE:
        whole, extra = divmod(n, RECORD_SIZE)
        if n == REQUEST_SIZE:
            hint = ('8 bytes is the size of an RDT request: a request was sent to the client '
                    'port, or the client is bound to the sensor port')
        else:
            hint = ('the datagram was truncated or is not RDT data; check that only the sensor '
                    'sends to this port and that nothing between cuts datagrams')
        raise NetFtPacketError(
            f'RDT datagram of {n} bytes is not a whole number of {RECORD_SIZE}-byte records '
            f'({whole} records and {extra} extra bytes): {hint}')
    return [RdtRecord._make(t) for t in _RECORD.iter_unpack(data)]


# --------------------------------------------------------------------------------------------
# status word

# Bit meanings follow ATI's published status-code bitmap of its Ethernet F/T sensors (Axia
# manuals, table "Status Code"). The older Net F/T box (NETBA) lays out its low bits
# differently, but both set bit 31 whenever an error bit is set. So: any nonzero status makes
# a record unusable; the named flags below are a best-effort explanation for the operator.
_BIT_NAMES = {
    0: 'internal temperature out of range',
    1: 'supply voltage out of range',
    2: 'broken gage',
    3: 'busy (calibration, filter or rate change in progress)',
    5: 'other error',
    7: 'calibration not accessible',
    16: 'monitor condition latched',
    27: 'gage out of range',
    28: 'simulated error',
    29: 'calibration checksum error',
    30: 'force/torque out of range (saturated)',
    31: 'error (some error bit is set)',
}
_SATURATION_MASK = (1 << 30) | (1 << 27)
_TRANSDUCER_MASK = (1 << 0) | (1 << 1) | (1 << 2) | (1 << 5) | (1 << 7) | (1 << 29)


@dataclass(frozen=True)
class RdtStatus:
    """Meaning of an RDT status word. 0 is healthy; anything else makes the record a fault.

    Assumed bit meanings (see module source): bit 31 any error; bit 30 F/T out of range
    (saturated); bit 27 gage out of range; bits 0, 1, 2, 5, 7, 29 transducer or electronics
    errors (temperature, supply, broken gage, other, calibration missing or corrupt); bit 3 busy;
    bit 28 simulated error.
    """

    raw: int

    @property
    def ok(self) -> bool:
        return self.raw == 0

    @property
    def any_error(self) -> bool:
        return bool(self.raw & (1 << 31))

    @property
    def saturated(self) -> bool:
        """A reading or a gage is outside its range: the force values are not trustworthy."""
        return bool(self.raw & _SATURATION_MASK)

    @property
    def transducer_error(self) -> bool:
        """The transducer or its electronics report an error (broken gage, calibration, ...)."""
        return bool(self.raw & _TRANSDUCER_MASK)

    @property
    def busy(self) -> bool:
        return bool(self.raw & (1 << 3))

    def describe(self) -> str:
        """Readable list of the set bits, e.g. 'error; force/torque out of range (saturated)'."""
        if self.raw == 0:
            return 'healthy'
        names, unknown = [], 0
        for bit in range(31, -1, -1):
            if self.raw & (1 << bit):
                if bit in _BIT_NAMES:
                    names.append(_BIT_NAMES[bit])
                else:
                    unknown |= 1 << bit
        if unknown:
            names.append(f'undocumented bits 0x{unknown:08x}')
        return f'0x{self.raw:08x}: ' + '; '.join(names)


# --------------------------------------------------------------------------------------------
# conversion to SI

@dataclass(frozen=True, slots=True)
class NetFtSample:
    """One decoded record in SI units.

    force: (Fx, Fy, Fz) [N, sensor frame]; torque: (Tx, Ty, Tz) [N m, sensor frame]; status:
    the raw status word. A sample with ``ok`` False carries a fault and must not be used as a
    measurement: ``status_info`` tells why.
    """

    rdt_sequence: int
    ft_sequence: int
    status: int
    force: tuple[float, float, float]
    torque: tuple[float, float, float]

    @property
    def ok(self) -> bool:
        return self.status == 0

    @property
    def status_info(self) -> RdtStatus:
        return RdtStatus(self.status)


@dataclass(frozen=True)
class NetFtCalibration:
    """Counts per unit: counts_per_force [counts/N], counts_per_torque [counts/(N m)]."""

    counts_per_force: float = 1_000_000.0
    counts_per_torque: float = 1_000_000.0

    def __post_init__(self):
        for name in ('counts_per_force', 'counts_per_torque'):
            value = getattr(self, name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = math.nan
            if not (math.isfinite(number) and number > 0):
                raise ProtocolConfigError(
                    f'{name} must be a finite positive number; got {value!r}: read calcpf / '
                    f'calcpt from the sensor (netftcalapi.xml) and pass them as parameters')
            object.__setattr__(self, name, number)

    def to_sample(self, record: RdtRecord) -> NetFtSample:
        """Record [counts] -> sample [N, N m]; the status is carried, not judged."""
        f, t = self.counts_per_force, self.counts_per_torque
        return NetFtSample(record.rdt_sequence, record.ft_sequence, record.status,
                           (record.fx / f, record.fy / f, record.fz / f),
                           (record.tx / t, record.ty / t, record.tz / t))

    def to_counts(self, wrench: Sequence[float]) -> tuple[tuple[int, ...], bool]:
        """(Fx, Fy, Fz [N], Tx, Ty, Tz [N m]) -> (six int32 counts, saturated).

        Values beyond int32 saturate at INT32_MIN / INT32_MAX, and NaN reads as positive full
        scale (like a broken gage); ``saturated`` says whether that happened. Used by simulators.
        """
        if len(wrench) != 6:
            raise ProtocolConfigError(f'a wrench has 6 components (Fx Fy Fz Tx Ty Tz); got '
                                      f'{len(wrench)}')
        out, saturated = [], False
        for i, value in enumerate(wrench):
            scaled = float(value) * (self.counts_per_force if i < 3 else self.counts_per_torque)
            if math.isnan(scaled) or scaled >= INT32_MAX:
                out.append(INT32_MAX)
                saturated = True
            elif scaled <= INT32_MIN:
                out.append(INT32_MIN)
                saturated = True
            else:
                out.append(int(round(scaled)))
        return tuple(out), saturated


# the stream logic lives beside the codec; its names stay importable from here
from .netft_stream import RdtSequenceStats, RdtSequenceTracker, SampleClock, SequenceVerdict  # noqa: E402,F401
