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


def test_stamps_follow_a_step_of_the_system_clock_at_once():
    """The host's system clock (what the ROS clock and the motion capture's stamps read) is
    stepped 0.22 s forward, later 0.5 s back, while the monotonic clock runs on; every stamp
    must stay on the sample's time in the system clock of that moment. Anchored in the system
    clock, the stamps after the forward step lagged by it (the force 0.22 s before the pose it
    belongs with), for the many minutes the drift allowance takes to catch up."""
    rng = np.random.default_rng(5)
    rate = 1000.0
    n = 9000
    steady = 50.0 + np.arange(n) / rate                     # sample times, monotonic clock
    system_minus_steady = np.full(n, 1.7e9)
    system_minus_steady[3000:] += 0.22
    system_minus_steady[6000:] -= 0.5
    lag = 0.0005 + rng.exponential(0.001, n)
    # the system clock read a little after the steady one, now and then much later (the
    # reading thread preempted between the two readings)
    late_read = rng.exponential(2e-6, n) + np.where(rng.random(n) < 0.01, 0.004, 0.0)
    late_read[0] = 0.0045           # the very first reading among the late ones
    clock = SampleClock(rate)
    stamps = np.array([clock.stamp_in(i, float(t + d), float(t + d + off + r))
                       for i, t, d, off, r in zip(range(n), steady, lag, system_minus_steady,
                                                  late_read)])
    err = stamps - (steady + system_minus_steady)
    settled = np.r_[100:3000, 3010:6000, 6010:n]     # a step is followed within a few samples
    assert np.all(np.abs(err[settled]) < 0.003), np.abs(err[settled]).max()
    assert np.median(np.abs(err[settled])) < 0.002
    in_order = np.diff(stamps) > 0
    assert in_order[100:5999].all() and in_order[6010:].all(), \
        'a late reading put the stamps out of order'
    assert clock.restarts == 0
    # the clock anchored in the system clock instead: behind by the step after it
    old = SampleClock(rate)
    old_stamps = np.array([old.stamp(i, float(t + d + off))
                           for i, t, d, off in zip(range(n), steady, lag, system_minus_steady)])
    assert np.all((steady + system_minus_steady - old_stamps)[3100:5900] > 0.2)


def test_stamps_stay_in_order_while_the_anchor_settles():
    """The first records of a stream waited 3-6 ms in a busy host, the later ones 0.5 ms: each
    less-delayed record lowers the anchor, and stamped as they came, samples fell before the ones
    already sent. The stamps given stay in order (and within the corrections of the true times);
    a step of the system clock back by half a second is still followed at once."""
    rate = 1000.0
    n = 400
    steady = 20.0 + np.arange(n) / rate
    lag = np.where(np.arange(n) < 20, 0.006 - 0.00015 * np.arange(n), 0.0005)
    system_minus_steady = np.full(n, 1.7e9)
    system_minus_steady[300:] -= 0.5
    clock = SampleClock(rate)
    stamps = np.array([clock.stamp_in(i, float(t + d), float(t + d + off))
                       for i, t, d, off in zip(range(n), steady, lag, system_minus_steady)])
    raw = SampleClock(rate)
    unheld = np.array([raw.stamp(i, float(t + d)) for i, t, d in zip(range(n), steady, lag)])
    assert np.any(np.diff(unheld[:300]) < 0), 'the case does not lower the anchor'
    assert np.all(np.diff(stamps[:300]) > 0) and np.all(np.diff(stamps[305:]) > 0)
    err = stamps - (steady + system_minus_steady)
    followed = np.r_[:300, 305:n]            # the step back is confirmed within a few records
    assert np.all(np.abs(err[followed]) < 0.007), np.abs(err[followed]).max()
    assert np.all(np.abs(err[np.r_[40:300, 305:n]]) < 0.001), np.abs(err[40:300]).max()
    assert stamps[305] < stamps[299] - 0.4     # the clock's own step back, followed


def test_stamps_in_another_clock_start_over_with_a_restarted_sensor():
    """The sensor restarts and counts from 5 again: the clock starts over, and so does the
    clocks' difference it stamps with (this raised a TypeError, losing the sample)."""
    clock = SampleClock(1000.0)
    for n in range(3000):
        clock.stamp_in(n, 100.0 + n / 1000.0, 1.7e9 + 100.0 + n / 1000.0)
    t = clock.stamp_in(5, 200.0, 1.7e9 + 200.0)
    assert clock.restarts == 1 and abs(t - (1.7e9 + 200.0)) < 1e-6
