"""The coordinator's feedback while a designed experiment runs, and its shutdown in the middle of
one: the iteration status (what `wind-shaper status` prints) says an experiment runs, with its
row and progress, instead of a stale 'idle'; a coordinator destroyed mid-experiment (Ctrl-C,
SIGTERM) ends the experiment's service callback without touching the destroyed node."""
import gc
import sys
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from wind_shaper_msgs.msg import IterationStatus  # noqa: E402

from test_coordinator import Graph, collect_request, setup, wait_until  # noqa: E402,F401

pytestmark = pytest.mark.ros


@pytest.fixture
def graph(ros_context, setup, tmp_path):   # noqa: F811 - the fixture of test_coordinator
    g = Graph(ros_context, setup, tmp_path)
    yield g
    g.close()


def test_the_iteration_status_says_an_experiment_runs_and_then_what_the_fans_do(graph, setup):
    graph.start_coordinator(sweep_duration_s=1.0)
    design, request = collect_request(setup, 'lhs:3')
    assert wait_until(lambda: graph.status() is not None)
    future = graph.call_async(graph.collect, request)
    assert wait_until(lambda: any(m.state == 'sweeping' for m in graph.experiment_statuses))
    seen = len(graph.statuses)
    # the status goes on at 2 Hz during the experiment, and says what runs
    assert wait_until(lambda: len(graph.statuses) >= seen + 2, timeout=5.0)
    s = graph.status()
    assert s.state == IterationStatus.STATE_COLLECTING, (s.state, s.message)
    assert s.state == 'collecting'
    assert 'experiment exp: sweep' in s.message and 'of 3' in s.message, s.message
    row = graph.experiment_statuses[-1].sweep
    assert np.allclose(s.pwm, design.commands[row]), (s.pwm, design.commands[row])
    assert 0.0 < s.progress < 1.0
    assert wait_until(future.done, timeout=40.0)
    assert future.result().success, future.result().message
    # once it is over, the status is the run's own again, with the fans off
    assert wait_until(lambda: graph.status().state != 'collecting'
                      and np.allclose(graph.status().pwm, 0.0), timeout=3.0)
    assert graph.status().state == IterationStatus.STATE_IDLE


@pytest.mark.parametrize('state', ['commanding', 'sweeping'])
def test_a_coordinator_destroyed_mid_experiment_raises_nothing_into_its_destroyed_node(
        graph, setup, state):
    """The runner shuts the executor down and destroys the node: the collect service's coroutine,
    left waiting (for the fans to settle, for the sweep service), is closed later (garbage
    collection) and its clean-up used the destroyed node (its status publishers, the wait's
    timer): rclpy's InvalidHandle, printed as an exception ignored at shutdown."""
    graph.start_coordinator(sweep_duration_s=5.0, settle_s=5.0)
    _, request = collect_request(setup, 'lhs:3')
    graph.call_async(graph.collect, request)
    assert wait_until(lambda: any(m.state == state for m in graph.experiment_statuses),
                      timeout=20.0)
    time.sleep(0.5)
    ignored = []
    previous = sys.unraisablehook
    sys.unraisablehook = lambda u: ignored.append(u)
    try:
        graph.stop_coordinator()
        for _ in range(3):
            gc.collect()
    finally:
        sys.unraisablehook = previous
    problems = [f'{type(u.exc_value).__name__}: {u.exc_value} in {u.object!r}' for u in ignored]
    assert not problems, problems
