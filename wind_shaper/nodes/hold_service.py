"""The coordinator's hold_point service: one point of the held-plate calibration batch.

``/wind_shaper/hold_point`` (wind_shaper_msgs/HoldPoint) checks the point's commands against
the tunnel (its fans, the configured range, 0 = off), applies them through fan_output and waits
for them to settle, has the plate brought to (x, y) (the ``place_service``, a motion stage or
the simulated tunnel; when that parameter is empty a person carries it there), waits until the
mocap pose shows the plate within ``tolerance_m`` of the point and still
(``coordination.held.Stillness``), then records the force over ``samples`` poses through the
field estimator (begin_sweep / estimate: the refused field estimate still returns the pairs) and
answers their mean. A plate that leaves the tolerance while recording fails the point (redo
it). Whatever the outcome, the fans are then held off. ``cancel_iteration`` cancels it.
"""
from __future__ import annotations

import time

import numpy as np
from wind_shaper_msgs.srv import HoldPoint, Place

from ..coordination import IterationStopped
from ..coordination.held import Stillness
from ..coordination.requests import check_hold_request
from ..core.errors import WindShaperError
from ..experiment import check_design
from ..ros import names

DEFAULT_TOLERANCE_M, DEFAULT_SAMPLES, DEFAULT_TIMEOUT_S = 0.01, 20, 120.0
#: Pose rate assumed for the recording's time limit (mocap runs at 100 Hz) [Hz].
MIN_POSE_HZ = 10.0
#: No answer leaves sooner than this after its request came [s]. Fast DDS drops a reply when
#: the server has not yet discovered the caller's reply reader (it waits 100 ms for it), and a
#: new command's first request follows its discovery at once: a refusal answered at once ("wait
#: for it", a point refused) was lost on a loaded machine and the command waited out its timeout.
MIN_ANSWER_S = 2.0


class HoldService:
    """hold_point requests for ``node`` (the coordinator; see the module docstring)."""

    def __init__(self, node, place_service: str):
        self.node = node
        self.active = False
        self.stillness = Stillness()
        self._place = (node.create_client(Place, place_service, callback_group=node.callback_group)
                       if place_service else None)
        self._recording = False
        self._poses, self._strays = 0, 0
        self._target = (0.0, 0.0, DEFAULT_TOLERANCE_M)
        node.create_service(HoldPoint, names.HOLD_POINT, self._handle,
                            callback_group=node.callback_group)

    def on_pose(self, x: float, y: float) -> None:
        if not self.active:
            return
        self.stillness.add(time.monotonic(), x, y)
        if self._recording:
            self._poses += 1
            tx, ty, tol = self._target
            if np.hypot(x - tx, y - ty) > tol:
                self._strays += 1
        self.node.poke()

    async def _handle(self, request: HoldPoint.Request, response: HoldPoint.Response):
        came = time.monotonic()
        response = await self._serve(request, response)
        early = MIN_ANSWER_S - (time.monotonic() - came)
        if early > 0:
            await self.node.pause(early)
        return response

    async def _serve(self, request: HoldPoint.Request, response: HoldPoint.Response):
        node = self.node
        tol = request.tolerance_m if request.tolerance_m > 0 else DEFAULT_TOLERANCE_M
        samples = int(request.samples) if request.samples > 0 else DEFAULT_SAMPLES
        wait_s = request.timeout_s if request.timeout_s > 0 else DEFAULT_TIMEOUT_S
        with node.lock:
            busy = node.busy()
            if busy:
                response.success, response.message = False, busy
                return response
            try:
                check_hold_request(node.limits, request.fan_names, request.pwm)
                b = node.setup.shaping.bounds
                U = check_design(list(request.fan_names), np.array([request.pwm], dtype=float),
                                 ['this point'], node.setup.geometry.fans, b.u_min, b.u_max,
                                 'hold_point').commands[0]
                if not (np.isfinite(request.x) and np.isfinite(request.y)):
                    raise WindShaperError(f'the point ({request.x}, {request.y}) is not finite')
            except (WindShaperError, ValueError, IndexError) as exc:
                response.success = False
                response.message = f'point refused, no fan was commanded: {exc}'
                return response
            node.begin_procedure(0.0, wait_s + samples / MIN_POSE_HZ + 4 * node.params.service_timeout_s
                                 + node.params.apply_timeout_s + node.params.settle_s)
            self.active = True
        self.stillness.clear()
        self._target = (float(request.x), float(request.y), tol)
        where = f'({request.x:+.3f}, {request.y:+.3f}) m'
        still_s = node.params.hold_still_s
        try:
            node.hold(U)
            await node.command_fans(U)
            node.check_boundary()
            if self._place is not None:
                moved = await node.call(self._place, Place.Request(x=request.x, y=request.y),
                                        'the plate placement (sim_tunnel or motion stage)', wait_s)
                if not moved.success:
                    raise IterationStopped('failed', f'the plate could not be placed: {moved.message}')
            else:
                node.get_logger().info(f'hold the plate at {where} (tolerance {100 * tol:.1f} cm)')
            still = await node.wait_for(lambda: self.stillness.verdict(*self._target, still_s) == '',
                                        wait_s)
            if not still:
                raise IterationStopped('failed', f'the plate was not held still at {where} within '
                                       f'{wait_s:g} s: {self.stillness.verdict(*self._target, still_s)}')
            await node.begin_sweep()
            self._poses, self._strays, self._recording = 0, 0, True
            got = await node.wait_for(lambda: self._poses >= samples or self._strays > 0,
                                      samples / MIN_POSE_HZ + node.params.service_timeout_s)
            self._recording = False
            answer = await node.estimate(-1, U)
            if self._strays:
                raise IterationStopped('failed', f'the plate left the point while recording '
                                       f'({self._strays} pose(s) farther than {100 * tol:.1f} cm): '
                                       f'hold it still and redo the point')
            sweep = answer.sweep
            if not got or sweep is None or len(sweep) == 0:
                raise IterationStopped('failed', f'no (force, pose) pairs at {where} ({self._poses} '
                                       f'poses): {answer.message}; check the force sensor and '
                                       f'mocap streams')
            near = np.hypot(sweep.positions[:, 0] - request.x, sweep.positions[:, 1] - request.y) <= tol
            f, P = sweep.forces[near], sweep.positions[near]
            response.success = True
            response.force_mean, response.force_std = float(np.mean(f)), float(np.std(f))
            response.n = int(near.sum())
            response.x_mean, response.y_mean = (float(v) for v in P.mean(axis=0))
            response.message = (f'{response.n} poses at {where}: {response.force_mean:.3f} ± '
                                f'{response.force_std:.3f} N')
        except IterationStopped as stop:
            response.success = False
            response.message = f'point {stop.state}: {stop}'
        except Exception as exc:  # noqa: BLE001 - the service must answer, and say why
            node.get_logger().error(f'hold_point failed unexpectedly: {exc!r}')
            response.success, response.message = False, f'unexpected error: {exc!r}'
        finally:
            self._recording = False
            self.active = False
            node.hold(np.zeros(len(node.fan_names)))   # off between points, and after the last
            node.end_procedure()
        (node.get_logger().info if response.success else node.get_logger().warning)(response.message)
        return response


__all__ = ['HoldService']
