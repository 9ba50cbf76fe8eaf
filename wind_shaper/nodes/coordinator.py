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
``config_dir`` through ``wind_shaper.app.Setup``. The decisions and the bookkeeping are in
``wind_shaper.coordination`` (``state``, ``sweeping``, ``iteration``, ``collect``, ``hold_point``);
this node translates between them and ROS.
"""
from __future__ import annotations

import threading
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger
from wind_shaper_msgs.msg import FanCommand, IterationStatus
from wind_shaper_msgs.srv import SetModel

from ..app import Setup
from ..coordination import IterationStopped, ShapingRun
from ..coordination.requests import check_model_request, read_model, why
from ..coordination.state import CoordinatorState
from ..core.limits import Limits
from ..ros import diagnostics as diag
from ..ros import names, qos
from ..ros.convert import fan_command, pwm_from_command
from ..ros.log import log_note
from ..ros.params import declare_parameters, param
from ..ros.runner import run
from ..ros.waiting import Waits, in_thread
from .collect_service import CollectService
from .hold_service import HoldService
from .iteration_service import IterationService
from .rig_link import RigLink

STATUS_HZ = 2.0  # status rate while an iteration runs [Hz]


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
    bias_zero: str = param('never', "designed experiments (collect) and shaping iterations: bias "
                           "the force sensor (its bias service) 'never', at 'fans_off' sweeps once "
                           "the fans settled, or before 'every_sweep' with every fan off (a "
                           "spin-down and settle_s more per sweep; also zeroes a draft that blows "
                           "with the fans off)")
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
                                     'duration; an estimate: twice this, for a field_estimator '
                                     'restarted mid-sweep) [s]', low=0.1, high=600.0)
    iteration_timeout_s: float = param(300.0, 'a whole iteration may take at most this long [s] '
                                       '(a request can override it)', low=1.0, high=86400.0)
    republish_hz: float = param(2.0, "rate of republishing the command in force (fan_output's "
                                'watchdog) [Hz]', low=0.1, high=100.0)


class CoordinatorNode(Node):
    """Runs the shaping loop one service call at a time; see the module docstring. The run, the
    iteration's steps and the bookkeeping are ``wind_shaper.coordination``; this node only wires
    them to topics, services and timers."""

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
            log_note(self.get_logger(), level == 'warning', note)
        self.fan_names = run_.fan_names
        self.lock = threading.Lock()
        self.book = CoordinatorState(run_, p.sweep_duration_s)
        self._model_check = False   # a set_model request is being read (one at a time)
        self._closing = False       # destroy_node has begun: publish nothing more

        self.callback_group = self._cb = ReentrantCallbackGroup()
        self._waits = Waits(self, self._cb, IterationStopped, describe=lambda: self.book.state,
                            procedure='the iteration')
        self._cmd_pub = self.create_publisher(FanCommand, names.FAN_COMMAND, qos.LATCHED)
        self._status_pub = self.create_publisher(IterationStatus, names.STATUS, qos.LATCHED)
        self._diag_pub = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.create_subscription(FanCommand, names.FAN_APPLIED, self._on_fans_applied, qos.LATCHED,
                                 callback_group=self._cb)
        # the plate's poses only while a procedure runs: at 100 Hz on this single-threaded
        # executor they cost about 20 % of a core, also while the coordinator waits for a call
        self._pose_sub = None
        self.create_service(Trigger, names.CANCEL_ITERATION, self._handle_cancel_iteration,
                            callback_group=self._cb)
        self.create_service(SetModel, names.SET_MODEL, self._handle_set_model, callback_group=self._cb)
        self.rig = RigLink(self, run_, self.book, self._waits)
        self.iteration = IterationService(self, run_)
        self.collect = CollectService(self)
        self._hold = HoldService(self, p.place_service)
        self.create_timer(1.0 / p.republish_hz, self.publish_command, callback_group=self._cb)
        self.create_timer(1.0 / STATUS_HZ, self._on_status_timer, callback_group=self._cb)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=self._cb)

        self.publish_command()
        self.publish_status()
        last = run_.last_completed
        resumed = f'resuming after iteration {last}' if last >= 0 else 'new run'
        self.get_logger().info(
            f'{resumed} in {run_.store.folder}: next k={run_.k}, target {run_.target_spec!r}, '
            f'commands {np.round(run_.U, 4).tolist()}, prior {run_.model!r}')

    # -- topics ---------------------------------------------------------------------------------------
    def _on_fans_applied(self, msg: FanCommand) -> None:
        try:
            applied = pwm_from_command(msg, self.fan_names)
        except ValueError as exc:
            self.get_logger().warning(f'ignoring {self.resolve_topic_name(names.FAN_APPLIED)}: {exc}',
                                      throttle_duration_sec=10)
            return
        self.book.saw_applied(applied)
        self._waits.poke()

    def _on_plate_pose(self, msg: PoseStamped) -> None:
        x, y = msg.pose.position.x, msg.pose.position.y
        if self.book.count_pose() and self.collect.active:
            self.collect.on_pose(x, y)
        if self._hold.active:
            self._hold.on_pose(x, y)

    def hold(self, U) -> None:
        """Hold the commands ``U`` (an experiment's row, or off after it) until an iteration
        begins, and publish them at once."""
        self.book.hold(U)
        self.publish_command()

    def publish_command(self) -> None:
        U = self.book.command_in_force()
        if U is not None and not self._closing:
            self._cmd_pub.publish(fan_command(self.fan_names, U, self.get_clock().now().to_msg()))

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
        if self.collect.active:  # the experiment's feedback; the iteration status says so
            self.collect.set_state(state, message)
            self.publish_status()
            return
        with self.lock:
            self.book.enter(state, message)
        self.publish_status()
        if message:
            self.get_logger().info(f'[{state}] {message}')

    def _on_status_timer(self) -> None:
        if self.collect.active:
            self.collect.publish()
        if self.book.running:
            self.publish_status()

    def publish_status(self) -> None:
        if self._closing:   # a procedure ending after destroy_node: the publisher is gone
            return
        collect = self.collect
        with self.lock:
            fields = self.book.status_fields(self.fan_names,
                                             collect.feedback if collect.active else None)
        msg = IterationStatus(**fields)
        msg.header.stamp = self.get_clock().now().to_msg()
        self._status_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        failed, message, values = self.book.diagnostics(self.fan_names, self.collect.active)
        self._diag_pub.publish(diag.array(self, diag.status(
            f'wind_shaper/{names.COORDINATOR}', diag.WARN if failed else diag.OK, message, values)))

    # -- one procedure at a time: an iteration or an experiment ------------------------------------------
    def busy(self) -> str:
        """'' when idle, else why a new request must wait (call with ``lock`` held)."""
        return self.book.busy(self.resolve_service_name(names.CANCEL_ITERATION),
                              self.collect.status_text() if self.collect.active else '',
                              self._hold.active)

    def begin_procedure(self, sweep_duration_s: float, timeout_s: float) -> None:
        """Mark a procedure running (call with ``lock`` held): its sweeps last
        ``sweep_duration_s`` (<= 0: the parameter) and it ends by ``timeout_s`` [s] from now."""
        self.book.begin(sweep_duration_s)
        self._waits.start(timeout_s)
        if self._pose_sub is None:
            self._pose_sub = self.create_subscription(PoseStamped, names.PLATE_POSE,
                                                      self._on_plate_pose, qos.STREAM,
                                                      callback_group=self._cb)

    def end_procedure(self) -> None:
        with self.lock:
            self.book.end()
            sub, self._pose_sub = self._pose_sub, None
        if sub is not None and not self._closing:
            self.destroy_subscription(sub)
        self.publish_status()   # the commands in force may have changed (an experiment: off)

    def poke(self) -> None:
        """A message a wait may depend on arrived (the waits re-check their condition)."""
        self._waits.poke()

    def snapshot(self) -> dict:
        """The parameters, for the record of a run or an experiment."""
        return asdict(self.params)

    # -- services -------------------------------------------------------------------------------------
    def _handle_cancel_iteration(self, request: Trigger.Request, response: Trigger.Response):
        with self.lock:
            if not self.book.running:
                response.success = False
                response.message = f'no iteration or experiment is running (state {self.book.state})'
                return response
            message = self.book.cancel_text(self.collect.status_text() if self.collect.active else '')
        self._waits.cancel()
        response.success, response.message = True, message
        self.get_logger().info(response.message)
        return response

    async def _handle_set_model(self, request: SetModel.Request, response: SetModel.Response):
        """Read and check the model off the executor (a large text takes seconds), then swap it
        in; one request at a time, every refusal answered with what was wrong."""
        with self.lock:
            busy, self._model_check = self._model_check, True
        if busy:
            response.success = False
            response.message = ('another set_model request is being checked: call again when it '
                                'is answered')
            return response
        try:
            check_model_request(self.limits, request.model_yaml, request.path)
            text, source, model = await in_thread(self, read_model, self._run, self.limits,
                                                  request.model_yaml, request.path,
                                                  name='wind_shaper-set_model')
            with self.lock:
                self._run.adopt_model(text, model)
                warning = self._run.model_warning
        except Exception as exc:  # noqa: BLE001 - any refusal is answered, never raised
            response.success = False
            response.message = (f'model refused, the old one stays: {why(exc)} (prior in use: '
                                f'{self._run.model!r})')
            self.get_logger().warning(response.message)
            return response
        finally:
            with self.lock:
                self._model_check = False
        response.success = True
        response.message = f'prior set from {source}: {model!r}'
        if warning:
            response.message += f'; WARNING: {warning}'
            self.get_logger().warning(response.message)
        else:
            self.get_logger().info(response.message)
        return response


def main(args=None) -> int:
    return run(CoordinatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
