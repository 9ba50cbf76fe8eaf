"""test/graph: the ``up`` fixture starts `wind-shaper up --sim` in the test's tmp_path; in the
shared graph lane each test holds the graph lock shared (graph_lock.py)."""
import fcntl

import pytest
from graph_lock import SHARED_LANE, held
from up_driver import Up


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    # outermost: the wait for the lock is not counted in the test's time limit (pytest-timeout
    # times the protocol inside this) nor in its reported duration
    if not SHARED_LANE:
        yield
        return
    with held(fcntl.LOCK_SH):
        yield


@pytest.fixture
def up(ros_env, tmp_path):
    """``start(*args) -> Up``; every `wind-shaper up` still running at teardown is killed."""
    started = []

    def start(*args):
        u = Up(ros_env, tmp_path, *args)
        started.append(u)
        return u
    yield start
    for u in started:
        u.kill()
