"""coordination.state: the coordinator's bookkeeping (commands in force, read-back, the
iteration's state and progress, the status and diagnostics fields, the words of a refusal and a
cancel) without rclpy, on a stand-in run and a clock the test moves."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from wind_shaper.coordination import COMMANDING, FAILED, IDLE, PROGRESS, SWEEPING, FanWatch
from wind_shaper.coordination.state import COLLECTING, CoordinatorState

FANS = ['LM1', 'HM1']


class Clock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def fake_run(command=None):
    return SimpleNamespace(command=command, U=np.array([0.3, 0.4]), k=3, last_completed=2,
                           target_spec='parabolic', last_rmse=0.25, model='Prior()',
                           store=SimpleNamespace(folder='runs/r'))


@pytest.fixture
def clock():
    return Clock()


def test_the_commands_in_force_are_the_runs_until_an_experiment_holds_its_own(clock):
    run = fake_run()
    book = CoordinatorState(run, 20.0, clock)
    assert book.command_in_force() is None   # a new run: nothing commanded yet
    run.command = np.array([0.5, 0.6])
    assert np.allclose(book.command_in_force(), [0.5, 0.6])
    held = [0.1, 0.2]
    book.hold(held)
    held[0] = 0.9                              # the held row is a copy
    assert np.allclose(book.command_in_force(), [0.1, 0.2])
    book.held = None
    assert np.allclose(book.command_in_force(), [0.5, 0.6])


def test_only_a_read_back_after_the_wait_began_counts_as_applied(clock):
    book = CoordinatorState(fake_run(), 20.0, clock)
    U = np.array([0.5, 0.5])
    assert not book.applied_since(0.0, U, 0.01)
    book.saw_applied(np.array([0.5, 0.505]))
    assert book.applied_since(100.0, U, 0.01)
    assert not book.applied_since(100.5, U, 0.01)   # kept from before the wait: proves nothing
    assert not book.applied_since(100.0, U, 0.001)  # off by more than the tolerance
    text = book.not_applied_text(U, 10.0, 0.005, '/wind_shaper/fans/applied')
    assert '[0.5, 0.505]' in text and 'within 10 s' in text and '/wind_shaper/fans/applied' in text
    assert 'last read-back: nothing' in CoordinatorState(fake_run(), 20.0, clock).not_applied_text(
        U, 10.0, 0.005, 'topic')


def test_a_sweep_being_watched_sees_every_read_back(clock):
    book = CoordinatorState(fake_run(), 20.0, clock)
    book.fan_watch = watch = FanWatch(clock(), np.array([0.5, 0.5]), 0.01)
    clock.t += 1.0
    book.saw_applied(np.array([0.5, 0.7]))
    assert 'HM1 at 0.700 instead of 0.500' in watch.problem(clock(), 2.0, FANS)


def test_entering_a_state_sets_its_progress_and_sweeping_moves_on_with_the_time(clock):
    book = CoordinatorState(fake_run(), 20.0, clock)
    book.begin(0.0)                            # <= 0: the default sweep length
    assert book.running and book.sweep_duration_s == 20.0
    book.enter(COMMANDING, 'iteration 3: commanding the fans')
    assert book.progress == PROGRESS[COMMANDING] and book.message.startswith('iteration 3')
    book.enter('made-up state', '')
    assert book.progress == PROGRESS[COMMANDING]   # a state without a share keeps the progress
    book.enter(SWEEPING, 'sweeping')
    clock.t += 10.0                            # half the sweep
    status = book.status_fields(FANS)
    span = PROGRESS['estimating'] - PROGRESS['sweeping']
    assert status['progress'] == pytest.approx(PROGRESS['sweeping'] + 0.5 * span)
    clock.t += 100.0                           # overdue: never reaches the next state's share
    assert book.status_fields(FANS)['progress'] < PROGRESS['estimating']
    book.begin(5.0)
    assert book.sweep_duration_s == 5.0
    book.end()
    assert not book.running and not book.counting


def test_the_status_names_the_run_and_the_commands_in_force(clock):
    run = fake_run()
    book = CoordinatorState(run, 20.0, clock)
    status = book.status_fields(FANS)
    assert status['iteration'] == 2 and status['state'] == IDLE and status['target'] == 'parabolic'
    assert status['pwm'] == [0.3, 0.4]         # nothing in force yet: the run's next commands
    assert math.isnan(status['coverage']) and math.isnan(status['max_std'])
    assert status['rmse'] == 0.25 and status['run_folder'] == 'runs/r' and status['fan_names'] == FANS
    book.hold([0.0, 0.0])
    assert book.status_fields(FANS)['pwm'] == [0.0, 0.0]


def test_a_running_experiment_speaks_through_the_iteration_status(clock):
    book = CoordinatorState(fake_run(), 20.0, clock)
    book.samples, book.max_std = 7, 0.2
    experiment = SimpleNamespace(status_text=lambda: 'exp: sweep 2 of 4 (lhs 2), sweeping',
                                 message='sweeping', progress=0.4, samples=55, coverage=0.8)
    status = book.status_fields(FANS, experiment)
    assert status['state'] == COLLECTING
    assert status['message'] == 'experiment exp: sweep 2 of 4 (lhs 2), sweeping: sweeping'
    assert status['progress'] == pytest.approx(0.4) and status['samples'] == 55
    assert status['coverage'] == pytest.approx(0.8) and math.isnan(status['max_std'])
    experiment.message = ''
    assert book.status_fields(FANS, experiment)['message'] == 'experiment exp: sweep 2 of 4 (lhs 2), sweeping'


def test_pose_counting_and_a_new_sweep(clock):
    book = CoordinatorState(fake_run(), 20.0, clock)
    assert not book.count_pose() and book.samples == 0
    book.counting = True
    assert book.count_pose() and book.count_pose() and book.samples == 2
    book.coverage, book.max_std = 0.5, 0.1
    book.sweep_begun()
    assert book.samples == 0 and math.isnan(book.coverage) and math.isnan(book.max_std)
    book.start_iteration(4)
    assert book.status_k == 4


def test_a_busy_coordinator_says_what_runs_and_how_to_cancel_it(clock):
    book = CoordinatorState(fake_run(), 20.0, clock)
    assert book.busy('/wind_shaper/cancel_iteration') == ''
    book.begin(0.0)
    book.enter(SWEEPING, '')
    wait = 'wait for it or cancel it (`wind-shaper cancel`, or call /c)'
    assert book.busy('/c') == f'an iteration is running (k=3, sweeping): {wait}'
    assert book.busy('/c', holding=True).startswith('a held-plate point is being recorded')
    assert book.busy('/c', 'exp: starting, idle') == f'an experiment is running (exp: starting, idle): {wait}'
    assert book.cancel_text().startswith('cancelling iteration 3 (sweeping)')
    assert 'the fans go off' in book.cancel_text('exp: sweep 1 of 2 (a), sweeping')


def test_the_diagnostics_warn_after_a_failed_iteration(clock):
    run = fake_run()
    book = CoordinatorState(run, 20.0, clock)
    failed, message, values = book.diagnostics(FANS, False)
    assert not failed and message == IDLE and values['commands'] == 'none yet'
    assert values['next_iteration'] == 3 and values['prior'] == "'Prior()'"
    run.command = np.array([0.25, 0.5])
    book.enter(FAILED, 'the sweep failed')
    book.stopped(FAILED)
    failed, message, values = book.diagnostics(FANS, True)
    assert failed and message == 'failed: the sweep failed'
    assert values['state'] == COLLECTING and values['commands'] == 'LM1=0.2500 HM1=0.5000'
    book.stopped('cancelled')
    assert not book.diagnostics(FANS, False)[0]
