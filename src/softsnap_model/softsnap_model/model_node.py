"""ROS 2 model node: forward/inverse shape services and live shapes for a whole robot.

Run: ``ros2 run softsnap_model model_node --ros-args -r __ns:=/brittle_star -p scene:=brittle_star``
(pip-only: ``.venv/lib/softsnap_model/model_node --ros-args ...``).

Topics (relative to the node's namespace; SI units):
- subscribes ``<module>/cable_length/command`` and ``<module>/cable_length/measured``
  (softsnap_interfaces/CableLength) for every module of the scene;
- publishes ``<module>/shape/commanded`` and ``<module>/shape/predicted`` (ModuleShape),
  ``model/shape/commanded`` and ``model/shape/predicted`` (RobotShape, all modules with
  their base poses) and ``model/diagnostics`` (ModelDiagnostics, what was solved and
  skipped).
Services: ``~/forward_shape`` (ForwardShape), ``~/inverse_design`` (InverseDesign).

All science lives in :mod:`softsnap_model.predictor`, :mod:`.forward` and :mod:`.inverse`;
this node only converts messages and parameters (metres) to core calls (millimetres).
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import rclpy
from geometry_msgs.msg import Point, Pose
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.qos import QoSProfile
from rclpy.task import Future

from softsnap_driver.ros_parameters import SoftSnapNode
from softsnap_interfaces.msg import CableLength, Design, ModelDiagnostics, ModuleShape, RobotShape
from softsnap_interfaces.srv import ForwardShape, InverseDesign

from .forward import solve_forward
from .inverse import design_threading
from .predictor import SOURCES, RobotPredictor
from .scene import SceneError, load_scene

MM_PER_M = 1000.0
LENGTH_TOPIC = {'commanded': 'cable_length/command', 'predicted': 'cable_length/measured'}


def _points_m(points_mm) -> list[Point]:
    """(N, 2) or (N, 3) array in mm -> geometry_msgs/Point list in metres."""
    return [Point(x=float(p[0]) / MM_PER_M, y=float(p[1]) / MM_PER_M,
                  z=float(p[2]) / MM_PER_M if len(p) > 2 else 0.0) for p in points_mm]


class ModelNode(SoftSnapNode):
    """Thin shell around :class:`RobotPredictor` and the forward/inverse solvers."""

    def __init__(self):
        super().__init__('model_node')
        self.declare_parameter('scene', 'brittle_star', ParameterDescriptor(
            description='Robot scene: a name (brittle_star, starfish, snake, gripper, ring) '
                        'or a path to a scene YAML file', read_only=True))
        self.declare_parameter('rate', 100.0, ParameterDescriptor(
            description='Prediction rate: how often new lengths are solved and shapes '
                        'published (Hz)',
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=1000.0)]))
        self.declare_parameter('length_tolerance', 1e-7, ParameterDescriptor(
            description='Cable length change below which a module is not solved again (m)',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1e-3)]))
        self.declare_parameter('rib_centers', 'auto', ParameterDescriptor(
            description="Rib centres in shape messages: 'auto' (only while a topic has "
                        "subscribers), 'always' or 'never'"))
        self.declare_parameter('skip_work', True, ParameterDescriptor(
            description='Skip unneeded solves (unchanged lengths, identical modules, rib '
                        'centres nobody reads); false re-solves everything (benchmarking)',
            read_only=True))
        self.declare_parameter('diagnostics_period', 1.0, ParameterDescriptor(
            description='Period of model/diagnostics messages (s)',
            floating_point_range=[FloatingPointRange(from_value=0.05, to_value=60.0)]))
        self.add_on_set_parameters_callback(self.parameters_callback)

        self.scene = load_scene(self.get_parameter('scene').value)
        self.skeleton = self.scene.skeleton
        self.predictor = RobotPredictor(
            self.scene, self.get_parameter('length_tolerance').value * MM_PER_M,
            skip=self.get_parameter('skip_work').value)
        self.rib_centers_mode = self.get_parameter('rib_centers').value
        if self.rib_centers_mode not in ('auto', 'always', 'never'):
            raise ValueError(f"rib_centers must be 'auto', 'always' or 'never', "
                             f'got {self.rib_centers_mode!r}')
        self.service_calls = 0
        self.service_failures = 0
        self._last_msgs: dict[tuple[str, str], tuple] = {}  # (shape, its message)
        self._solve_time_reported = (0, 0.0)

        # Lengths are a stream where only the newest matters: sensor-data QoS would drop
        # messages under load; keep a small reliable queue so no command is lost silently.
        qos = QoSProfile(depth=10)
        # Length topics are drained once per tick instead of waking the executor for every
        # message: only the newest length per module matters for a prediction, and rclpy's
        # per-message dispatch (~0.2 ms) would otherwise dominate the node's CPU at 100 Hz.
        # The subscriptions live on an inbox node that no executor spins; up to `depth`
        # messages per topic wait in DDS between two ticks.
        # A `-r __node:=NAME` on the command line renames every node of the process: the
        # inbox's own (node-local, so winning) remap keeps it from taking the model's name.
        self._inbox = Node('model_node_inbox', namespace=self.get_namespace(),
                           context=self.context, start_parameter_services=False,
                           enable_rosout=False,
                           cli_args=['--ros-args', '-r', f'__node:={self.get_name()}_inbox'])
        self._length_subscriptions = []
        self.module_publishers = {}
        for module in self.scene.modules:
            for source in SOURCES:
                subscription = self._inbox.create_subscription(
                    CableLength, f'{module.name}/{LENGTH_TOPIC[source]}', lambda msg: None, qos)
                self._length_subscriptions.append((module.name, source, subscription))
                self.module_publishers[(module.name, source)] = self.create_publisher(
                    ModuleShape, f'{module.name}/shape/{source}', qos)
        self.robot_publishers = {s: self.create_publisher(RobotShape, f'model/shape/{s}', qos)
                                 for s in SOURCES}
        self.diagnostics_publisher = self.create_publisher(ModelDiagnostics, 'model/diagnostics', qos)
        self.create_service(ForwardShape, '~/forward_shape', self.forward_shape_callback)
        # An inverse design can take up to ~1 s: it runs on a worker thread (one at a time)
        # so that predictions and forward solves go on meanwhile; the guard condition wakes
        # the executor when the answer is ready.
        # While its coroutine awaits, a callback keeps its group busy: the service and the
        # guard get a reentrant group of their own, so neither they nor the default group
        # (lengths, timers, forward service) are blocked by a design in progress.
        design_group = ReentrantCallbackGroup()
        self._design_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='inverse_design')
        self._design_done = self.create_guard_condition(lambda: None, callback_group=design_group)
        self.create_service(InverseDesign, '~/inverse_design', self.inverse_design_callback,
                            callback_group=design_group)
        self.tick_timer = self.create_timer(1.0 / self.get_parameter('rate').value, self.tick_callback)
        self.diagnostics_timer = self.create_timer(
            self.get_parameter('diagnostics_period').value, self.diagnostics_callback)
        self.get_logger().info(
            f'scene {self.scene.name!r}: {len(self.scene.modules)} modules '
            f'({", ".join(self.scene.module_names)}), predicting at '
            f'{self.get_parameter("rate").value:g} Hz')

    # ------------------------------------------------------------------ parameters
    def parameters_callback(self, params) -> SetParametersResult:
        for param in params:
            if param.name == 'rib_centers' and param.value not in ('auto', 'always', 'never'):
                return SetParametersResult(successful=False, reason=(
                    f"rib_centers must be 'auto', 'always' or 'never', got {param.value!r}"))
            if param.name in ('rate', 'length_tolerance', 'diagnostics_period'):
                value = param.value
                if not isinstance(value, (int, float)) or not math.isfinite(value):
                    return SetParametersResult(successful=False,
                                               reason=f'{param.name} must be a finite number')
        # Apply after validation (ranges are enforced by the descriptors).
        for param in params:
            if param.name == 'rib_centers':
                self.rib_centers_mode = param.value
            elif param.name == 'length_tolerance':
                self.predictor.length_tol_mm = float(param.value) * MM_PER_M
            elif param.name == 'rate':
                self.tick_timer.cancel()
                self.tick_timer = self.create_timer(1.0 / float(param.value), self.tick_callback)
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ topics
    def length_callback(self, msg: CableLength, module: str, source: str) -> None:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        try:
            self.predictor.submit(source, module, msg.cable_length * MM_PER_M, stamp_ns)
        except ValueError as error:
            self.get_logger().warning(
                f'refused {source} length for {module!r}: {error}; keeping the last valid shape',
                throttle_duration_sec=1.0)

    def _want_rib_centers(self, source: str) -> bool:
        if self.rib_centers_mode != 'auto':
            return self.rib_centers_mode == 'always'
        if self.robot_publishers[source].get_subscription_count() > 0:
            return True
        return any(self.module_publishers[(m.name, source)].get_subscription_count() > 0
                   for m in self.scene.modules)

    def tick_callback(self) -> None:
        try:
            self._tick()
        except Exception as error:  # never let one bad tick stop the predictions
            self.get_logger().error(f'prediction tick failed: {error!r}', throttle_duration_sec=1.0)

    def _drain_lengths(self) -> None:
        """Submit every length message that arrived since the last tick, oldest first."""
        for module, source, subscription in self._length_subscriptions:
            with subscription.handle:
                while (taken := subscription.handle.take_message(CableLength, False)) is not None:
                    self.length_callback(taken[0], module, source)

    def _tick(self) -> None:
        self._drain_lengths()
        want = {source: self._want_rib_centers(source) for source in SOURCES}
        updated = self.predictor.tick(want)
        for module, source, reason in self.predictor.errors:
            self.get_logger().warning(f'could not solve the {source} shape of {module!r}: '
                                      f'{reason}; keeping the last valid shape',
                                      throttle_duration_sec=1.0)
        self.predictor.errors.clear()
        stamp = self.get_clock().now().to_msg()
        for source in SOURCES:
            if not updated[source]:
                continue
            # Serialising costs ~0.1 ms a message: topics nobody listens to are skipped, and
            # a shape's message is built once, only when some topic needs it.
            for shape in updated[source]:
                publisher = self.module_publishers[(shape.module, source)]
                if publisher.get_subscription_count() > 0:
                    publisher.publish(self._message_for(shape, stamp))
            if self.robot_publishers[source].get_subscription_count() == 0:
                continue
            robot = RobotShape()
            robot.header.stamp = stamp
            robot.header.frame_id = self.scene.name
            robot.robot = self.scene.name
            for module, shape, (position, orientation) in zip(
                    self.scene.modules, self.predictor.shapes(source),
                    self.predictor.base_poses(source)):
                robot.modules.append(ModuleShape(module=module.name, source=source)
                                     if shape is None else self._message_for(shape, stamp))
                pose = Pose()
                pose.position.x, pose.position.y, pose.position.z = position
                (pose.orientation.x, pose.orientation.y,
                 pose.orientation.z, pose.orientation.w) = orientation
                robot.base_poses.append(pose)
            self.robot_publishers[source].publish(robot)

    def _message_for(self, shape, stamp) -> ModuleShape:
        """The message of a shape, built on first use and reused while the shape is current."""
        key = (shape.module, shape.source)
        cached = self._last_msgs.get(key)
        if cached is None or cached[0] is not shape:
            cached = (shape, self._shape_msg(shape, stamp))
            self._last_msgs[key] = cached
        return cached[1]

    def _shape_msg(self, shape, stamp) -> ModuleShape:
        msg = ModuleShape()
        # A shape is the state at the time its length was commanded or measured: keep
        # that stamp (end-to-end latency is then arrival time minus stamp).
        if shape.stamp_ns > 0:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(shape.stamp_ns, 1_000_000_000)
        else:
            msg.header.stamp = stamp
        msg.header.frame_id = f'{self.scene.name}/{shape.module}'
        msg.module = shape.module
        msg.source = shape.source
        msg.cable_length = shape.cable_length_mm / MM_PER_M
        msg.angles = shape.angles.tolist()
        if shape.rib_centers_mm is not None:
            msg.rib_centers = _points_m(shape.rib_centers_mm)
        msg.tension = shape.tension * MM_PER_M  # rad^2/mm -> rad^2/m
        msg.energy = shape.energy
        msg.converged = shape.converged
        msg.residual = shape.residual
        msg.solve_time = shape.solve_time_s
        return msg

    def diagnostics_callback(self) -> None:
        c = self.predictor.counters
        solves_before, time_before = self._solve_time_reported
        n = c.solves - solves_before
        msg = ModelDiagnostics(
            solves=c.solves, skipped_unchanged=c.skipped_unchanged,
            skipped_duplicate=c.skipped_duplicate, skipped_rib_points=c.skipped_rib_points,
            refused=c.refused, service_calls=self.service_calls,
            service_failures=self.service_failures,
            mean_solve_time=(c.solve_time_s - time_before) / n if n else 0.0)
        msg.header.stamp = self.get_clock().now().to_msg()
        self._solve_time_reported = (c.solves, c.solve_time_s)
        self.diagnostics_publisher.publish(msg)

    # ------------------------------------------------------------------ services
    def _threading_mm(self, holes, threading_m):
        """Threading from hole names or offsets (m) -> offsets in mm (ValueError if bad)."""
        if len(holes) and len(threading_m):
            raise ValueError('give the threading as hole names or as offsets, not both')
        if len(holes):
            return self.skeleton.threading_mm(list(holes))
        offsets = np.asarray(threading_m, dtype=float) * MM_PER_M
        if not np.all(np.isfinite(offsets)):
            raise ValueError(f'threading offsets must be finite, got {list(threading_m)}')
        return self.skeleton.threading_mm(offsets)

    def forward_shape_callback(self, request, response):
        self.service_calls += 1
        try:
            threading = self._threading_mm(request.holes, request.threading)
            initial = np.asarray(request.initial_angles, dtype=float) if len(request.initial_angles) else None
            start = time.perf_counter()
            result = solve_forward(self.skeleton, threading, request.cable_length * MM_PER_M,
                                   initial=initial)
            response.solve_time = time.perf_counter() - start
        except (ValueError, TypeError) as error:
            self.service_failures += 1
            response.success = False
            response.message = str(error)
            return response
        except Exception as error:  # a solver bug must not take the node down
            self.service_failures += 1
            self.get_logger().error(f'forward_shape internal error: {error!r}')
            response.success = False
            response.message = f'internal error: {error!r}'
            return response
        response.success = bool(result.converged)
        response.message = getattr(result, 'message', '') or ('converged' if result.converged
                                                             else 'did not converge')
        if not result.converged:
            self.service_failures += 1
        response.angles = np.asarray(result.angles, dtype=float).tolist()
        response.rib_centers = _points_m(result.rib_centers)
        response.cable_path = _points_m(result.cable_path)
        response.energy = float(result.energy)
        response.tension = float(result.tension) * MM_PER_M
        response.converged = bool(result.converged)
        response.residual = float(result.residual)
        response.iterations = int(result.iterations)
        return response

    async def inverse_design_callback(self, request, response):
        self.service_calls += 1
        start = time.perf_counter()
        done = Future()

        def work():
            try:
                answer = self._inverse_design(request, InverseDesign.Response())
            except (ValueError, TypeError) as error:
                answer = InverseDesign.Response(success=False, message=str(error))
            except Exception as error:  # a solver bug must not take the node down
                answer = InverseDesign.Response(success=False, message=f'internal error: {error!r}')
            done.set_result(answer)
            self._design_done.trigger()

        self._design_pool.submit(work)
        response = await done
        if not response.success:
            self.service_failures += 1
            self.get_logger().warning(f'inverse_design refused: {response.message}')
        response.solve_time = time.perf_counter() - start
        return response

    def destroy_node(self):
        self._design_pool.shutdown(wait=False, cancel_futures=True)
        self._inbox.destroy_node()
        return super().destroy_node()

    def _inverse_design(self, request, response):
        has_angles, has_points = len(request.target_angles) > 0, len(request.target_points) > 0
        if has_angles == has_points:
            raise ValueError('give exactly one of target_angles and target_points')
        kwargs = {'k': int(request.alternatives)}
        if request.allowed_holes:
            kwargs['allowed_holes'] = list(request.allowed_holes)
        if request.forbidden_holes:
            kwargs['forbidden_holes'] = list(request.forbidden_holes)
        if request.fixed_holes:
            kwargs['fixed_holes'] = [h or None for h in request.fixed_holes]
        if request.min_cable_length > 0.0 or request.max_cable_length > 0.0:
            high = request.max_cable_length if request.max_cable_length > 0.0 else math.inf
            kwargs['cable_length_range'] = (request.min_cable_length * MM_PER_M, high * MM_PER_M)
        if has_angles:
            result = design_threading(self.skeleton, target_angles=list(request.target_angles),
                                      **kwargs)
        else:
            points = [(p.x * MM_PER_M, p.y * MM_PER_M) for p in request.target_points]
            result = design_threading(self.skeleton, target_points=points, **kwargs)
        response.success = True
        response.message = getattr(result, 'message', '') or 'ok'
        response.best = self._design_msg(result)
        response.alternatives = [self._design_msg(alt) for alt in result.alternatives]
        response.fit_error = float(getattr(result, 'fit_error', 0.0) or 0.0) / MM_PER_M
        return response

    @staticmethod
    def _design_msg(result) -> Design:
        return Design(
            holes=list(result.holes),
            threading=(np.asarray(result.threading, dtype=float) / MM_PER_M).tolist(),
            cable_length=float(result.cable_length) / MM_PER_M,
            angles=np.asarray(result.angles, dtype=float).tolist(),
            rib_centers=_points_m(result.rib_centers),
            error=float(result.error),
            position_error=float(result.position_error) / MM_PER_M)


def main(args=None):
    # rclpy.init() is a context manager only from Kilted on; this form also runs on Jazzy.
    rclpy.init(args=args)
    try:
        node = ModelNode()
    except (SceneError, ValueError) as error:
        # A bad configuration is reported once, clearly, instead of a traceback.
        rclpy.logging.get_logger('model_node').fatal(f'cannot start: {error}')
        rclpy.try_shutdown()
        raise SystemExit(2)
    # One thread runs every callback (no locks needed around the predictor; lower latency
    # than the multi-threaded executor); inverse designs run on the node's worker thread.
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
