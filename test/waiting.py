"""Polling for the node and loopback tests: wait until a condition holds, bounded (test/ is on
the import path: pytest puts the folder of test/conftest.py there)."""
import time


def wait_for(predicate, timeout_s=3.0, interval_s=0.01):
    """Poll ``predicate`` every ``interval_s`` [s] until it is true or ``timeout_s`` [s] pass;
    return its last value."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(interval_s)
