"""Errors of the socket transports. Each message says what was wrong and what to do."""
from ..core.errors import ConfigError, WindShaperError


class TransportError(WindShaperError, RuntimeError):
    """A link or client cannot do what was asked: it is closed, or its socket failed."""


class LinkConfigError(ConfigError):
    """A transport parameter (address, URL, signing key, rate, timeout) is unusable."""
