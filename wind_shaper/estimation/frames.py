"""Rigid transforms between the motion-capture frame, the tracked body and the tunnel frame.

Quaternions are (x, y, z, w) like geometry_msgs, Hamilton convention, active rotations: a
transform ``T_a_b`` (read "a from b") maps a point given in frame b to frame a,
``p_a = R(q) p_b + t``. ``T_a_b.compose(T_b_c)`` (also ``T_a_b @ T_b_c``) is ``T_a_c``.

``PlateRelay`` is the per-sample logic of the mocap relay node: it turns the tracked rigid
body's pose (mocap frame) into the plate centre's pose (tunnel frame) and gates it: poses with
NaN or a degenerate quaternion, poses that do not move forward in time, and jumps (a move faster
than ``max_speed_m_s`` since the last accepted pose) are rejected and counted; accepted poses
outside ``max_radius_m`` from the tunnel axis are flagged. No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple, Sequence

import numpy as np

from ..core.errors import ConfigError, FrameError

__all__ = ['quat_normalize', 'quat_multiply', 'quat_conjugate', 'quat_to_matrix', 'quat_rotate',
           'quat_to_yaw', 'quat_from_yaw', 'RigidTransform', 'Verdict', 'RelayResult',
           'RelayStats', 'PlateRelay']

#: A quaternion whose norm is further than this from 1 is refused rather than normalised.
UNIT_TOLERANCE = 1e-3


def quat_normalize(q: Sequence[float], tolerance: float = UNIT_TOLERANCE) -> np.ndarray:
    """q (x, y, z, w) scaled to norm 1. FrameError if q has NaN/inf or its norm is further than
    ``tolerance`` from 1 (a zero or garbled quaternion is not silently "fixed")."""
    arr = np.asarray(q, dtype=float).reshape(-1)
    if arr.shape != (4,):
        raise FrameError(f'a quaternion has 4 components (x, y, z, w); got {arr.size}')
    if not np.all(np.isfinite(arr)):
        raise FrameError(f'quaternion {arr.tolist()} is not finite')
    norm = float(np.linalg.norm(arr))
    if abs(norm - 1.0) > tolerance:
        raise FrameError(f'quaternion {arr.tolist()} has norm {norm:.6g}, not 1: give a unit '
                         f'quaternion in (x, y, z, w) order (identity is 0 0 0 1)')
    return arr / norm


def quat_multiply(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Hamilton product a * b of (x, y, z, w) quaternions: rotate by b, then by a."""
    ax, ay, az, aw = np.asarray(a, dtype=float)
    bx, by, bz, bw = np.asarray(b, dtype=float)
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def quat_conjugate(q: Sequence[float]) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion)."""
    x, y, z, w = np.asarray(q, dtype=float)
    return np.array([-x, -y, -z, w])


def quat_to_matrix(q: Sequence[float]) -> np.ndarray:
    """3x3 rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = np.asarray(q, dtype=float)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def quat_rotate(q: Sequence[float], v) -> np.ndarray:
    """Rotate vector(s) v, shape (3,) or (N, 3), by the unit quaternion q."""
    arr = np.asarray(v, dtype=float)
    return arr @ quat_to_matrix(q).T


def quat_to_yaw(q: Sequence[float]) -> float:
    """Yaw [rad, -pi..pi]: rotation about z of the z-y-x (yaw-pitch-roll) decomposition."""
    x, y, z, w = np.asarray(q, dtype=float)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_from_yaw(yaw: float) -> np.ndarray:
    """The rotation by ``yaw`` [rad] about z, as (x, y, z, w)."""
    return np.array([0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)])


@dataclass(frozen=True, eq=False)
class RigidTransform:
    """``T_a_b``: p_a = R(rotation) p_b + translation.

    translation (3,) [m, frame a]; rotation (4,) unit quaternion (x, y, z, w) of frame b's axes
    in frame a.
    """

    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))

    def __post_init__(self):
        t = np.asarray(self.translation, dtype=float).reshape(-1)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise FrameError(f'a translation is 3 finite numbers [m]; got {t.tolist()}')
        t.flags.writeable = False
        q = quat_normalize(self.rotation)
        q.flags.writeable = False
        object.__setattr__(self, 'translation', t)
        object.__setattr__(self, 'rotation', q)

    @classmethod
    def identity(cls) -> 'RigidTransform':
        return cls()

    @classmethod
    def from_xyz_quat(cls, values: Sequence[float]) -> 'RigidTransform':
        """From 7 numbers tx ty tz [m] qx qy qz qw (the layout of the relay's parameter)."""
        arr = np.asarray(values, dtype=float).reshape(-1)
        if arr.shape != (7,):
            raise ConfigError(f'a transform is 7 numbers: tx ty tz [m] qx qy qz qw; got '
                              f'{arr.size}')
        try:
            return cls(arr[:3], arr[3:])
        except FrameError as exc:
            raise ConfigError(f'transform {arr.tolist()}: {exc}') from None

    def compose(self, other: 'RigidTransform') -> 'RigidTransform':
        """self (T_a_b) after other (T_b_c) = T_a_c."""
        return RigidTransform(self.apply(other.translation),
                              quat_multiply(self.rotation, other.rotation))

    __matmul__ = compose

    def inverse(self) -> 'RigidTransform':
        """T_b_a of T_a_b."""
        q_inv = quat_conjugate(self.rotation)
        return RigidTransform(-quat_rotate(q_inv, self.translation), q_inv)

    def apply(self, points) -> np.ndarray:
        """Point(s) (3,) or (N, 3) [m, frame b] -> frame a."""
        return quat_rotate(self.rotation, points) + self.translation

    @property
    def matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(self.rotation)
        m[:3, 3] = self.translation
        return m

    @property
    def yaw(self) -> float:
        """Yaw of the rotation [rad]."""
        return quat_to_yaw(self.rotation)

    def allclose(self, other: 'RigidTransform', atol: float = 1e-9) -> bool:
        """Same transform (q and -q are the same rotation)."""
        same_t = np.allclose(self.translation, other.translation, atol=atol)
        return bool(same_t and abs(abs(float(np.dot(self.rotation, other.rotation))) - 1.0)
                    <= atol)

    def __repr__(self) -> str:
        t = ', '.join(f'{v:.4g}' for v in self.translation)
        q = ', '.join(f'{v:.4g}' for v in self.rotation)
        return f'RigidTransform(t=[{t}] m, q=[{q}])'


# --------------------------------------------------------------------------------------------
# plate relay

class Verdict(str, Enum):
    """What the relay did with one pose."""

    ACCEPTED = 'accepted'
    INVALID = 'invalid'   # NaN/inf position or quaternion, or a quaternion of norm far from 1
    STALE = 'stale'       # stamp not after the last accepted one (duplicate or out of order)
    JUMP = 'jump'         # moved faster than max_speed_m_s since the last accepted pose


class RelayResult(NamedTuple):
    """verdict; position (3,) [m, tunnel frame] of the plate centre and orientation (x, y, z, w)
    of the plate in the tunnel frame (None unless accepted); outside: accepted but farther than
    max_radius_m from the tunnel axis; speed: implied speed [m/s] since the last accepted pose
    (None for the first)."""

    verdict: Verdict
    position: np.ndarray | None = None
    orientation: np.ndarray | None = None
    outside: bool = False
    speed: float | None = None


@dataclass(frozen=True)
class RelayStats:
    """Counters since construction: accepted / invalid / stale / jumps; outside: accepted poses
    outside the tunnel radius."""

    accepted: int = 0
    invalid: int = 0
    stale: int = 0
    jumps: int = 0
    outside: int = 0


class PlateRelay:
    """Tracked rigid body pose (mocap frame) -> gated plate centre pose (tunnel frame).

    tunnel_from_mocap: T_tunnel_mocap (the calibrated transform); plate_offset (3,) [m]: the
    plate centre in the rigid body's frame; max_speed_m_s [m/s]: faster implied motion is a
    jump; max_radius_m [m]: accepted poses farther from the tunnel axis (x, y) are flagged.

    Jumps are judged against the last accepted pose, so after a real jump (e.g. the tracker
    re-acquired the body elsewhere) poses are accepted again once distance / elapsed time falls
    below max_speed_m_s. Times are the poses' capture stamps [s] and must increase.
    """

    def __init__(self, tunnel_from_mocap: RigidTransform, plate_offset: Sequence[float] = (0, 0, 0),
                 max_speed_m_s: float = 3.0, max_radius_m: float = 0.4):
        offset = np.asarray(plate_offset, dtype=float).reshape(-1)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise ConfigError(f'plate_offset is 3 finite numbers [m, body frame]; got '
                              f'{offset.tolist()}')
        for name, value in (('max_speed_m_s', max_speed_m_s), ('max_radius_m', max_radius_m)):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f'{name} must be a finite positive number; got {value!r}')
        self.tunnel_from_mocap = tunnel_from_mocap
        self.plate_offset = offset
        self.max_speed_m_s = float(max_speed_m_s)
        self.max_radius_m = float(max_radius_m)
        self._last_time: float | None = None
        self._last_position: np.ndarray | None = None
        self._counts = dict(accepted=0, invalid=0, stale=0, jumps=0, outside=0)

    @property
    def stats(self) -> RelayStats:
        return RelayStats(**self._counts)

    @property
    def last_time(self) -> float | None:
        """Capture time [s] of the last accepted pose."""
        return self._last_time

    @property
    def last_position(self) -> np.ndarray | None:
        """Plate centre [m, tunnel frame] of the last accepted pose."""
        return None if self._last_position is None else self._last_position.copy()

    def plate_pose(self, position: Sequence[float], orientation: Sequence[float]
                   ) -> RigidTransform:
        """T_tunnel_plate from the body pose in the mocap frame (FrameError if unusable)."""
        mocap_from_body = RigidTransform(position, orientation)
        body_from_plate = RigidTransform(self.plate_offset)
        return self.tunnel_from_mocap @ mocap_from_body @ body_from_plate

    def process(self, t: float, position: Sequence[float], orientation: Sequence[float]
                ) -> RelayResult:
        """Gate one pose: t [s] capture time; position (3,) [m, mocap frame]; orientation
        (x, y, z, w) of the rigid body in the mocap frame."""
        try:
            if not math.isfinite(t):
                raise FrameError(f'capture time {t!r} is not finite')
            pose = self.plate_pose(position, orientation)
        except FrameError:
            self._counts['invalid'] += 1
            return RelayResult(Verdict.INVALID)
        centre = pose.translation
        speed = None
        if self._last_time is not None:
            dt = t - self._last_time
            if dt <= 0.0:
                self._counts['stale'] += 1
                return RelayResult(Verdict.STALE)
            speed = float(np.linalg.norm(centre - self._last_position)) / dt
            if speed > self.max_speed_m_s:
                self._counts['jumps'] += 1
                return RelayResult(Verdict.JUMP, speed=speed)
        self._last_time = float(t)
        self._last_position = np.array(centre)
        outside = math.hypot(centre[0], centre[1]) > self.max_radius_m
        self._counts['accepted'] += 1
        if outside:
            self._counts['outside'] += 1
        return RelayResult(Verdict.ACCEPTED, np.array(centre), np.array(pose.rotation), outside,
                           speed)
