"""Protocol codecs (pure: no sockets, no rclpy): ATI Net F/T RDT and MAVLink fan output."""
from .errors import FanCommandError, NetFtPacketError, ProtocolConfigError, ProtocolError
from .mavlink_fans import (FanChannel, FanChannelMap, FanCommand, FanOutput, Flavour, SlewLimiter,
                           applied_fractions, build_fan_messages, servo_output_pulses)
from .netft import (RDT_PORT, NetFtCalibration, NetFtSample, RdtCommand, RdtRecord, RdtRequest,
                    RdtSequenceStats, RdtSequenceTracker, RdtStatus, SequenceVerdict,
                    decode_records, decode_request, encode_records, encode_request)

__all__ = [
    'ProtocolError', 'NetFtPacketError', 'FanCommandError', 'ProtocolConfigError',
    'RDT_PORT', 'RdtCommand', 'RdtRequest', 'RdtRecord', 'RdtStatus', 'NetFtCalibration',
    'NetFtSample', 'RdtSequenceTracker', 'RdtSequenceStats', 'SequenceVerdict',
    'encode_request', 'decode_request', 'encode_records', 'decode_records',
    'Flavour', 'FanChannel', 'FanChannelMap', 'FanCommand', 'FanOutput', 'SlewLimiter',
    'build_fan_messages', 'servo_output_pulses', 'applied_fractions',
]
