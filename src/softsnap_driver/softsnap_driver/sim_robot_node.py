"""sim_robot as an rclpy node: what ``sim_robot --ros-args ...`` runs.

Every option of :data:`softsnap_driver.sim_robot_runner.OPTIONS` is a read-only parameter with a
descriptor and a range (plain options before ``--ros-args`` give the defaults), so
``ros2 run softsnap_driver sim_robot --ros-args -r __ns:=/snake -p scene:=snake`` and
launch files work as for ``sim_module``.

The simulation (:class:`~softsnap_driver.sim_robot_runner.SimRobotRunner`: its own thread and
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
- ``<module>/shape/ground_truth`` (softsnap_interfaces/MeasuredShape, frame
  ``<scene>/<module>``), one per module, every ``ground_truth_rate_hz`` of simulated time
  (default 30 Hz, 0: off): the simulated rib centres in the module base frame (m, the
  MuJoCo rib bodies' origins), source ``simulator``, every rib visible, residual 0,
  ``cable_length`` the winch's cable length (m), ``rmse_to_model`` NaN (no model here).
  Sampled in the simulation thread on the ``/clock`` ticks (one instant, stamped with the
  physics' time) and published by a thread of its own
  (:mod:`softsnap_driver.sim_observation`), so the physics never waits for ROS.

and, on the absolute ``/clock`` (rosgraph_msgs/Clock, the QoS every ROS clock source uses:
keep last 1, best effort, volatile), the simulation time every ``clock_rate_hz`` of
simulated time (default 50 Hz; the tick's own time, an exact grid), from the simulation
thread right after the step that reached it. Every other node of a simulated robot runs with ``use_sim_time:=true`` (the
demo's and the launch files' graph sets it), so their timers, stamps and the gait follow
the simulation, also when it runs slower than real time. The simulation time starts at 0
when sim_robot starts; the first ``/clock`` is one clock period later.

Stamps of the published snapshots are their simulation time (the same clock). This node's
own timer runs on the steady clock: it publishes what the simulation thread made,
whatever the time source of the graph.
"""
from __future__ import annotations

import argparse
import math
import sys

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMessage

from softsnap_ros.node import SoftSnapNode, table_descriptor
from softsnap_driver.sim_camera_publisher import CAMERA_OPTIONS, CAMERA_RANGES
from softsnap_driver.sim_observation import (DEFAULT_GROUND_TRUTH_RATE_HZ, GroundTruthSample,
                                             ObservationWorker, TickSchedule,
                                             sample_ground_truth)
from softsnap_driver.sim_robot import PHYSICS_TIMESTEP_RANGE_S, RobotSnapshot, SimRobotError
from softsnap_driver.sim_robot_runner import (OPTIONS, SimRobotRunner, _bool_text, build_parser,
                                              report_stop)
from softsnap_ros.spinning import run_simulator_main
from softsnap_ros.units import NS_PER_S, sec_nanosec
from softsnap_interfaces.msg import MeasuredShape, ModuleShape, RobotShape

WORLD_FRAME = 'world'
#: QoS of ``/clock``: what rclcpp's ClockQoS and rclpy's TimeSource use (only the newest
#: time matters; a late subscriber waits for the next one).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
#: Ranges of the numeric options (inclusive), as sim_robot.check_options enforces them.
RANGES = {
    'port_base': (0, 65535),
    'time_factor': (0.0, 1000.0),
    'duration_s': (0.0, 1e7),
    'payload_mass_kg': (0.0, 1.0),
    'payload_size_m': (0.0, 0.2),
    'payload_height_m': (0.0, 0.4),
    'payload_release_mm': (0.0, 200.0),
    'links_per_segment': (0, 64),
    'physics_timestep_s': PHYSICS_TIMESTEP_RANGE_S,
    'stall_torque_nm': (1e-4, 100.0),
    'no_load_rpm': (0.001, 100000.0),
    'battery_full_v': (0.1, 50.0),
    'snapshot_rate_hz': (0.1, 1000.0),
    'clock_rate_hz': (1.0, 1000.0),
    'seed': (-1, 2**31 - 1),
    'drop_probability': (0.0, 1.0),
    'ground_truth_rate_hz': (0.0, 1000.0),
    **CAMERA_RANGES,
}
#: Options of the node only (published topics; the simulation without ROS has none):
#: name: (type, default, help), as sim_robot.OPTIONS.
NODE_OPTIONS = {
    'ground_truth_rate_hz': (float, DEFAULT_GROUND_TRUTH_RATE_HZ,
                             'every module\'s simulated rib centres published as '
                             'MeasuredShape on <module>/shape/ground_truth this often, Hz of '
                             'simulated time (at most clock_rate_hz; 0: off)'),
    **CAMERA_OPTIONS,
}


def _descriptor(name: str, kind: type, text: str) -> ParameterDescriptor:
    return table_descriptor(kind, text, RANGES.get(name))


def _stamp(time_s: float) -> Time:
    """A simulation time (s, >= 0) as a message stamp, to the nanosecond."""
    sec, nanosec = sec_nanosec(round(time_s * NS_PER_S))
    return Time(sec=sec, nanosec=nanosec)


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
        options = {**OPTIONS, **NODE_OPTIONS}
        for name, (kind, _default, text) in options.items():
            self.declare_parameter(name, kind(getattr(defaults, name)), _descriptor(name, kind, text))
        opts = argparse.Namespace(**{name: self.get_parameter(name).value for name in options})
        _check_node_options(opts)
        if opts.camera:
            from softsnap_driver.sim_camera import CameraError, offscreen_backend
            try:
                offscreen_backend()   # before mujoco is imported: it reads MUJOCO_GL once
            except CameraError as exc:
                raise SimRobotError(f'camera: {exc}') from None
        # ValueError (SimRobotError, SceneError) or OSError: main reports and exits 2.
        self.runner = SimRobotRunner(opts)
        self.scene = self.runner.robot.scene
        self.camera = self._start_camera(opts) if opts.camera else None
        self.base_pose_publisher = self.create_publisher(PoseStamped, 'sim/base_pose', 10)
        self.payload_publisher = (self.create_publisher(PoseStamped, 'sim/payload_pose', 10)
                                  if opts.payload != 'none' else None)
        self.shape_publisher = self.create_publisher(RobotShape, 'model/shape/simulated', 10)
        self.clock_publisher = self.create_publisher(ClockMessage, '/clock', CLOCK_QOS)
        self._clock_message = ClockMessage()
        self._published_time_s = -math.inf
        self._fault_reported = False
        self._start_ground_truth(opts.ground_truth_rate_hz)
        self.runner.robot.clock_listener = self.tick_callback
        self.runner.start()
        for name, server in self.runner.servers.servers.items():
            self.get_logger().info(f'{name}: serving the firmware protocol on '
                                   f'{server.host}:{server.port}')
        wall_rate = opts.snapshot_rate_hz * max(opts.time_factor, 1.0)
        # The steady clock: with use_sim_time set on this node too (a launch-wide
        # setting), the timer would otherwise wait for the clock this node makes.
        self.create_timer(1.0 / min(wall_rate, 200.0), self.snapshot_callback,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _start_ground_truth(self, rate_hz: float) -> None:
        self._ground_truth_schedule = TickSchedule(rate_hz) if rate_hz > 0 else None
        self._ground_truth_publishers = {}
        self._ground_truth_worker = None
        if self._ground_truth_schedule is None:
            return
        for name in self.runner.robot.module_names:
            # Depth 100: a reader that falls seconds behind (a demo observer on a loaded
            # machine) still gets every sample; they are small.
            self._ground_truth_publishers[name] = self.create_publisher(
                MeasuredShape, f'{name}/shape/ground_truth', 100)
        self._ground_truth_worker = ObservationWorker(
            'sim_robot.ground_truth', self.publish_ground_truth, self._observation_failed)

    def _start_camera(self, opts):
        from softsnap_driver.sim_camera import CameraError
        from softsnap_driver.sim_camera_publisher import (CameraPublisher, camera_settings,
                                                          marker_layout)
        try:
            camera = CameraPublisher(self, self.runner.robot.simulation, camera_settings(opts),
                                     marker_layout(opts, self.scene), opts.camera_rate_hz,
                                     f'{self.scene.name}/camera_optical')
        except CameraError as exc:
            raise SimRobotError(str(exc)) from None
        self.get_logger().info(camera.describe())
        return camera

    def tick_callback(self, time_s: float) -> None:
        """Each /clock tick (the simulation thread): publish the clock, sample what is due.

        Never raises into the simulation loop (a failed sample is logged).
        """
        self.clock_callback(time_s)
        schedule = self._ground_truth_schedule
        if schedule is not None and schedule.due(time_s):
            try:
                sample = sample_ground_truth(self.runner.robot.simulation,
                                             self.runner.robot.module_names)
            except Exception as exc:  # noqa: BLE001 - the physics must not stop for it
                self._observation_failed(None, exc)
                return
            if not self._ground_truth_worker.offer(sample):
                self.get_logger().warning(
                    f'ground truth publishing falls behind: {self._ground_truth_worker.dropped} '
                    'samples dropped so far', throttle_duration_sec=5.0)
        if self.camera is not None:
            self.camera.on_tick(time_s)

    def publish_ground_truth(self, sample: GroundTruthSample) -> None:
        """One MeasuredShape per module (the worker thread): source "simulator", every rib
        visible, residual 0, no model comparison (rmse_to_model NaN)."""
        stamp = _stamp(sample.time_s)
        for name, centers, length_m in zip(sample.names, sample.rib_centers_m.tolist(),
                                           sample.cable_lengths_m):
            shape = MeasuredShape()
            shape.header.stamp = stamp
            shape.header.frame_id = f'{self.scene.name}/{name}'
            shape.module = name
            shape.source = 'simulator'
            shape.rib_centers = [Point(x=x, y=y, z=z) for x, y, z in centers]
            shape.visible = [True] * len(centers)
            shape.residual = 0.0
            shape.cable_length = float(length_m)
            shape.rmse_to_model = math.nan
            self._ground_truth_publishers[name].publish(shape)

    def _observation_failed(self, item, exc: BaseException) -> None:
        if self.context.ok():
            self.get_logger().error(f'simulation sample not published: {exc!r}',
                                    throttle_duration_sec=5.0)

    def clock_callback(self, time_s: float) -> None:
        """Publish the simulation time on /clock (called from the simulation thread).

        Never raises into the simulation loop: a failed publish (the context shutting
        down) is logged, and the simulation goes on.
        """
        message = self._clock_message   # only the simulation thread touches it
        message.clock = _stamp(time_s)
        try:
            self.clock_publisher.publish(message)
        except Exception as exc:  # noqa: BLE001 - the physics must not stop for a publish
            if self.context.ok():
                self.get_logger().error(f'/clock not published: {exc!r}',
                                        throttle_duration_sec=5.0)

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
        self.publish_snapshot(snapshot, _stamp(snapshot.time_s))

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
        worker = getattr(self, '_ground_truth_worker', None)
        if worker is not None:
            worker.stop()
        camera = getattr(self, 'camera', None)
        if camera is not None:
            camera.stop()
        super().destroy_node()


def _check_node_options(opts: argparse.Namespace) -> None:
    """Raise SimRobotError naming a node option outside its range."""
    for name, low in (('ground_truth_rate_hz', 0.0), ('camera_rate_hz', 0.1)):
        rate = getattr(opts, name)
        if not (math.isfinite(rate) and low <= rate <= opts.clock_rate_hz):
            raise SimRobotError(f'{name} must be in [{low:g}, clock_rate_hz = '
                                f'{opts.clock_rate_hz:g}] Hz (samples are taken on /clock '
                                f'ticks), got {rate!r}')
    if opts.camera:
        from softsnap_driver.sim_camera_publisher import camera_settings
        try:
            camera_settings(opts)
        except ValueError as exc:
            raise SimRobotError(str(exc)) from None


def build_node_parser() -> argparse.ArgumentParser:
    """sim_robot's options and the node's own (plain options give the parameters' defaults)."""
    parser = build_parser()
    for name, (kind, default, text) in NODE_OPTIONS.items():
        parser.add_argument(f'--{name.replace("_", "-")}', dest=name,
                            type=_bool_text if kind is bool else kind, default=default,
                            help=f'{text} (default {default})')
    return parser


def _stop(node: SimRobotNode) -> int:
    runner = node.runner
    node.destroy_node()
    return report_stop(runner)


def main(argv: list[str] | None = None) -> int:
    # The simulation and the servers run on their own threads; the executor publishes
    # snapshots and serves the parameter services.
    return run_simulator_main(argv, 'sim_robot', build_node_parser, SimRobotNode, _stop,
                              served=lambda node: node.runner.servers.connections)


if __name__ == '__main__':
    sys.exit(main())
