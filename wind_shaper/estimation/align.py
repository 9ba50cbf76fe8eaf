"""Time alignment of one sweep's force and pose streams into (position, force) pairs.

The force sensor streams vertical force at ~1 kHz (stamped at reception), the motion capture
streams the plate position at ~100 Hz (stamped at capture). For each pose sample the plate
position is paired with the mean force over the window [t - T/2, t + T/2) around the pose stamp
t, T being the pose period (estimated from the pose stamps unless given). Windows are half-open,
so with evenly spaced poses every force sample counts in exactly one pair.

Times are seconds on one clock shared by both streams; positions [m, tunnel frame]; forces [N].
No ROS here: the field estimator node feeds it arrays taken from its message buffers.
"""
from __future__ import annotations

import threading
from collections import deque

import numpy as np

from ..core.errors import SweepError
from ..core.tunnel import Sweep

#: The force and pose streams must overlap over at least this fraction of the pose time span.
MIN_OVERLAP = 0.5


def _finite_sorted(t, *columns, what: str):
    """Drop rows with a non-finite value, sort by t (stable); returns (t, *columns)."""
    arrays = [np.asarray(a, dtype=float).ravel() for a in (t, *columns)]
    if any(a.shape != arrays[0].shape for a in arrays):
        raise SweepError(f'{what}: stamps and values differ in length '
                         f'({", ".join(str(len(a)) for a in arrays)}); every sample needs both')
    ok = np.logical_and.reduce([np.isfinite(a) for a in arrays])
    order = np.argsort(arrays[0][ok], kind='stable')
    return tuple(a[ok][order] for a in arrays)


def pose_period(pose_t) -> float:
    """The pose sampling period [s]: median spacing of the distinct finite pose stamps [s]."""
    t = np.unique(np.asarray(pose_t, dtype=float)[np.isfinite(pose_t)])
    if len(t) < 2:
        raise SweepError(f'{len(t)} distinct pose stamps: the pose period needs at least 2; '
                         f'check that the motion capture publishes the plate pose during the sweep')
    return float(np.median(np.diff(t)))


def align_sweep(force_t, force, pose_t, pose_x, pose_y, pwm=(), *, period: float | None = None,
                t0: float | None = None, min_overlap: float = MIN_OVERLAP) -> Sweep:
    """Pair each pose with the mean force in its window; returns a ``Sweep``.

    force_t (F,) [s], force (F,) vertical force [N]; pose_t (P,) [s], pose_x, pose_y (P,)
    plate centre [m, tunnel frame]; pwm: commands in force during the sweep [fraction], copied
    into the sweep. Input may be unsorted; samples with a NaN/inf stamp or value are dropped.
    period [s]: pose period (default: ``pose_period(pose_t)``); t0 [s]: origin of the returned
    times (default: the first pose stamp). Poses with no force sample in their window are
    dropped. Raises ``SweepError`` when a stream is empty or the two streams overlap over less
    than ``min_overlap`` of the pose time span (clocks out of step).
    """
    ft, fz = _finite_sorted(force_t, force, what='force stream')
    pt, px, py = _finite_sorted(pose_t, pose_x, pose_y, what='pose stream')
    if len(ft) == 0:
        raise SweepError('no finite force sample in the sweep: check that the force sensor node '
                         'streams on the force topic while the plate moves')
    if len(pt) == 0:
        raise SweepError('no finite pose sample in the sweep: check that the motion capture tracks '
                         'the plate and mocap_relay publishes the plate pose')
    if period is None:
        period = pose_period(pt)
    elif not (np.isfinite(period) and period > 0):
        raise SweepError(f'pose period must be a finite time > 0 s, got {period}')
    half = 0.5 * float(period)

    p0, p1, f0, f1 = pt[0], pt[-1], ft[0], ft[-1]
    span = (p1 - p0) + period  # the poses' windows cover this much time
    overlap = min(p1 + half, f1) - max(p0 - half, f0)
    if overlap < min_overlap * span:
        raise SweepError(
            f'force and pose streams are out of step: force stamps span [{f0:.3f}, {f1:.3f}] s, '
            f'pose stamps [{p0:.3f}, {p1:.3f}] s; they overlap {max(overlap, 0.0):.3f} s of the '
            f'{span:.3f} s sweep (starts differ by {f0 - p0:+.3f} s). Both streams must be stamped '
            f'on one clock: synchronise the machines (chrony/NTP) and set use_sim_time alike on '
            f'every node')

    csum = np.concatenate([[0.0], np.cumsum(fz)])
    lo = np.searchsorted(ft, pt - half, side='left')
    hi = np.searchsorted(ft, pt + half, side='left')
    count = hi - lo
    keep = count > 0
    if not keep.any():
        raise SweepError(f'none of the {len(pt)} poses has a force sample within +-{1e3 * half:.1f} ms '
                         f'of its stamp: the force stream has gaps over the whole sweep')
    forces = (csum[hi[keep]] - csum[lo[keep]]) / count[keep]
    origin = pt[0] if t0 is None else float(t0)
    return Sweep(np.column_stack([px[keep], py[keep]]), forces, pt[keep] - origin,
                 np.asarray(pwm, dtype=float))


class SampleBuffer:
    """Thread-safe buffer of stamped samples (t [s], v_1..v_n) keeping the newest ``max_span_s``.

    Stream callbacks ``append`` from one thread while a service takes ``arrays()`` from another.
    When the newest stamp is more than ``max_span_s`` [s] after the oldest, the oldest rows are
    dropped (and counted in ``dropped``), so a sweep nobody ends cannot fill the memory.
    """

    def __init__(self, n_values: int, max_span_s: float):
        if not max_span_s > 0:
            raise SweepError(f'a sample buffer needs max_span_s > 0 s, got {max_span_s}')
        self.n_values = int(n_values)
        self.max_span_s = float(max_span_s)
        self._rows: deque = deque()
        self._newest = -np.inf
        self._lock = threading.Lock()
        self.dropped = 0

    def append(self, t: float, *values: float) -> None:
        if len(values) != self.n_values:
            raise ValueError(f'expected {self.n_values} values per sample, got {len(values)}')
        with self._lock:
            self._rows.append((t, *values))
            if t > self._newest:
                self._newest = t
            self._drop_old_locked()

    def extend(self, t, *values) -> None:
        """Append a block of samples: ``t`` and each of ``values`` are sequences of one length,
        oldest first; the same as ``append`` of each row in turn."""
        if len(values) != self.n_values:
            raise ValueError(f'expected {self.n_values} value columns, got {len(values)}')
        rows = list(zip(t, *values))
        if any(len(v) != len(t) for v in values):
            raise ValueError(f'a block of {len(t)} stamps has value columns of lengths '
                             f'{[len(v) for v in values]}')
        if not rows:
            return
        with self._lock:
            self._rows.extend(rows)
            self._newest = max(self._newest, max(t))
            self._drop_old_locked()

    def _drop_old_locked(self) -> None:
        limit = self._newest - self.max_span_s
        while self._rows and self._rows[0][0] < limit:
            self._rows.popleft()
            self.dropped += 1

    def clear(self) -> None:
        with self._lock:
            self._rows.clear()
            self._newest = -np.inf
            self.dropped = 0

    def __len__(self) -> int:
        return len(self._rows)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(t, v_1, ..., v_n), each (rows,) float, in arrival order (a copy)."""
        with self._lock:
            rows = np.array(self._rows, dtype=float).reshape(-1, 1 + self.n_values)
        return tuple(rows[:, i].copy() for i in range(rows.shape[1]))


__all__ = ['align_sweep', 'pose_period', 'SampleBuffer', 'MIN_OVERLAP']
