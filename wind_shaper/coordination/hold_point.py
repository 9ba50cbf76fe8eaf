"""One point of the held-plate calibration batch on a rig, without ROS: the logic of the
coordinator's hold_point service.

``check_point`` checks a request's commands against the tunnel (its fans, the configured
range, 0 = off) and its point before any fan moves. ``hold_point`` then applies the commands,
has the plate placed at (x, y) (a placement service, or a person carries it there), waits until
``PointRecorder`` sees the plate within the tolerance of the point and still
(``held.Stillness``), records ``samples`` poses through the field estimator and returns the
mean force of the pairs near the point. A plate that leaves the tolerance while recording fails
the point (redo it). Any port may raise ``IterationStopped`` (failed or cancelled).

Positions and tolerances [m, tunnel frame]; commands [fraction 0..1, the tunnel's fan order];
forces [N]; times [s].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

from ..core.errors import WindShaperError
from ..experiment import check_design
from .held import Stillness
from .iteration import FAILED, FieldAnswer, IterationStopped
from .requests import check_hold_request

DEFAULT_TOLERANCE_M, DEFAULT_SAMPLES, DEFAULT_TIMEOUT_S = 0.01, 20, 120.0
#: Pose rate assumed for the recording's time limit (mocap runs at 100 Hz) [Hz].
MIN_POSE_HZ = 10.0
#: How long the estimator goes on collecting after the last pose a point needs, before its
#: estimate [s]: force reaches it later than the poses (blocks of 20 samples, a sensor's RDT
#: buffering, a busy host), and a point records only 0.2 s of poses at 100 Hz: a CI run saw a
#: point whose 23 poses had 20 force samples beside them, all after the last pose.
FORCE_CATCH_UP_S = 0.3


@dataclass(frozen=True)
class HeldTarget:
    """A checked point: commands ``U`` (n_fans,), plate position (``x``, ``y``), how near it
    counts (``tolerance_m``), the poses to record and how long the plate may take to be there
    and still (``wait_s``). Zeros in a request mean the defaults."""

    U: np.ndarray
    x: float
    y: float
    tolerance_m: float
    samples: int
    wait_s: float

    @property
    def where(self) -> str:
        return f'({self.x:+.3f}, {self.y:+.3f}) m'

    def time_limit(self, service_timeout_s: float, apply_timeout_s: float, settle_s: float) -> float:
        """The longest the whole point may take [s]: placing, recording at MIN_POSE_HZ, and the
        rig's own waits."""
        return (self.wait_s + self.samples / MIN_POSE_HZ + FORCE_CATCH_UP_S + 4 * service_timeout_s
                + apply_timeout_s + settle_s)


def check_point(limits, setup, fan_names: Sequence[str], pwm: Sequence[float], x: float, y: float,
                tolerance_m: float = 0.0, samples: int = 0, timeout_s: float = 0.0) -> HeldTarget:
    """A hold_point request checked against ``setup``'s tunnel and ``limits``; WindShaperError,
    ValueError or IndexError say what is wrong before any fan is commanded."""
    check_hold_request(limits, fan_names, pwm)
    b = setup.shaping.bounds
    U = check_design(list(fan_names), np.array([pwm], dtype=float), ['this point'],
                     setup.geometry.fans, b.u_min, b.u_max, 'hold_point').commands[0]
    if not (np.isfinite(x) and np.isfinite(y)):
        raise WindShaperError(f'the point ({x}, {y}) is not finite')
    return HeldTarget(U, float(x), float(y),
                      tolerance_m if tolerance_m > 0 else DEFAULT_TOLERANCE_M,
                      int(samples) if samples > 0 else DEFAULT_SAMPLES,
                      timeout_s if timeout_s > 0 else DEFAULT_TIMEOUT_S)


class PointRecorder:
    """The plate's poses while a point is held: whether it is there and still, and while
    recording how many poses came and how many strayed beyond the tolerance."""

    def __init__(self):
        self.stillness = Stillness()
        self.recording = False
        self.poses, self.strays = 0, 0
        self.target = (0.0, 0.0, DEFAULT_TOLERANCE_M)

    def start(self, point: HeldTarget) -> None:
        self.stillness.clear()
        self.target = (point.x, point.y, point.tolerance_m)

    def on_pose(self, t: float, x: float, y: float) -> None:
        """A plate pose at time ``t`` [s]."""
        self.stillness.add(t, x, y)
        if self.recording:
            self.poses += 1
            tx, ty, tol = self.target
            if np.hypot(x - tx, y - ty) > tol:
                self.strays += 1

    def verdict(self, still_s: float) -> str:
        """'' when the plate has been at the point and still for ``still_s`` [s], else why not."""
        return self.stillness.verdict(*self.target, still_s)

    def begin_recording(self) -> None:
        self.poses, self.strays, self.recording = 0, 0, True


@dataclass(frozen=True)
class PointResult:
    """The force at a held point: mean and std [N] of the ``n`` pairs within the tolerance,
    where the plate was on average [m], and the line that says so."""

    force_mean: float
    force_std: float
    n: int
    x_mean: float
    y_mean: float
    message: str


class PointPorts(Protocol):
    """What a held point needs from the rig (the coordinator node implements it)."""

    def hold(self, U: np.ndarray) -> None:
        """Hold the commands U as the commands in force."""

    async def command_fans(self, U: np.ndarray) -> None:
        """Send U and return once the fans report it applied and have settled."""

    def check_boundary(self) -> None:
        """Raise IterationStopped on a cancel request or a passed deadline."""

    async def place(self, x: float, y: float, timeout_s: float):
        """Have the plate brought to (x, y): the placement's answer (``success``, ``message``),
        or None when no placement service is configured (a person carries it there)."""

    def info(self, message: str) -> None:
        """Log a line for the operator."""

    async def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until ``predicate()`` holds (True) or ``timeout_s`` passes (False)."""

    async def begin_sweep(self) -> None:
        """Tell the estimator to start collecting."""

    async def estimate(self, k: int, U: np.ndarray) -> FieldAnswer:
        """The estimator's answer for what it collected (its pairs even when it refuses)."""


def point_result(point: HeldTarget, sweep) -> PointResult:
    """The mean force of ``sweep``'s pairs within the point's tolerance."""
    near = (np.hypot(sweep.positions[:, 0] - point.x, sweep.positions[:, 1] - point.y)
            <= point.tolerance_m)
    f, P = sweep.forces[near], sweep.positions[near]
    mean, std, n = float(np.mean(f)), float(np.std(f)), int(near.sum())
    x_mean, y_mean = (float(v) for v in P.mean(axis=0))
    return PointResult(mean, std, n, x_mean, y_mean,
                       f'{n} poses at {point.where}: {mean:.3f} ± {std:.3f} N')


async def hold_point(point: HeldTarget, recorder: PointRecorder, ports: PointPorts, *,
                     still_s: float, service_timeout_s: float) -> PointResult:
    """Hold ``point`` (see the module docstring): the plate must stay still for ``still_s``
    [s] before recording; the recording may take ``samples / MIN_POSE_HZ`` plus
    ``service_timeout_s`` [s]. Raises IterationStopped when the point fails or is cancelled; the
    caller turns the fans off afterwards whatever happened."""
    tol, where = point.tolerance_m, point.where
    ports.hold(point.U)
    await ports.command_fans(point.U)
    ports.check_boundary()
    moved = await ports.place(point.x, point.y, point.wait_s)
    if moved is None:
        ports.info(f'hold the plate at {where} (tolerance {100 * tol:.1f} cm)')
    elif not moved.success:
        raise IterationStopped(FAILED, f'the plate could not be placed: {moved.message}')
    still = await ports.wait_for(lambda: recorder.verdict(still_s) == '', point.wait_s)
    if not still:
        raise IterationStopped(FAILED, f'the plate was not held still at {where} within '
                               f'{point.wait_s:g} s: {recorder.verdict(still_s)}')
    await ports.begin_sweep()
    recorder.begin_recording()
    got = await ports.wait_for(lambda: recorder.poses >= point.samples or recorder.strays > 0,
                               point.samples / MIN_POSE_HZ + service_timeout_s)
    recorder.recording = False
    if got and not recorder.strays:
        await ports.wait_for(lambda: False, FORCE_CATCH_UP_S)   # the force catches up
    answer = await ports.estimate(-1, point.U)   # -1: the estimate belongs to no iteration
    if recorder.strays:
        raise IterationStopped(FAILED, f'the plate left the point while recording '
                               f'({recorder.strays} pose(s) farther than {100 * tol:.1f} cm): '
                               f'hold it still and redo the point')
    sweep = answer.sweep
    if not got or sweep is None or len(sweep) == 0:
        raise IterationStopped(FAILED, f'no (force, pose) pairs at {where} ({recorder.poses} '
                               f'poses): {answer.message}; check the force sensor and mocap '
                               f'streams')
    return point_result(point, sweep)


__all__ = ['DEFAULT_SAMPLES', 'DEFAULT_TIMEOUT_S', 'DEFAULT_TOLERANCE_M', 'FORCE_CATCH_UP_S',
           'MIN_POSE_HZ', 'HeldTarget', 'PointPorts', 'PointRecorder', 'PointResult', 'check_point',
           'hold_point', 'point_result']
