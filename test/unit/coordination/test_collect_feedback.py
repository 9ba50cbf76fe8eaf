"""coordination.collect: what a designed experiment's status says while it runs (rows, states,
progress, the live coverage) and the answer of a collect request, without rclpy."""
import math

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination import CHECKING, COMMANDING, SWEEPING, Experiment
from wind_shaper.coordination.collect import (ROW_PROGRESS, ExperimentFeedback, collect_answer,
                                              collect_time_limit)
from wind_shaper.experiment import make_design
from wind_shaper.storage import FLAGGED, PENDING, STORED


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


class Clock:
    t = 50.0

    def __call__(self):
        return self.t


def open_experiment(setup, root):
    b = setup.shaping.bounds
    d = make_design('lhs:4', setup.geometry.fans, b.u_min, b.u_max, seed=0)
    return Experiment.open(setup, root, 'exp', d.fan_names, d.commands, d.labels, 'lhs:4')


def test_before_the_table_is_read_the_status_names_the_experiment_only():
    fb = ExperimentFeedback(Clock())
    fb.start('exp')
    assert fb.status_text() == 'exp: starting, idle' and fb.where(2) == 'row 2'
    fields = fb.status_fields(20.0)
    assert fields == dict(name='exp', state='idle', sweep=-1, attempt=0, message='', samples=0)
    assert fb.progress == 0.0 and math.isnan(fb.coverage)


def test_the_progress_counts_rows_done_and_the_time_of_the_row_being_swept(setup, tmp_path):
    clock = Clock()
    exp = open_experiment(setup, tmp_path)
    fb = ExperimentFeedback(clock)
    fb.start('exp')
    fb.opened(exp)
    fb.at_row(1, 0)
    fb.set_state(COMMANDING, 'sweep 2 of 4: commanding the fans')
    fields = fb.status_fields(20.0)
    assert fields['n_sweeps'] == 4 and fields['stored'] == 0 and fields['flagged'] == 0
    assert fields['label'] == exp.design.labels[1]
    assert np.allclose(fields['pwm'], exp.design.commands[1])
    assert fields['progress'] == pytest.approx(ROW_PROGRESS[COMMANDING] / 4) == fb.progress
    assert fields['coverage'] == 0.0 and fields['run_folder'] == str(exp.folder)
    assert fb.status_text() == f'exp: sweep 2 of 4 ({exp.design.labels[1]}), commanding'
    fb.set_state(SWEEPING, '')
    clock.t += 10.0   # half of a 20 s sweep
    assert fb.status_fields(20.0)['progress'] == pytest.approx((0.1 + 0.8 * 0.5) / 4)
    clock.t += 100.0  # overdue: the row never counts as done while sweeping
    assert fb.status_fields(20.0)['progress'] < (ROW_PROGRESS[CHECKING] + 0.01) / 4 + 1e-9
    fb.set_state('done', 'all stored')
    assert fb.status_fields(20.0)['progress'] == pytest.approx(1 / 4)


def test_poses_count_towards_the_coverage_only_while_sweeping_and_a_new_row_starts_afresh(setup, tmp_path):
    exp = open_experiment(setup, tmp_path)
    fb = ExperimentFeedback(Clock())
    fb.start('exp')
    fb.opened(exp)
    kp = exp.store.plan.key_points
    fb.set_state(COMMANDING, '')
    fb.on_pose(*kp[0])
    assert fb.samples == 0 and fb.coverage == 0.0
    fb.set_state(SWEEPING, '')
    fb.on_pose(*kp[0])
    assert fb.samples == 1 and 0.0 < fb.coverage < 0.1
    for p in kp:
        fb.on_pose(*p)
    assert fb.samples == 1 + len(kp) and fb.coverage == 1.0
    fb.at_row(0, 2)    # a re-sweep of the same row pools its coverage
    assert fb.samples == 1 + len(kp) and fb.coverage == 1.0
    fb.at_row(1, 1)    # a new row starts again
    assert fb.samples == 0 and fb.coverage == 0.0


def test_a_request_is_limited_by_its_own_timeout_or_by_its_rows():
    assert collect_time_limit(60.0, 30, 7, 300.0) == 60.0
    assert collect_time_limit(0.0, 28, 7, 300.0) == 4 * 300.0
    assert collect_time_limit(0.0, 0, 0, 300.0) == 300.0   # at least one row


def test_the_answer_succeeds_only_when_done_with_every_row_stored(setup, tmp_path):
    exp = open_experiment(setup, tmp_path)
    states = [STORED, STORED, FLAGGED, PENDING]
    answer = collect_answer('done', '', exp, states, [1.0, 0.9, float('inf'), float('nan')], '2 of 4')
    assert not answer['success'] and answer['stored'] == 2 and answer['outcome'] == states
    assert answer['coverage'][:2] == [1.0, 0.9] and all(math.isnan(c) for c in answer['coverage'][2:])
    assert answer['message'] == '2 of 4; the fans are off' and answer['labels'] == list(exp.design.labels)
    done = collect_answer('done', '', exp, [STORED] * 4, [1.0] * 4, 'all')
    assert done['success'] and done['run_folder'] == str(exp.folder)
    cancelled = collect_answer('cancelled', 'experiment cancelled: by you; ', exp, [STORED] * 4,
                               [1.0] * 4, 'all')
    assert not cancelled['success'] and cancelled['message'].startswith('experiment cancelled: by you; all')
