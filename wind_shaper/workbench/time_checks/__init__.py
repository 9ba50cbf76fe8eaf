"""Time in the diagnosis: does the residual depend on when a force was recorded?

A stage of the diagnosis that reads the data before any candidate effect is tried
(``check_time``): each registered ``TimeCheck`` answers one question about the recording as a
whole (the fans-off sweeps' zero, the residual against the recording order, against the time
since the commands changed, against time within a sweep) and says what it found and what to do,
naming the repair of recorded sweeps (``workbench.time_repairs``). A fault in time makes every
candidate fit the wrong thing, so while one stands no effect is named (``Diagnosis``'s
``hold_on_time_fault``).

A new check is one new module here (a ``TimeCheck`` subclass decorated with
``register_time_check``) and one import line below, in the place it should run.
"""
from .base import TIME_CHECKS, Recording, TimeCheck, TimeResult, register_time_check

# the checks, in the order they run: one line each
from . import sensor_zero  # noqa: E402,F401
from . import recording_order  # noqa: E402,F401
from . import since_command  # noqa: E402,F401
from . import within_sweep  # noqa: E402,F401

from .stage import check_time, time_text  # noqa: E402

__all__ = ['TIME_CHECKS', 'TimeCheck', 'TimeResult', 'Recording', 'register_time_check',
           'check_time', 'time_text']
