"""Errors of the model workbench. Each message says what was wrong and what to do."""
from ..core.errors import WindShaperError


class WorkbenchError(WindShaperError):
    """Base class of the workbench's errors."""


class DataSourceError(WorkbenchError, ValueError):
    """Sweeps cannot be read from a bag, run folder or report, or there are too few of them."""


class WiringSweepsOnly(DataSourceError):
    """The sweeps are the single-off design: they check the wiring (``wiring``, a
    ``WiringCheck``) but do not vary the commands enough to calibrate a prior."""

    def __init__(self, message: str, wiring):
        super().__init__(message)
        self.wiring = wiring


class FitError(WorkbenchError, ValueError):
    """A model cannot be fitted to the data (too few samples, fans that do not match)."""


class CandidateError(WorkbenchError, ValueError):
    """A candidate effect is unknown or cannot apply to this model or tunnel."""
