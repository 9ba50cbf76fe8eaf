"""Geometry that a fit computes again and again, remembered.

A fit evaluates the model hundreds of times on the same points while only a few parameters move
(the thrust curves, one candidate's). Most of each evaluation is geometry that depends on the
points and on parameters that did not move: the point set each wrapper moves (a shifted jet, a
widened footprint) and each fan's footprint over it. ``remember(points, key, compute)`` returns
``compute()`` and keeps it, so the next call with the same points and the same ``key`` (the
parameters the result depends on, by value) gets the same array back. The result being the same
array object, the next level down (a footprint over the moved points) is found again as well.

Only *read-only* point sets take part: an array nobody can write to cannot change under the
cache (``FitData`` freezes its arrays). Results are returned read-only. The cache is bounded by
bytes (least recently used entries go first) and safe to use from several threads.
"""
from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict
from typing import Callable, Hashable

import numpy as np

__all__ = ['remember', 'freeze', 'clear', 'switched_off', 'MAX_BYTES']

#: Bytes of results kept at most (about 1300 footprints of 3000 points).
MAX_BYTES = 64 << 20

_lock = threading.Lock()
_entries: OrderedDict = OrderedDict()  # key -> (points, result, bytes)
_bytes = 0
_on = True


def _immutable(a: np.ndarray) -> bool:
    """Whether nothing can write to ``a``'s memory: it and every array it views are read-only."""
    while isinstance(a, np.ndarray):
        if a.flags.writeable:
            return False
        a = a.base
    return a is None or isinstance(a, bytes)


def freeze(a) -> np.ndarray:
    """``a`` as a float or int array nobody can write to (a copy unless it already is one)."""
    a = np.asarray(a)
    if _immutable(a):
        return a
    a = a.copy()
    a.flags.writeable = False
    return a


def remember(points: np.ndarray, key: Hashable, compute: Callable[[], np.ndarray | tuple]):
    """``compute()``, a pure function of ``points`` and of what ``key`` names (give parameter
    values, not objects), kept for the next call with the same read-only ``points`` and equal
    ``key``. ``compute`` returns a new array or a tuple of new arrays; they are made read-only.
    With writable ``points`` simply ``compute()``."""
    global _bytes
    if not (_on and _immutable(points)):
        return compute()
    # an entry holds its ``points``, so while it lives no other array can have their id
    full = (id(points), key)
    with _lock:
        hit = _entries.get(full)
        if hit is not None:
            _entries.move_to_end(full)
            return hit[1]
    value = compute()
    arrays = value if isinstance(value, tuple) else (value,)
    for a in arrays:
        a.flags.writeable = False
    size = sum(a.nbytes for a in arrays)
    with _lock:
        if full not in _entries:
            _entries[full] = (points, value, size)
            _bytes += size
            while _bytes > MAX_BYTES and len(_entries) > 1:
                _, (_, _, old) = _entries.popitem(last=False)
                _bytes -= old
    return value


def clear() -> None:
    """Forget every remembered result."""
    global _bytes
    with _lock:
        _entries.clear()
        _bytes = 0


@contextlib.contextmanager
def switched_off():
    """Within the block nothing is remembered (to measure what the cache saves)."""
    global _on
    clear()
    _on = False
    try:
        yield
    finally:
        _on = True
