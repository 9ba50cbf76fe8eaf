"""coordinator: the online-learning loop (Algorithm 1) over the node graph, one iteration per call.

``/wind_shaper/run_iteration`` (wind_shaper_msgs/RunIteration) runs one iteration, as
docs/graph.md describes: ``commanding`` (publish U_k on ``/wind_shaper/fans/command``, wait until
``/wind_shaper/fans/applied`` reports it within ``apply_tolerance``, wait ``settle_s``),
``sweeping`` (field_estimator ``begin_sweep``, then the ``sweep_service`` or, when that parameter
is empty, ``sweep_duration_s`` for an operator to move the plate), ``estimating`` (field_estimator
``estimate``), ``updating`` (the core update rule gives U_{k+1}; the iteration is written to the
run folder, then U_{k+1} is published), ``done``. A call while an iteration runs is refused at
once. A ``target`` in the request becomes the run's target (validated first: a bad one is refused
and nothing changes). ``/wind_shaper/cancel_iteration`` (std_srvs/Trigger) stops a running
iteration at the next step boundary; the fans keep the commands of the last completed iteration
and the run does not advance. ``/wind_shaper/set_model`` (wind_shaper_msgs/SetModel) swaps the
prior (YAML text or a path; validated on the tunnel's fans; a refused model leaves the old one).

The run folder ``<run_root>/<run_name>/`` (``wind_shaper.storage.runstore``) survives restarts: on
start the coordinator resumes after the last completed iteration and publishes its commands.
The command in force is republished at ``republish_hz`` to feed fan_output's watchdog.
``/wind_shaper/iteration/status`` (IterationStatus, latched) goes out on every state change and
at 2 Hz during an iteration; /diagnostics at 1 Hz.

PWM commands are fractions 0..1 of full PWM in tunnel.yaml's fan order; forces [N]; key points
[m, tunnel frame]. Tunnel, shaping (update rule, bounds, u0) and the prior come from
``config_dir`` through ``wind_shaper.app.Setup``.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import Trigger
from wind_shaper_msgs.msg import FanCommand, IterationStatus
from wind_shaper_msgs.srv import EstimateField, RunIteration, SetModel, Sweep

from ..app import Setup
from ..core.config import read_yaml
from ..core.errors import ConfigError, WindShaperError
from ..estimation.field import FieldEstimate, closest_samples
from ..model.modelfile import load_model, model_from_text
from ..storage.runstore import IterationData, RunInfo, RunStore
from ..control.update import PastIteration, UpdateInput
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import estimate_from_msg, fan_command, pwm_from_command, sweep_from_msg
from ..ros.params import declare_parameters, param
from ..ros.runner import run

STATUS_HZ = 2.0  # status rate while an iteration runs [Hz]
#: Share of an iteration's progress reached at the start of each state.
PROGRESS = {'commanding': 0.0, 'sweeping': 0.1, 'estimating': 0.8, 'updating': 0.9, 'done': 1.0}


@dataclass(frozen=True)
class CoordinatorParams:
    config_dir: str = param('', "folder holding tunnel.yaml, shaping.yaml, model.yaml ('' = the "
                            'shipped config, or $WIND_SHAPER_CONFIG)')
    run_root: str = param('runs', 'folder of the run folders (relative: to the working directory)')
    run_name: str = param('default', 'run folder name under run_root; an existing run is resumed')
    target: str = param('parabolic', 'target of a new run, CLI syntax (parabolic, uniform:2.5, '
                        'gaussian@LM1, expr:..., csv:...); a resumed run keeps its own')
    sweep_duration_s: float = param(20.0, 'how long one sweep lasts [s]', low=0.1, high=3600.0)
    sweep_service: str = param(names.SWEEP, "wind_shaper_msgs/Sweep service that moves the plate; "
                               "'' = wait sweep_duration_s for an operator to move it")
    settle_s: float = param(2.0, 'wait after the fans report the commands, before sweeping [s]',
                            low=0.0, high=600.0)
    apply_tolerance: float = param(0.005, 'largest difference between commanded and applied PWM '
                                   'that counts as applied [fraction]', low=0.0, high=1.0)
    apply_timeout_s: float = param(10.0, 'wait at most this long for the fans to report the '
                                   'commands [s]', low=0.1, high=600.0)
    readback_timeout_s: float = param(2.0, 'during a sweep the fans\' read-back may pause this '
                                      'long at most [s]; a longer pause, or a read-back off the '
                                      'commands, discards the sweep', low=0.1, high=600.0)
    max_sweeps: int = param(3, 'sweeps per iteration at most: when the estimator refuses a '
                            'sweep (gaps, too few samples) the plate sweeps again and the '
                            'estimate uses all samples', low=1, high=10)
    service_timeout_s: float = param(10.0, 'wait at most this long for a field_estimator or sweep '
                                     'service to appear or to answer (a sweep: beyond its '
                                     'duration) [s]', low=0.1, high=600.0)
    iteration_timeout_s: float = param(300.0, 'a whole iteration may take at most this long [s] '
                                       '(a request can override it)', low=1.0, high=86400.0)
    republish_hz: float = param(2.0, "rate of republishing the command in force (fan_output's "
                                'watchdog) [Hz]', low=0.1, high=100.0)


class _Stop(Exception):
    """Ends an iteration early: state 'failed' or 'cancelled', with the reason."""

    def __init__(self, state: str, message: str):
        super().__init__(message)
        self.state = state


#: Shortest interval between resends of an unanswered idempotent request [s].
RESEND_MIN_S = 2.5


class _FanWatch:
    """The fans' read-back during one sweep: the longest pause between reports [s] and the
    first report off the commands U [fraction] by more than ``tolerance``."""

    def __init__(self, start: float, U, tolerance: float):
        self.U, self.tolerance = np.asarray(U, dtype=float), float(tolerance)
        self.start = self.last = start
        self.longest_pause = 0.0
        self.off: tuple[float, np.ndarray] | None = None

    def saw(self, now: float, applied: np.ndarray) -> None:
        self.longest_pause = max(self.longest_pause, now - self.last)
        self.last = now
        if self.off is None and np.max(np.abs(applied - self.U)) > self.tolerance:
            self.off = (now - self.start, applied.copy())

    def problem(self, now: float, timeout_s: float, fan_names) -> str:
        """Why the sweep cannot be trusted, or ''."""
        if self.off is not None:
            t, applied = self.off
            worst = int(np.argmax(np.abs(applied - self.U)))
            return (f'{t:.1f} s into the sweep the fans reported {fan_names[worst]} at '
                    f'{applied[worst]:.3f} instead of {self.U[worst]:.3f}')
        pause = max(self.longest_pause, now - self.last)
        if pause > timeout_s:
            return (f'the fans did not report their outputs for {pause:.1f} s during the sweep '
                    f'(readback_timeout_s {timeout_s:g})')
        return ''


class CoordinatorNode(Node):
    """Runs the shaping loop one service call at a time; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__(names.COORDINATOR, **kwargs)
        self.params = p = declare_parameters(self, CoordinatorParams)
        self._setup = setup = Setup.load(p.config_dir or None)
        geo = setup.geometry
        self._fan_names = list(geo.fans.names)
        self._enabled = geo.fans.enabled
        self._key_points = geo.key_points
        self._bounds = setup.shaping.bounds
        setup.make_target(p.target)  # a bad target parameter stops the node at start (its
        # reach is checked against the run's prior below)
        u0 = self._bounds.project(np.full(len(self._fan_names), float(setup.shaping.u0)),
                                  self._enabled)
        info = RunInfo(p.target, tuple(self._fan_names), self._key_points,
                       {'tunnel': read_yaml(setup.config_dir / 'tunnel.yaml'),
                        'shaping': read_yaml(setup.config_dir / 'shaping.yaml'),
                        'model_file': str(setup.model_path), 'coordinator': asdict(p)})
        self._store = RunStore.open(p.run_root, p.run_name, info, initial_pwm=u0)
        state = self._store.state()
        if self._store.model_path.is_file():
            self._model = load_model(self._store.model_path, geo.fans)
            self.get_logger().info(f'prior from the run folder: {self._store.model_path}')
        else:
            self._model = setup.load_model()
        self._target_spec = state.target
        self._target = setup.make_target(state.target, model=self._model)
        if state.target != p.target:
            self.get_logger().warning(
                f'the run {self._store.folder} has target {state.target!r}; the target parameter '
                f'{p.target!r} applies to new runs only (a run_iteration request can change it)')
        # earlier iterations, for update rules that learn from the run (core.update.PastIteration)
        self._past = [self._past_iteration(r.pwm, r.estimate.mean, r.estimate.std, r.info)
                      for r in self._store.load_history()]
        self._k = state.next_k
        self._U = self._bounds.project(state.next_pwm, self._enabled)
        if not np.allclose(self._U, state.next_pwm):
            self.get_logger().warning(f'the run\'s next commands {state.next_pwm.tolist()} lie outside '
                                      f'the bounds of shaping.yaml: clipped to {self._U.tolist()}')

        self._lock = threading.Lock()
        self._running = False
        self._cancel = False
        self._cancel_hooks: set = set()
        self._applied: np.ndarray | None = None
        self._applied_hook = None
        self._state = IterationStatus.STATE_IDLE
        self._message = ''
        self._progress = 0.0
        self._samples = 0
        self._counting = False
        self._phase_start = time.monotonic()
        self._last_rmse = math.nan
        self._last_failed = False
        last = state.last_completed
        self._status_k = last  # the iteration the status is about: running, or last completed
        if last >= 0:
            self._last_rmse = float(self._store.load_record(last)['rmse_N'])
        # the commands in force: none until the first iteration of a new run; a resumed run
        # holds the last completed iteration's next commands at once
        self._command: np.ndarray | None = self._U.copy() if last >= 0 else None
        self._fan_watch: _FanWatch | None = None
        self._applied_at: float | None = None   # time.monotonic() of the last read-back

        self._cb = ReentrantCallbackGroup()
        self._cmd_pub = self.create_publisher(FanCommand, names.FAN_COMMAND, qos.LATCHED)
        self._status_pub = self.create_publisher(IterationStatus, names.STATUS, qos.LATCHED)
        self._diag_pub = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.create_subscription(FanCommand, names.FAN_APPLIED, self._on_fans_applied, qos.LATCHED,
                                 callback_group=self._cb)
        self.create_subscription(PoseStamped, names.PLATE_POSE, self._on_plate_pose, qos.STREAM,
                                 callback_group=self._cb)
        self._begin_client = self.create_client(Trigger, names.BEGIN_SWEEP, callback_group=self._cb)
        self._estimate_client = self.create_client(EstimateField, names.ESTIMATE_FIELD,
                                                   callback_group=self._cb)
        self._sweep_client = (self.create_client(Sweep, p.sweep_service, callback_group=self._cb)
                              if p.sweep_service else None)
        self.create_service(RunIteration, names.RUN_ITERATION, self._handle_run_iteration,
                            callback_group=self._cb)
        self.create_service(Trigger, names.CANCEL_ITERATION, self._handle_cancel_iteration,
                            callback_group=self._cb)
        self.create_service(SetModel, names.SET_MODEL, self._handle_set_model, callback_group=self._cb)
        self.create_timer(1.0 / p.republish_hz, self._publish_command, callback_group=self._cb)
        self.create_timer(1.0 / STATUS_HZ, self._on_status_timer, callback_group=self._cb)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=self._cb)

        self._publish_command()
        self._publish_status()
        resumed = f'resuming after iteration {last}' if last >= 0 else 'new run'
        self.get_logger().info(
            f'{resumed} in {self._store.folder}: next k={self._k}, target {self._target_spec!r}, '
            f'commands {np.round(self._U, 4).tolist()}, prior {self._model!r}')

    # -- topics ---------------------------------------------------------------------------------------
    def _on_fans_applied(self, msg: FanCommand) -> None:
        try:
            applied = pwm_from_command(msg, self._fan_names)
        except ValueError as exc:
            self.get_logger().warning(f'ignoring {names.FAN_APPLIED}: {exc}', throttle_duration_sec=10)
            return
        self._applied, self._applied_at = applied, time.monotonic()
        watch = self._fan_watch
        if watch is not None:
            watch.saw(time.monotonic(), applied)
        hook = self._applied_hook
        if hook is not None:
            hook()

    def _on_plate_pose(self, msg: PoseStamped) -> None:
        if self._counting:
            self._samples += 1

    def _publish_command(self) -> None:
        U = self._command
        if U is not None:
            self._cmd_pub.publish(fan_command(self._fan_names, U, self.get_clock().now().to_msg()))

    # -- status ---------------------------------------------------------------------------------------
    def _set_state(self, state: str, message: str = '') -> None:
        with self._lock:
            self._state, self._message = state, message
            self._phase_start = time.monotonic()
            self._progress = PROGRESS.get(state, self._progress)
        self._publish_status()
        if message:
            self.get_logger().info(f'[{state}] {message}')

    def _on_status_timer(self) -> None:
        if self._running:
            self._publish_status()

    def _publish_status(self) -> None:
        with self._lock:
            progress = self._progress
            if self._state == IterationStatus.STATE_SWEEPING and self._running:
                frac = (time.monotonic() - self._phase_start) / self.params.sweep_duration_s
                span = PROGRESS['estimating'] - PROGRESS['sweeping']
                progress = PROGRESS['sweeping'] + span * min(max(frac, 0.0), 0.99)
            U = self._command if self._command is not None else self._U
            msg = IterationStatus(
                iteration=int(self._status_k), state=self._state,
                progress=float(progress), samples=int(self._samples), message=self._message,
                target=self._target_spec, fan_names=self._fan_names,
                pwm=[float(u) for u in U], rmse=float(self._last_rmse),
                run_folder=str(self._store.folder))
        msg.header.stamp = self.get_clock().now().to_msg()
        self._status_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        values = {'state': self._state, 'next_iteration': self._k, 'target': self._target_spec,
                  'rmse_N': self._last_rmse, 'run_folder': str(self._store.folder),
                  'commands': 'none yet' if self._command is None
                  else ' '.join(f'{n}={u:.4f}' for n, u in zip(self._fan_names, self._command)),
                  'prior': repr(self._model)}
        message = f'{self._state}: {self._message}' if self._message else self._state
        self._diag_pub.publish(diag.array(self, diag.status(
            f'wind_shaper/{names.COORDINATOR}', diag.WARN if self._last_failed else diag.OK,
            message, values)))

    # -- awaiting without blocking the executor ---------------------------------------------------------
    def _wake(self) -> None:
        executor = self.executor
        if executor is not None:
            executor.wake()

    async def _wait(self, future: Future | None, timeout_s: float, *, applied: np.ndarray | None = None,
                    cancellable: bool = True) -> str:
        """Until ``future`` is done ('done'), the fans report ``applied`` ('done'), ``timeout_s``
        [s] passes ('timeout') or a cancel request comes ('cancelled')."""
        gate = Future()
        gate_lock = threading.Lock()

        def open_gate(reason: str) -> None:
            with gate_lock:
                if gate.done():
                    return
                gate.set_result(reason)
            self._wake()

        since = time.monotonic()

        def on_applied() -> None:
            # only a report that arrived after the wait began: a read-back kept from before (a
            # fan_output that has since restarted and ramps from safe) proves nothing
            A, at = self._applied, self._applied_at
            if (A is not None and at is not None and at >= since
                    and np.max(np.abs(A - applied)) <= self.params.apply_tolerance):
                open_gate('done')

        timer = self.create_timer(max(timeout_s, 1e-3), lambda: open_gate('timeout'),
                                  callback_group=self._cb)
        if cancellable:
            hook = lambda: open_gate('cancelled')  # noqa: E731
            with self._lock:
                self._cancel_hooks.add(hook)
                if self._cancel:
                    open_gate('cancelled')
        if future is not None:
            future.add_done_callback(lambda _f: open_gate('done'))
        if applied is not None:
            self._applied_hook = on_applied
        try:
            return await gate
        finally:
            if applied is not None:
                self._applied_hook = None
            if cancellable:
                with self._lock:
                    self._cancel_hooks.discard(hook)
            timer.cancel()
            self.destroy_timer(timer)

    async def _call(self, client, request, what: str, timeout_s: float, deadline: float, *,
                    resend: bool = False):
        """Call a service and return its response; a missing service, a timeout or a cancel
        ends the iteration (_Stop). ``resend`` (idempotent calls only): while no answer came the
        request goes out again every max(RESEND_MIN_S, timeout_s / 4), for a server restarted in
        the meantime never saw the earlier one (DDS drops a request sent before the server was
        matched)."""
        if not client.service_is_ready():
            give_up = min(time.monotonic() + self.params.service_timeout_s, deadline)
            while not client.service_is_ready() and time.monotonic() < give_up:
                if await self._wait(None, 0.1) == 'cancelled':
                    raise _Stop(IterationStatus.STATE_CANCELLED, f'cancelled while waiting for {what}')
            if not client.service_is_ready():
                self._boundary(deadline)
                raise _Stop(IterationStatus.STATE_FAILED,
                            f'no {client.srv_name} service within {self.params.service_timeout_s:g} s: '
                            f'is {what} running?')
        # resend: every `every` [s] while no answer came, until timeout_s
        every = max(RESEND_MIN_S, timeout_s / 4) if resend else timeout_s
        give_up = time.monotonic() + self._bounded(timeout_s, deadline)
        future = client.call_async(request)
        reason = await self._wait(future, min(every, give_up - time.monotonic()))
        while reason == 'timeout' and time.monotonic() < give_up - 1e-3:
            client.remove_pending_request(future)
            self.get_logger().warning(f'{what} did not answer yet: asking again (a restarted '
                                      f'{what} never saw the earlier request)',
                                      throttle_duration_sec=5.0)
            future = client.call_async(request)
            reason = await self._wait(future, min(every, give_up - time.monotonic()))
        if reason != 'done':
            client.remove_pending_request(future)
            self._raise_for(reason, f'{what} did not answer within {timeout_s:g} s', deadline)
        return future.result()

    def _bounded(self, timeout_s: float, deadline: float) -> float:
        return max(min(timeout_s, deadline - time.monotonic()), 0.0)

    def _raise_for(self, reason: str, timeout_message: str, deadline: float) -> None:
        if reason == 'cancelled':
            raise _Stop(IterationStatus.STATE_CANCELLED, f'cancelled while {self._state}')
        if time.monotonic() >= deadline - 1e-3:
            raise _Stop(IterationStatus.STATE_FAILED, f'the iteration timed out while {self._state}')
        raise _Stop(IterationStatus.STATE_FAILED, timeout_message)

    def _boundary(self, deadline: float) -> None:
        """Between steps: honour a cancel request and the iteration deadline."""
        if self._cancel:
            raise _Stop(IterationStatus.STATE_CANCELLED, f'cancelled after {self._state}')
        if time.monotonic() >= deadline:
            raise _Stop(IterationStatus.STATE_FAILED, f'the iteration timed out after {self._state}')

    # -- services -------------------------------------------------------------------------------------
    async def _handle_run_iteration(self, request: RunIteration.Request,
                                    response: RunIteration.Response):
        response.fan_names = self._fan_names
        response.run_folder = str(self._store.folder)
        response.rmse_before = response.rmse_predicted_after = response.max_std = math.nan
        spec = request.target.strip()
        with self._lock:
            if self._running:
                response.success = False
                response.iteration = self._k
                response.message = (f'an iteration is running (k={self._k}, {self._state}): wait '
                                    f'for it or call {names.CANCEL_ITERATION}')
                return response
            try:
                target = self._setup.make_target(spec, model=self._model) if spec else None
                rule = self._setup.shaping.make_rule(
                    **({'gain': float(request.step_gain)} if request.step_gain > 0 else {}))
            except WindShaperError as exc:
                response.success = False
                response.iteration = self._k
                response.message = (f'refused, nothing changed (the run keeps target '
                                    f'{self._target_spec!r}): {exc}')
                return response
            self._running, self._cancel = True, False
        try:
            if target is not None and spec != self._target_spec:
                self._store.set_target(spec)
                with self._lock:
                    self._target, self._target_spec = target, spec
                self.get_logger().info(f'target changed to {spec!r}: {target.describe()}')
            timeout = request.timeout_s if request.timeout_s > 0 else self.params.iteration_timeout_s
            return await self._iterate(rule, timeout, response)
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            self.get_logger().error(f'iteration {self._k} failed unexpectedly: {exc!r}')
            return self._end(response, IterationStatus.STATE_FAILED, f'unexpected error: {exc!r}')
        finally:
            with self._lock:
                self._running = False
                self._counting = False

    async def _iterate(self, rule, timeout_s: float, response):
        p = self.params
        k, U = self._k, self._U.copy()
        deadline = time.monotonic() + timeout_s
        stamps = {'started': time.time()}
        response.iteration = k
        response.pwm_before = response.pwm_after = [float(u) for u in U]
        with self._lock:
            self._samples, self._status_k = 0, k
        try:
            # 1. commanding
            self._command = U
            self._set_state(IterationStatus.STATE_COMMANDING, f'iteration {k}: commanding the fans')
            self._publish_command()
            reason = await self._wait(None, self._bounded(p.apply_timeout_s, deadline), applied=U)
            if reason != 'done':
                got = 'nothing' if self._applied is None else np.round(self._applied, 4).tolist()
                self._raise_for(reason, (
                    f'the fans did not report the commands {np.round(U, 4).tolist()} applied within '
                    f'{p.apply_timeout_s:g} s (tolerance {p.apply_tolerance:g}; last read-back: '
                    f'{got} on {names.FAN_APPLIED}): is fan_output running and the autopilot '
                    f'connected?'), deadline)
            stamps['applied'] = time.time()
            if p.settle_s > 0:
                await self._wait(None, self._bounded(p.settle_s, deadline))
            self._boundary(deadline)

            # 2. sweeping
            # resend is safe here: begin only clears buffers, and no sweep has started yet
            begin = await self._call(self._begin_client, Trigger.Request(), 'field_estimator',
                                     p.service_timeout_s, deadline, resend=True)
            if not begin.success:
                raise _Stop(IterationStatus.STATE_FAILED, f'begin_sweep refused: {begin.message}')
            with self._lock:
                self._samples, self._counting = 0, True
            stamps['sweep_started'] = time.time()
            # The estimator refuses a sweep that missed part of the area or has too few samples,
            # and keeps collecting: sweep again at the same commands, then estimate on all of it.
            for attempt in range(1, p.max_sweeps + 1):
                await self._sweep_once(k, attempt, deadline)
                with self._lock:
                    self._counting = False
                stamps['sweep_ended'] = time.time()
                self._boundary(deadline)

                # 3. estimating
                self._set_state(IterationStatus.STATE_ESTIMATING,
                                f'iteration {k}: estimating the field')
                answer = await self._call(
                    self._estimate_client,
                    EstimateField.Request(iteration=k, fan_names=self._fan_names,
                                          pwm=[float(u) for u in U]),
                    'field_estimator', p.service_timeout_s, deadline, resend=True)
                if answer.success:
                    break
                if attempt == p.max_sweeps:
                    raise _Stop(IterationStatus.STATE_FAILED,
                                f'no field estimate after {attempt} sweep(s): {answer.message}')
                self.get_logger().warning(f'iteration {k}: {answer.message}; sweeping again to '
                                          f'fill the gaps ({attempt + 1} of {p.max_sweeps})')
                with self._lock:
                    self._counting = True
            stamps['estimated'] = time.time()
            self._boundary(deadline)

            # 4. updating
            self._set_state(IterationStatus.STATE_UPDATING, f'iteration {k}: updating the commands')
            data = self._update(k, U, rule, answer, stamps)
            folder = self._store.write_iteration(data)
            self._past.append(self._past_iteration(U, data.estimate.mean, data.estimate.std,
                                                   data.info))
            with self._lock:
                self._k, self._U = k + 1, data.pwm_after.copy()
                self._last_rmse = data.rmse
                self._samples = len(data.sweep)
            self._command = data.pwm_after.copy()
            self._publish_command()
        except _Stop as stop:
            return self._end(response, stop.state, f'iteration {k} {stop.state}: {stop}'
                             + ('; the fans keep the last completed iteration\'s commands and the '
                                'run stays at this iteration' if stop.state == 'cancelled' else ''))
        # 5. done
        response.success = True
        response.rmse_before = data.rmse
        response.rmse_predicted_after = data.rmse_predicted_after
        response.max_std = float(np.max(data.estimate.std))
        response.pwm_after = [float(u) for u in data.pwm_after]
        response.run_folder = str(folder)
        response.message = (f'iteration {k}: RMSE {data.rmse:.4f} N, predicted after the update '
                            f'{data.rmse_predicted_after:.4f} N; step {data.step_size:.3f}; '
                            f'{len(data.sweep)} pairs')
        if data.info.get('stop'):
            response.message += ('; the update rule advises stopping: '
                                 f'{data.info.get("stop_reason", "")}')

        self._last_failed = False
        self._set_state(IterationStatus.STATE_DONE, response.message)
        return response

    async def _sweep_once(self, k: int, attempt: int, deadline: float) -> None:
        """Move the plate once (sweep service) or give an operator the sweep's duration; a sweep
        during which the fans left their commands (or stopped reporting) is refused (_Stop)."""
        self._fan_watch = watch = _FanWatch(time.monotonic(), self._command,
                                            self.params.apply_tolerance)
        try:
            await self._move_plate(k, attempt, deadline)
        finally:
            self._fan_watch = None
        problem = watch.problem(time.monotonic(), self.params.readback_timeout_s, self._fan_names)
        if problem:
            raise _Stop(IterationStatus.STATE_FAILED,
                        f'sweep discarded: {problem} (fan_output restarted, the autopilot link '
                        f'dropped, or an emergency stop?); the run stays at iteration {k}: check '
                        f'the fans, then call {names.RUN_ITERATION} again')

    async def _move_plate(self, k: int, attempt: int, deadline: float) -> None:
        p = self.params
        again = '' if attempt == 1 else f' (sweep {attempt} of {p.max_sweeps})'
        if self._sweep_client is not None:
            self._set_state(IterationStatus.STATE_SWEEPING,
                            f'iteration {k}: sweeping for {p.sweep_duration_s:g} s{again}')
            moved = await self._call(self._sweep_client,
                                     Sweep.Request(duration_s=p.sweep_duration_s, seed=0),
                                     'the sweep (sim_tunnel or motion stage)',
                                     p.sweep_duration_s + p.service_timeout_s, deadline)
            if not moved.success:
                raise _Stop(IterationStatus.STATE_FAILED, f'the sweep failed: {moved.message}')
        else:
            self._set_state(IterationStatus.STATE_SWEEPING,
                            f'iteration {k}: move the plate over the whole area now '
                            f'({p.sweep_duration_s:g} s){again}')
            await self._wait(None, self._bounded(p.sweep_duration_s, deadline))
            self._boundary(deadline)

    def _update(self, k: int, U: np.ndarray, rule, answer, stamps: dict) -> IterationData:
        """The update rule's step from the measured field; everything the run folder keeps."""
        kp, mean, std = estimate_from_msg(answer.estimate)
        if kp.shape != self._key_points.shape or not np.allclose(kp, self._key_points, atol=1e-9):
            raise _Stop(IterationStatus.STATE_FAILED,
                        f'the field estimator used {len(kp)} other key points than the coordinator '
                        f'({len(self._key_points)}): both must read the same config_dir')
        sweep = sweep_from_msg(answer.samples)
        sweep = type(sweep)(sweep.positions, sweep.forces, sweep.times, U)
        key_distance = closest_samples(sweep, kp).key_distance
        estimate = FieldEstimate(kp, mean, std, key_distance, int(answer.estimate.n_used))
        with self._lock:
            target_values, spec, model = self._target.values(kp), self._target_spec, self._model
        J = model.jacobian(U, kp)  # the rule's search direction and the prediction below
        step = rule.step(UpdateInput(k, U.copy(), target_values - mean, J, self._enabled, std,
                                     model=model, key_points=kp, target=target_values,
                                     history=tuple(self._past)))
        U_next = self._bounds.project(step.U_next, self._enabled)  # never outside the bounds
        predicted = mean + J @ (U_next - U)
        stamps['finished'] = time.time()
        return IterationData(
            k=k, target=spec, pwm_before=U, pwm_after=U_next, step_size=float(step.step_size),
            rmse=float(np.sqrt(np.mean((mean - target_values) ** 2))),
            rmse_predicted_after=float(np.sqrt(np.mean((predicted - target_values) ** 2))),
            estimate=estimate, target_values=target_values, sweep=sweep, model=repr(model),
            timestamps=stamps, info={'gain': getattr(rule, 'gain', None),
                                     'estimator_compute_s': float(answer.compute_s), **dict(step.info)})

    @staticmethod
    def _past_iteration(U, mean, std, info) -> PastIteration:
        """An earlier iteration as update rules see it (rules that do not learn from the run
        ignore the history)."""
        return PastIteration(np.asarray(U, float), np.asarray(mean, float),
                             np.asarray(std, float), dict(info))

    def _end(self, response, state: str, message: str):
        """Answer a stopped iteration: nothing advanced, the commands in force unchanged."""
        self._last_failed = state == IterationStatus.STATE_FAILED
        response.success = False
        response.message = message
        response.pwm_after = [float(u) for u in self._U]
        if self._command is not None:
            self._publish_command()
        (self.get_logger().warning if self._last_failed else self.get_logger().info)(message)
        self._set_state(state, message)
        return response

    def _handle_cancel_iteration(self, request: Trigger.Request, response: Trigger.Response):
        with self._lock:
            if not self._running:
                response.success = False
                response.message = f'no iteration is running (state {self._state})'
                return response
            self._cancel = True
            hooks = list(self._cancel_hooks)
            k, state = self._k, self._state
        for hook in hooks:
            hook()
        response.success = True
        response.message = (f'cancelling iteration {k} ({state}) at the next step boundary; the fans '
                            f'keep the last completed iteration\'s commands')
        self.get_logger().info(response.message)
        return response

    def _handle_set_model(self, request: SetModel.Request, response: SetModel.Response):
        text, source = request.model_yaml, 'the model_yaml text'
        try:
            if not text.strip():
                if not request.path:
                    raise ConfigError('give a model file as model_yaml text or as a path')
                source = request.path
                try:
                    text = Path(request.path).read_text()
                except OSError as exc:
                    raise ConfigError(f'cannot read {request.path}: {exc.strerror or exc}') from None
            model = self._model_from_text(text, source)
        except WindShaperError as exc:
            response.success = False
            response.message = f'model refused, the old one stays: {exc} (prior in use: {self._model!r})'
            self.get_logger().warning(response.message)
            return response
        self._store.save_model_text(text)
        with self._lock:
            self._model = model
        response.success = True
        response.message = f'prior set from {source}: {model!r}'
        self.get_logger().info(response.message)
        return response

    def _model_from_text(self, text: str, source: str):
        """Build a model file's prior for the tunnel's fans and check it gives a finite Jacobian."""
        try:
            model = model_from_text(text, self._setup.geometry.fans, source=source)
        except WindShaperError as exc:
            raise ConfigError(str(exc)) from None
        J = model.jacobian(self._U, self._key_points)
        if J.shape != (len(self._key_points), len(self._fan_names)) or not np.all(np.isfinite(J)):
            raise ConfigError(f'{source}: the model\'s Jacobian at the current commands is not '
                              f'finite; check its parameters')
        return model


def main(args=None) -> int:
    return run(CoordinatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
