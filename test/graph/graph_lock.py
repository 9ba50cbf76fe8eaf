"""The lock that lets the graph tier run as two pytest processes at once.

tools/dev.sh runs the graph tier in two lanes (WIND_SHAPER_GRAPH_LOCK names a lock file both
see). Most graph tests only need their own graph to work, but a few measure the field through
it: the designed experiment whose hidden effect the diagnosis must name, and the runs whose
errors are compared. A second graph sweeping on the same two cores disturbed those (a held-out
noise of 0.29 N per sample instead of 0.07-0.11 N, the hidden effect not named), so they run
inside ``graph_alone()``: the other lane (WIND_SHAPER_GRAPH_LANE=shared, each of its tests
holding the lock shared, test/graph/conftest.py) finishes the test it is in and waits. The
lane that measures is let in ahead of the other's next test (a turnstile lock), so it never
waits more than one test. Without the variable (one pytest process) nothing is locked.
"""
import contextlib
import fcntl
import os

LOCK = os.environ.get('WIND_SHAPER_GRAPH_LOCK')
SHARED_LANE = os.environ.get('WIND_SHAPER_GRAPH_LANE') == 'shared'


@contextlib.contextmanager
def held(mode, path=LOCK):
    """The graph lock (the file ``path``) held in ``mode`` (fcntl.LOCK_SH or LOCK_EX) for the
    block, taken through the turnstile (``path``.turnstile): a lane waiting for the exclusive
    lock keeps the shared lane's next test out. No ``path``: nothing is locked."""
    if not path:
        yield
        return
    with open(path + '.turnstile', 'a') as gate, open(path, 'a') as lock:
        fcntl.flock(gate, fcntl.LOCK_EX)
        try:
            fcntl.flock(lock, mode)
        finally:
            fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def graph_alone():
    """Context manager: while the block runs, no test of the shared graph lane runs (it waits
    for the one running to end). For what measures the field through the graph."""
    return held(fcntl.LOCK_EX)
