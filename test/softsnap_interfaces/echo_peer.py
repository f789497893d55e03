"""A minimal peer process for the workspace round-trip test.

Republishes every softsnap_interfaces/CableLength it receives on `echo/in` to `echo/out`
with the length doubled, and answers softsnap_interfaces/SetGait by echoing the gait name.
"""
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from softsnap_interfaces.msg import CableLength
from softsnap_interfaces.srv import SetGait


class EchoPeer(Node):

    def __init__(self):
        super().__init__('echo_peer')
        self.publisher = self.create_publisher(CableLength, 'echo/out', 10)
        self.subscription = self.create_subscription(CableLength, 'echo/in', self.in_callback, 10)
        self.service = self.create_service(SetGait, 'echo/set_gait', self.set_gait_callback)

    def in_callback(self, msg: CableLength):
        msg.cable_length *= 2.0
        self.publisher.publish(msg)

    def set_gait_callback(self, request, response):
        response.success = request.period > 0.0
        response.message = f'echo:{request.gait}:{request.period:.3f}'
        return response


def main():
    # rclpy.init() is a context manager only from Kilted on; this form runs on Jazzy too.
    rclpy.init()
    try:
        rclpy.spin(EchoPeer())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
