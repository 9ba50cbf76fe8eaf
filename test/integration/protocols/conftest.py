"""Loopback fixtures: every test must leave no thread of its own running."""
import threading
import time

import pytest


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


def _wait_for(predicate, timeout_s=3.0, interval_s=0.01):
    """Poll predicate until true or timeout; returns its last value."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(interval_s)


@pytest.fixture
def wait_for():
    """wait_for(predicate, timeout_s=3.0): poll until true or timeout, return the last value."""
    return _wait_for
