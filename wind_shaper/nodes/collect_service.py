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
the next iteration: a design's last commands are never left running. The feedback's bookkeeping
is ``coordination.collect``; this class publishes it and answers the service.
"""
from __future__ import annotations

import numpy as np
from wind_shaper_msgs.msg import ExperimentStatus, SweepSamples
from wind_shaper_msgs.srv import Collect

from ..coordination import Experiment, IterationStopped, run_experiment
from ..coordination.collect import ExperimentFeedback, collect_answer, collect_time_limit
from ..coordination.requests import check_collect_request, why
from ..core.errors import WindShaperError
from ..core.limits import duration_text
from ..ros import names, qos
from ..ros.convert import sweep_to_msg
from ..ros.waiting import in_thread
from ..storage import STORED


class CollectService:
    """Collect requests for ``node`` (the coordinator: its lock, rig link and parameters); also
    the ``ExperimentPorts`` that ``run_experiment`` drives, forwarding the rig's ports."""

    def __init__(self, node):
        self.node = node
        self.active = False
        self.feedback = ExperimentFeedback()
        self._status_pub = node.create_publisher(ExperimentStatus, names.EXPERIMENT_STATUS, qos.LATCHED)
        self._sweeps_pub = node.create_publisher(SweepSamples, names.EXPERIMENT_SWEEPS, qos.COMMAND)
        node.create_service(Collect, names.COLLECT, self._handle, callback_group=node.callback_group)
        self.publish()

    # -- feedback -----------------------------------------------------------------------------------
    def set_state(self, state: str, message: str) -> None:
        self.feedback.set_state(state, message)
        self.publish()
        if message:
            self.node.get_logger().info(f'[experiment {state}] {message}')

    def warn(self, message: str) -> None:
        self.node.rig.warn(message)

    def on_pose(self, x: float, y: float) -> None:
        self.feedback.on_pose(x, y)

    def where(self, row: int) -> str:
        return self.feedback.where(row)

    def status_text(self) -> str:
        return self.feedback.status_text()

    def publish(self) -> None:
        if self.node.closing:   # an experiment ending after destroy_node: nothing to publish on
            return
        msg = ExperimentStatus(**self.feedback.status_fields(self.node.book.sweep_duration_s),
                               fan_names=self.node.fan_names)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._status_pub.publish(msg)

    # -- ExperimentPorts ----------------------------------------------------------------------------
    def check_boundary(self) -> None:
        self.node.rig.check_boundary()

    async def command_fans(self, U: np.ndarray) -> None:
        self.node.hold(U)
        await self.node.rig.command_fans(U)

    async def compute(self, fn, *args, **kwargs):
        return await self.node.rig.compute(fn, *args, **kwargs)

    async def begin_sweep(self) -> None:
        await self.node.rig.begin_sweep()

    async def sweep(self, row: int, attempt: int) -> None:
        await self.node.rig.sweep(row, attempt)

    async def bias_sensor(self) -> None:
        await self.node.rig.bias_sensor()

    async def estimate(self, row: int, U: np.ndarray):
        return await self.node.rig.estimate(-1, U)  # -1: the estimate belongs to no iteration

    def at_row(self, row: int, attempt: int) -> None:
        self.feedback.at_row(row, attempt)

    def row_done(self, row: int, outcome: str, sweep, coverage: float) -> None:
        if outcome == STORED and sweep is not None:
            self._sweeps_pub.publish(sweep_to_msg(sweep, row, self.node.fan_names,
                                                  stamp=self.node.get_clock().now().to_msg()))
        self.publish()

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
            node.begin_procedure(request.sweep_duration_s, collect_time_limit(
                request.timeout_s, len(request.commands), len(request.fan_names),
                node.params.iteration_timeout_s))
            self.feedback.start(request.name)
            self.active = True
        outcome, text, exp = ExperimentStatus.STATE_DONE, '', None
        try:
            try:   # checking the table and writing its folder take seconds for a large one
                exp = await in_thread(node, Experiment.open, node.setup, node.params.run_root,
                                      request.name, list(request.fan_names), list(request.commands),
                                      list(request.labels), request.design,
                                      {'coordinator': node.snapshot()}, name='wind_shaper-collect')
            except Exception as exc:  # noqa: BLE001 - any refusal is answered, never raised
                return self._refuse(response, why(exc))
            self.feedback.opened(exp)
            node.get_logger().info(f'experiment {request.name}: {len(exp)} sweeps from '
                                   f'{exp.design.source!r}, {len(exp.pending())} to sweep (about '
                                   f'{duration_text(plate_s)} of plate time), in {exp.folder}')
            node.rig.check_boundary()
            await run_experiment(exp, self, max_sweeps=node.params.max_sweeps,
                                 bias_zero=node.params.bias_zero)
        except IterationStopped as stop:
            outcome, text = stop.state, f'experiment {stop.state}: {stop}; '
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            node.get_logger().error(f'experiment {request.name} failed unexpectedly: {exc!r}')
            outcome, text = ExperimentStatus.STATE_FAILED, f'unexpected error: {why(exc)}; '
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
        for field, value in collect_answer(outcome, text, exp, states, coverage, summary).items():
            setattr(response, field, value)
        self.set_state(outcome, response.message)
        return response

    def _refuse(self, response: Collect.Response, reason: str) -> Collect.Response:
        response.success = False
        response.message = f'experiment refused, no fan was commanded: {reason}'
        self.node.get_logger().warning(response.message)
        return response


__all__ = ['CollectService']
