"""Errors of the bag subpackage. Each message says what was wrong and what to do."""
from ..core.errors import WindShaperError


class BagError(WindShaperError):
    """Base class of the errors raised while writing, reading or replaying a bag."""


class BagNotFoundError(BagError, FileNotFoundError):
    """The bag path does not exist or is not a rosbag2 bag."""


class BagReadError(BagError):
    """The bag exists but cannot be read: damaged, truncated or never closed."""


class BagContentError(BagError, ValueError):
    """The bag is readable but lacks what was asked of it (topics, sweeps, known types)."""


class BagWriteError(BagError):
    """A bag cannot be written (the folder exists, unknown type, bag not open)."""
