"""Errors of the simulator. Each message says what was wrong and what to do."""
from ..core.errors import ConfigError, WindShaperError


class EffectError(ConfigError):
    """A hidden effect is unknown, or one of its parameters is out of its physical bounds."""


class CommandError(WindShaperError, ValueError):
    """A fan command or a plate position given to the simulated tunnel has the wrong shape or
    non-finite values."""
