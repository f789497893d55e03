"""sim_robot as an rclpy node: what ``sim_robot --ros-args ...`` runs.

Every option of :data:`softsnap_driver.sim_robot.OPTIONS` is a read-only parameter with a
descriptor and a range (plain options before ``--ros-args`` give the defaults), so
``ros2 run softsnap_driver sim_robot --ros-args -r __ns:=/snake -p scene:=snake`` and
launch files work as for ``sim_module``.

The simulation (:class:`~softsnap_driver.sim_robot.SimRobotRunner`: its own thread and
the module servers' threads) shares no state with ROS. A timer here takes the latest
:class:`~softsnap_driver.sim_robot.RobotSnapshot` (a frozen copy, handed over under a
lock) and publishes, in the node's namespace:

- ``sim/base_pose`` (geometry_msgs/PoseStamped, frame ``world``): the robot's base
  (connector, or the first module of a chain) in the world, m;
- ``sim/payload_pose`` (geometry_msgs/PoseStamped, frame ``world``): the payload's centre,
  m (only with a payload; orientation identity);
- ``model/shape/simulated`` (softsnap_interfaces/RobotShape, frame ``world``): every
  module's simulated rib centres in its base frame (m), source ``simulated``, with
  ``base_poses`` the world poses of the module bases. ``angles`` are the simulated
  segments' bending angles (rad), ``cable_length`` the winch's cable length (m);
  ``tension`` is left 0 (the field's unit is the quasi-static
  model's, rad^2/m; the tendon tension in newtons is in the log).

Stamps are the node's clock when the snapshot is published (with ``time_factor`` 1 the
simulation runs with the wall clock).
"""
from __future__ import annotations

import argparse
import math
import sys

from geometry_msgs.msg import Point, Pose, PoseStamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from softsnap_driver.ros_parameters import SoftSnapNode
from softsnap_driver.sim_robot import (OPTIONS, PHYSICS_TIMESTEP_RANGE_S, RobotSnapshot,
                                       SimRobotRunner, build_parser, report_stop)
from softsnap_driver.spinning import run_simulator_main
from softsnap_interfaces.msg import ModuleShape, RobotShape

WORLD_FRAME = 'world'
#: Ranges of the numeric options (inclusive), as sim_robot.check_options enforces them.
RANGES = {
    'port_base': (0, 65535),
    'time_factor': (0.0, 1000.0),
    'duration_s': (0.0, 1e7),
    'payload_mass_kg': (0.0, 1.0),
    'payload_size_m': (0.0, 0.2),
    'payload_release_mm': (0.0, 200.0),
    'links_per_segment': (0, 64),
    'physics_timestep_s': PHYSICS_TIMESTEP_RANGE_S,
    'stall_torque_nm': (1e-4, 100.0),
    'no_load_rpm': (0.001, 100000.0),
    'battery_full_v': (0.1, 50.0),
    'snapshot_rate_hz': (0.1, 1000.0),
    'seed': (-1, 2**31 - 1),
    'drop_probability': (0.0, 1.0),
}


def _descriptor(name: str, kind: type, text: str) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(description=text + ' (fixed at start-up)', read_only=True)
    if name in RANGES:
        low, high = RANGES[name]
        if kind is int:
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        elif kind is float:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return descriptor


def _pose(position, orientation_wxyz) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    w, x, y, z = (float(v) for v in orientation_wxyz)
    pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z = w, x, y, z
    return pose


class SimRobotNode(SoftSnapNode):
    """Parameters in, simulation threads started; snapshots out as messages."""

    def __init__(self, defaults: argparse.Namespace):
        super().__init__('sim_robot')
        for name, (kind, _default, text) in OPTIONS.items():
            self.declare_parameter(name, kind(getattr(defaults, name)), _descriptor(name, kind, text))
        opts = argparse.Namespace(**{name: self.get_parameter(name).value for name in OPTIONS})
        # ValueError (SimRobotError, SceneError) or OSError: main reports and exits 2.
        self.runner = SimRobotRunner(opts)
        self.scene = self.runner.robot.scene
        self.base_pose_publisher = self.create_publisher(PoseStamped, 'sim/base_pose', 10)
        self.payload_publisher = (self.create_publisher(PoseStamped, 'sim/payload_pose', 10)
                                  if opts.payload != 'none' else None)
        self.shape_publisher = self.create_publisher(RobotShape, 'model/shape/simulated', 10)
        self._published_time_s = -math.inf
        self._fault_reported = False
        self.runner.start()
        for name, server in self.runner.servers.servers.items():
            self.get_logger().info(f'{name}: serving the firmware protocol on '
                                   f'{server.host}:{server.port}')
        wall_rate = opts.snapshot_rate_hz * max(opts.time_factor, 1.0)
        self.create_timer(1.0 / min(wall_rate, 200.0), self.snapshot_callback)

    def snapshot_callback(self) -> None:
        """Publish the latest snapshot if it is new; report a stopped simulation once."""
        fault = self.runner.robot.fault
        if fault and not self._fault_reported:
            self._fault_reported = True
            self.get_logger().error(fault)
        snapshot = self.runner.robot.latest_snapshot()
        if snapshot is None or snapshot.time_s <= self._published_time_s:
            return
        self._published_time_s = snapshot.time_s
        stamp = self.get_clock().now().to_msg()
        self.publish_snapshot(snapshot, stamp)

    def publish_snapshot(self, snapshot: RobotSnapshot, stamp) -> None:
        base = PoseStamped()
        base.header.stamp = stamp
        base.header.frame_id = WORLD_FRAME
        base.pose = _pose(snapshot.base_position_m, snapshot.base_orientation_wxyz)
        self.base_pose_publisher.publish(base)
        if self.payload_publisher is not None and snapshot.payload_position_m is not None:
            payload = PoseStamped()
            payload.header.stamp = stamp
            payload.header.frame_id = WORLD_FRAME
            payload.pose = _pose(snapshot.payload_position_m, (1.0, 0.0, 0.0, 0.0))
            self.payload_publisher.publish(payload)
        robot = RobotShape()
        robot.header.stamp = stamp
        robot.header.frame_id = WORLD_FRAME
        robot.robot = self.scene.name
        for module in snapshot.modules:
            shape = ModuleShape()
            shape.header.stamp = stamp
            shape.header.frame_id = f'{self.scene.name}/{module.name}'
            shape.module = module.name
            shape.source = 'simulated'
            shape.cable_length = float(module.cable_length_m)
            shape.rib_centers = [Point(x=x, y=y, z=z) for x, y, z in module.rib_centers_m]
            shape.angles = list(module.angles_rad)
            shape.converged = True
            robot.modules.append(shape)
            robot.base_poses.append(_pose(module.base_position_m, module.base_orientation_wxyz))
        self.shape_publisher.publish(robot)

    def destroy_node(self) -> None:
        runner = getattr(self, 'runner', None)
        if runner is not None:
            runner.stop()
        super().destroy_node()


def _stop(node: SimRobotNode) -> int:
    runner = node.runner
    node.destroy_node()
    return report_stop(runner)


def main(argv: list[str] | None = None) -> int:
    # The simulation and the servers run on their own threads; the executor publishes
    # snapshots and serves the parameter services.
    return run_simulator_main(argv, 'sim_robot', build_parser, SimRobotNode, _stop)


if __name__ == '__main__':
    sys.exit(main())
