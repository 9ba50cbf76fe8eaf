"""Waiting inside a node's coroutine callbacks without blocking its executor.

A service callback that drives a long procedure (the coordinator's iteration) awaits timers,
other services and conditions on topics. ``Waits`` gives it three awaitables that all honour one
cancel request: ``wait`` (until a future is done, a condition holds, a timeout passes or a cancel
comes), ``call`` (a service call with a timeout, resent while unanswered when it is idempotent)
and ``poke`` (re-check the condition after a message arrived). Failures raise the caller's own
exception, built by ``stop(state, message)`` with state 'failed' or 'cancelled'.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable

from rclpy.exceptions import InvalidHandle
from rclpy.task import Future

#: Shortest interval between resends of an unanswered idempotent request [s].
RESEND_MIN_S = 2.5


class Waits:
    """Awaitable waits for ``node``'s coroutines; timers run in ``callback_group``. ``deadline``
    (time.monotonic() [s]) bounds every wait; ``describe()`` names what is going on for messages
    ('cancelled while sweeping'), ``procedure`` what times out ('the iteration timed out')."""

    def __init__(self, node, callback_group, stop: Callable[[str, str], Exception],
                 describe: Callable[[], str] = lambda: 'waiting', procedure: str = 'the procedure'):
        self._node, self._group, self._stop, self._describe = node, callback_group, stop, describe
        self._procedure = procedure
        self._lock = threading.Lock()
        self._cancel = False
        self._hooks: set = set()
        self._condition: Callable[[], None] | None = None
        self.deadline = math.inf

    # -- cancel -----------------------------------------------------------------------------------------
    def start(self, timeout_s: float) -> None:
        """A new procedure: no cancel pending, every wait ends by now + timeout_s."""
        with self._lock:
            self._cancel = False
        self.deadline = time.monotonic() + timeout_s

    def cancel(self) -> None:
        with self._lock:
            self._cancel = True
            hooks = list(self._hooks)
        for hook in hooks:
            hook()

    @property
    def cancelled(self) -> bool:
        return self._cancel

    # -- waiting ----------------------------------------------------------------------------------------
    def remaining(self, timeout_s: float) -> float:
        """``timeout_s`` [s], cut at the deadline."""
        return max(min(timeout_s, self.deadline - time.monotonic()), 0.0)

    def poke(self) -> None:
        """Something the waited-for condition depends on changed (a message arrived)."""
        check = self._condition
        if check is not None:
            check()

    async def wait(self, future: Future | None, timeout_s: float, *,
                   until: Callable[[float], bool] | None = None, cancellable: bool = True) -> str:
        """'done' when ``future`` is done or ``until(since)`` holds at a ``poke`` (``since``:
        time.monotonic() when the wait began), 'timeout' after ``timeout_s`` [s], 'cancelled' on
        a cancel request."""
        gate = Future()
        gate_lock = threading.Lock()

        def open_gate(reason: str) -> None:
            with gate_lock:
                if gate.done():
                    return
                gate.set_result(reason)
            executor = self._node.executor
            if executor is not None:
                executor.wake()

        since = time.monotonic()
        timer = self._node.create_timer(max(timeout_s, 1e-3), lambda: open_gate('timeout'),
                                        callback_group=self._group)
        if cancellable:
            hook = lambda: open_gate('cancelled')  # noqa: E731
            with self._lock:
                self._hooks.add(hook)
                if self._cancel:
                    open_gate('cancelled')
        if future is not None:
            future.add_done_callback(lambda _f: open_gate('done'))
        if until is not None:
            self._condition = lambda: open_gate('done') if until(since) else None
        try:
            return await gate
        finally:
            if until is not None:
                self._condition = None
            if cancellable:
                with self._lock:
                    self._hooks.discard(hook)
            try:
                timer.cancel()
                self._node.destroy_timer(timer)
            except InvalidHandle:
                # the node was destroyed while this wait was pending (a shutdown): its timers
                # went with it, and the coroutine is being closed, nothing more to free
                pass

    def raise_for(self, reason: str, timeout_message: str) -> None:
        """Turn a wait's outcome other than 'done' into the caller's exception."""
        if reason == 'cancelled':
            raise self._stop('cancelled', f'cancelled while {self._describe()}')
        if time.monotonic() >= self.deadline - 1e-3:
            raise self._stop('failed', f'{self._procedure} timed out while {self._describe()}')
        raise self._stop('failed', timeout_message)

    def ending(self) -> bool:
        """True once a cancel is requested or the deadline has passed."""
        return self._cancel or time.monotonic() >= self.deadline

    def check(self) -> None:
        """Between steps: raise on a cancel request or a passed deadline."""
        if self._cancel:
            raise self._stop('cancelled', f'cancelled after {self._describe()}')
        if time.monotonic() >= self.deadline:
            raise self._stop('failed', f'{self._procedure} timed out after {self._describe()}')

    async def wait_ready(self, client, what: str, ready_timeout_s: float) -> None:
        """Return once ``client``'s service is there; raise if it is not within
        ``ready_timeout_s`` [s], on a cancel, or at the deadline."""
        if client.service_is_ready():
            return
        give_up = min(time.monotonic() + ready_timeout_s, self.deadline)
        while not client.service_is_ready() and time.monotonic() < give_up:
            if await self.wait(None, 0.1) == 'cancelled':
                raise self._stop('cancelled', f'cancelled while waiting for {what}')
        if not client.service_is_ready():
            self.check()
            raise self._stop('failed', f'no {client.srv_name} service within '
                                       f'{ready_timeout_s:g} s: is {what} running?')

    async def call(self, client, request, what: str, timeout_s: float, *, ready_timeout_s: float,
                   resend: bool = False):
        """Call a service and return its response; a service that is not there within
        ``ready_timeout_s``, no answer within ``timeout_s`` [s] or a cancel raises. ``resend``
        (idempotent calls only): while no answer came the request goes out again every
        max(RESEND_MIN_S, timeout_s / 4), for a server restarted in the meantime never saw the
        earlier one (DDS drops a request sent before the server was matched)."""
        await self.wait_ready(client, what, ready_timeout_s)
        every = max(RESEND_MIN_S, timeout_s / 4) if resend else timeout_s
        give_up = time.monotonic() + self.remaining(timeout_s)
        future = client.call_async(request)
        reason = await self.wait(future, min(every, give_up - time.monotonic()))
        while reason == 'timeout' and time.monotonic() < give_up - 1e-3:
            client.remove_pending_request(future)
            self._node.get_logger().warning(f'{what} did not answer yet: asking again (a restarted '
                                            f'{what} never saw the earlier request)',
                                            throttle_duration_sec=5.0)
            future = client.call_async(request)
            reason = await self.wait(future, min(every, give_up - time.monotonic()))
        if reason != 'done':
            client.remove_pending_request(future)
            self.raise_for(reason, f'{what} did not answer within {timeout_s:g} s')
        return future.result()


__all__ = ['Waits', 'RESEND_MIN_S']


def in_thread(node, fn: Callable, *args, name: str = 'wind_shaper-work') -> Future:
    """Run ``fn(*args)`` in a thread of its own and return a Future of its result (or of the
    exception it raised) that a coroutine callback of ``node`` can await: parsing, writing a
    large folder or fitting then never holds up the executor, so other services, timers and
    topics (a cancel, the status, the command republish) go on meanwhile. The thread cannot be
    stopped: a caller that stops waiting leaves it to finish and drops its result."""
    future = Future()

    def work():
        try:
            result = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting coroutine
            future.set_exception(exc)
        else:
            future.set_result(result)
        executor = node.executor
        if executor is not None:
            executor.wake()

    threading.Thread(target=work, name=name, daemon=True).start()
    return future
