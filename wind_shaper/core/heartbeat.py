"""A process's sign of life for its supervisor: a file whose modification time it keeps fresh.

``wind-shaper up`` (``wind_shaper.supervisor``) gives each node process the path of a file in
``HEARTBEAT_ENV``; the node runner (``wind_shaper.ros.runner``) calls ``Heartbeat.beat`` between
slices of its executor, so the file's age says how long the executor has not run. A node that is
alive but stuck (a callback that never returns, a publish blocked in the middle layer) stops
beating and is restarted.
"""
from __future__ import annotations

import os
import time

#: Environment variable naming the file a node touches while its executor runs.
HEARTBEAT_ENV = 'WIND_SHAPER_HEARTBEAT'


class Heartbeat:
    """Touches the file ``path`` (None: nothing to do) at most every ``period_s`` [s]."""

    def __init__(self, path: str | None, period_s: float = 0.5):
        self.path, self.period_s, self._last = path or None, period_s, -float('inf')

    @classmethod
    def from_environment(cls) -> 'Heartbeat':
        return cls(os.environ.get(HEARTBEAT_ENV))

    def beat(self) -> None:
        now = time.monotonic()
        if self.path is None or now - self._last < self.period_s:
            return
        self._last = now
        try:
            with open(self.path, 'a'):
                os.utime(self.path)
        except OSError:
            self.path = None   # the supervisor's folder is gone: nobody is listening


__all__ = ['HEARTBEAT_ENV', 'Heartbeat']
