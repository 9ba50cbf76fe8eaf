"""A sweep's field estimate computed in a process of its own (``EstimateWorker``).

A node that pairs the streams and fits the GP on its executor thread takes no samples, answers
no call and lets its heartbeat age until the estimate is done: on a busy machine a long
estimate (four sweeps' worth of samples, several seconds) was once taken for a hung node and
killed. A thread of the node's own process is no cure: it shares the interpreter lock with the
executor, and the executor's answers came 10-20 s late beside it. The worker is one child
process, started once (``spawn``: forking a process that runs DDS threads is unsafe) and
reused; the node waits for its answer in a thread, so its executor goes on meanwhile. A worker
that dies is replaced at the next estimate, and the estimate it was computing fails with the
reason.

Inputs and outputs are plain arrays and dataclasses (pickled): force and pose streams [s, N,
m], commands [fraction], key points [m, tunnel frame].
"""
from __future__ import annotations

import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

import numpy as np

from ..core.errors import WindShaperError
from .align import align_sweep


@dataclass(frozen=True)
class StreamSnapshot:
    """What a sweep collected so far: force stamps and values (F,) [s, N], pose stamps and
    plate centre (P,) [s, m], the commands in force (n_fans,) [fraction], the sweep's start [s]."""

    force_t: np.ndarray
    force: np.ndarray
    pose_t: np.ndarray
    pose_x: np.ndarray
    pose_y: np.ndarray
    pwm: np.ndarray
    t0: float


@dataclass(frozen=True)
class EstimateOutcome:
    """The paired sweep (None when the streams could not be paired), the estimate (None when
    refused) and the reason it was refused (None when it was not); ``check``: with a peek, the
    coverage check of the required key points (the estimate itself asks for none, so that the
    field so far exists for the live view)."""

    sweep: object
    estimate: object
    error: WindShaperError | None
    check: WindShaperError | None = None


def align_and_estimate(estimator, key_points, streams: StreamSnapshot, required=None, reuse=None,
                       peek: bool = False) -> EstimateOutcome:
    """Pair ``streams`` into a sweep and estimate the field at ``key_points`` with
    ``estimator`` (``FieldEstimator``; ``required`` and ``reuse`` as its ``estimate`` takes
    them). With ``peek`` the estimate requires no key point and ``required`` is checked apart.
    Errors a lab can act on come back in the outcome, not raised."""
    sweep = None
    try:
        sweep = align_sweep(streams.force_t, streams.force, streams.pose_t, streams.pose_x,
                            streams.pose_y, streams.pwm, t0=streams.t0)
        if not peek:
            return EstimateOutcome(sweep, estimator.estimate(sweep, key_points, required=required,
                                                             reuse=reuse), None)
        est = estimator.estimate(sweep, key_points, required=np.zeros(len(key_points), dtype=bool),
                                 reuse=reuse)
    except WindShaperError as exc:
        return EstimateOutcome(sweep, None, exc)
    try:
        estimator.check_coverage(sweep, key_points, required=required)
    except WindShaperError as exc:
        return EstimateOutcome(sweep, est, None, exc)
    return EstimateOutcome(sweep, est, None)


def _ready() -> bool:
    return True


def _init_worker(parent: int) -> None:
    """In the worker, once: BLAS on one thread (its matrices are small, and beside the graph's
    busy processes a second BLAS thread spinning for its turn made an estimate several times
    slower), and a watch on the node process ``parent``: a node killed outright (SIGKILL, as
    the supervisor kills a hung one) never tells its worker to stop, and the worker holds both
    ends of its own task pipe, so it would wait for work forever."""
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_PARENT_CHECK_S)
        os._exit(0)
    threading.Thread(target=watch, name='wind_shaper-parent-watch', daemon=True).start()


#: how often the worker checks that its node process still runs [s]
_PARENT_CHECK_S = 1.0


class EstimateWorker:
    """One child process that runs ``align_and_estimate``; ``timeout_s`` [s]: the longest an
    estimate may take before it is given up (the worker is then replaced). ``start()`` begins
    it (and its imports) before the first sweep needs it; ``run(...)`` blocks until the answer;
    ``close()`` ends it. Thread-safe: one estimate at a time."""

    def __init__(self, timeout_s: float = 300.0):
        if not timeout_s > 0:
            raise ValueError(f'timeout_s must be > 0, got {timeout_s!r}')
        self.timeout_s = float(timeout_s)
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self.started = 0   # worker processes started (1 + replacements)

    def start(self) -> None:
        with self._lock:
            self._ensure()

    def _ensure(self) -> ProcessPoolExecutor:
        procs = getattr(self._pool, '_processes', None) or {}
        if any(not proc.is_alive() for proc in list(procs.values())):
            # the worker died while idle (killed between sweeps): nothing was being computed,
            # so a new one takes the next estimate
            self._replace()
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                             initializer=_init_worker, initargs=(os.getpid(),))
            self._pool.submit(_ready)   # the child imports numpy, scipy and the estimator now
            self.started += 1
        return self._pool

    def _replace(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            for proc in list(getattr(pool, '_processes', {}).values()):
                proc.kill()   # a child stuck in an estimate is not waited for
            _abandon(pool)

    def run(self, estimator, key_points, streams: StreamSnapshot, required=None, reuse=None,
            peek: bool = False) -> EstimateOutcome:
        """``align_and_estimate(...)`` in the worker; WindShaperError when the worker died
        while computing it or it took longer than ``timeout_s`` (the worker is replaced)."""
        return self._call(align_and_estimate, estimator, key_points, streams, required, reuse, peek)

    def _call(self, fn, *args):
        with self._lock:
            try:
                future = self._ensure().submit(fn, *args)
            except BrokenProcessPool:   # ... and the pool saw it before _ensure did
                self._replace()
                future = self._ensure().submit(fn, *args)
            try:
                return future.result(timeout=self.timeout_s)
            except BrokenProcessPool:
                self._replace()
                raise WindShaperError('the estimate worker process died while computing this '
                                      'estimate (out of memory? killed?); a new one is started: '
                                      'ask again') from None
            except FutureTimeout:
                self._replace()
                raise WindShaperError(f'the estimate took longer than {self.timeout_s:g} s and was '
                                      f'given up; a new worker is started: ask again, or sweep '
                                      f'shorter') from None

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            _abandon(pool)


def _abandon(pool: ProcessPoolExecutor) -> None:
    """Shut ``pool`` down without waiting, and let the process exit without waiting either
    for a task still on its way to a worker that reads no more: its queue's feeder thread would
    block writing into the pipe (the parent holds both ends) and multiprocessing joins it at
    exit. A CI lane hung so after its last test, the feeder 98 KB into a write; not reproduced
    since, so this is a precaution the tests do not show."""
    queue = getattr(pool, '_call_queue', None)
    if queue is not None:
        queue.cancel_join_thread()
    pool.shutdown(wait=False, cancel_futures=True)


__all__ = ['EstimateOutcome', 'EstimateWorker', 'StreamSnapshot', 'align_and_estimate']
