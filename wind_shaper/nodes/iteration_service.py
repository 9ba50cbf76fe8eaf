"""The coordinator's run_iteration service: one shaping iteration per call.

``/wind_shaper/run_iteration`` (wind_shaper_msgs/RunIteration) is refused at once while another
procedure runs; a ``target`` in the request is validated before anything changes (a bad one is
refused and the run keeps its target), then ``coordination.run_iteration`` drives the rig's
ports (``RigLink``) through commanding, sweeping, estimating and updating. A stopped iteration
(failed or cancelled) leaves the run where it was and the fans at the last completed
iteration's commands; the answer says which.
"""
from __future__ import annotations

import numpy as np
from wind_shaper_msgs.msg import IterationStatus
from wind_shaper_msgs.srv import RunIteration

from ..coordination import IterationStopped, run_iteration
from ..coordination.requests import check_target_request, why
from ..ros import names
from ..ros.log import log_note
from ..ros.waiting import in_thread


class IterationService:
    """run_iteration requests for ``node`` (the coordinator: its lock, bookkeeping, rig link
    and parameters) on ``run`` (its ``ShapingRun``)."""

    def __init__(self, node, run):
        self.node, self.run = node, run
        node.create_service(RunIteration, names.RUN_ITERATION, self._handle,
                            callback_group=node.callback_group)

    async def _handle(self, request: RunIteration.Request, response: RunIteration.Response):
        node, run_ = self.node, self.run
        response.fan_names = node.fan_names
        response.run_folder = str(run_.store.folder)
        response.rmse_before = response.rmse_predicted_after = response.max_std = float('nan')
        response.iteration = run_.k
        with node.lock:
            busy = node.busy()
        if busy:
            response.success, response.message = False, busy
            return response
        try:
            check_target_request(node.limits, request.target)
            # a target may read a CSV file or build an expression: off the executor
            target, rule = await in_thread(node, run_.prepare, request.target, request.step_gain)
        except Exception as exc:  # noqa: BLE001 - any refusal is answered, never raised
            response.success = False
            response.message = (f'refused, nothing changed (the run keeps target '
                                f'{run_.target_spec!r}): {why(exc)}')
            return response
        with node.lock:
            busy = node.busy()
            if busy:
                response.success, response.message = False, busy
                return response
            node.begin_procedure(0.0, request.timeout_s if request.timeout_s > 0
                                 else node.params.iteration_timeout_s)
            node.book.held = None   # the run's commands again, after an experiment held its own
        try:
            spec = request.target.strip()
            if target is not None:
                with node.lock:
                    changed = run_.set_target(spec, target)
                if changed:
                    node.get_logger().info(f'target changed to {spec!r}: {target.describe()}')
            return await self._iterate(rule, response)
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            node.get_logger().error(f'iteration {run_.k} failed unexpectedly: {exc!r}')
            return self._end(response, IterationStatus.STATE_FAILED, f'unexpected error: {exc!r}')
        finally:
            node.end_procedure()

    async def _iterate(self, rule, response: RunIteration.Response):
        node, run_ = self.node, self.run
        k = run_.k
        response.iteration = k
        response.pwm_before = response.pwm_after = [float(u) for u in run_.U]
        with node.lock:
            node.book.start_iteration(k)
        try:
            data = await run_iteration(run_, node.rig, rule, max_sweeps=node.params.max_sweeps,
                                       bias_zero=node.params.bias_zero)
        except IterationStopped as stop:
            return self._end(response, stop.state, f'iteration {k} {stop.state}: {stop}'
                             + ('; the fans keep the last completed iteration\'s commands and the '
                                'run stays at this iteration' if stop.state == 'cancelled' else ''))
        with node.lock:
            node.book.samples = len(data.sweep)
        node.publish_command()
        response.success = True
        response.rmse_before = data.rmse
        response.rmse_predicted_after = data.rmse_predicted_after
        response.max_std = float(np.max(data.estimate.std))
        response.pwm_after = [float(u) for u in data.pwm_after]
        response.run_folder = str(run_.last_record_folder)
        response.message = run_.done_message(data)
        node.book.last_failed = False
        node.set_state(IterationStatus.STATE_DONE, response.message)
        return response

    def _end(self, response: RunIteration.Response, state: str, message: str):
        """Answer a stopped iteration: nothing advanced, the commands in force unchanged."""
        node, run_ = self.node, self.run
        node.book.stopped(state)
        response.success = False
        response.message = message
        response.pwm_after = [float(u) for u in run_.U]
        if run_.command is not None:
            node.publish_command()
        log_note(node.get_logger(), node.book.last_failed, message)
        node.set_state(state, message)
        return response


__all__ = ['IterationService']
