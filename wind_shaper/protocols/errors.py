"""Errors of the protocol codecs. Each message says what was wrong and what to do."""
from ..core.errors import ConfigError, WindShaperError


class ProtocolError(WindShaperError, ValueError):
    """Bytes or a message that a codec cannot turn into a valid value."""


class NetFtPacketError(ProtocolError):
    """An ATI Net F/T RDT request or record datagram is truncated, too long or has a bad header."""


class FanCommandError(ProtocolError):
    """A fan command cannot be sent: an unknown fan name, or a NaN fraction."""


class ProtocolConfigError(ConfigError):
    """A channel map, calibration, flavour or tracker parameter is missing or out of range."""
