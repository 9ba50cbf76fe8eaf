"""Loopback fixtures: every test must leave no thread of its own running."""
import threading
import time

import pytest
from waiting import wait_for as _wait_for


@pytest.fixture(autouse=True)
def no_leaked_threads():
    before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        leaked = [t for t in threading.enumerate() if t not in before and t.is_alive()]
        if not leaked:
            return
        time.sleep(0.02)
    pytest.fail(f'threads left running: {[t.name for t in leaked]}')


@pytest.fixture
def wait_for():
    """wait_for(predicate, timeout_s=3.0): poll until true or timeout, return the last value."""
    return _wait_for
