"""Running a node process: the Jazzy shutdown idiom in one place.

``run(NodeClass, args)`` initialises rclpy, builds the node, spins it on a multi-threaded
executor (or the events executor for high-rate streams) until Ctrl-C / SIGTERM / external
shutdown, then destroys the node (so its ``destroy_node`` can make hardware safe) and shuts
rclpy down. A configuration error is printed as one clear line and exits with code 2.
"""
from __future__ import annotations

import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

from ..core.errors import WindShaperError


def _sigterm_as_interrupt(signum, frame):
    # SIGTERM (e.g. from the supervisor) takes the same clean path as Ctrl-C.
    raise KeyboardInterrupt


def run(node_cls, args=None, *, executor: str = 'multi', threads: int = 4) -> int:
    rclpy.init(args=args)
    signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    node = None
    code = 0
    try:
        node = node_cls()
        if executor == 'events':
            from rclpy.experimental import EventsExecutor
            ex = EventsExecutor()
        else:
            ex = MultiThreadedExecutor(num_threads=threads)
        ex.add_node(node)
        if executor == 'events':
            # EventsExecutor.spin() stays in C++ and never lets the Python SIGINT/SIGTERM
            # handlers run: spin in slices of 0.2 s instead.
            from rclpy.task import Future
            never = Future()
            while rclpy.ok():
                ex.spin_until_future_complete(never, timeout_sec=0.2)
        else:
            ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except WindShaperError as exc:
        print(f'{node_cls.__name__}: error: {exc}', file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
