"""Publish FanCommand messages until stopped: the far end of test_interfaces' two-process test.

Usage: python fan_command_publisher.py TOPIC LIFETIME_S NAME [NAME...]

Publishes at 20 Hz; message k has ``names`` = NAME..., ``pwm[i] = (i + 1) / (len(names) + 1)``
and ``header.frame_id`` = ``str(k)``. Ends by itself after LIFETIME_S [s] or when its parent
process is gone, so a killed test run leaves nothing behind.
"""
import os
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from wind_shaper_msgs.msg import FanCommand


def main(argv):
    topic, lifetime_s, names = argv[1], float(argv[2]), argv[3:]
    parent = os.getppid()
    end = time.monotonic() + lifetime_s
    rclpy.init()
    node = rclpy.create_node('fan_command_publisher')
    publisher = node.create_publisher(FanCommand, topic, 10)
    count = 0

    def publish():
        nonlocal count
        msg = FanCommand(names=names, pwm=[(i + 1) / (len(names) + 1) for i in range(len(names))])
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.header.frame_id = str(count)
        publisher.publish(msg)
        count += 1

    node.create_timer(0.05, publish)
    print(f'publishing FanCommand on {topic}', flush=True)
    try:
        while time.monotonic() < end and os.getppid() == parent:
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f'published {count} messages on {topic}', flush=True)


if __name__ == '__main__':
    main(sys.argv)
