"""What the live view shows, without ROS: the field at the key points (estimate, std, target,
residual), the fans (hub, command, spin) and the plate's path over the running sweep.

``wind_shaper.ros.live`` turns these into sensor_msgs/PointCloud2 and visualization_msgs for
RViz, ``wind_shaper.ros.foxglove_view`` into Foxglove schemas. Positions [m, tunnel frame];
forces [N]; commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The point cloud's fields, in order: position, then the field's values per key point.
POINT_FIELDS = ('x', 'y', 'z', 'force', 'std', 'target', 'residual')


def field_points(key_points, mean, std, target=None) -> np.ndarray:
    """(N, 7) float32 rows x, y, z = 0 [m], force, std, target, residual = force - target [N]
    (target and residual NaN when no target is known)."""
    kp = np.asarray(key_points, dtype=float).reshape(-1, 2)
    n = len(kp)
    mean = np.asarray(mean, dtype=float).reshape(-1)
    std = np.asarray(std, dtype=float).reshape(-1)
    if mean.shape != (n,) or std.shape != (n,):
        raise ValueError(f'{n} key points but {mean.size} field values and {std.size} stds')
    tgt = np.full(n, np.nan) if target is None else np.asarray(target, dtype=float).reshape(-1)
    if tgt.shape != (n,):
        raise ValueError(f'{n} key points but {tgt.size} target values')
    return np.column_stack([kp, np.zeros(n), mean, std, tgt, mean - tgt]).astype(np.float32)


@dataclass(frozen=True)
class FanView:
    """One fan as drawn: name, hub (x, y) [m], radius [m], command [0..1], spin +1 CCW / -1 CW
    (seen from above), enabled."""

    name: str
    x: float
    y: float
    radius: float
    command: float
    spin: int
    enabled: bool

    def label(self) -> str:
        turn = 'CCW' if self.spin > 0 else 'CW'
        return f'{self.name} {100 * self.command:.0f} % {turn}' if self.enabled else f'{self.name} off'


def fan_views(fans, pwm=None) -> list[FanView]:
    """The fans of a ``core.geometry.FanArray`` at commands ``pwm`` (n_fans,) (None: all 0). The
    drawn radius is a third of the distance to the nearest other hub (0.05 m for a lone fan)."""
    pos = np.asarray(fans.positions, dtype=float)
    u = np.zeros(len(pos)) if pwm is None else np.clip(np.asarray(pwm, dtype=float), 0.0, 1.0)
    if len(u) != len(pos):
        raise ValueError(f'{len(u)} commands for {len(pos)} fans')
    d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    d[np.diag_indices_from(d)] = np.inf
    nearest = d.min(axis=1) if len(pos) > 1 else np.array([0.15])
    return [FanView(str(n), float(p[0]), float(p[1]), float(r / 3), float(c), int(s), bool(e))
            for n, p, r, c, s, e in zip(fans.names, pos, nearest, u, fans.spin_sign, fans.enabled)]


class SweepTrail:
    """The plate's positions over the running sweep, at most ``max_points`` (every other point
    dropped when full, so a long sweep keeps its whole extent at a coarser step)."""

    def __init__(self, max_points: int = 2000):
        if max_points < 2:
            raise ValueError(f'max_points must be >= 2; got {max_points}')
        self.max_points = int(max_points)
        self._points: list[tuple[float, float]] = []
        self._stride, self._seen = 1, 0

    def clear(self) -> None:
        self._points.clear()
        self._stride, self._seen = 1, 0

    def add(self, x: float, y: float) -> None:
        if not (np.isfinite(x) and np.isfinite(y)):
            return
        self._seen += 1
        if (self._seen - 1) % self._stride:
            return
        self._points.append((float(x), float(y)))
        if len(self._points) > self.max_points:
            self._points = self._points[::2]
            self._stride *= 2

    @property
    def points(self) -> np.ndarray:
        return np.asarray(self._points, dtype=float).reshape(-1, 2)


__all__ = ['POINT_FIELDS', 'field_points', 'FanView', 'fan_views', 'SweepTrail']
