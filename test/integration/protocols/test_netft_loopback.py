"""NetFtClient against SimNetFtServer over UDP loopback: counts, values, faults, sources."""
import math
import socket
import threading
import time

import pytest

from wind_shaper.protocols.netft import (NetFtCalibration, RdtRecord, RdtSequenceTracker,
                                              decode_records, encode_records)
from wind_shaper.io import LinkConfigError, NetFtClient, TransportError
from wind_shaper.protocols.errors import ProtocolConfigError
from wind_shaper.sim.netft_server import NetFtFaults, SimNetFtServer

TOP = 2**32
RATE = 1000.0


def wrench(t):
    """Smooth test wrench: forces [N], torques [N m]."""
    return (math.sin(2 * math.pi * t), 0.5 * math.cos(t), 9.81 + 0.1 * t, 0.01 * t, -0.02, 0.003)


class Collector:
    def __init__(self):
        self.samples, self.stats = [], None
        self.lock = threading.Lock()

    def __call__(self, sample, stats):
        with self.lock:
            self.samples.append(sample)
            self.stats = stats


@pytest.fixture
def rig():
    made = []

    def make(faults=None, initial=1, source=wrench, client_kw=None, **server_kw):
        server = SimNetFtServer(source, rate_hz=server_kw.pop('rate_hz', RATE), faults=faults,
                                initial_rdt_sequence=initial, **server_kw)
        made.append(server)
        got = Collector()
        client = NetFtClient('127.0.0.1', server.port, local_host='127.0.0.1', on_sample=got,
                             calibration=NetFtCalibration(server.calibration.counts_per_force,
                                                          server.calibration.counts_per_torque),
                             **(client_kw or {}))
        made.append(client)
        return server, client, got

    yield make
    for obj in reversed(made):
        obj.close()


@pytest.mark.fault
def test_one_second_at_1khz_with_faults_counts_exactly_what_the_server_did(rig, wait_for,
                                                                            fault_row):
    initial = TOP - 400                                    # the stream wraps past 2^32
    faults = NetFtFaults(drop_probability=0.02, reorder_probability=0.03,
                         duplicate_probability=0.01, truncate_probability=0.005, seed=11)
    server, client, got = rig(faults, initial=initial)
    t0 = time.perf_counter()
    client.start(sample_count=1000)
    assert server.wait_idle(5.0, min_generated=1000)
    log = server.fault_log()
    assert wait_for(lambda: client.stats.datagrams == log.datagrams_sent, 2.0), \
        (client.stats, log.datagrams_sent)
    elapsed = time.perf_counter() - t0
    s = client.stats
    assert log.generated == 1000 and log.dropped and log.reordered and log.duplicated
    assert s.lost == len(log.dropped) + len(log.truncated) + log.late_skips
    assert s.out_of_order == len(log.reordered)
    assert s.duplicates == len(log.duplicated)
    assert s.malformed == len(log.truncated)
    assert s.rejected == 0 and s.stale == 0 and s.resyncs == 0
    assert s.received == 1000 - len(log.dropped) - len(log.truncated) + len(log.duplicated)
    # only in-order, intact records reach the callback, each once
    seqs = [x.rdt_sequence for x in got.samples]
    assert len(seqs) == len(set(seqs)) == s.accepted
    assert s.accepted == 1000 - len(log.dropped) - len(log.truncated) - len(log.reordered)
    lost = set(log.dropped) | set(log.truncated) | set(log.reordered)
    # a host too busy to keep up makes the server skip sequence numbers ahead (late_skips)
    universe = {(initial + k) % TOP for k in range(log.generated + log.late_skips)} - lost
    assert set(seqs) <= universe and len(universe) - len(seqs) == log.late_skips
    # values are the source's, at the ideal sample time, to the count resolution
    for x in got.samples:
        k = (x.rdt_sequence - initial) % TOP
        expected = wrench(k / RATE)
        assert x.ok
        assert all(abs(a - b) <= 1e-6 for a, b in zip(x.force + x.torque, expected))
    fault_row('Net F/T at 1 kHz over UDP: 2 % dropped, 3 % reordered, 1 % duplicated, 0.5 % '
              'truncated (corrupt) datagrams, sequence wrapping past 2^32',
              'every fault counted exactly; only intact in-order records used, each once',
              True, len(universe) - log.late_skips - len(seqs))
    print(f'\nRDT loopback: {s.accepted} samples in {elapsed:.3f} s '
          f'({s.received / elapsed:.0f} records/s received); {s}')


def test_records_after_a_stall_carry_the_values_of_their_sequence_numbers(rig, wait_for):
    """A server thread held up far beyond max_batch periods skips records; each record it
    sends afterwards still carries the wrench at its own sequence number's sample time."""
    stalled = []

    def stalling_source(t):
        if t >= 0.1 and not stalled:      # once, 0.1 s into the stream: a 0.3 s stall
            stalled.append(t)
            time.sleep(0.3)
        return wrench(t)

    server, client, got = rig(source=stalling_source, max_batch=20)
    client.start(sample_count=600)
    assert server.wait_idle(5.0, min_generated=600)
    assert wait_for(lambda: client.stats.datagrams == server.fault_log().datagrams_sent, 2.0)
    assert server.fault_log().late_skips > 0                  # the stall really skipped records
    first = got.samples[0].rdt_sequence
    for x in got.samples:
        expected = wrench(((x.rdt_sequence - 1) % TOP) / RATE)
        assert all(abs(a - b) <= 1e-6 for a, b in zip(x.force + x.torque, expected)), \
            (x.rdt_sequence, first)


def test_buffered_records_arrive_whole_in_order_and_stamped_by_their_sequence(rig, wait_for):
    """RDT buffering (several records per datagram, as a Net F/T can be set to send): every
    record arrives once, in order, with its own sample time's values, in a tenth as many
    datagrams; a stream stopped mid-datagram still sends the records it had. A server thread
    held up (a loaded machine) skips ahead as a sensor's clock does: the numbers it skipped are
    the only ones the client counts lost."""
    server, client, got = rig(records_per_datagram=10)
    client.start(sample_count=995)              # not a multiple of 10: the last datagram is short
    assert server.wait_idle(5.0, min_generated=995)
    log = server.fault_log()
    assert wait_for(lambda: client.stats.accepted == 995, 2.0), client.stats
    assert log.datagrams_sent == 100 and client.stats.datagrams == 100
    assert client.stats.lost == log.late_skips and client.stats.out_of_order == 0
    seqs = [x.rdt_sequence for x in got.samples]
    assert len(seqs) == 995 and all(b > a for a, b in zip(seqs, seqs[1:]))
    assert seqs[-1] - seqs[0] + 1 == 995 + log.late_skips
    for x in got.samples:
        expected = wrench((x.rdt_sequence - 1) / RATE)
        assert all(abs(a - b) <= 1e-6 for a, b in zip(x.force + x.torque, expected))


def test_buffering_and_fault_injection_are_refused_together_with_the_reason():
    with pytest.raises(ProtocolConfigError, match='records_per_datagram 1 with faults'):
        SimNetFtServer(wrench, faults=NetFtFaults(drop_probability=0.1), records_per_datagram=5)
    with pytest.raises(ProtocolConfigError, match='whole number in 1..40'):
        SimNetFtServer(wrench, records_per_datagram=0)


def test_decode_rate_of_the_pure_path_beats_the_sensor():
    """decode + sequence tracking + SI conversion of 7 kHz worth of records, timed."""
    cal = NetFtCalibration()
    tracker = RdtSequenceTracker()
    datagrams = [encode_records([RdtRecord(i, i, 0, i, -i, 3, 4, 5, 6)]) for i in range(20000)]
    t0 = time.perf_counter()
    n = 0
    for d in datagrams:
        for rec in decode_records(d):
            if tracker.accept(rec.rdt_sequence):
                cal.to_sample(rec)
                n += 1
    rate = n / (time.perf_counter() - t0)
    print(f'\nRDT pure decode path: {rate:.0f} records/s')
    assert n == 20000 and rate > 7000


@pytest.mark.fault
def test_packets_from_a_wrong_source_are_rejected(rig, wait_for, fault_row):
    server, client, got = rig()
    intruder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        intruder.bind(('127.0.0.1', 0))
        forged = encode_records([RdtRecord(5, 5, 0, *([123_000_000] * 6))])
        for _ in range(10):
            intruder.sendto(forged, client.local_address)
        client.start(sample_count=50)
        assert server.wait_idle(3.0, min_generated=50)
        assert wait_for(lambda: client.stats.rejected == 10 and client.stats.accepted == 50, 2.0), \
            client.stats
        assert all(abs(x.force[0]) < 2.0 for x in got.samples)   # none of the forged 123 N
    finally:
        intruder.close()
    fault_row('RDT packets from an address other than the sensor',
              'rejected and counted, never used', True)


def test_status_faults_and_overflow_are_reported_not_silently_used(rig, wait_for):
    faults = NetFtFaults(status_fault_probability=0.05, overflow_probability=0.05, seed=3)
    server, client, got = rig(faults)
    client.start(sample_count=400)
    assert server.wait_idle(3.0, min_generated=400)
    assert wait_for(lambda: client.stats.accepted == 400, 2.0)
    log = server.fault_log()
    bad = set(log.status_faults) | set(log.overflows)
    assert bad
    flagged = {x.rdt_sequence for x in got.samples if not x.ok}
    assert flagged == bad and client.stats.faulted == len(bad)
    for x in got.samples:
        if x.rdt_sequence in log.overflows:
            assert x.status_info.saturated and x.status_info.any_error
        elif x.rdt_sequence in log.status_faults:
            assert x.status_info.transducer_error          # default bits: broken gage


def test_saturating_source_sets_the_saturation_bits(rig, wait_for):
    server, client, got = rig(source=lambda t: (1e6, 0, 0, 0, 0, math.nan))
    client.start(sample_count=20)
    assert wait_for(lambda: client.stats.accepted == 20, 3.0)
    assert all(not x.ok and x.status_info.saturated for x in got.samples)


def test_bias_zeroes_the_reading_and_stop_stops_the_stream(rig, wait_for):
    server, client, got = rig(source=lambda t: (1.0, 2.0, 3.0, 0.1, 0.2, 0.3))
    client.start()
    assert wait_for(lambda: len(got.samples) >= 20, 2.0)
    assert got.samples[-1].force == (1.0, 2.0, 3.0)
    client.bias()
    assert wait_for(lambda: got.samples[-1].force == (0.0, 0.0, 0.0), 2.0)
    client.stop()
    assert wait_for(lambda: not server.streaming, 1.0)
    time.sleep(0.05)
    n = len(got.samples)
    time.sleep(0.1)
    assert len(got.samples) == n
    assert server.requests == dict(start=1, stop=1, bias=1, unknown=0, malformed=0)


def test_restart_resets_counters_and_a_callback_error_does_not_kill_the_reader(rig, wait_for):
    calls = []

    def flaky(sample, stats):
        calls.append(sample.rdt_sequence)
        if len(calls) == 3:
            raise RuntimeError('consumer bug')

    # no skipped records however long the host stalls: the counts below are exact
    server, client, _ = rig(max_batch=100_000)
    client.on_sample = flaky
    client.start(sample_count=30)
    assert wait_for(lambda: client.stats.accepted == 30, 3.0)
    assert client.stats.callback_errors == 1 and len(calls) == 30
    client.start(sample_count=10)                          # a new stream, numbered from 1 again
    assert wait_for(lambda: client.stats.accepted == 10, 3.0)
    assert client.stats.lost == 0 and client.stats.callback_errors == 0
    assert calls[30:] == list(range(1, 11))


def test_a_stream_requested_again_mid_stream_is_taken_whole(rig, wait_for):
    # request_stream() while records flow (the node asks again when its reader fell silent for
    # a while): the sensor starts a new stream from 1 and no record of it is taken as stale,
    # although the old stream's numbers were far ahead
    seen = []
    server, client, _ = rig()
    client.on_sample = lambda sample, stats: seen.append(sample.rdt_sequence)
    client.start()
    assert wait_for(lambda: len(seen) >= 1500, 5.0)
    asked = len(seen)   # the first stream also numbered from 1: the new one starts after this

    def new_stream_start():
        return next((i for i in range(asked, len(seen)) if seen[i] == 1), None)
    client.request_stream()
    assert wait_for(lambda: new_stream_start() is not None and len(seen) - new_stream_start() >= 200, 5.0)
    after = seen[new_stream_start():]
    # the new stream is taken in order from 1; numbers may be missing only where the sensor
    # skipped them (the host stalled) or the datagram was lost, and those are counted lost
    assert after[0] == 1 and all(b > a for a, b in zip(after, after[1:])), after[:50]
    gaps = sum(b - a - 1 for a, b in zip(after, after[1:]))
    assert gaps <= client.stats.lost, (gaps, client.stats)
    assert client.stats.stale == 0 and client.stats.resyncs >= 1


def test_closed_client_refuses_commands_and_bad_config_is_explained(rig, monkeypatch):
    server, client, _ = rig()
    client.close()
    client.close()
    with pytest.raises(TransportError, match='closed'):
        client.start()

    def no_dns(*args, **kwargs):
        raise socket.gaierror(-2, 'Name or service not known')

    with monkeypatch.context() as m:                       # no resolver traffic from tests
        m.setattr(socket, 'getaddrinfo', no_dns)
        with pytest.raises(LinkConfigError, match='resolve'):
            NetFtClient('sensor.example')
    with pytest.raises(LinkConfigError, match='port'):
        NetFtClient('127.0.0.1', port=0)
