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
from std_srvs.srv import Trigger
from wind_shaper_msgs.msg import FanCommand, IterationStatus
from wind_shaper_msgs.srv import EstimateField, RunIteration, SetModel, Sweep

from ..app import Setup
from ..coordination import FanWatch, FieldAnswer, IterationStopped, ShapingRun, run_iteration
from ..control.region import RegionPlan
from ..coordination.iteration import PROGRESS
from ..coordination.requests import check_model_request, check_target_request
from ..core.errors import ConfigError, WindShaperError
from ..core.limits import Limits, excerpt
from ..core.safe_yaml import read_text_file
from ..estimation import coverage_share
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import estimate_from_msg, fan_command, pwm_from_command, sweep_from_msg
from ..ros.params import declare_parameters, param
from ..ros.runner import run
from ..ros.waiting import Waits, in_thread
from .collect_service import CollectService
from .hold_service import HoldService

STATUS_HZ = 2.0  # status rate while an iteration runs [Hz]
#: IterationStatus.state while a designed experiment (collect) runs.
STATE_COLLECTING = getattr(IterationStatus, 'STATE_COLLECTING', 'collecting')


@dataclass(frozen=True)
class CoordinatorParams:
    config_dir: str = param('', "folder holding tunnel.yaml, shaping.yaml, model.yaml ('' = the "
                            'shipped config, or $WIND_SHAPER_CONFIG)')
    run_root: str = param('runs', 'folder of the run folders (relative: to the working directory; a '
                          'node in a namespace uses <run_root>/<namespace>)')
    run_name: str = param('default', 'run folder name under run_root; an existing run is resumed')
    target: str = param('parabolic', 'target of a new run, CLI syntax (parabolic, uniform:2.5, '
                        'gaussian@LM1, expr:..., csv:...); a resumed run keeps its own')
    sweep_duration_s: float = param(20.0, 'how long one sweep lasts [s]', low=0.1, high=3600.0)
    sweep_service: str = param(names.SWEEP, "wind_shaper_msgs/Sweep service that moves the plate; "
                               "'' = wait sweep_duration_s for an operator to move it")
    stop_sweep_service: str = param(names.STOP_SWEEP, "std_srvs/Trigger service that ends the "
                                    "running sweep once the estimate is good enough; '' = none "
                                    '(the plate moves on for sweep_duration_s)')
    sweep_min_s: float = param(6.0, 'with shaping.sweep.adaptive a sweep lasts at least this long '
                               '[s]; then it ends once every key point is passed and the estimate '
                               'is good enough (sweep_duration_s is the longest)', low=0.1,
                               high=3600.0)
    sweep_check_s: float = param(1.0, 'during a sweep, ask the field_estimator this often how far '
                                 'it is (coverage, largest std: live in the status) [s]',
                                 low=0.1, high=60.0)
    place_service: str = param(names.PLACE, "wind_shaper_msgs/Place service that brings the plate "
                               "to a held-plate calibration point; '' = a person carries it there")
    settle_s: float = param(2.0, 'wait after the fans report the commands, before sweeping [s]',
                            low=0.0, high=600.0)
    hold_still_s: float = param(1.0, 'a held-plate point is recorded once the plate has stayed '
                                'within its tolerance this long [s] (a motion stage settles '
                                'sooner than a hand)', low=0.0, high=60.0)
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


class CoordinatorNode(Node):
    """Runs the shaping loop one service call at a time; see the module docstring. The run and
    the iteration's steps are ``wind_shaper.coordination``; this node only wires them to topics,
    services and timers."""

    def __init__(self, **kwargs):
        super().__init__(names.COORDINATOR, **kwargs)
        self.params = p = declare_parameters(self, CoordinatorParams)
        self.limits = declare_parameters(self, Limits, prefix='limits.')
        self.setup = Setup.load(p.config_dir or None)
        # a graph in a namespace keeps its own run folder: runs/<namespace>/<run_name>
        run_root = Path(p.run_root) / names.folder_part(self.get_namespace())
        self._run = run_ = ShapingRun.open(self.setup, run_root, p.run_name, p.target,
                                           {'coordinator': asdict(p)})
        for level, note in run_.notes:
            (self.get_logger().warning if level == 'warning' else self.get_logger().info)(note)
        self.fan_names = self._fan_names = run_.fan_names

        self.lock = self._lock = threading.Lock()
        self._running = False
        self._held: np.ndarray | None = None   # commands an experiment holds (then: off)
        self.sweep_duration_s = p.sweep_duration_s  # of the procedure running [s]
        self._applied: np.ndarray | None = None
        self._state = IterationStatus.STATE_IDLE
        self._message = ''
        self._progress = 0.0
        self._samples = 0
        self._counting = False
        self._phase_start = time.monotonic()
        self._last_failed = False
        self._status_k = run_.last_completed  # the iteration the status is about
        self._fan_watch: FanWatch | None = None
        self._applied_at: float | None = None   # time.monotonic() of the last read-back
        self._model_check = False   # a set_model request is being read (one at a time)
        self._closing = False       # destroy_node has begun: publish nothing more

        self.callback_group = self._cb = ReentrantCallbackGroup()
        self._waits = Waits(self, self._cb, IterationStopped, describe=lambda: self._state,
                            procedure='the iteration')
        self._cmd_pub = self.create_publisher(FanCommand, names.FAN_COMMAND, qos.LATCHED)
        self._status_pub = self.create_publisher(IterationStatus, names.STATUS, qos.LATCHED)
        self._diag_pub = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.create_subscription(FanCommand, names.FAN_APPLIED, self._on_fans_applied, qos.LATCHED,
                                 callback_group=self._cb)
        # the plate's poses only while a procedure runs: at 100 Hz on this single-threaded
        # executor they cost about 20 % of a core, also while the coordinator waits for a call
        self._pose_sub = None
        self._begin_client = self.create_client(Trigger, names.BEGIN_SWEEP, callback_group=self._cb)
        self._estimate_client = self.create_client(EstimateField, names.ESTIMATE_FIELD,
                                                   callback_group=self._cb)
        self._sweep_client = (self.create_client(Sweep, p.sweep_service, callback_group=self._cb)
                              if p.sweep_service else None)
        self._stop_sweep_client = (self.create_client(Trigger, p.stop_sweep_service,
                                                      callback_group=self._cb)
                                   if p.sweep_service and p.stop_sweep_service else None)
        self._sweep_policy = self.setup.shaping.make_sweep_length()
        self._sweep_std_max = self._sweep_policy.std_max(self.setup.shaping.make_rule())
        self._coverage_radius = self.setup.shaping.make_estimator().max_gap
        self._coverage = self._max_std = math.nan
        self.create_service(RunIteration, names.RUN_ITERATION, self._handle_run_iteration,
                            callback_group=self._cb)
        self.create_service(Trigger, names.CANCEL_ITERATION, self._handle_cancel_iteration,
                            callback_group=self._cb)
        self.create_service(SetModel, names.SET_MODEL, self._handle_set_model, callback_group=self._cb)
        self._collect = CollectService(self)
        self._hold = HoldService(self, p.place_service)
        self.create_timer(1.0 / p.republish_hz, self._publish_command, callback_group=self._cb)
        self.create_timer(1.0 / STATUS_HZ, self._on_status_timer, callback_group=self._cb)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=self._cb)

        self._publish_command()
        self._publish_status()
        last = run_.last_completed
        resumed = f'resuming after iteration {last}' if last >= 0 else 'new run'
        self.get_logger().info(
            f'{resumed} in {run_.store.folder}: next k={run_.k}, target {run_.target_spec!r}, '
            f'commands {np.round(run_.U, 4).tolist()}, prior {run_.model!r}')

    # -- topics ---------------------------------------------------------------------------------------
    def _on_fans_applied(self, msg: FanCommand) -> None:
        try:
            applied = pwm_from_command(msg, self._fan_names)
        except ValueError as exc:
            self.get_logger().warning(f'ignoring {self.resolve_topic_name(names.FAN_APPLIED)}: {exc}',
                                      throttle_duration_sec=10)
            return
        self._applied, self._applied_at = applied, time.monotonic()
        watch = self._fan_watch
        if watch is not None:
            watch.saw(time.monotonic(), applied)
        self._waits.poke()

    def _on_plate_pose(self, msg: PoseStamped) -> None:
        if self._counting:
            self._samples += 1
            if self._collect.active:
                self._collect.on_pose(msg.pose.position.x, msg.pose.position.y)
        if self._hold.active:
            self._hold.on_pose(msg.pose.position.x, msg.pose.position.y)

    def command_in_force(self) -> np.ndarray | None:
        """What the fans are told now: an experiment's row (or off after one), else the run's."""
        return self._held if self._held is not None else self._run.command

    def hold(self, U) -> None:
        """Hold the commands ``U`` (an experiment's row, or off after it) until an iteration
        begins, and publish them at once."""
        self._held = np.asarray(U, dtype=float).copy()
        self._publish_command()

    def _publish_command(self) -> None:
        U = self.command_in_force()
        if U is not None and not self._closing:
            self._cmd_pub.publish(fan_command(self._fan_names, U, self.get_clock().now().to_msg()))

    @property
    def closing(self) -> bool:
        """destroy_node has begun: a procedure ending now publishes and answers nothing."""
        return self._closing

    def destroy_node(self):
        # a procedure still awaiting something ends at its next step, and publishes nothing
        # into the destroyed node on its way out
        self._closing = True
        self._waits.cancel()
        super().destroy_node()

    # -- status ---------------------------------------------------------------------------------------
    def set_state(self, state: str, message: str = '') -> None:
        if self._collect.active:  # the experiment's feedback; the iteration status says so
            self._collect.set_state(state, message)
            self._publish_status()
            return
        with self._lock:
            self._state, self._message = state, message
            self._phase_start = time.monotonic()
            self._progress = PROGRESS.get(state, self._progress)
        self._publish_status()
        if message:
            self.get_logger().info(f'[{state}] {message}')

    def warn(self, message: str) -> None:
        self.get_logger().warning(message)

    def _on_status_timer(self) -> None:
        if self._collect.active:
            self._collect.publish()
        if self._running:
            self._publish_status()

    def _publish_status(self) -> None:
        if self._closing:   # a procedure ending after destroy_node: the publisher is gone
            return
        run_ = self._run
        collect = self._collect
        with self._lock:
            state, message, progress = self._state, self._message, self._progress
            samples, coverage, max_std = self._samples, self._coverage, self._max_std
            if collect.active:
                # an experiment runs: the status says so (with its row and progress) rather
                # than the idle state or the last iteration's outcome
                state, message, progress = (STATE_COLLECTING, f'experiment {collect.status_text()}'
                                            + (f': {collect.message}' if collect.message else ''),
                                            collect.progress)
                samples, coverage, max_std = collect.samples, collect.coverage, math.nan
            elif self._state == IterationStatus.STATE_SWEEPING and self._running:
                frac = (time.monotonic() - self._phase_start) / self.sweep_duration_s
                span = PROGRESS['estimating'] - PROGRESS['sweeping']
                progress = PROGRESS['sweeping'] + span * min(max(frac, 0.0), 0.99)
            U = self.command_in_force()
            U = U if U is not None else run_.U
            msg = IterationStatus(
                iteration=int(self._status_k), state=state,
                progress=float(progress), samples=int(samples), message=message,
                coverage=float(coverage), max_std=float(max_std),
                target=run_.target_spec, fan_names=self._fan_names,
                pwm=[float(u) for u in U], rmse=float(run_.last_rmse),
                run_folder=str(run_.store.folder))
        msg.header.stamp = self.get_clock().now().to_msg()
        self._status_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        run_, U = self._run, self.command_in_force()
        values = {'state': 'collecting' if self._collect.active else self._state,
                  'next_iteration': run_.k, 'target': run_.target_spec,
                  'rmse_N': run_.last_rmse, 'run_folder': str(run_.store.folder),
                  'commands': 'none yet' if U is None
                  else ' '.join(f'{n}={u:.4f}' for n, u in zip(self._fan_names, U)),
                  'prior': repr(run_.model)}
        message = f'{self._state}: {self._message}' if self._message else self._state
        self._diag_pub.publish(diag.array(self, diag.status(
            f'wind_shaper/{names.COORDINATOR}', diag.WARN if self._last_failed else diag.OK,
            message, values)))

    # -- the rig's ports for coordination.run_iteration -------------------------------------------------
    def check_boundary(self) -> None:
        self._waits.check()

    async def compute(self, fn, *args, **kwargs):
        """``fn``'s result, computed in a worker thread while the executor goes on."""
        return await in_thread(self, lambda: fn(*args, **kwargs), name='wind_shaper-compute')

    async def command_fans(self, U: np.ndarray) -> None:
        p = self.params

        def applied(since: float) -> bool:
            # only a report that arrived after the wait began: a read-back kept from before (a
            # fan_output that has since restarted and ramps from safe) proves nothing
            A, at = self._applied, self._applied_at
            return (A is not None and at is not None and at >= since
                    and np.max(np.abs(A - U)) <= p.apply_tolerance)

        self._publish_command()
        reason = await self._waits.wait(None, self._waits.remaining(p.apply_timeout_s), until=applied)
        if reason != 'done':
            got = 'nothing' if self._applied is None else np.round(self._applied, 4).tolist()
            self._waits.raise_for(reason, (
                f'the fans did not report the commands {np.round(U, 4).tolist()} applied within '
                f'{p.apply_timeout_s:g} s (tolerance {p.apply_tolerance:g}; last read-back: '
                f'{got} on {self.resolve_topic_name(names.FAN_APPLIED)}): is fan_output running and the autopilot '
                f'connected?'))
        if p.settle_s > 0:
            await self._waits.wait(None, self._waits.remaining(p.settle_s))

    async def begin_sweep(self) -> None:
        # resend is safe here: begin only clears buffers, and no sweep has started yet
        begin = await self._call(self._begin_client, Trigger.Request(), 'field_estimator',
                                 self.params.service_timeout_s, resend=True)
        if not begin.success:
            raise IterationStopped(IterationStatus.STATE_FAILED,
                                   f'begin_sweep refused: {begin.message}')
        with self._lock:
            self._samples = 0
            self._coverage = self._max_std = math.nan

    async def sweep(self, k: int, attempt: int, plan: RegionPlan | None = None) -> None:
        """Move the plate once (sweep service) or give an operator the sweep's duration, over
        the whole area or ``plan``'s region; a sweep during which the fans left their commands
        (or stopped reporting) is refused."""
        self._fan_watch = watch = FanWatch(time.monotonic(), self.command_in_force(),
                                           self.params.apply_tolerance)
        with self._lock:
            self._counting = True
        try:
            await self._move_plate(k, attempt, plan)
        finally:
            self._fan_watch = None
            with self._lock:
                self._counting = False
        problem = watch.problem(time.monotonic(), self.params.readback_timeout_s, self._fan_names)
        if problem:
            stays = (f'the rows stored so far stay: check the fans, then call {self.resolve_service_name(names.COLLECT)} '
                     f'again with the same design' if self._collect.active else
                     f'the run stays at iteration {k}: check the fans, then call '
                     f'{self.resolve_service_name(names.RUN_ITERATION)} again')
            raise IterationStopped(
                IterationStatus.STATE_FAILED,
                f'sweep discarded: {problem} (fan_output restarted, the autopilot link dropped, '
                f'or an emergency stop?); {stays}')

    async def _move_plate(self, k: int, attempt: int, plan: RegionPlan | None) -> None:
        p, duration = self.params, self.sweep_duration_s
        doing = self._collect.where(k) if self._collect.active else f'iteration {k}'
        again = '' if attempt == 1 else f' (sweep {attempt} of {p.max_sweeps})'
        where, request = 'the whole area', Sweep.Request(duration_s=duration, seed=0)
        if plan is not None:
            # the region's share of the disc sets the time, with room to spare; never below
            # the sweep's minimum
            share = plan.area.disc_share(self._run.setup.geometry.sweep_radius)
            duration = min(duration, max(p.sweep_min_s, 1.5 * share * duration))
            where = f'the region {plan.area.text()} ({int(plan.needed.sum())} key points)'
            request = Sweep.Request(duration_s=duration, seed=0,
                                    region_x=[float(v) for v in plan.area.centres[:, 0]],
                                    region_y=[float(v) for v in plan.area.centres[:, 1]],
                                    region_reach=plan.area.reach)
        # an iteration's sweep is watched (live coverage and std) and, with shaping.sweep.adaptive,
        # ends once the estimate is good enough; a designed experiment's rows sweep in full
        watched = not self._collect.active
        if self._sweep_client is not None:
            self.set_state(IterationStatus.STATE_SWEEPING,
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
            self.set_state(IterationStatus.STATE_SWEEPING,
                           f'{doing}: move the plate over {where} now '
                           f'({duration:g} s){again}')
            if watched:
                if await self._watch_sweep(k, duration, None, plan):
                    self.set_state(IterationStatus.STATE_SWEEPING,
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
        """Ask the field_estimator how far the sweep is every sweep_check_s (live coverage and
        largest std in the status) until ``motion`` (the sweep service's future, or None for an
        operator) ends or ``duration`` passes; True as soon as the estimate is good enough
        (past sweep_min_s, every key point passed, std <= the threshold) when
        shaping.sweep.adaptive is on. A region sweep (``plan``) counts its key points only and
        judges the std of the estimate fused with what it carries over."""
        p = self.params
        t0 = time.monotonic()
        while True:
            elapsed = time.monotonic() - t0
            if motion is not None and motion.done():
                return False
            if elapsed + p.sweep_check_s >= duration:   # no check left before the end
                reason = await self._waits.wait(motion, self._waits.remaining(duration - elapsed))
                if reason == 'cancelled':
                    self._waits.raise_for(reason, '')
                return False
            reason = await self._waits.wait(motion, self._waits.remaining(p.sweep_check_s))
            if reason == 'cancelled':
                self._waits.raise_for(reason, '')
            if motion is not None and motion.done():
                return False
            try:
                coverage, max_std = await self._peek(k, plan)
            except IterationStopped as exc:
                if self._waits.ending():   # a cancel or the iteration's deadline ends it here
                    raise
                self.get_logger().warning(f'no sweep progress from the field_estimator ({exc}); '
                                          f'the sweep goes on', throttle_duration_sec=10.0)
                continue
            with self._lock:
                self._coverage, self._max_std = coverage, max_std
            self._publish_status()
            if (self._sweep_policy.adaptive and time.monotonic() - t0 >= p.sweep_min_s
                    and coverage >= 1.0 and max_std <= self._sweep_std_max):
                self.get_logger().info(
                    f'iteration {k}: the estimate is good enough after {time.monotonic() - t0:.1f} s '
                    f'(coverage {100 * coverage:.0f} %, largest std {max_std:.3f} N <= '
                    f'{self._sweep_std_max:.3f} N): ending the sweep')
                return True

    async def _peek(self, k: int, plan: RegionPlan | None = None) -> tuple[float, float]:
        """(coverage [0..1], largest std [N] or NaN) of the sweep so far; a region sweep's
        coverage of its own key points, its std fused with what it carries over."""
        U = self.command_in_force()
        wait = max(2.0, self.params.sweep_check_s)   # short: the sweep goes on without it
        answer = await self._waits.call(
            self._estimate_client,
            EstimateField.Request(iteration=k, fan_names=self._fan_names,
                                  pwm=[float(u) for u in U], peek=True, required=required(plan)),
            'field_estimator', wait, ready_timeout_s=wait)
        key_points = self._run.key_points if plan is None else self._run.key_points[plan.needed]
        coverage = math.nan
        if len(answer.samples.t):
            pos = np.column_stack([answer.samples.x, answer.samples.y])
            coverage = coverage_share(pos, key_points, self._coverage_radius)
        if not (answer.success and len(answer.estimate.std)):
            return coverage, math.nan
        std = np.asarray(answer.estimate.std, dtype=float)
        if plan is not None:
            std = plan.fuse(np.asarray(answer.estimate.mean, dtype=float), std)[1]
        return coverage, float(np.max(std))

    async def _call(self, client, request, what: str, timeout_s: float, *, resend: bool = False):
        return await self._waits.call(client, request, what, timeout_s, resend=resend,
                                      ready_timeout_s=self.params.service_timeout_s)

    async def estimate(self, k: int, U: np.ndarray, plan: RegionPlan | None = None) -> FieldAnswer:
        answer = await self._call(
            self._estimate_client,
            EstimateField.Request(iteration=k, fan_names=self._fan_names, pwm=[float(u) for u in U],
                                  required=required(plan)),
            'field_estimator', self.params.service_timeout_s, resend=True)
        if not answer.success:  # a refused sweep's pairs come along when they could be paired
            refused = sweep_from_msg(answer.samples) if len(answer.samples.t) else None
            return FieldAnswer(False, answer.message, sweep=refused)
        kp, mean, std = estimate_from_msg(answer.estimate)
        return FieldAnswer(True, answer.message, kp, mean, std, sweep_from_msg(answer.samples),
                           int(answer.estimate.n_used), float(answer.compute_s))

    # -- services -------------------------------------------------------------------------------------
    async def _handle_run_iteration(self, request: RunIteration.Request,
                                    response: RunIteration.Response):
        run_ = self._run
        response.fan_names = self._fan_names
        response.run_folder = str(run_.store.folder)
        response.rmse_before = response.rmse_predicted_after = response.max_std = math.nan
        response.iteration = run_.k
        with self._lock:
            busy = self.busy()
        if busy:
            response.success, response.message = False, busy
            return response
        try:
            check_target_request(self.limits, request.target)
            # a target may read a CSV file or build an expression: off the executor
            target, rule = await in_thread(self, run_.prepare, request.target, request.step_gain)
        except Exception as exc:  # noqa: BLE001 - any refusal is answered, never raised
            response.success = False
            response.message = (f'refused, nothing changed (the run keeps target '
                                f'{run_.target_spec!r}): {_why(exc)}')
            return response
        with self._lock:
            busy = self.busy()
            if busy:
                response.success, response.message = False, busy
                return response
            self.begin_procedure(0.0, request.timeout_s if request.timeout_s > 0
                                 else self.params.iteration_timeout_s)
            self._held = None   # the run's commands again, after an experiment held its own
        try:
            spec = request.target.strip()
            if target is not None:
                with self._lock:
                    changed = run_.set_target(spec, target)
                if changed:
                    self.get_logger().info(f'target changed to {spec!r}: {target.describe()}')
            return await self._iterate(rule, response)
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            self.get_logger().error(f'iteration {run_.k} failed unexpectedly: {exc!r}')
            return self._end(response, IterationStatus.STATE_FAILED, f'unexpected error: {exc!r}')
        finally:
            self.end_procedure()

    # -- one procedure at a time: an iteration or an experiment ------------------------------------------
    def busy(self) -> str:
        """'' when idle, else why a new request must wait (call with ``lock`` held)."""
        if not self._running:
            return ''
        if self._collect.active:
            return (f'an experiment is running ({self._collect.status_text()}): wait for it or '
                    f'call {self.resolve_service_name(names.CANCEL_ITERATION)}')
        if self._hold.active:
            return (f'a held-plate point is being recorded: wait for it or call '
                    f'{self.resolve_service_name(names.CANCEL_ITERATION)}')
        return (f'an iteration is running (k={self._run.k}, {self._state}): wait for it or call '
                f'{self.resolve_service_name(names.CANCEL_ITERATION)}')

    def begin_procedure(self, sweep_duration_s: float, timeout_s: float) -> None:
        """Mark a procedure running (call with ``lock`` held): its sweeps last
        ``sweep_duration_s`` (<= 0: the parameter) and it ends by ``timeout_s`` [s] from now."""
        self._running = True
        self.sweep_duration_s = (sweep_duration_s if sweep_duration_s > 0
                                 else self.params.sweep_duration_s)
        self._waits.start(timeout_s)
        if self._pose_sub is None:
            self._pose_sub = self.create_subscription(PoseStamped, names.PLATE_POSE,
                                                      self._on_plate_pose, qos.STREAM,
                                                      callback_group=self._cb)

    def end_procedure(self) -> None:
        with self._lock:
            self._running = False
            self._counting = False
            sub, self._pose_sub = self._pose_sub, None
        if sub is not None and not self._closing:
            self.destroy_subscription(sub)
        self._publish_status()   # the commands in force may have changed (an experiment: off)

    def poke(self) -> None:
        """A message a wait may depend on arrived (the waits re-check their condition)."""
        self._waits.poke()

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

    def snapshot(self) -> dict:
        """The parameters, for the record of a run or an experiment."""
        return asdict(self.params)

    async def _iterate(self, rule, response):
        run_ = self._run
        k = run_.k
        response.iteration = k
        response.pwm_before = response.pwm_after = [float(u) for u in run_.U]
        with self._lock:
            self._samples, self._status_k = 0, k
        try:
            data = await run_iteration(run_, self, rule, max_sweeps=self.params.max_sweeps)
        except IterationStopped as stop:
            return self._end(response, stop.state, f'iteration {k} {stop.state}: {stop}'
                             + ('; the fans keep the last completed iteration\'s commands and the '
                                'run stays at this iteration' if stop.state == 'cancelled' else ''))
        with self._lock:
            self._samples = len(data.sweep)
        self._publish_command()
        response.success = True
        response.rmse_before = data.rmse
        response.rmse_predicted_after = data.rmse_predicted_after
        response.max_std = float(np.max(data.estimate.std))
        response.pwm_after = [float(u) for u in data.pwm_after]
        response.run_folder = str(run_.last_record_folder)
        response.message = run_.done_message(data)
        self._last_failed = False
        self.set_state(IterationStatus.STATE_DONE, response.message)
        return response

    def _end(self, response, state: str, message: str):
        """Answer a stopped iteration: nothing advanced, the commands in force unchanged."""
        self._last_failed = state == IterationStatus.STATE_FAILED
        response.success = False
        response.message = message
        response.pwm_after = [float(u) for u in self._run.U]
        if self._run.command is not None:
            self._publish_command()
        (self.get_logger().warning if self._last_failed else self.get_logger().info)(message)
        self.set_state(state, message)
        return response

    def _handle_cancel_iteration(self, request: Trigger.Request, response: Trigger.Response):
        with self._lock:
            if not self._running:
                response.success = False
                response.message = f'no iteration or experiment is running (state {self._state})'
                return response
            k, state = self._run.k, self._state
            collecting = self._collect.active
        self._waits.cancel()
        response.success = True
        response.message = (
            f'cancelling the experiment ({self._collect.status_text()}) at the next step boundary; '
            f'the sweeps stored so far stay and the fans go off' if collecting else
            f'cancelling iteration {k} ({state}) at the next step boundary; the fans keep the last '
            f'completed iteration\'s commands')
        self.get_logger().info(response.message)
        return response

    async def _handle_set_model(self, request: SetModel.Request, response: SetModel.Response):
        """Read and check the model off the executor (a large text takes seconds), then swap it
        in; one request at a time, every refusal answered with what was wrong."""
        with self._lock:
            busy, self._model_check = self._model_check, True
        if busy:
            response.success = False
            response.message = ('another set_model request is being checked: call again when it '
                                'is answered')
            return response
        try:
            check_model_request(self.limits, request.model_yaml, request.path)
            text, source, model = await in_thread(self, self._read_model, request.model_yaml,
                                                  request.path, name='wind_shaper-set_model')
            with self._lock:
                self._run.adopt_model(text, model)
        except Exception as exc:  # noqa: BLE001 - any refusal is answered, never raised
            response.success = False
            response.message = (f'model refused, the old one stays: {_why(exc)} (prior in use: '
                                f'{self._run.model!r})')
            self.get_logger().warning(response.message)
            return response
        finally:
            with self._lock:
                self._model_check = False
        response.success = True
        response.message = f'prior set from {source}: {model!r}'
        self.get_logger().info(response.message)
        return response

    def _read_model(self, text: str, path: str):
        """(text, source, model) of a set_model request; runs in a worker thread."""
        source = 'the model_yaml text'
        if not text.strip():
            if not path:
                raise ConfigError('give a model file as model_yaml text or as a path')
            source = path
            try:
                text = read_text_file(path, self.limits.yaml_bytes, self.limits)
            except OSError as exc:
                raise ConfigError(f'cannot read {path}: {exc.strerror or exc}') from None
        return text, source, self._run.model_from_text(text, source)


def _why(exc: Exception) -> str:
    """A refusal's reason: a WindShaperError says it; anything else is named, shortly."""
    if isinstance(exc, WindShaperError):
        return str(exc)
    return f'unexpected {type(exc).__name__}: {excerpt(str(exc), quote=False)}'


def required(plan: RegionPlan | None) -> list[bool]:
    """EstimateField's ``required`` flags for a region sweep (empty: every key point)."""
    return [] if plan is None else [bool(v) for v in plan.needed]


def main(args=None) -> int:
    return run(CoordinatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
