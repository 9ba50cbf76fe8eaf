"""The node runner's signal handler: safe when a second signal interrupts the first.

A Python signal handler runs between two bytecodes of the main thread, so a second SIGTERM or
SIGINT can run it again inside the first. A handler that takes a lock (threading.Event.set
does) then waits for itself forever: seen as a field_estimator that outlived its supervisor,
every thread asleep on a futex, the stack five handlers deep."""
import subprocess
import sys

import pytest

pytest.importorskip('rclpy')

# Re-enter the handler at every call it makes, as a signal landing there would.
REENTER = '''
import sys
from wind_shaper.ros import runner

depth = [0]

def reenter(frame, event, arg):
    if event in ('call', 'c_call') and depth[0] == 0:
        depth[0] += 1
        try:
            runner._request_stop(15, None)
        finally:
            depth[0] -= 1

def handler_under_signals():
    sys.setprofile(reenter)
    try:
        runner._request_stop(2, None)
    finally:
        sys.setprofile(None)

handler_under_signals()
print('handled', runner._stop.requested, flush=True)
'''


def test_the_stop_handler_survives_a_signal_inside_itself():
    try:
        done = subprocess.run([sys.executable, '-c', REENTER], capture_output=True, text=True,
                              timeout=20)
    except subprocess.TimeoutExpired:
        pytest.fail('the signal handler deadlocked when re-entered (it takes a lock)')
    assert done.returncode == 0 and 'handled True' in done.stdout, done.stderr


# A node run by the runner: it prints a line once spinning, then waits for signals.
IDLE_NODE = '''
from rclpy.node import Node
from wind_shaper.ros import runner

class Idle(Node):
    def __init__(self):
        super().__init__('runner_signal_test')
        self.create_timer(0.1, self.once)
        self._said = False

    def once(self):
        if not self._said:
            print('spinning', flush=True)
            self._said = True

raise SystemExit(runner.run(Idle))
'''


def test_sigusr1_prints_where_every_thread_of_a_running_node_waits(ros_env):
    """A node alive but not answering: `kill -USR1` shows where it waits, and it runs on."""
    import signal
    import time
    node = subprocess.Popen([sys.executable, '-c', IDLE_NODE], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ros_env)
    try:
        assert node.stdout.readline().strip() == 'spinning'
        node.send_signal(signal.SIGUSR1)
        time.sleep(0.5)
        assert node.poll() is None, 'SIGUSR1 ended the node'
        node.send_signal(signal.SIGTERM)
        _, err = node.communicate(timeout=20)
    finally:
        if node.poll() is None:
            node.kill()
    assert node.returncode == 0, err
    assert 'Current thread' in err and 'spin_until_future_complete' in err, err


# The same node, whose teardown hangs the way a node's did in the middleware (holding the GIL
# in a C call: here a sleep in destroy_node, which a Python-level watchdog could not interrupt
# either way).
HANGING_TEARDOWN = IDLE_NODE.replace('''    def once(self):''', '''    def destroy_node(self):
        import time
        time.sleep(60)

    def once(self):''')


def test_a_node_whose_teardown_hangs_still_exits_within_the_shutdown_limit(ros_env):
    """A stopped node exits within SHUTDOWN_LIMIT_S even when its teardown never returns, and
    says where it hung (an orphaned coordinator once spun in its teardown for minutes)."""
    import signal
    import time
    from wind_shaper.ros.runner import SHUTDOWN_LIMIT_S
    node = subprocess.Popen([sys.executable, '-c', HANGING_TEARDOWN], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ros_env)
    try:
        assert node.stdout.readline().strip() == 'spinning'
        node.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        _, err = node.communicate(timeout=SHUTDOWN_LIMIT_S + 20)
        took = time.monotonic() - t0
    except subprocess.TimeoutExpired:
        pytest.fail('the node hung in its teardown past the shutdown limit')
    finally:
        if node.poll() is None:
            node.kill()
    assert node.returncode == 1 and 'destroy_node' in err, err
    assert took < SHUTDOWN_LIMIT_S + 10, took
