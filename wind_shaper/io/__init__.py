"""Socket transports for the hardware (threads, no rclpy): Net F/T RDT client, MAVLink fan link."""
from .errors import LinkConfigError, TransportError
from .mavlink_link import LinkStats, MavlinkFanLink, SendResult
from .netft_client import NetFtClient, NetFtStreamStats

__all__ = ['NetFtClient', 'NetFtStreamStats', 'MavlinkFanLink', 'SendResult', 'LinkStats',
           'TransportError', 'LinkConfigError']
