"""numpy <-> wind_shaper_msgs conversions (no business logic here)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from builtin_interfaces.msg import Time
from wind_shaper_msgs.msg import FanCommand, FieldEstimate, SweepSamples

from ..core.tunnel import Sweep
from . import names

if TYPE_CHECKING:   # the GP's module loads SciPy: nodes that only convert messages skip it
    from ..estimation import FieldEstimate as CoreEstimate


def stamp_to_seconds(stamp: Time) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def seconds_to_stamp(t: float) -> Time:
    sec = int(np.floor(t))
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


def fan_command(names_: list[str], pwm, stamp: Time | None = None) -> FanCommand:
    msg = FanCommand(names=list(names_), pwm=[float(u) for u in pwm])
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def pwm_from_command(msg: FanCommand, fan_names: list[str]) -> np.ndarray:
    """PWM fractions in ``fan_names`` order; unknown names or a length mismatch raise ValueError."""
    if len(msg.names) != len(msg.pwm):
        raise ValueError(f'FanCommand has {len(msg.names)} names but {len(msg.pwm)} pwm values')
    lookup = dict(zip(msg.names, msg.pwm))
    unknown = set(lookup) - set(fan_names)
    if unknown:
        raise ValueError(f'FanCommand names unknown fans {sorted(unknown)}; fans are {fan_names}')
    missing = [n for n in fan_names if n not in lookup]
    if missing:
        raise ValueError(f'FanCommand lacks fans {missing}')
    return np.array([lookup[n] for n in fan_names], dtype=float)


def estimate_to_msg(est: CoreEstimate, iteration: int, fan_names, pwm, n_samples: int,
                    stamp: Time | None = None) -> FieldEstimate:
    msg = FieldEstimate(iteration=int(iteration), x=est.key_points[:, 0].tolist(),
                        y=est.key_points[:, 1].tolist(), mean=est.mean.tolist(),
                        std=est.std.tolist(), fan_names=list(fan_names),
                        pwm=[float(u) for u in pwm], n_samples=int(n_samples), n_used=int(est.n_used))
    msg.header.frame_id = names.TUNNEL_FRAME
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def estimate_from_msg(msg: FieldEstimate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(key points (N, 2) [m], mean (N,) [N], std (N,) [N])."""
    return (np.column_stack([msg.x, msg.y]).astype(float), np.asarray(msg.mean, float),
            np.asarray(msg.std, float))


def sweep_to_msg(sweep: Sweep, iteration: int, fan_names, stamp: Time | None = None) -> SweepSamples:
    msg = SweepSamples(iteration=int(iteration), t=sweep.times.tolist(),
                       x=sweep.positions[:, 0].tolist(), y=sweep.positions[:, 1].tolist(),
                       force=sweep.forces.tolist(), fan_names=list(fan_names),
                       pwm=[float(u) for u in sweep.pwm])
    msg.header.frame_id = names.TUNNEL_FRAME
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def sweep_from_msg(msg: SweepSamples) -> Sweep:
    return Sweep(np.column_stack([msg.x, msg.y]).reshape(-1, 2), np.asarray(msg.force, float),
                 np.asarray(msg.t, float), np.asarray(msg.pwm, float))
