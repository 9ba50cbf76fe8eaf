"""test/graph: the ``up`` fixture starts `wind-shaper up --sim` in the test's tmp_path."""
import pytest
from up_driver import Up


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
