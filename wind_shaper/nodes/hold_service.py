"""The coordinator's hold_point service: one point of the held-plate calibration batch.

``/wind_shaper/hold_point`` (wind_shaper_msgs/HoldPoint) checks the point's commands against
the tunnel (its fans, the configured range, 0 = off), applies them through fan_output and waits
for them to settle, has the plate brought to (x, y) (the ``place_service``, a motion stage or
the simulated tunnel; when that parameter is empty a person carries it there), waits until the
mocap pose shows the plate within ``tolerance_m`` of the point and still
(``coordination.held.Stillness``), then records the force over ``samples`` poses through the
field estimator (begin_sweep / estimate: the refused field estimate still returns the pairs) and
answers their mean. A plate that leaves the tolerance while recording fails the point (redo
it). Whatever the outcome, the fans are then held off. ``cancel_iteration`` cancels it. The
procedure is ``coordination.hold_point``; this class wires it to the service, the placement
client and the plate's poses.
"""
from __future__ import annotations

import time

import numpy as np
from wind_shaper_msgs.srv import HoldPoint, Place

from ..coordination import IterationStopped
from ..coordination.hold_point import PointRecorder, check_point, hold_point
from ..core.errors import WindShaperError
from ..ros import names
from ..ros.log import log_note

#: No answer leaves sooner than this after its request came [s]. Fast DDS drops a reply when
#: the server has not yet discovered the caller's reply reader (it waits 100 ms for it), and a
#: new command's first request follows its discovery at once: a refusal answered at once ("wait
#: for it", a point refused) was lost on a loaded machine and the command waited out its timeout.
MIN_ANSWER_S = 2.0


class HoldService:
    """hold_point requests for ``node`` (the coordinator; see the module docstring); also the
    ``PointPorts`` that ``hold_point`` drives, forwarding the rig's ports."""

    def __init__(self, node, place_service: str):
        self.node = node
        self.active = False
        self.recorder = PointRecorder()
        self._place = (node.create_client(Place, place_service, callback_group=node.callback_group)
                       if place_service else None)
        node.create_service(HoldPoint, names.HOLD_POINT, self._handle,
                            callback_group=node.callback_group)

    def on_pose(self, x: float, y: float) -> None:
        if not self.active:
            return
        self.recorder.on_pose(time.monotonic(), x, y)
        self.node.poke()

    # -- PointPorts -------------------------------------------------------------------------------
    def hold(self, U: np.ndarray) -> None:
        self.node.hold(U)

    async def command_fans(self, U: np.ndarray) -> None:
        await self.node.rig.command_fans(U)

    def check_boundary(self) -> None:
        self.node.rig.check_boundary()

    async def place(self, x: float, y: float, timeout_s: float):
        if self._place is None:   # a person carries the plate there
            return None
        return await self.node.rig.call(self._place, Place.Request(x=x, y=y),
                                        'the plate placement (sim_tunnel or motion stage)', timeout_s)

    def info(self, message: str) -> None:
        self.node.get_logger().info(message)

    async def wait_for(self, predicate, timeout_s: float) -> bool:
        return await self.node.rig.wait_for(predicate, timeout_s)

    async def begin_sweep(self) -> None:
        await self.node.rig.begin_sweep()

    async def estimate(self, k: int, U: np.ndarray):
        return await self.node.rig.estimate(k, U)

    # -- the service ------------------------------------------------------------------------------
    async def _handle(self, request: HoldPoint.Request, response: HoldPoint.Response):
        came = time.monotonic()
        response = await self._serve(request, response)
        early = MIN_ANSWER_S - (time.monotonic() - came)
        if early > 0:
            await self.node.rig.pause(early)
        return response

    async def _serve(self, request: HoldPoint.Request, response: HoldPoint.Response):
        node, p = self.node, self.node.params
        with node.lock:
            busy = node.busy()
            if busy:
                response.success, response.message = False, busy
                return response
            try:
                point = check_point(node.limits, node.setup, request.fan_names, request.pwm,
                                    request.x, request.y, request.tolerance_m, request.samples,
                                    request.timeout_s)
            except (WindShaperError, ValueError, IndexError) as exc:
                response.success = False
                response.message = f'point refused, no fan was commanded: {exc}'
                return response
            node.begin_procedure(0.0, point.time_limit(p.service_timeout_s, p.apply_timeout_s,
                                                       p.settle_s))
            self.active = True
        self.recorder.start(point)
        try:
            result = await hold_point(point, self.recorder, self, still_s=p.hold_still_s,
                                      service_timeout_s=p.service_timeout_s)
            response.success = True
            response.force_mean, response.force_std = result.force_mean, result.force_std
            response.n, response.x_mean, response.y_mean = result.n, result.x_mean, result.y_mean
            response.message = result.message
        except IterationStopped as stop:
            response.success = False
            response.message = f'point {stop.state}: {stop}'
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            node.get_logger().error(f'hold_point failed unexpectedly: {exc!r}')
            response.success, response.message = False, f'unexpected error: {exc!r}'
        finally:
            self.recorder.recording = False
            self.active = False
            node.hold(np.zeros(len(node.fan_names)))   # off between points, and after the last
            node.end_procedure()
        log_note(node.get_logger(), not response.success, response.message)
        return response


__all__ = ['HoldService']
