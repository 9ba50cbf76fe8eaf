"""The graph lanes' lock (graph_lock.py): what measures waits for the other lane's running
test only, and keeps that lane's next test out until it is done. Threads stand in for the two
lanes' processes (each opens the lock files itself, as a process does)."""
import fcntl
import threading
import time

from graph_lock import held


def test_the_exclusive_block_waits_for_the_running_shared_test_and_keeps_the_next_one_out(tmp_path):
    path = str(tmp_path / 'graph.lock')
    events = []
    log = threading.Lock()

    def note(what):
        with log:
            events.append(what)

    def shared_lane():
        for k in range(3):
            with held(fcntl.LOCK_SH, path):
                note(f'shared {k} in')
                time.sleep(0.3)
                note(f'shared {k} out')

    lane = threading.Thread(target=shared_lane)
    lane.start()
    time.sleep(0.1)   # the shared lane's first test is running
    with held(fcntl.LOCK_EX, path):
        note('alone in')
        time.sleep(0.3)
        note('alone out')
    lane.join(10)
    assert not lane.is_alive()
    alone = events.index('alone in')
    # it came in right after the test that ran, before the shared lane's next one, and nothing
    # of the shared lane ran while it did
    assert events[:alone] == ['shared 0 in', 'shared 0 out'], events
    assert events[alone + 1] == 'alone out', events
    assert events[alone + 2:] == ['shared 1 in', 'shared 1 out', 'shared 2 in', 'shared 2 out']


def test_without_a_lock_file_nothing_waits():
    with held(fcntl.LOCK_EX, None), held(fcntl.LOCK_EX, None):
        pass
