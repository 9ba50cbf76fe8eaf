"""Time alignment of force (1 kHz) and pose (100 Hz) streams into (position, force) pairs."""
import numpy as np
import pytest

from wind_shaper.estimation.align import SampleBuffer, align_sweep, pose_period
from wind_shaper.core.errors import SweepError

FORCE_HZ, POSE_HZ = 1000.0, 100.0


def path(t):
    """A known plate path: a circle of radius 0.2 m, one turn per 4 s [m]."""
    w = 2 * np.pi / 4.0
    return np.column_stack([0.2 * np.cos(w * t), 0.2 * np.sin(w * t)])


def field(xy):
    """A known force field [N] of position [m]."""
    return 2.0 + 30.0 * (xy[:, 0] ** 2 + xy[:, 1] ** 2) + 1.5 * xy[:, 0] - 0.7 * xy[:, 1]


def streams(duration=10.0, start=100.0, pose_offset=0.0005):
    """Force at 1 kHz as a function of the true plate position, and poses at 100 Hz. Pose
    stamps sit half a force period off the force grid so each window holds 10 force samples
    placed symmetrically around the pose."""
    ft = start + np.arange(int(duration * FORCE_HZ)) / FORCE_HZ
    pt = start + pose_offset + np.arange(int(duration * POSE_HZ)) / POSE_HZ
    return ft, field(path(ft)), pt, path(pt)


def test_recovers_a_known_field_along_a_known_path():
    ft, fz, pt, pose = streams()
    sweep = align_sweep(ft, fz, pt, pose[:, 0], pose[:, 1], pwm=[0.5, 0.4])
    # 10 s at 100 Hz: the last pose's window runs past the force stream but still holds samples
    assert len(sweep) == 1000
    np.testing.assert_allclose(sweep.positions, pose)
    # the window mean of a smooth signal sampled symmetrically is the value at the centre to
    # second order: 10 ms windows on a 0.31 m/s path -> well under a millinewton
    interior = slice(1, -1)
    np.testing.assert_allclose(sweep.forces[interior], field(pose)[interior], atol=2e-4)
    np.testing.assert_allclose(sweep.times, pt - pt[0])
    np.testing.assert_array_equal(sweep.pwm, [0.5, 0.4])


def test_pairs_use_the_mean_over_each_window_exactly():
    ft = np.arange(0, 1.0, 0.001)
    fz = np.arange(len(ft), dtype=float)  # sample i has force i
    pt = np.array([0.1005, 0.1105, 0.1205])
    sweep = align_sweep(ft, fz, pt, np.zeros(3), np.zeros(3))
    # window [0.0955, 0.1055) holds samples 96..105, mean 100.5
    np.testing.assert_allclose(sweep.forces, [100.5, 110.5, 120.5])


def test_unsorted_input_gives_the_same_pairs(rng):
    ft, fz, pt, pose = streams(duration=3.0)
    ref = align_sweep(ft, fz, pt, pose[:, 0], pose[:, 1])
    i, j = rng.permutation(len(ft)), rng.permutation(len(pt))
    got = align_sweep(ft[i], fz[i], pt[j], pose[j, 0], pose[j, 1])
    np.testing.assert_allclose(got.forces, ref.forces, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got.positions, ref.positions)
    np.testing.assert_array_equal(got.times, ref.times)


def test_nan_samples_are_dropped_not_spread():
    ft, fz, pt, pose = streams(duration=3.0)
    fz, pose = fz.copy(), pose.copy()
    fz[500] = np.nan            # one force sample lost: its window averages the other nine
    pose[40, 1] = np.nan        # one mocap dropout: that pose gives no pair
    pt = pt.copy()
    pt[41] = np.inf             # a broken stamp: dropped
    sweep = align_sweep(ft, fz, pt, pose[:, 0], pose[:, 1])
    assert len(sweep) == len(pt) - 2
    assert np.all(np.isfinite(sweep.forces)) and np.all(np.isfinite(sweep.positions))
    k = np.flatnonzero(np.isclose(sweep.times, pt[50] - pt[0]))[0]
    window = (ft >= pt[50] - 0.005) & (ft < pt[50] + 0.005) & np.isfinite(fz)
    assert window.sum() == 9
    assert sweep.forces[k] == pytest.approx(fz[window].mean(), abs=1e-9)


def test_poses_without_force_in_their_window_are_dropped():
    ft, fz, pt, pose = streams(duration=4.0)
    gap = (ft > 101.0) & (ft < 101.5)  # the force stream stalls for half a second
    sweep = align_sweep(ft[~gap], fz[~gap], pt, pose[:, 0], pose[:, 1])
    assert len(sweep) == len(pt) - 49
    assert not np.any((sweep.times > 1.006) & (sweep.times < 1.494))


def test_period_comes_from_the_pose_stamps_despite_jitter(rng):
    pt = np.arange(1000) / 100.0 + rng.normal(0, 0.0005, 1000)
    assert pose_period(pt) == pytest.approx(0.01, rel=0.02)
    with pytest.raises(SweepError, match='at least 2'):
        pose_period([3.0, 3.0, np.nan])


@pytest.mark.parametrize('shift', [8.0, 30.0, -9.0])
def test_streams_out_of_step_are_refused_with_the_reason(shift):
    ft, fz, pt, pose = streams(duration=10.0)
    with pytest.raises(SweepError, match='out of step') as err:
        align_sweep(ft + shift, fz, pt, pose[:, 0], pose[:, 1])
    assert 'clock' in str(err.value)


def test_a_small_clock_offset_still_aligns():
    ft, fz, pt, pose = streams(duration=10.0)
    sweep = align_sweep(ft + 2.0, fz, pt, pose[:, 0], pose[:, 1])
    assert 750 <= len(sweep) <= 810  # the poses of the first 2 s have no force


def test_empty_or_mismatched_streams_say_what_is_missing():
    ft, fz, pt, pose = streams(duration=1.0)
    with pytest.raises(SweepError, match='no finite force sample'):
        align_sweep([], [], pt, pose[:, 0], pose[:, 1])
    with pytest.raises(SweepError, match='no finite pose sample'):
        align_sweep(ft, fz, [], [], [])
    with pytest.raises(SweepError, match='differ in length'):
        align_sweep(ft, fz[:-1], pt, pose[:, 0], pose[:, 1])
    with pytest.raises(SweepError, match='period'):
        align_sweep(ft, fz, pt, pose[:, 0], pose[:, 1], period=0.0)


def test_sample_buffer_keeps_the_newest_span_and_copies_out():
    buf = SampleBuffer(2, max_span_s=1.0)
    dt = 1 / 64  # exact in binary: the span test has no rounding
    for i in range(300):
        buf.append(i * dt, float(i), -float(i))
    t, a, b = buf.arrays()
    # newest 299/64 s: rows older than 1 s before it (i < 235) are dropped
    assert len(buf) == 65 and buf.dropped == 235
    assert t[0] == 235 * dt and t[-1] == 299 * dt
    np.testing.assert_array_equal(b, -a)
    t[:] = 0  # a copy: the buffer is untouched
    assert buf.arrays()[0][-1] == 299 * dt
    buf.clear()
    assert len(buf) == 0 and [len(x) for x in buf.arrays()] == [0, 0, 0]
    with pytest.raises(ValueError, match='2 values'):
        buf.append(0.0, 1.0)


def test_sample_buffer_takes_appends_from_many_threads():
    import threading
    buf = SampleBuffer(1, max_span_s=1e9)

    def fill(offset):
        for i in range(2000):
            buf.append(offset + i, 1.0)

    threads = [threading.Thread(target=fill, args=(k * 10_000,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=10)
    assert len(buf) == 8000 and buf.arrays()[1].sum() == 8000


def test_a_block_of_samples_is_the_same_as_each_appended_in_turn():
    """The field estimator takes the force in blocks (``extend``): the buffer must hold what
    appending each sample would, the oldest rows dropped the same way."""
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 5.0, 200))
    f = rng.normal(size=200)
    one, block = SampleBuffer(1, 2.0), SampleBuffer(1, 2.0)
    for ti, fi in zip(t, f):
        one.append(ti, fi)
    for start in range(0, 200, 20):
        block.extend(t[start:start + 20], f[start:start + 20])
    block.extend([], [])
    for a, b in zip(one.arrays(), block.arrays()):
        np.testing.assert_array_equal(a, b)
    assert one.dropped == block.dropped > 0
    with pytest.raises(ValueError, match='lengths'):
        block.extend([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match='value columns'):
        block.extend([1.0], [1.0], [2.0])
