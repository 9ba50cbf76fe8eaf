"""Running a node process: the Jazzy shutdown idiom in one place.

``run(NodeClass, args)`` initialises rclpy, builds the node, spins it on a single-threaded
executor (or the events executor for high-rate streams) until Ctrl-C / SIGTERM / external
shutdown, then destroys the node (so its ``destroy_node`` can make hardware safe) and shuts
rclpy down. A configuration error is printed as one clear line and exits with code 2.

No node uses rclpy's MultiThreadedExecutor: in Jazzy it spins hot while a subscription has
messages waiting (measured: 3.3 s of CPU in 3 s for a 500 Hz topic), and its threads then hold
the GIL so long that a reader thread in the same process published only 96 of ~850 samples.
Callbacks that wait (a sweep, a service call) are coroutines instead, so one thread serves all.

rclpy's own SIGINT handler is not installed: it shuts the context down at once, so a node's
``destroy_node`` (fans to safe, streams stopped) would run on a dead context and reader threads
would publish into it. Instead SIGINT and SIGTERM only set a flag (raising from a signal
handler can land inside a pybind11 call and come out as a RuntimeError); the main thread spins
in 0.2 s slices, sees the flag, and destroys the node while the context is still valid.

Each slice also beats the heart (``core.heartbeat``): when ``WIND_SHAPER_HEARTBEAT`` names a
file (the supervisor of ``wind-shaper up`` sets it), its modification time is set to now at most
every 0.5 s. A node whose executor thread is stuck (a callback that never returns, a publish
blocked forever in the middle layer) stops beating, and the supervisor restarts it.
"""
from __future__ import annotations

import faulthandler
import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from ..core.errors import WindShaperError
from ..core.heartbeat import Heartbeat


class _StopFlag:
    """Set from a signal handler: a plain attribute, no lock. (A threading.Event takes a lock
    in set(); a second signal landing while the first handler holds it deadlocks the process:
    seen as a field_estimator that outlived its supervisor, all threads asleep on futexes.)"""

    requested = False


_stop = _StopFlag()

#: Longest a node's shutdown may take before it is ended hard [s] (``wind-shaper up`` SIGKILLs a
#: node 5 s after its SIGINT; a node started alone has nobody to do that).
SHUTDOWN_LIMIT_S = 4.0


def _request_stop(signum, frame):
    # SIGINT and SIGTERM (e.g. from the supervisor) take the same clean path.
    _stop.requested = True


def run(node_cls, args=None, *, executor: str = 'single') -> int:
    """Run ``node_cls`` in this process; ``executor`` is 'single' or 'events'."""
    if executor not in ('single', 'events'):
        raise ValueError(f"executor must be 'single' or 'events', not {executor!r}")
    # `kill -USR1 <pid>` prints every thread's Python stack to stderr (the supervisor shows it
    # as the node's lines): where a node that is alive but does not answer is waiting
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    _stop.requested = False
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)
    node = ex = None
    code = 0
    try:
        node = node_cls()
        if executor == 'events':
            from rclpy.experimental import EventsExecutor
            ex = EventsExecutor()
        else:
            ex = SingleThreadedExecutor()
        ex.add_node(node)
        # spin() waits in C++ and would never let the Python signal handlers run.
        never = Future()
        heart = Heartbeat.from_environment()
        while rclpy.ok() and not _stop.requested:
            heart.beat()
            ex.spin_until_future_complete(never, timeout_sec=0.2)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except WindShaperError as exc:
        print(f'{node_cls.__name__}: error: {exc}', file=sys.stderr)
        code = 2
    finally:
        # A clean shutdown takes well under a second; one that hangs in the middleware (seen: a
        # coordinator orphaned by a SIGKILLed supervisor, stuck in Fast DDS's participant
        # teardown at 100 % CPU for minutes) is ended by faulthandler's C watchdog, which needs
        # no GIL: it prints every thread's stack and exits with code 1.
        faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
        try:
            if ex is not None:
                ex.shutdown(timeout_sec=2.0)  # let running callbacks finish before the node goes
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            faulthandler.cancel_dump_traceback_later()
    return code
