"""The coordinator's collect service: a designed experiment through the node graph.

``/wind_shaper/collect`` (wind_shaper_msgs/Collect) runs a command table, row by row, on the same
ports as a shaping iteration (``wind_shaper.coordination.experiment``): the fans get each row's
commands through fan_output, the plate sweeps once (sweep service or an operator), the field
estimator checks the coverage, and the row is stored in ``<run_root>/<name>/`` or flagged for a
re-sweep. Feedback goes out on ``/wind_shaper/experiment/status`` (ExperimentStatus, latched: on
every change and at 2 Hz), with the live share of key points the plate has passed; every stored
row's pairs go out once on ``/wind_shaper/experiment/sweeps`` (SweepSamples, iteration = the row),
so a bag of the experiment holds exactly the sweeps of its folder. ``/wind_shaper/cancel_iteration``
cancels at the next step boundary. Whatever the outcome, the fans are then held off (0) until
the next iteration: a design's last commands are never left running.
"""
from __future__ import annotations

import math
import time

import numpy as np
from wind_shaper_msgs.msg import ExperimentStatus, SweepSamples
from wind_shaper_msgs.srv import Collect

from ..coordination import Experiment, IterationStopped, run_experiment
from ..coordination.experiment import CHECKING, COMMANDING, SWEEPING
from ..coordination.requests import check_collect_request
from ..core.errors import WindShaperError
from ..core.limits import duration_text, excerpt
from ..estimation import Coverage
from ..ros import names, qos
from ..ros.convert import sweep_to_msg
from ..ros.waiting import in_thread
from ..storage import FLAGGED, STORED

#: Share of a row's progress at the start of each state.
ROW_PROGRESS = {COMMANDING: 0.0, SWEEPING: 0.1, CHECKING: 0.9}


class CollectService:
    """Collect requests for ``node`` (the coordinator: its lock, waits, ports and parameters);
    also the ``ExperimentPorts`` that ``run_experiment`` drives, forwarding the rig's ports."""

    def __init__(self, node):
        self.node = node
        self.active = False
        self._status_pub = node.create_publisher(ExperimentStatus, names.EXPERIMENT_STATUS, qos.LATCHED)
        self._sweeps_pub = node.create_publisher(SweepSamples, names.EXPERIMENT_SWEEPS, qos.COMMAND)
        node.create_service(Collect, names.COLLECT, self._handle, callback_group=node.callback_group)
        self._exp: Experiment | None = None
        self._name, self._state, self._message = '', ExperimentStatus.STATE_IDLE, ''
        self._row, self._attempt, self._row_start = -1, 0, 0.0
        self._coverage: Coverage | None = None
        self._samples = 0
        self.progress = 0.0   # share of the experiment done [0..1], as last published
        self._publish()

    # -- feedback -----------------------------------------------------------------------------------
    def set_state(self, state: str, message: str) -> None:
        self._state, self._message = state, message
        self._row_start = time.monotonic()
        self._publish()
        if message:
            self.node.get_logger().info(f'[experiment {state}] {message}')

    def warn(self, message: str) -> None:
        self.node.warn(message)

    def on_pose(self, x: float, y: float) -> None:
        if self._coverage is not None and self._state == SWEEPING:
            self._coverage.add((x, y))
            self._samples += 1

    def where(self, row: int) -> str:
        """How messages name a row: 'sweep 3 of 12 (lhs 2)'."""
        exp = self._exp
        return f'sweep {row + 1} of {len(exp)} ({exp.design.labels[row]})' if exp else f'row {row}'

    def status_text(self) -> str:
        """'sweep 3 of 12 (lhs 2), sweeping' for messages."""
        where = self.where(self._row) if self._row >= 0 else 'starting'
        return f'{self._name}: {where}, {self._state}'

    @property
    def message(self) -> str:
        return self._message

    @property
    def samples(self) -> int:
        """Plate poses received in this sweep."""
        return self._samples

    @property
    def coverage(self) -> float:
        """Share of the key points the plate has passed in this sweep [0..1]; NaN: none yet."""
        return math.nan if self._coverage is None else float(self._coverage.share)

    def publish(self) -> None:
        self._publish()

    def _publish(self) -> None:
        if self.node.closing:   # an experiment ending after destroy_node: nothing to publish on
            return
        exp = self._exp
        msg = ExperimentStatus(name=self._name, state=self._state, sweep=int(self._row),
                               attempt=int(self._attempt), message=self._message,
                               samples=int(self._samples), fan_names=self.node.fan_names)
        if exp is not None:
            states = exp.states()
            msg.n_sweeps, msg.stored, msg.flagged = len(exp), states.count(STORED), states.count(FLAGGED)
            msg.run_folder = str(exp.folder)
            row_frac = 1.0 if self._state in ('done', 'failed', 'cancelled') else ROW_PROGRESS.get(self._state, 0.0)
            if self._state == SWEEPING:
                frac = (time.monotonic() - self._row_start) / max(self.node.sweep_duration_s, 1e-3)
                row_frac = ROW_PROGRESS[SWEEPING] + 0.8 * min(max(frac, 0.0), 0.99)
            if 0 <= self._row < len(exp):
                msg.label = exp.design.labels[self._row]
                msg.pwm = [float(u) for u in exp.design.commands[self._row]]
                done = msg.stored + msg.flagged - (1 if states[self._row] != 'pending' else 0)
                msg.progress = float(min((done + row_frac) / len(exp), 1.0))
            else:
                msg.progress = float(msg.stored / len(exp)) if len(exp) else 1.0
        if self._coverage is not None:
            msg.coverage = float(self._coverage.share)
        self.progress = float(msg.progress)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._status_pub.publish(msg)

    # -- ExperimentPorts ----------------------------------------------------------------------------
    def check_boundary(self) -> None:
        self.node.check_boundary()

    async def command_fans(self, U: np.ndarray) -> None:
        self.node.hold(U)
        await self.node.command_fans(U)

    async def compute(self, fn, *args, **kwargs):
        return await self.node.compute(fn, *args, **kwargs)

    async def begin_sweep(self) -> None:
        await self.node.begin_sweep()

    async def sweep(self, row: int, attempt: int) -> None:
        await self.node.sweep(row, attempt)

    async def estimate(self, row: int, U: np.ndarray):
        return await self.node.estimate(-1, U)  # -1: the estimate belongs to no iteration

    def at_row(self, row: int, attempt: int) -> None:
        self._row, self._attempt = row, attempt
        if attempt <= 1 and self._coverage is not None:
            self._coverage.reset()   # re-sweeps of a row pool their samples, and their coverage
            self._samples = 0

    def row_done(self, row: int, outcome: str, sweep, coverage: float) -> None:
        if outcome == STORED and sweep is not None:
            self._sweeps_pub.publish(sweep_to_msg(sweep, row, self.node.fan_names,
                                                  stamp=self.node.get_clock().now().to_msg()))
        self._publish()

    # -- the service --------------------------------------------------------------------------------
    async def _handle(self, request: Collect.Request, response: Collect.Response):
        node = self.node
        sweep_s = request.sweep_duration_s if request.sweep_duration_s > 0 else node.params.sweep_duration_s
        try:   # sizes and plate time first: nothing of a refused request is parsed or kept
            plate_s = check_collect_request(node.limits, request.name, request.design,
                                            request.fan_names, request.commands, request.labels,
                                            sweep_s + node.params.settle_s)
        except WindShaperError as exc:
            return self._refuse(response, str(exc))
        with node.lock:
            busy = node.busy()
            if busy:
                response.success = False
                response.message = busy
                return response
            rows = max(len(request.commands) // max(len(request.fan_names), 1), 1)
            node.begin_procedure(request.sweep_duration_s,
                                 request.timeout_s if request.timeout_s > 0 else
                                 rows * node.params.iteration_timeout_s)
            self._exp, self._name = None, request.name
            self._row, self._attempt, self._samples = -1, 0, 0
            self._coverage = None
            self.active = True
        outcome, text, exp = ExperimentStatus.STATE_DONE, '', None
        try:
            try:   # checking the table and writing its folder take seconds for a large one
                exp = await in_thread(node, Experiment.open, node.setup, node.params.run_root,
                                      request.name, list(request.fan_names), list(request.commands),
                                      list(request.labels), request.design,
                                      {'coordinator': node.snapshot()}, name='wind_shaper-collect')
            except Exception as exc:  # noqa: BLE001 - any refusal is answered, never raised
                return self._refuse(response, _why(exc))
            self._exp = exp
            self._coverage = Coverage(exp.store.plan.key_points, exp.radius)
            node.get_logger().info(f'experiment {request.name}: {len(exp)} sweeps from '
                                   f'{exp.design.source!r}, {len(exp.pending())} to sweep (about '
                                   f'{duration_text(plate_s)} of plate time), in {exp.folder}')
            node.check_boundary()
            await run_experiment(exp, self, max_sweeps=node.params.max_sweeps)
        except IterationStopped as stop:
            outcome, text = stop.state, f'experiment {stop.state}: {stop}; '
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            node.get_logger().error(f'experiment {request.name} failed unexpectedly: {exc!r}')
            outcome, text = ExperimentStatus.STATE_FAILED, f'unexpected error: {_why(exc)}; '
        finally:
            if exp is not None:
                node.hold(np.zeros(len(node.fan_names)))   # off, whatever happened
            self.active = False   # first: the iteration status then stops speaking of it
            node.end_procedure()
        if node.closing:   # the node is going away (Ctrl-C, SIGTERM): no one to answer
            return response
        # reading every row's record back is disk work: off the executor too
        states, coverage, summary = await in_thread(
            node, lambda: (exp.states(), exp.store.coverage(), exp.summary()))
        response.run_folder = str(exp.folder)
        response.labels = list(exp.design.labels)
        response.outcome = states
        response.coverage = [float(c) if math.isfinite(c) else math.nan for c in coverage]
        response.stored = states.count(STORED)
        response.success = outcome == ExperimentStatus.STATE_DONE and response.stored == len(exp)
        response.message = text + summary + '; the fans are off'
        self.set_state(outcome, response.message)
        return response

    def _refuse(self, response: Collect.Response, why: str) -> Collect.Response:
        response.success = False
        response.message = f'experiment refused, no fan was commanded: {why}'
        self.node.get_logger().warning(response.message)
        return response


def _why(exc: Exception) -> str:
    if isinstance(exc, WindShaperError):
        return str(exc)
    return f'unexpected {type(exc).__name__}: {excerpt(str(exc), quote=False)}'


__all__ = ['CollectService']
