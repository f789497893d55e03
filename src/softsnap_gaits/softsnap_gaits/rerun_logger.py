"""ROS node recording a SoftSnap robot to rerun: commanded and predicted shapes over time.

Subscribes (relative names, so they live in the robot's namespace, e.g. /brittle_star):
  model/shape/commanded, model/shape/predicted   softsnap_interfaces/RobotShape
  model/shape/simulated                          softsnap_interfaces/RobotShape (sim_robot)
  sim/base_pose                                  geometry_msgs/PoseStamped (sim_robot)
  <module>/cable_length/command                  softsnap_interfaces/CableLength
  <module>/cable_length/measured                 softsnap_interfaces/CableLength
  <module>/state                                 softsnap_interfaces/ModuleState

and writes a .rrd file and/or streams to a viewer. It reports on /diagnostics
(diagnostic_msgs/DiagnosticArray, status ``softsnap/<robot>/rerun_logger``) every
DIAGNOSTICS_PERIOD_S, and at once when a topic delivers its first message: how many
messages it took per topic, logged, dropped and could not log.

Everything about rerun (entity paths, colours, blueprint, units) lives in
softsnap_model.recording; this node only adapts messages and parameters. The shape,
length and state topics are taken raw (CDR bytes) and read by softsnap_ros.cdr, much
cheaper than rclpy's deserialisation. See docs/rerun.md.

Parameters (read-only except ``rate``):
  output      .rrd path; '' = runs/<robot>-<UTC time>.rrd under the current directory;
              'none' = no file (stream only)
  viewer_url  rerun gRPC url of a running viewer to stream to, '' = none
  serve_grpc_port, serve_web_port, serve_bind_ip
              host a gRPC server (and rerun's bundled web viewer) so viewers can
              connect to the live recording; 0 = off, bind 127.0.0.1 by default
  rate        largest logging rate per module and data source, Hz (0 = everything)
  scene       scene name or YAML path: restricts logging to its modules and gives the
              threadings for drawing the cable; '' = log every module RobotShape names
  modules     module names to log when no scene is given ([] = all seen)
  robot       robot name for the default file name ('' = the node's namespace)
  rib_spacing spine arc length between ribs, m, used when a shape has no rib centres
              (the scene's skeleton spacing wins when a scene is given)
  flush_period
              rows are sent to rerun in per-entity column batches at most this long
              after they arrive, s (0 = log each row at once, ~10x the CPU)
  skip_unchanged
              do not log a module's shape again while it is unchanged (the model node
              re-sends unchanged modules in every RobotShape)
  world_view  3D view in the world frame, the robot moved by sim/base_pose (physics runs)
  camera      also record sim_robot's camera (camera/image_raw, camera_info, pose), the
              tracker's <module>/shape/measured and the prediction projected onto the
              frames (softsnap_gaits.rerun_camera)
"""
from __future__ import annotations

import datetime as dt
import math
import sys
import time
from pathlib import Path

import rclpy
import rclpy.node
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.parameter import Parameter
from geometry_msgs.msg import PoseStamped
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from softsnap_driver.diagnostics import RECENT_S
from softsnap_ros.diagnostics import key_values
from softsnap_ros.node import SoftSnapNode
from softsnap_ros.spinning import (exit_without_teardown, hold_signals, init_ros,
                                   spin_until_shutdown)
from softsnap_interfaces.msg import CableLength, ModuleState, RobotShape
from softsnap_model import recording

from softsnap_ros import cdr
from softsnap_ros.units import MM_PER_M, stamp_ns

# Reliable, like the default QoS the model node, the drivers and the gait node publish
# with, so samples sent right after discovery are not lost; a KEEP_LAST reader never
# blocks a publisher. The depth absorbs bursts (one RobotShape per model tick per source):
# 100 holds 1 s of a 100 Hz model, 10 drain periods.
SUBSCRIPTION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                              reliability=ReliabilityPolicy.RELIABLE)
MAX_RATE_HZ = 1000.0
#: Default of the flush_period parameter (s): a live viewer lags by at most this much;
#: longer periods cost less CPU (one send_columns per entity and flush).
DEFAULT_FLUSH_PERIOD_S = 1.0
#: How often the inbox is drained (s): the most a message waits before it is handled.
#: 0.1 rather than 0.05 saved ~1% of a core (a timer wake costs ~0.5 ms under load); a
#: recording needs no lower latency, and rows wait up to flush_period anyway.
DRAIN_PERIOD_S = 0.1
#: How often the node publishes its status on /diagnostics (s). A topic's first message
#: also triggers one at once: that is how a waiting peer (the demo) learns that messages
#: reach the recording, which a subscription seen in the ROS graph does not prove (the
#: publishers may discover it seconds later on a loaded machine).
DIAGNOSTICS_PERIOD_S = 1.0


def recorder_status(name: str, output: Path | None, recorder: recording.RobotRecorder,
                    taken: dict[str, int], not_logged: int, not_logged_recently: bool
                    ) -> DiagnosticStatus:
    """The logger's DiagnosticStatus: WARN while messages could not be logged within the
    last RECENT_S (bytes no reader accepts, a shape with the wrong rib count), else OK.

    Values: the output file and its size, the recorder's counters, and one value per
    subscribed topic: key the topic's full name, value the messages taken from it.
    """
    try:
        size = output.stat().st_size if output is not None else 0
    except OSError:  # rerun creates the file asynchronously
        size = 0
    status = DiagnosticStatus(name=name, hardware_id='')
    if not_logged_recently:
        status.level = DiagnosticStatus.WARN
        status.message = f'messages not logged within {RECENT_S:g} s (see the log)'
    else:
        status.level = DiagnosticStatus.OK
        status.message = f'recording to {output}' if output is not None else 'streaming'
    values = {'output': str(output or ''), 'file size (bytes)': size,
              'messages logged (count)': recorder.logged,
              'dropped by rate (count)': recorder.dropped,
              'unchanged shapes not logged again (count)': recorder.unchanged,
              'messages not logged (count)': not_logged,
              **dict(sorted(taken.items()))}
    status.values = key_values(values)
    return status


def default_output(robot: str, now: dt.datetime | None = None) -> Path:
    """runs/<robot>-<UTC timestamp>.rrd relative to the current directory."""
    now = now or dt.datetime.now(dt.timezone.utc)
    return Path('runs') / f'{robot}-{now.strftime("%Y%m%dT%H%M%SZ")}.rrd'


class RerunLoggerNode(SoftSnapNode):
    """Adapts shape, cable length and state messages to a recording.RobotRecorder."""

    def __init__(self):
        super().__init__('rerun_logger')
        self.declare_parameter('output', '', ParameterDescriptor(
            description="Path of the .rrd recording; '' = runs/<robot>-<UTC time>.rrd, "
                        "'none' = write no file", read_only=True))
        self.declare_parameter('viewer_url', '', ParameterDescriptor(
            description='rerun gRPC url of a viewer to stream to, e.g. '
                        "rerun+http://127.0.0.1:9876/proxy; '' = none", read_only=True))
        port_range = [IntegerRange(from_value=0, to_value=65535)]
        self.declare_parameter('serve_grpc_port', 0, ParameterDescriptor(
            description='Host a rerun gRPC server on this port for viewers to connect to '
                        '(0 = off; 9876 when serve_web_port is set)',
            integer_range=port_range, read_only=True))
        self.declare_parameter('serve_web_port', 0, ParameterDescriptor(
            description="Serve rerun's bundled web viewer on this HTTP port, showing the "
                        'live recording (0 = off)', integer_range=port_range, read_only=True))
        self.declare_parameter('serve_bind_ip', '127.0.0.1', ParameterDescriptor(
            description='Address the gRPC server listens on (0.0.0.0 = every interface; '
                        'there is no authentication)', read_only=True))
        self.declare_parameter('rate', 30.0, ParameterDescriptor(
            description='Largest logging rate per module and data source, in Hz '
                        '(0 = log every message)',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=MAX_RATE_HZ)]))
        self.declare_parameter('scene', '', ParameterDescriptor(
            description="Scene name or YAML path; only its modules are logged and their "
                        "threadings draw the cable; '' = every module seen", read_only=True))
        self.declare_parameter('modules', Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            description='Module names to log when no scene is given (empty = all seen)',
            read_only=True))
        self.declare_parameter('robot', '', ParameterDescriptor(
            description="Robot name for the default file name; '' = the node namespace",
            read_only=True))
        self.declare_parameter('rib_spacing', recording.RIB_SPACING_MM / MM_PER_M,
                               ParameterDescriptor(
            description='Spine arc length between adjacent ribs, in metres (m), for shapes '
                        'that carry no rib centres',
            floating_point_range=[FloatingPointRange(from_value=0.001, to_value=0.1)],
            read_only=True))
        self.declare_parameter('flush_period', DEFAULT_FLUSH_PERIOD_S, ParameterDescriptor(
            description='Rows wait at most this long and are then sent to rerun as one '
                        'column batch per entity, in seconds (s); 0 = log every row at once '
                        '(about 10x the CPU)',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=10.0)],
            read_only=True))
        self.declare_parameter('skip_unchanged', True, ParameterDescriptor(
            description='Do not log a module shape again while it is unchanged (same angles '
                        'and rib centres); the viewer keeps showing the latest one',
            read_only=True))
        self.declare_parameter('world_view', False, ParameterDescriptor(
            description='3D view in the world frame: the robot moves by sim/base_pose '
                        '(runs simulated in physics)', read_only=True))
        self.declare_parameter('camera', False, ParameterDescriptor(
            description="sim_robot's camera images, the tracker's detections and the "
                        'prediction projected onto them (softsnap_gaits.rerun_camera)',
            read_only=True))
        self.add_on_set_parameters_callback(self.parameters_callback)

        scene = self._load_scene(self.get_parameter('scene').value)
        modules = self._module_names(scene)
        robot = (self.get_parameter('robot').value or getattr(scene, 'name', '')
                 or self.get_namespace().strip('/').replace('/', '_') or 'robot')
        output = self.get_parameter('output').value
        self.output = None if output.lower() == 'none' else Path(output or default_output(robot))
        viewer_url = self.get_parameter('viewer_url').value or None
        web_port = self.get_parameter('serve_web_port').value
        grpc_port = self.get_parameter('serve_grpc_port').value or (9876 if web_port else 0)
        bind_ip = self.get_parameter('serve_bind_ip').value

        # Module colours (identity) and the robot's extent (the default top-down camera).
        colors, bounds = recording.scene_style(scene) if scene is not None else (None, None)
        self.rec = recording.open_recording(self.output, viewer_url,
                                            serve_grpc_port=grpc_port or None,
                                            serve_bind_ip=bind_ip,
                                            blueprint=recording.build_blueprint(
                                                colors, bounds,
                                                self.get_parameter('world_view').value),
                                            application_id=f'softsnap_{robot}')
        self.web_url = None
        if web_port:
            host = '127.0.0.1' if bind_ip in ('0.0.0.0', '::') else bind_ip
            self.web_url = recording.serve_web_viewer(web_port, grpc_port, host)
        self.recorder = recording.RobotRecorder(
            self.rec, modules=modules,
            threadings_mm={m.name: m.threading_mm for m in getattr(scene, 'modules', [])},
            rate_hz=self.get_parameter('rate').value,
            spacing_mm=(scene.skeleton.spacing_mm if scene is not None
                        else self.get_parameter('rib_spacing').value * MM_PER_M),
            colors=colors, flush_period_s=self.get_parameter('flush_period').value,
            skip_unchanged=self.get_parameter('skip_unchanged').value,
            sim_time=self.get_parameter('use_sim_time').value)
        # Base poses from the scene, used when a RobotShape carries none.
        self.scene_poses = {m.name: (m.base_position_m, m.base_orientation_xyzw)
                            for m in getattr(scene, 'modules', [])}
        self._closed = False
        self.diagnostic_name = f'softsnap/{robot}/rerun_logger'
        self.taken: dict[str, int] = {}  # full topic name -> messages taken
        self.not_logged = 0  # messages (or a message's module shapes) taken, not logged
        self._not_logged_at = -math.inf  # time.monotonic() of the latest
        self._diagnostics_due = 0.0  # time.monotonic() of the next periodic report
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._last_shapes: dict[tuple[str, str], tuple] = {}  # (stamp ns, angles) last seen
        self._last_poses: tuple | None = None  # (module names, pose bytes) last handed on
        self.cdr_fallbacks = 0  # messages the cdr reader refused (rclpy decoded them)

        # A recording needs no low latency, so messages are not dispatched one by one (an
        # executor wake costs ~0.5 ms on the loaded development machine, and the demo sends
        # ~550 messages/s): the subscriptions live on an inbox node that no executor
        # spins, and a timer takes everything that arrived every DRAIN_PERIOD_S, topic by
        # topic (the queues' depth holds 1 s at 100 Hz). The inbox's node-local remap
        # keeps a `-r __node:=NAME` from giving it this node's name.
        self._inbox = rclpy.node.Node(
            f'{self.get_name()}_inbox', namespace=self.get_namespace(), context=self.context,
            start_parameter_services=False, enable_rosout=False,
            cli_args=['--ros-args', '-r', f'__node:={self.get_name()}_inbox'])
        self._drained: list[tuple] = []  # (subscription, message type, raw, handler)
        # Shapes are taken raw, as CDR bytes, and read by cdr: rclpy's deserialisation
        # builds ~100 Python objects per RobotShape and was most of this node's CPU.
        self._subscribe(RobotShape, 'model/shape/commanded', self.commanded_shape_callback,
                        raw=True)
        self._subscribe(RobotShape, 'model/shape/predicted', self.predicted_shape_callback,
                        raw=True)
        # The steady clock: draining is work pacing, not part of the robot's time (with
        # use_sim_time a stopped /clock would otherwise leave the inbox undrained).
        self.create_timer(DRAIN_PERIOD_S, self.drain_callback,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        # sim_robot's shapes and robot pose; silent unless a physics simulation runs.
        self._subscribe(RobotShape, 'model/shape/simulated', self.simulated_shape_callback,
                        raw=True)
        self._subscribe(PoseStamped, 'sim/base_pose', self.base_pose_callback)
        self._module_subscriptions: dict[str, list] = {}
        for module in sorted(modules or ()):
            self._subscribe_module(module)
        self.camera = None
        if self.get_parameter('camera').value:
            from .rerun_camera import attach_camera
            self.camera = attach_camera(self, scene)
        rate = self.get_parameter('rate').value
        self.get_logger().info(
            f'recording {robot} to {self.output or "(no file)"}'
            + (f' and {viewer_url}' if viewer_url else '')
            + (f', serving gRPC on {bind_ip}:{grpc_port}' if grpc_port else '')
            + (f', web viewer at {self.web_url}' if self.web_url else '')
            + (f', at most {rate:g} Hz per stream' if rate else ', every message')
            + '; modules: ' + (', '.join(sorted(modules)) if modules else 'all seen'))

    # --- parameters ---------------------------------------------------------------------

    def parameters_callback(self, params: list[Parameter]) -> SetParametersResult:
        """Accept a new ``rate`` in [0, MAX_RATE_HZ]; everything else is read-only."""
        for param in params:
            if param.name == 'rate':
                value = param.value
                if not isinstance(value, (int, float)) or not 0.0 <= value <= MAX_RATE_HZ:
                    return SetParametersResult(
                        successful=False,
                        reason=f'rate must be between 0 and {MAX_RATE_HZ} Hz, got {value!r}')
        for param in params:
            if param.name == 'rate' and hasattr(self, 'recorder'):
                self.recorder.limiter = recording.RateLimiter(float(param.value))
        return SetParametersResult(successful=True)

    def _load_scene(self, name: str):
        if not name:
            return None
        from softsnap_model.scene import load_scene  # optional: only with a scene
        return load_scene(name)

    def _module_names(self, scene) -> frozenset[str] | None:
        if scene is not None:
            return frozenset(m.name for m in scene.modules)
        names = [n for n in (self.get_parameter('modules').value or []) if n]
        return frozenset(names) or None

    def _subscribe(self, msg_type, topic: str, handler, raw: bool = False,
                   qos: QoSProfile = SUBSCRIPTION_QOS):
        subscription = self._inbox.create_subscription(msg_type, topic, lambda msg: None,
                                                       qos, raw=raw)
        self._drained.append((subscription, msg_type, raw, handler))
        self.taken.setdefault(subscription.topic_name, 0)
        return subscription

    def _subscribe_module(self, module: str) -> None:
        if module in self._module_subscriptions:
            return
        # Raw too: these are most of the messages (7 of 11 in the demo), and rclpy would
        # build a message, a Header and a Time object for each.
        self._module_subscriptions[module] = [
            self._subscribe(CableLength, f'{module}/cable_length/command',
                            lambda data, m=module: self.cable_length_callback(data, m, 'commanded'),
                            raw=True),
            self._subscribe(CableLength, f'{module}/cable_length/measured',
                            lambda data, m=module: self.cable_length_callback(data, m, 'measured'),
                            raw=True),
            self._subscribe(ModuleState, f'{module}/state',
                            lambda data, m=module: self.state_callback(data, m), raw=True),
        ]

    def drain_callback(self) -> None:
        """Handle every message that arrived since the last drain, then flush if due."""
        if self._closed:
            return
        first_messages = False
        for subscription, msg_type, raw, handler in list(self._drained):  # may grow meanwhile
            count = 0
            with subscription.handle:
                while (taken := subscription.handle.take_message(msg_type, raw)) is not None:
                    count += 1
                    try:
                        handler(taken[0])
                    except Exception as exc:  # noqa: BLE001 - one bad message must not stop the rest
                        self._count_not_logged()
                        self.get_logger().error(f'{subscription.topic_name}: message not logged: '
                                                f'{exc!r}', throttle_duration_sec=5.0)
            if count:
                topic = subscription.topic_name
                first_messages |= self.taken[topic] == 0
                self.taken[topic] += count
        if self.recorder.flush_period_s:
            self.recorder.flush_if_due()
        now = time.monotonic()
        if first_messages or now >= self._diagnostics_due:
            self._diagnostics_due = now + DIAGNOSTICS_PERIOD_S
            self.publish_diagnostics(now)

    def _count_not_logged(self) -> None:
        self.not_logged += 1
        self._not_logged_at = time.monotonic()

    def publish_diagnostics(self, now: float) -> None:
        """Publish the logger's status (`recorder_status`) on /diagnostics."""
        status = recorder_status(self.diagnostic_name, self.output, self.recorder, self.taken,
                                 self.not_logged, now - self._not_logged_at < RECENT_S)
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_publisher.publish(msg)

    # --- callbacks ----------------------------------------------------------------------

    def _stamp(self, header) -> int:
        """Message stamp in ns, or now if the publisher left it zero."""
        ns = stamp_ns(header.stamp)
        return ns if ns else self.get_clock().now().nanoseconds

    def commanded_shape_callback(self, data: bytes) -> None:
        self._robot_shape(self._decode(data), 'commanded')

    def predicted_shape_callback(self, data: bytes) -> None:
        shape = self._decode(data)
        self._robot_shape(shape, 'predicted')
        if self.camera is not None:
            self.camera.predicted_shape(shape)

    def simulated_shape_callback(self, data: bytes) -> None:
        # Its base poses are in the world: the module frames keep the model's poses in
        # the robot frame, and the robot frame follows sim/base_pose.
        shape = self._decode(data)
        self._robot_shape(shape, 'simulated', base_poses=False)
        if self.camera is not None:
            self.camera.simulated(shape)

    def _decode(self, data: bytes) -> cdr.RobotShapeCdr:
        """A raw RobotShape (rclpy reads what the cdr readers refuse, see `_fallback`)."""
        return cdr.read_robot_shape(data, self._fallback)

    def _fallback(self, msg_type) -> None:
        """Counts the messages rclpy had to read (another encoding, say big-endian); bytes
        rclpy refuses too raise, and the drain logs that."""
        self.cdr_fallbacks += 1
        if self.cdr_fallbacks == 1:
            self.get_logger().warning(f'{msg_type.__name__} bytes not plain little-endian '
                                      'CDR: rclpy decodes them (slower)')

    def base_pose_callback(self, msg: PoseStamped) -> None:
        if not self._closed:
            p, q = msg.pose.position, msg.pose.orientation
            self.recorder.robot_pose(self._stamp(msg.header), (p.x, p.y, p.z),
                                     (q.x, q.y, q.z, q.w))

    def _robot_shape(self, msg: cdr.RobotShapeCdr, source: str,
                     base_poses: bool = True) -> None:
        if self._closed:
            return
        stamp = msg.stamp_ns or self.get_clock().now().nanoseconds
        names = tuple(shape.module for shape in msg.modules)
        # Base poses rarely change: hand them on only when their bytes or the modules do.
        poses_seen = (names, msg.base_poses.tobytes())
        if not base_poses or poses_seen == self._last_poses:
            pass
        elif len(msg.base_poses) == len(msg.modules):
            self.recorder.base_poses(stamp, {name: (pose[:3], pose[3:])
                                             for name, pose in zip(names, msg.base_poses)})
            self._last_poses = poses_seen
        else:
            self.recorder.base_poses(stamp, {name: self.scene_poses[name] for name in names
                                             if name in self.scene_poses})
            self._last_poses = poses_seen
        for shape in msg.modules:
            if not self.recorder.wants(shape.module):
                continue
            if not len(shape.angles):
                # The model's placeholder for a module it has no length of yet (no driver
                # reports one): nothing to draw, and no error either.
                continue
            self._subscribe_module(shape.module)
            shape_stamp = shape.stamp_ns or stamp
            source_of = shape.source if shape.source in recording.SOURCES else source
            if self.recorder.skip_unchanged:
                # The model node re-sends an unchanged module's message as it was: same
                # stamp, same angles. Skip it before converting its points.
                # Only a logged shape counts: one the rate limit dropped is taken later.
                seen = (shape_stamp, shape.angles.tobytes())
                if self._last_shapes.get((shape.module, source_of)) == seen:
                    self.recorder.unchanged += 1
                    continue
            centres = shape.rib_centers if len(shape.rib_centers) else None
            try:
                if self.recorder.shape(shape_stamp, shape.module, source_of,
                                       shape.angles, centres,
                                       None if source == 'simulated' else shape.solve_time):
                    self._last_shapes[(shape.module, source_of)] = (
                        shape_stamp, shape.angles.tobytes())
            except ValueError as exc:
                self._count_not_logged()
                self.get_logger().warning(f'{shape.module} {source} shape not logged: {exc}',
                                          throttle_duration_sec=5.0)

    def cable_length_callback(self, data: bytes, module: str, kind: str) -> None:
        if self._closed:
            return
        stamp, length = cdr.read_cable_length(data, self._fallback)
        self.recorder.cable_length(stamp or self.get_clock().now().nanoseconds, module, kind,
                                   length)

    def state_callback(self, data: bytes, module: str) -> None:
        if self._closed:
            return
        stamp, name, battery_v = cdr.read_module_state(data, self._fallback)
        self.recorder.module_state(stamp or self.get_clock().now().nanoseconds,
                                   name or module, battery_v)

    # --- shutdown -----------------------------------------------------------------------

    def destroy_node(self):
        if hasattr(self, '_inbox'):
            self._inbox.destroy_node()
        return super().destroy_node()

    def close(self) -> str:
        """Flush and close the recording so the file is complete; returns a summary.

        Idempotent. It does not log itself: after Ctrl-C the context is shut down and the
        node's rosout publisher is gone, so main() logs the summary once the node is
        destroyed.
        """
        if not self._closed:
            self._closed = True
            self.recorder.flush()
            recording.close_recording(self.rec)
        size = self.output.stat().st_size if self.output and self.output.exists() else 0
        return (f'recording closed: {self.output or "(no file)"} ({size} bytes), '
                f'{self.recorder.logged} messages logged, '
                f'{self.recorder.dropped} dropped by rate, '
                f'{self.recorder.unchanged} unchanged shapes not logged again')


def main(args=None):
    """The ``rerun_logger`` executable; ends the process (status 0, or 2 on a bad setup)."""
    init_ros(args=args)
    node = None
    status = 0
    try:
        node = RerunLoggerNode()
        # One thread: rerun's current time is per thread and the recorder keeps per-module
        # state, so callbacks must not run concurrently.
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_until_shutdown(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as exc:  # bad parameters or scene: say why and exit non-zero
        get_logger('rerun_logger').fatal(str(exc))
        status = 2
    finally:
        stopped = time.monotonic()
        hold_signals()   # a second Ctrl-C while the recording closes: no traceback
        if node is not None:
            logger = node.get_logger()
            summary = node.close()
            node.destroy_node()
            logger.info(summary)
        rclpy.try_shutdown()
        hold_signals(final=True)   # ignored from here to the exit
    # The recording is closed (flushed, footer written) and ROS is shut down: nothing of
    # ours is left to finish. Interpreter teardown of rerun's and pyarrow's runtime takes
    # 0.5-2 s more on a busy machine, past the 2 s a SIGINT may take: skip it.
    exit_without_teardown(status, rclpy.get_default_context(), stopped)


if __name__ == '__main__':
    sys.exit(main())
