"""RDT requests and records against hand-built bytes; malformed packets; SI conversion; status."""
import math
import struct

import pytest

from wind_shaper.protocols.errors import NetFtPacketError, ProtocolConfigError
from wind_shaper.protocols.netft import (INT32_MAX, INT32_MIN, NetFtCalibration, RdtCommand,
                                              RdtRecord, RdtRequest, RdtStatus, decode_records,
                                              decode_request, encode_records, encode_request)


@pytest.mark.parametrize('command, count', [(RdtCommand.START_REALTIME, 0),
                                            (RdtCommand.STOP_STREAMING, 0),
                                            (RdtCommand.SET_SOFTWARE_BIAS, 0),
                                            (RdtCommand.START_REALTIME, 1000),
                                            (RdtCommand.START_REALTIME, 2**32 - 1)])
def test_request_bytes_are_big_endian_header_command_count(command, count):
    data = encode_request(command, count)
    assert data == struct.pack('>HHI', 0x1234, int(command), count)
    assert len(data) == 8
    assert decode_request(data) == RdtRequest(int(command), count)


def test_start_request_exact_bytes():
    assert encode_request(RdtCommand.START_REALTIME) == b'\x12\x34\x00\x02\x00\x00\x00\x00'
    assert encode_request(RdtCommand.SET_SOFTWARE_BIAS) == b'\x12\x34\x00\x42\x00\x00\x00\x00'


@pytest.mark.parametrize('data', [b'', b'\x12\x34', b'\x12\x34\x00\x02\x00\x00\x00',
                                  b'\x12\x34\x00\x02\x00\x00\x00\x00\x00'])
def test_request_of_wrong_length_is_refused_with_the_length(data):
    with pytest.raises(NetFtPacketError, match=f'exactly 8 bytes; got {len(data)}'):
        decode_request(data)


def test_request_with_wrong_header_names_the_header_and_byte_order():
    little_endian = struct.pack('<HHI', 0x1234, 2, 0)
    with pytest.raises(NetFtPacketError, match=r'0x3412.*big-endian'):
        decode_request(little_endian)


@pytest.mark.parametrize('command, count', [(-1, 0), (0x10000, 0), (2, -1), (2, 2**32)])
def test_request_fields_out_of_range_are_refused(command, count):
    with pytest.raises(ProtocolConfigError):
        encode_request(command, count)


def test_record_bytes_match_struct_layout():
    rec = RdtRecord(7, 123456, 0, 1_000_000, -2_000_000, 3, -4, INT32_MAX, INT32_MIN)
    expected = struct.pack('>III6i', 7, 123456, 0, 1_000_000, -2_000_000, 3, -4,
                           2**31 - 1, -2**31)
    assert rec.encode() == expected
    assert len(expected) == 36
    assert decode_records(expected) == [rec]
    # byte-exact start: rdt_sequence 7 big-endian
    assert expected[:4] == b'\x00\x00\x00\x07'
    assert rec.counts == (1_000_000, -2_000_000, 3, -4, INT32_MAX, INT32_MIN)


def test_several_records_in_one_datagram_all_decode_in_order():
    recs = [RdtRecord(2**32 - 2 + i, i, 0, i, -i, 2 * i, 0, 0, 0) for i in range(2)] + \
           [RdtRecord(0, 2, 0x80000000, 5, 5, 5, 5, 5, 5)]
    data = encode_records(recs)
    assert len(data) == 3 * 36
    assert data == b''.join(struct.pack('>III6i', *r) for r in recs)
    assert decode_records(data) == recs
    assert decode_records(memoryview(bytearray(data))) == recs


@pytest.mark.parametrize('n', [0, 1, 8, 35, 37, 71, 73])
@pytest.mark.fault
def test_datagram_not_a_multiple_of_36_is_malformed_with_a_clear_message(n, fault_row):
    with pytest.raises(NetFtPacketError) as info:
        decode_records(bytes(n))
    msg = str(info.value)
    assert f'{n} bytes' in msg and '36-byte' in msg
    if n == 8:
        assert 'request' in msg
    else:
        assert 'truncated' in msg
    fault_row('malformed or truncated RDT datagram',
              'refused with its length; the stream goes on', True)


@pytest.mark.parametrize('fields', [(-1, 0, 0, 0, 0, 0, 0, 0, 0), (2**32, 0, 0, 0, 0, 0, 0, 0, 0),
                                    (0, 0, 0, 2**31, 0, 0, 0, 0, 0)])
def test_record_fields_out_of_range_cannot_be_encoded(fields):
    with pytest.raises(ProtocolConfigError, match='saturate'):
        RdtRecord(*fields).encode()


def test_counts_become_newtons_and_newton_metres():
    cal = NetFtCalibration(counts_per_force=1_000_000, counts_per_torque=500_000)
    s = cal.to_sample(RdtRecord(1, 2, 0, 1_500_000, -250_000, 0, 1_000_000, 0, -5))
    assert s.force == (1.5, -0.25, 0.0)
    assert s.torque == (2.0, 0.0, -1e-5)
    assert s.ok and s.status_info.ok


@pytest.mark.parametrize('bad', [0, -1.0, math.nan, math.inf, 'x', None])
def test_calibration_must_be_finite_positive(bad):
    with pytest.raises(ProtocolConfigError, match='calcpf'):
        NetFtCalibration(counts_per_force=bad)


def test_to_counts_saturates_overflow_and_nan():
    cal = NetFtCalibration(1e6, 1e6)
    counts, sat = cal.to_counts((1.0, -2.0, 0.5, 0, 0, 0.001))
    assert counts == (1_000_000, -2_000_000, 500_000, 0, 0, 1000) and not sat
    counts, sat = cal.to_counts((1e4, -1e4, math.nan, 0, 0, 0))
    assert sat and counts[:3] == (INT32_MAX, INT32_MIN, INT32_MAX)
    with pytest.raises(ProtocolConfigError):
        cal.to_counts((1.0, 2.0))


def test_status_word_flags():
    assert RdtStatus(0).ok and RdtStatus(0).describe() == 'healthy'
    sat = RdtStatus(0xC0000000)
    assert not sat.ok and sat.any_error and sat.saturated and not sat.transducer_error
    assert 'saturated' in sat.describe()
    gage = RdtStatus(0x80000004)
    assert gage.transducer_error and not gage.saturated and 'broken gage' in gage.describe()
    assert RdtStatus(0x88000000).saturated                 # gage out of range
    assert RdtStatus(0xA0000000).transducer_error          # calibration checksum
    busy = RdtStatus(0x00000008)
    assert busy.busy and not busy.ok and not busy.any_error
    assert 'undocumented bits 0x00000100' in RdtStatus(0x100).describe()


@pytest.mark.fault
def test_sample_with_fault_status_is_not_ok(fault_row):
    s = NetFtCalibration().to_sample(RdtRecord(1, 1, 0xC0000000, *([INT32_MAX] * 6)))
    assert not s.ok and s.status_info.saturated
    fault_row('RDT status word with saturation/fault bits',
              'sample flagged not ok, never published', True)
