"""Publish one sweep the way the graph does: the far end of test_bag_roundtrip's recording test.

Usage: python sweep_publisher.py SWEEP_S LIFETIME_S

Waits (up to 20 s) until every topic has a subscriber (the recorder), then publishes: status
'commanding' of iteration 0 and a FanCommand (latched), status 'sweeping', SWEEP_S seconds of
force at 1 kHz (WrenchStamped stamped with its sample time on a 1 ms schedule, as the force
sensor's sample clock does, torque.x = its publication time [s], force.z = 2.5 N, frame_id = its index k)
and plate pose at 100 Hz (PoseStamped, frame 'tunnel', position x = 0.001 j, y = -0.002 j for the
j-th pose), then status 'estimating'. Prints the counts and exits; ends by itself after
LIFETIME_S [s] or when its parent process is gone.
"""
import os
import sys
import time

from geometry_msgs.msg import PoseStamped, WrenchStamped
import rclpy
import rclpy.time
from rclpy.duration import Duration
from wind_shaper.bag import topics as bt
from wind_shaper_msgs.msg import FanCommand, IterationStatus

from wind_shaper.ros import names, qos

FANS = ['fan_00', 'fan_01', 'fan_02']
PWM = [0.2, 0.4, 0.6]


def main(argv):
    sweep_s, lifetime_s = float(argv[1]), float(argv[2])
    parent = os.getppid()
    end = time.monotonic() + lifetime_s
    rclpy.init()
    node = rclpy.create_node('sweep_publisher')
    force = node.create_publisher(WrenchStamped, bt.FORCE, qos.STREAM)
    pose = node.create_publisher(PoseStamped, bt.PLATE_POSE, qos.STREAM)
    status = node.create_publisher(IterationStatus, bt.STATUS, qos.LATCHED)
    command = node.create_publisher(FanCommand, bt.FAN_COMMAND, qos.LATCHED)
    clock = node.get_clock()

    def alive():
        return time.monotonic() < end and os.getppid() == parent

    def send_status(state):
        msg = IterationStatus(iteration=0, state=state, fan_names=FANS, pwm=PWM, rmse=float('nan'))
        msg.header.stamp = clock.now().to_msg()
        status.publish(msg)

    try:
        deadline = time.monotonic() + 20.0
        while alive() and time.monotonic() < deadline and min(
                p.get_subscription_count() for p in (force, pose, status, command)) == 0:
            time.sleep(0.02)
        print('subscribers found; publishing', flush=True)
        send_status(IterationStatus.STATE_COMMANDING)
        cmd = FanCommand(names=FANS, pwm=PWM)
        cmd.header.stamp = clock.now().to_msg()
        command.publish(cmd)
        time.sleep(0.2)
        send_status(IterationStatus.STATE_SWEEPING)
        time.sleep(0.05)
        # the first stamp is read before the schedule starts, so no sample is stamped later than
        # it is published (read after, a pause between the two readings stamped samples ahead)
        stamp0_ns = clock.now().nanoseconds
        start = time.monotonic()
        k = j = 0
        while alive() and k < int(sweep_s * 1000):
            due = start + k * 1e-3
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
            # stamped with the schedule, not the publish time: a stalled publisher (busy machine)
            # sends late, as a real driver would, but its samples keep their times
            stamp = rclpy.time.Time(nanoseconds=stamp0_ns + k * 1_000_000).to_msg()
            msg = WrenchStamped()
            msg.header.stamp = stamp
            msg.header.frame_id = str(k)
            msg.wrench.force.z = 2.5
            msg.wrench.torque.x = time.time()    # when it was published [s, epoch]
            force.publish(msg)
            if k % 10 == 5:
                p = PoseStamped()
                p.header.stamp = stamp
                p.header.frame_id = names.TUNNEL_FRAME
                p.pose.position.x, p.pose.position.y = 0.001 * j, -0.002 * j
                p.pose.orientation.w = 1.0
                pose.publish(p)
                j += 1
            k += 1
        time.sleep(0.05)
        send_status(IterationStatus.STATE_ESTIMATING)
        for pub in (force, pose, status, command):
            pub.wait_for_all_acked(Duration(seconds=5))
        print(f'published {k} force and {j} pose messages', flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main(sys.argv)
