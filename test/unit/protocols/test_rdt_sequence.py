"""RdtSequenceTracker: exact counts on crafted sequences and against a reference model."""
import random

import pytest

from wind_shaper.protocols.errors import ProtocolConfigError
from wind_shaper.protocols.netft import RdtSequenceTracker, SequenceVerdict as V

TOP = 2**32


def run(seqs, **kw):
    tr = RdtSequenceTracker(**kw)
    verdicts = [tr.observe(s % TOP) for s in seqs]
    return tr, verdicts


def test_in_order_stream_loses_nothing():
    tr, v = run(range(100, 200))
    s = tr.stats
    assert (s.received, s.accepted, s.lost, s.out_of_order, s.duplicates) == (100, 100, 0, 0, 0)
    assert v[0] is V.FIRST and set(v[1:]) == {V.IN_ORDER}


def test_gap_counts_every_skipped_number():
    tr, v = run([1, 2, 5, 6, 10])
    assert tr.stats.lost == 2 + 3
    assert tr.stats.accepted == 5


def test_reorder_that_fills_a_gap_uncounts_the_loss_and_is_dropped():
    tr, v = run([1, 3, 2, 4])
    s = tr.stats
    assert v == [V.FIRST, V.IN_ORDER, V.OUT_OF_ORDER, V.IN_ORDER]
    assert (s.lost, s.out_of_order, s.accepted) == (0, 1, 3)


def test_reorder_can_be_used_on_request():
    tr, _ = run([1, 3, 2], use_out_of_order=True)
    assert tr.stats.accepted == 3


def test_duplicates_of_newest_and_of_older_records():
    tr, v = run([1, 2, 2, 1, 3, 1])
    s = tr.stats
    assert v == [V.FIRST, V.IN_ORDER, V.DUPLICATE, V.DUPLICATE, V.IN_ORDER, V.DUPLICATE]
    assert (s.duplicates, s.out_of_order, s.lost, s.accepted) == (3, 0, 0, 3)


def test_duplicate_of_a_filled_gap_is_a_duplicate_not_a_second_fill():
    tr, v = run([1, 3, 2, 2])
    s = tr.stats
    assert v[-1] is V.DUPLICATE
    assert (s.lost, s.out_of_order, s.duplicates) == (0, 1, 1)


def test_wraparound_at_2_to_the_32_is_in_order():
    tr, v = run([TOP - 3, TOP - 2, TOP - 1, 0, 1, 2])
    s = tr.stats
    assert (s.lost, s.out_of_order, s.duplicates, s.resyncs) == (0, 0, 0, 0)
    assert v[3] is V.IN_ORDER


def test_gap_and_reorder_across_the_wrap():
    tr, v = run([TOP - 2, TOP - 1, 1, 2])            # 0 missing
    assert tr.stats.lost == 1
    tr.observe(0)                                    # arrives late, across the wrap
    assert tr.stats.lost == 0 and tr.stats.out_of_order == 1
    tr2, _ = run([TOP - 1, 2, 0, 1, TOP - 1])
    s = tr2.stats
    assert (s.lost, s.out_of_order, s.duplicates) == (0, 2, 1)


def test_record_from_before_the_first_one_is_out_of_order_but_was_never_lost():
    tr, v = run([10, 9, 11])
    s = tr.stats
    assert v[1] is V.OUT_OF_ORDER
    assert (s.lost, s.out_of_order) == (0, 1)


def test_loss_is_final_once_the_number_leaves_the_window():
    tr, v = run([101, 120, 105], window=8)
    s = tr.stats
    assert v[-1] is V.STALE
    assert (s.lost, s.stale, s.out_of_order, s.accepted) == (18, 1, 1, 2)


def test_jump_larger_than_the_window_then_a_reorder_inside_it():
    tr, _ = run([1, 100, 95, 99], window=8)
    s = tr.stats
    assert s.lost == 98 - 2 and s.out_of_order == 2


def test_a_stream_numbered_from_1_again_is_a_restart_however_short_the_old_one():
    # the old stream's last records arrived after the start request was sent again (its
    # restart_stream()), so the newest is far ahead when the new stream's first records come
    tr, v = run([3000, 3001, 1, 2, 3], max_backstep=1 << 16, window=1024)
    s = tr.stats
    assert v[2] is V.RESYNC and v[3:] == [V.IN_ORDER, V.IN_ORDER]
    assert (s.resyncs, s.stale, s.accepted) == (1, 0, 5)


def test_large_backward_jump_is_a_restart():
    tr, v = run([1_000_000, 1_000_001, 5, 6], max_backstep=1000, window=64)
    s = tr.stats
    assert v[2] is V.RESYNC and s.resyncs == 1
    assert (s.lost, s.accepted) == (0, 4)


def test_reset_forgets_everything():
    tr, _ = run([1, 5, 3])
    tr.reset()
    assert tr.newest is None and tr.stats.received == 0
    assert tr.observe(2) is V.FIRST


@pytest.mark.parametrize('kw', [dict(window=0), dict(window=1.5), dict(window=100, max_backstep=50),
                                dict(max_backstep=2**31)])
def test_bad_parameters(kw):
    with pytest.raises(ProtocolConfigError):
        RdtSequenceTracker(**kw)


def test_sequence_outside_uint32_is_refused():
    with pytest.raises(ProtocolConfigError):
        RdtSequenceTracker().observe(TOP)


def reference_counts(arrivals):
    """Exact counts when no record is displaced by a window or more: lost = numbers between the
    first and the newest never received; out of order = first arrivals older than the newest."""
    seen, newest, ooo, dup = set(), None, 0, 0
    first = arrivals[0]
    for s in arrivals:
        if s in seen:
            dup += 1
            continue
        if newest is not None and s < newest:
            ooo += 1
        seen.add(s)
        newest = s if newest is None else max(newest, s)
    lost = sum(1 for s in range(first, newest) if s not in seen)
    return lost, ooo, dup


@pytest.mark.parametrize('seed', range(20))
def test_random_drops_reorders_duplicates_match_the_reference(seed):
    rng = random.Random(seed)
    start = rng.choice([0, 1000, TOP - 500])
    stream = [start + i for i in range(2000) if rng.random() > 0.05]       # drops
    for _ in range(150):                                                  # local reorders
        i = rng.randrange(len(stream) - 10)
        j = i + rng.randrange(1, 10)
        stream[i], stream[j] = stream[j], stream[i]
    for _ in range(40):                                                   # duplicates
        i = rng.randrange(len(stream))
        stream.insert(min(len(stream), i + rng.randrange(0, 20)), stream[i])
    tr, _ = run(stream, window=64)
    lost, ooo, dup = reference_counts(stream)
    s = tr.stats
    assert (s.lost, s.out_of_order, s.duplicates, s.stale) == (lost, ooo, dup, 0)
    assert s.received == len(stream)
    assert s.accepted == len(set(stream)) - ooo


def test_restart_stream_takes_a_sensor_that_counts_from_one_again_without_stale_records():
    tr, v = run([20_000, 20_001])
    tr.restart_stream()                 # the start request was sent again after a silence
    assert [tr.observe(s) for s in (1, 2, 3)] == [V.FIRST, V.IN_ORDER, V.IN_ORDER]
    s = tr.stats
    assert (s.accepted, s.stale, s.resyncs, s.lost) == (5, 0, 1, 0)
