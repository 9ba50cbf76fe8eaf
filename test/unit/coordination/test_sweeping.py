"""coordination.sweeping: a sweep's span, the figures of a peek, the early end of an adaptive
sweep and the watch loop, with plain asyncio stand-ins for the node's waits (no rclpy)."""
import asyncio
import math
from types import SimpleNamespace

import numpy as np
import pytest

from wind_shaper.coordination import CANCELLED, FAILED, IterationStopped
from wind_shaper.coordination.sweeping import (SweepJudge, discarded_text, peek_figures, required,
                                               sweep_span, watch_sweep)

KEY_POINTS = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [0.2, 0.2]])


def fake_plan(needed=(True, True, False, False), share=0.25):
    area = SimpleNamespace(disc_share=lambda radius: share, text=lambda: 'around LM1',
                           centres=np.array([[0.0, 0.0], [0.1, 0.0]]), reach=0.1)
    carried = np.full(len(needed), 0.5)

    def fuse(mean, std):   # as RegionPlan.fuse with a carried std of 0.5 N
        w1, w2 = 1 / np.asarray(std) ** 2, 1 / carried ** 2
        return mean, 1 / np.sqrt(w1 + w2)

    return SimpleNamespace(needed=np.array(needed), area=area, fuse=fuse)


def test_required_flags_are_empty_for_the_whole_area():
    assert required(None) == []
    assert required(fake_plan()) == [True, True, False, False]


def test_a_region_sweep_is_shorter_by_its_share_of_the_disc_but_never_below_the_minimum():
    whole = sweep_span(None, 20.0, 6.0, 0.4)
    assert whole.duration_s == 20.0 and whole.where == 'the whole area' and whole.region_x == ()
    region = sweep_span(fake_plan(share=0.5), 20.0, 6.0, 0.4)
    assert region.duration_s == pytest.approx(15.0)   # 1.5 x the share, with room to spare
    assert region.where == 'the region around LM1 (2 key points)'
    assert region.region_x == (0.0, 0.1) and region.region_y == (0.0, 0.0) and region.region_reach == 0.1
    assert sweep_span(fake_plan(share=0.05), 20.0, 6.0, 0.4).duration_s == 6.0
    assert sweep_span(fake_plan(share=0.9), 20.0, 6.0, 0.4).duration_s == 20.0


def test_peek_figures_count_the_key_points_passed_and_the_largest_std():
    positions = np.array([[0.0, 0.0], [0.1, 0.0]])
    coverage, max_std, rms_std = peek_figures(positions, True, [1, 1, 1, 1], [0.1, 0.3, 0.2, 0.2],
                                              KEY_POINTS, 0.03)
    assert coverage == pytest.approx(0.5) and max_std == pytest.approx(0.3)
    assert rms_std == pytest.approx(np.sqrt((0.01 + 0.09 + 0.04 + 0.04) / 4))
    coverage, max_std, rms_std = peek_figures(None, False, [], [], KEY_POINTS, 0.03)
    assert math.isnan(coverage) and math.isnan(max_std) and math.isnan(rms_std)   # nothing yet
    # a region sweep: its own key points only, and the std fused with what it carries over
    coverage, max_std, _ = peek_figures(positions, True, [1, 1, 1, 1], [0.1, 0.3, 0.2, 10.0],
                                        KEY_POINTS, 0.03, fake_plan())
    assert coverage == 1.0 and max_std == pytest.approx(1 / np.sqrt(1 / 10.0 ** 2 + 1 / 0.5 ** 2))


def test_a_sweep_is_good_enough_only_when_adaptive_long_enough_covered_and_sure():
    judge = SweepJudge(adaptive=True, min_s=6.0, std_max=0.1)
    assert judge.verdict(2, 5.0, 1.0, 0.05) == ''     # too early
    assert judge.verdict(2, 7.0, 0.9, 0.05) == ''     # a key point not passed yet
    assert judge.verdict(2, 7.0, 1.0, 0.2) == ''      # not sure enough
    text = judge.verdict(2, 7.04, 1.0, 0.05)
    assert text.startswith('iteration 2: the estimate is good enough after 7.0 s')
    assert 'coverage 100 %' in text and '0.050 N RMS <= 0.100 N' in text
    assert SweepJudge(False, 6.0, 0.1).verdict(2, 50.0, 1.0, 0.0) == ''
    # the RMS over the key points decides, as long as no key point is above twice the threshold
    assert judge.verdict(2, 7.0, 1.0, 0.15, 0.08).startswith('iteration 2: the estimate is good enough')
    assert judge.verdict(2, 7.0, 1.0, 0.15, 0.12) == ''   # the RMS too large
    assert judge.verdict(2, 7.0, 1.0, 0.25, 0.05) == ''   # one spot barely passed


class FakeWaits:
    """The node's waits on a clock that each wait moves on; ``cancel_at`` [s] cancels."""

    def __init__(self, clock, cancel_at=math.inf, ending=False):
        self.clock, self.cancel_at, self._ending = clock, cancel_at, ending
        self.waited = []

    def remaining(self, timeout_s):
        return timeout_s

    async def wait(self, future, timeout_s):
        self.waited.append(timeout_s)
        if self.clock.t + timeout_s >= self.cancel_at:
            return 'cancelled'
        self.clock.t += timeout_s
        await asyncio.sleep(0)
        return 'done' if future is not None and future.done() else 'timeout'

    def raise_for(self, reason, message):
        raise IterationStopped(CANCELLED if reason == 'cancelled' else FAILED, message or reason)

    def ending(self):
        return self._ending


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def watch(waits, clock, figures, judge, motion=None, duration=10.0):
    reports, warnings, infos = [], [], []
    queue = list(figures)

    async def peek():
        item = queue.pop(0) if queue else (0.5, 1.0)
        if isinstance(item, Exception):
            raise item
        return item

    def enough(elapsed, coverage, max_std):
        return judge.verdict(1, elapsed, coverage, max_std)

    result = asyncio.run(watch_sweep(waits, motion, duration, 1.0, peek, lambda c, s: reports.append((c, s)),
                                     enough, warn=warnings.append, info=infos.append, clock=clock))
    return result, reports, warnings, infos


def test_an_operator_sweep_runs_its_whole_duration_when_never_good_enough():
    clock = Clock()
    waits = FakeWaits(clock)
    result, reports, warnings, infos = watch(waits, clock, [], SweepJudge(True, 3.0, 0.1))
    assert result is False and not infos and clock.t == pytest.approx(10.0)
    assert len(reports) == 9   # a check each second, the last second waited out


def test_a_watched_sweep_ends_as_soon_as_the_estimate_is_good_enough():
    clock = Clock()
    figures = [(0.5, 1.0), (0.9, 0.3), (1.0, 0.2), (1.0, 0.05), (1.0, 0.05)]
    result, reports, warnings, infos = watch(FakeWaits(clock), clock, figures, SweepJudge(True, 3.0, 0.1))
    assert result is True and len(reports) == 4 and clock.t == pytest.approx(4.0)
    assert infos and 'good enough after 4.0 s' in infos[0]


def test_a_failed_peek_is_warned_about_and_the_sweep_goes_on_unless_it_is_ending():
    clock = Clock()
    figures = [IterationStopped(FAILED, 'no answer'), (1.0, 0.05), (1.0, 0.05)]
    result, reports, warnings, infos = watch(FakeWaits(clock), clock, figures, SweepJudge(True, 1.0, 0.1))
    assert result is True and len(warnings) == 1 and 'no answer' in warnings[0]
    assert 'the sweep goes on' in warnings[0]
    clock = Clock()
    with pytest.raises(IterationStopped):
        watch(FakeWaits(clock, ending=True), clock, [IterationStopped(FAILED, 'no answer')],
              SweepJudge(True, 1.0, 0.1))


def test_a_cancel_during_the_watch_raises():
    clock = Clock()
    with pytest.raises(IterationStopped) as stop:
        watch(FakeWaits(clock, cancel_at=2.5), clock, [], SweepJudge(True, 1.0, 0.1))
    assert stop.value.state == CANCELLED


def test_the_watch_ends_with_the_sweep_motion():
    clock = Clock()
    motion = SimpleNamespace(done=lambda: clock.t >= 3.0)
    result, reports, warnings, infos = watch(FakeWaits(clock), clock, [], SweepJudge(True, 1.0, 0.1),
                                             motion=motion)
    assert result is False and len(reports) == 2 and clock.t == pytest.approx(3.0)


def test_a_discarded_sweep_says_why_and_what_stays():
    text = discarded_text('the fans did not report', 'the run stays at iteration 4')
    assert text.startswith('sweep discarded: the fans did not report (fan_output restarted')
    assert text.endswith('; the run stays at iteration 4')
