"""Messages covering the CDR layouts' corners, and a peer process publishing them.

`sample_shapes()` is shared by the CDR tests: strings of every length modulo 8 (they
move the alignment of what follows), empty sequences, negative stamps, NaN and infinite
values; `sample_lengths()` and `sample_states()` likewise for CableLength and
ModuleState. Run as a script, it publishes them on ``TOPIC``, ``TOPIC_length`` and
``TOPIC_state`` once two subscriptions to each (the test's raw and deserialising ones)
are matched, then waits for SIGINT.
"""
from __future__ import annotations

import math
import sys


def sample_shapes() -> list:
    from geometry_msgs.msg import Point, Pose
    from softsnap_interfaces.msg import ModuleShape, RobotShape

    names = ['', 'y', 'red', 'blue', 'green', 'orange', 'yellow!', 'm0000000', 'grün',
             'a' * 13]
    messages = []
    for i in range(12):
        msg = RobotShape(robot=names[i % len(names)])
        msg.header.stamp.sec = (-1 if i == 3 else 1_795_000_000 + i)
        msg.header.stamp.nanosec = 999_999_999 if i == 3 else 20_000_000 * i
        msg.header.frame_id = names[(i + 3) % len(names)]
        for k in range(i % 6):  # 0..5 modules
            n = (0, 1, 11, 11, 3)[(i + k) % 5]
            shape = ModuleShape(module=names[(i + k) % len(names)],
                                source=('commanded', 'predicted', 'simulated', '')[(i + k) % 4])
            shape.header.stamp.sec = 1_795_000_000 + k
            shape.header.stamp.nanosec = 123 * k
            shape.header.frame_id = names[(i * 7 + k) % len(names)]
            shape.cable_length = 0.2 - 0.001 * i - 1e-4 * k
            shape.angles = [0.01 * (j + 1) * (k + 1) - 0.003 * i for j in range(n)]
            if (i + k) % 3:
                shape.rib_centers = [Point(x=0.0165 * j, y=-1e-3 * j * k, z=1e-9 * i)
                                     for j in range(n + 1)]
            shape.tension = (math.nan if (i, k) == (5, 1) else math.inf if (i, k) == (5, 2)
                             else 3.5 * k)
            shape.energy = 0.25 * i
            shape.converged = bool((i + k) % 2)
            shape.residual = 1e-13 * (k + 1)
            shape.solve_time = 1.5e-4 * (i + 1)
            msg.modules.append(shape)
            if i % 4 != 1:  # some messages carry no base poses
                pose = Pose()
                pose.position.x, pose.position.y, pose.position.z = 0.07 * k, -0.01 * i, 0.0
                pose.orientation.z, pose.orientation.w = math.sin(0.1 * k), math.cos(0.1 * k)
                msg.base_poses.append(pose)
        messages.append(msg)
    return messages


def sample_lengths() -> list:
    from softsnap_interfaces.msg import CableLength

    messages = []
    for i in range(9):
        msg = CableLength(cable_length=(math.nan if i == 4 else 0.198 - 0.0031 * i))
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1_795_000_000 + i, 7 * i
        msg.header.frame_id = 'f' * i  # every length modulo 8
        messages.append(msg)
    return messages


def sample_states() -> list:
    from softsnap_interfaces.msg import ModuleState

    messages = []
    for i in range(10):
        msg = ModuleState(module='m' * i + ('grün' if i == 9 else ''), online=bool(i % 2),
                          paused=bool(i % 3), measured_cable_length=0.19 - 0.001 * i,
                          target_cable_length=math.nan if i % 4 else 0.18,
                          encoder_count=-1234 * i, encoder_target=99 * i, motor_power=255 - i,
                          battery_voltage=7.4 - 0.125 * i, last_error='e' * i)
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1_795_000_100 + i, 11 * i
        msg.header.frame_id = 'g' * (i % 5)
        messages.append(msg)
    return messages


def main(topic: str) -> int:
    import time

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from softsnap_interfaces.msg import CableLength, ModuleState, RobotShape

    rclpy.init()
    node = rclpy.create_node('shape_peer')
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    publishers = [(node.create_publisher(RobotShape, topic, qos), sample_shapes()),
                  (node.create_publisher(CableLength, f'{topic}_length', qos), sample_lengths()),
                  (node.create_publisher(ModuleState, f'{topic}_state', qos), sample_states())]
    try:
        while any(p.get_subscription_count() < 2 for p, _ in publishers):
            time.sleep(0.05)
        time.sleep(0.5)  # discovery completes on both ends
        for publisher, messages in publishers:
            for msg in messages:
                publisher.publish(msg)
        print('published', flush=True)
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else 'cdr/in'))
