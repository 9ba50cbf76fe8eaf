"""The coordinator's link to the rig: the ports that ``coordination.run_iteration``,
``run_experiment`` and ``hold_point`` await, over the node's service clients and waits (and the
force sensor's bias service, when ``bias_zero`` asks a designed experiment to bias it).

The fans are commanded on the node's command topic and their read-back awaited; the field
estimator is asked to begin, peek at and estimate a sweep; the plate is moved by the sweep
service (stopped early through the stop service when the estimate is good enough) or an
operator is given the sweep's time. What to ask and when a sweep is good enough is
``coordination.sweeping`` and ``coordination.state``; this class only calls services and waits.
Commands [fraction 0..1, the tunnel's fan order]; times [s].
"""
from __future__ import annotations

import time

import numpy as np
from std_srvs.srv import Trigger
from wind_shaper_msgs.msg import IterationStatus
from wind_shaper_msgs.srv import EstimateField, Sweep

from ..control.region import RegionPlan
from ..coordination import FanWatch, FieldAnswer, IterationStopped
from ..core.bias import check_bias_mode
from ..coordination.sweeping import (SweepJudge, discarded_text, peek_figures, required, sweep_span,
                                     watch_sweep)
from ..ros import names
from ..ros.convert import estimate_from_msg, sweep_from_msg
from ..ros.waiting import in_thread


#: An estimate is asked for (again and again, ``Waits.call``) for up to this many times
#: ``service_timeout_s``: a field_estimator restarted in the middle of a sweep answers only after
#: its start-up and the backoff before it (seen: 11 s on a busy 2-core machine), and the samples
#: its journal kept are worth the wait.
ESTIMATE_PATIENCE = 2.0


class RigLink:
    """The rig's ports for ``node`` (the coordinator: its parameters, lock, bookkeeping
    ``book``, run and ``waits``); see the module docstring."""

    def __init__(self, node, run, book, waits):
        self.node, self._run, self.book, self._waits = node, run, book, waits
        self.params = p = node.params
        self.lock, self.fan_names = node.lock, node.fan_names
        cb = node.callback_group
        self._begin_client = node.create_client(Trigger, names.BEGIN_SWEEP, callback_group=cb)
        self._estimate_client = node.create_client(EstimateField, names.ESTIMATE_FIELD, callback_group=cb)
        self._sweep_client = (node.create_client(Sweep, p.sweep_service, callback_group=cb)
                              if p.sweep_service else None)
        self._stop_sweep_client = (node.create_client(Trigger, p.stop_sweep_service, callback_group=cb)
                                   if p.sweep_service and p.stop_sweep_service else None)
        check_bias_mode(p.bias_zero, node.setup.shaping.bounds.u_min)
        self._bias_client = (node.create_client(Trigger, names.FORCE_BIAS, callback_group=cb)
                             if p.bias_zero != 'never' else None)
        shaping = node.setup.shaping
        policy = shaping.make_sweep_length()
        self._judge = SweepJudge(policy.adaptive, p.sweep_min_s, policy.std_max(shaping.make_rule()),
                                 policy.worst_factor)
        self._coverage_radius = shaping.make_estimator().max_gap

    def set_state(self, state: str, message: str) -> None:
        self.node.set_state(state, message)

    def warn(self, message: str) -> None:
        self.node.get_logger().warning(message)

    def check_boundary(self) -> None:
        self._waits.check()

    async def compute(self, fn, *args, **kwargs):
        """``fn``'s result, computed in a worker thread while the executor goes on."""
        return await in_thread(self.node, lambda: fn(*args, **kwargs), name='wind_shaper-compute')

    async def command_fans(self, U: np.ndarray) -> None:
        p = self.params
        told = self.book.command_in_force()
        if told is None or not np.allclose(told, U):
            # the node publishes the command in force: waiting for another would only time out
            raise RuntimeError(f'command_fans({np.round(U, 4).tolist()}) while the command in force '
                               f'is {None if told is None else np.round(told, 4).tolist()}')
        self.node.publish_command()
        reason = await self._waits.wait(
            None, self._waits.remaining(p.apply_timeout_s),
            until=lambda since: self.book.applied_since(since, U, p.apply_tolerance))
        if reason != 'done':
            self._waits.raise_for(reason, self.book.not_applied_text(
                U, p.apply_timeout_s, p.apply_tolerance, self.node.resolve_topic_name(names.FAN_APPLIED)))
        if p.settle_s > 0:
            await self._waits.wait(None, self._waits.remaining(p.settle_s))

    async def begin_sweep(self) -> None:
        # resend is safe here: begin only clears buffers, and no sweep has started yet
        begin = await self._call(self._begin_client, Trigger.Request(), 'field_estimator',
                                 self.params.service_timeout_s, resend=True)
        if not begin.success:
            raise IterationStopped(IterationStatus.STATE_FAILED,
                                   f'begin_sweep refused: {begin.message}')
        with self.lock:
            self.book.sweep_begun()

    async def sweep(self, k: int, attempt: int, plan: RegionPlan | None = None) -> None:
        """Move the plate once (sweep service) or give an operator the sweep's duration, over
        the whole area or ``plan``'s region; a sweep during which the fans left their commands
        (or stopped reporting) is refused."""
        book = self.book
        book.fan_watch = watch = FanWatch(time.monotonic(), book.command_in_force(),
                                          self.params.apply_tolerance)
        with self.lock:
            book.counting = True
        try:
            await self._move_plate(k, attempt, plan)
        finally:
            book.fan_watch = None
            with self.lock:
                book.counting = False
        problem = watch.problem(time.monotonic(), self.params.readback_timeout_s, self.fan_names)
        if problem:
            resolve = self.node.resolve_service_name
            stays = (f'the rows stored so far stay: check the fans, then call '
                     f'{resolve(names.COLLECT)} again with the same design'
                     if self.node.collect.active else
                     f'the run stays at iteration {k}: check the fans, then call '
                     f'{resolve(names.RUN_ITERATION)} again')
            raise IterationStopped(IterationStatus.STATE_FAILED, discarded_text(problem, stays))

    async def _move_plate(self, k: int, attempt: int, plan: RegionPlan | None) -> None:
        p = self.params
        doing = self.node.collect.where(k) if self.node.collect.active else f'iteration {k}'
        again = '' if attempt == 1 else f' (sweep {attempt} of {p.max_sweeps})'
        span = sweep_span(plan, self.book.sweep_duration_s, p.sweep_min_s,
                          self._run.setup.geometry.sweep_radius)
        duration, where = span.duration_s, span.where
        request = (Sweep.Request(duration_s=duration, seed=0) if plan is None else
                   Sweep.Request(duration_s=duration, seed=0, region_x=list(span.region_x),
                                 region_y=list(span.region_y), region_reach=span.region_reach))
        # an iteration's sweep is watched (live coverage and std) and, with shaping.sweep.adaptive,
        # ends once the estimate is good enough; a designed experiment's rows sweep in full
        watched = not self.node.collect.active
        if self._sweep_client is not None:
            self.node.set_state(IterationStatus.STATE_SWEEPING,
                                f'{doing}: sweeping {where} for {duration:g} s{again}')
            what = 'the sweep (sim_tunnel or motion stage)'
            if not watched:
                moved = await self._call(self._sweep_client, request, what,
                                         duration + p.service_timeout_s)
            else:
                moved = await self._watched_sweep(k, duration, what, request, plan)
            if not moved.success:
                raise IterationStopped(IterationStatus.STATE_FAILED,
                                       f'the sweep failed: {moved.message}')
        else:
            self.node.set_state(IterationStatus.STATE_SWEEPING,
                                f'{doing}: move the plate over {where} now ({duration:g} s){again}')
            if watched:
                if await self._watch_sweep(k, duration, None, plan):
                    self.node.set_state(IterationStatus.STATE_SWEEPING,
                                        f'{doing}: enough samples, you can stop sweeping')
            else:
                await self._waits.wait(None, self._waits.remaining(duration))
            self.check_boundary()

    async def _watched_sweep(self, k: int, duration: float, what: str, request: Sweep.Request,
                             plan: RegionPlan | None):
        """The sweep service's motion, watched; stopped early (stop_sweep_service) when the
        estimate is good enough. Returns the sweep service's response."""
        p, client = self.params, self._sweep_client
        await self._waits.wait_ready(client, what, p.service_timeout_s)
        future = client.call_async(request)
        try:
            enough = await self._watch_sweep(k, duration, future, plan)
            if enough and not future.done() and self._stop_sweep_client is not None:
                if self._stop_sweep_client.service_is_ready():
                    await self._call(self._stop_sweep_client, Trigger.Request(), 'the sweep stop',
                                     p.service_timeout_s)
            reason = await self._waits.wait(future, self._waits.remaining(duration + p.service_timeout_s))
        except BaseException:
            client.remove_pending_request(future)
            raise
        if reason != 'done':
            client.remove_pending_request(future)
            self._waits.raise_for(reason, f'{what} did not answer within '
                                          f'{duration + p.service_timeout_s:g} s')
        return future.result()

    async def _watch_sweep(self, k: int, duration: float, motion, plan: RegionPlan | None = None) -> bool:
        """``coordination.sweeping.watch_sweep`` with the field_estimator's peek; the live
        coverage and largest std go into the status."""
        def report(coverage: float, max_std: float) -> None:
            with self.lock:
                self.book.coverage, self.book.max_std = coverage, max_std
            self.node.publish_status()

        log = self.node.get_logger()
        return await watch_sweep(
            self._waits, motion, duration, self.params.sweep_check_s, lambda: self._peek(k, plan),
            report, lambda *figures: self._judge.verdict(k, *figures),
            warn=lambda text: log.warning(text, throttle_duration_sec=10.0), info=log.info)

    async def _peek(self, k: int, plan: RegionPlan | None = None) -> tuple[float, float, float]:
        """(coverage [0..1], largest std and the std's RMS over the key points [N] or NaN) of the
        sweep so far."""
        U = self.book.command_in_force()
        wait = max(2.0, self.params.sweep_check_s)   # short: the sweep goes on without it
        answer = await self._waits.call(
            self._estimate_client,
            EstimateField.Request(iteration=k, fan_names=self.fan_names,
                                  pwm=[float(u) for u in U], peek=True, required=required(plan)),
            'field_estimator', wait, ready_timeout_s=wait)
        samples = answer.samples
        positions = np.column_stack([samples.x, samples.y]) if len(samples.t) else None
        return peek_figures(positions, answer.success, answer.estimate.mean, answer.estimate.std,
                            self._run.key_points, self._coverage_radius, plan)

    async def bias_sensor(self) -> None:
        """Zero the force sensor's reading (its bias service); the fans are off and settled."""
        if self._bias_client is None:
            return
        done = await self._call(self._bias_client, Trigger.Request(), 'the force sensor\'s bias',
                                self.params.service_timeout_s)
        if not done.success:
            raise IterationStopped(IterationStatus.STATE_FAILED,
                                   f'the force sensor refused the bias: {done.message}; check the '
                                   f'force_sensor node, or set bias_zero to never')

    async def _call(self, client, request, what: str, timeout_s: float, *, resend: bool = False):
        return await self._waits.call(client, request, what, timeout_s, resend=resend,
                                      ready_timeout_s=self.params.service_timeout_s)

    async def estimate(self, k: int, U: np.ndarray, plan: RegionPlan | None = None) -> FieldAnswer:
        answer = await self._call(
            self._estimate_client,
            EstimateField.Request(iteration=k, fan_names=self.fan_names, pwm=[float(u) for u in U],
                                  required=required(plan)),
            'field_estimator', ESTIMATE_PATIENCE * self.params.service_timeout_s, resend=True)
        if not answer.success:  # a refused sweep's pairs come along when they could be paired
            refused = sweep_from_msg(answer.samples) if len(answer.samples.t) else None
            return FieldAnswer(False, answer.message, sweep=refused)
        kp, mean, std = estimate_from_msg(answer.estimate)
        return FieldAnswer(True, answer.message, kp, mean, std, sweep_from_msg(answer.samples),
                           int(answer.estimate.n_used), float(answer.compute_s))

    async def wait_for(self, predicate, timeout_s: float) -> bool:
        """Wait until ``predicate()`` holds (re-checked at each ``poke``) or ``timeout_s`` [s]
        passes (False); a cancel or the procedure's deadline raises IterationStopped."""
        if predicate():
            return True
        reason = await self._waits.wait(None, self._waits.remaining(timeout_s),
                                        until=lambda since: predicate())
        if reason == 'cancelled':
            self._waits.raise_for(reason, '')
        self._waits.check()
        return reason == 'done'

    async def pause(self, seconds: float) -> None:
        """Let ``seconds`` [s] pass without blocking the executor; no cancel or deadline ends it."""
        await self._waits.wait(None, seconds, cancellable=False)

    async def call(self, client, request, what: str, timeout_s: float):
        """A service call bounded by ``timeout_s`` [s] (and the procedure's deadline)."""
        return await self._call(client, request, what, timeout_s)


__all__ = ['RigLink']
