"""Errors of the pure core. Each message says what was wrong and what to do."""


class WindShaperError(Exception):
    """Base class of every error wind_shaper raises on purpose."""


class ConfigError(WindShaperError, ValueError):
    """A configuration value is missing, malformed or out of range."""


class TargetError(WindShaperError, ValueError):
    """A target profile (expression, CSV or name) cannot be used."""


class ModelFileError(WindShaperError, ValueError):
    """A model file cannot be read or does not describe a valid model."""


class SweepError(WindShaperError, ValueError):
    """A sweep cannot be turned into a field estimate (too few samples, bad values)."""


class FrameError(WindShaperError, ValueError):
    """A transform or pose cannot be used (NaN, a quaternion that is not of unit norm)."""


class RunFolderError(WindShaperError):
    """A run folder cannot be created, reopened or written (another tunnel, bad or missing files)."""


class LimitError(WindShaperError, ValueError):
    """An input is larger or deeper than a bound of ``core.limits.Limits``; nothing was parsed."""
