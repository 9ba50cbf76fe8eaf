"""SampleClock: force sample times from RDT sequence numbers, not from arrival times."""
import numpy as np

from wind_shaper.protocols.netft import SampleClock
def test_sample_clock_ignores_arrival_lag_spikes():
    rng = np.random.default_rng(3)
    rate = 1000.0
    clock = SampleClock(rate)
    true_t = 100.0 + np.arange(5000) / rate
    lag = 0.0005 + rng.exponential(0.002, 5000)
    lag[2000:2100] += np.linspace(0.3, 0.0, 100)  # the host stalled for 300 ms
    seqs = (4_294_960_000 + np.arange(5000)) % (1 << 32)  # wraps around 2^32 on the way
    stamps = np.array([clock.stamp(int(s), float(t + d)) for s, t, d in zip(seqs, true_t, lag)])
    err = stamps[500:] - true_t[500:]
    assert np.all(np.abs(err) < 0.002), np.abs(err).max()
    assert lag[2000:2100].max() > 0.2  # what stamping at arrival would have been off by [s]


def test_sample_clock_restarts_and_follows_drift():
    clock = SampleClock(1000.0, max_drift=1e-4)
    # the sensor's crystal is 50 ppm slow: its samples come later and later
    for n in range(20000):
        t = clock.stamp(n, n / 1000.0 * (1 + 50e-6) + 0.001)
    assert abs(t - (19999 / 1000.0 * (1 + 50e-6) + 0.001)) < 0.002
    t = clock.stamp(5, 50.0)  # sensor restarted: the sequence jumped back
    assert abs(t - 50.0) < 1e-9


def test_sample_clock_starts_over_when_a_restarted_sensor_counts_from_one_again():
    # 4 s of stream (shorter than restart_s), the sensor dies, comes back 6 s later from 1
    clock = SampleClock(1000.0)
    for n in range(4000):
        clock.stamp(20 + n, 100.0 + n / 1000.0 + 0.001)
    stamps = [clock.stamp(1 + n, 110.0 + n / 1000.0 + 0.001) for n in range(100)]
    assert abs(stamps[-1] - (110.0 + 99 / 1000.0)) < 0.002
    assert clock.restarts == 1


def test_sample_clock_starts_over_when_the_numbers_continue_after_a_long_silence():
    # the new stream's numbers happen to continue the old ones: the 8 s of lag gives it away
    clock = SampleClock(1000.0)
    for n in range(3000):
        clock.stamp(n, 100.0 + n / 1000.0)
    t = clock.stamp(3000, 111.0)
    assert abs(t - 111.0) < 1e-9 and clock.restarts == 1


def test_sample_clock_keeps_its_anchor_through_a_one_second_host_stall():
    clock = SampleClock(1000.0)
    for n in range(3000):
        clock.stamp(n, 100.0 + n / 1000.0 + 0.001)
    late = clock.stamp(3000, 104.0)       # true time 103.0: a second in the socket buffer
    assert abs(late - 103.0) < 0.002 and clock.restarts == 0
