"""ROS 2 model node: forward/inverse shape services and live shapes for a whole robot.

Run: ``ros2 run softsnap_model model_node --ros-args -r __ns:=/brittle_star -p scene:=brittle_star``
(pip-only: ``.venv/lib/softsnap_model/model_node --ros-args ...``).

Topics (relative to the node's namespace; SI units):
- subscribes ``<module>/cable_length/command`` and ``<module>/cable_length/measured``
  (softsnap_interfaces/CableLength) for every module of the scene;
- publishes ``<module>/shape/commanded`` and ``<module>/shape/predicted`` (ModuleShape),
  ``model/shape/commanded`` and ``model/shape/predicted`` (RobotShape, all modules with
  their base poses) and ``model/diagnostics`` (ModelDiagnostics, what was solved and
  skipped);
- standard outputs (built by :mod:`softsnap_model.standard_messages`, only for
  subscribers): ``model/markers`` (visualization_msgs/MarkerArray at ``marker_rate``, in
  the frame named after the scene, with the simulated shapes received on
  ``model/shape/simulated``), ``model/joint_states/commanded`` and
  ``model/joint_states/predicted`` (sensor_msgs/JointState, joints
  ``<module>/segment_<i>``) and, on the absolute ``/diagnostics``, the node's
  diagnostic_msgs/DiagnosticArray every ``diagnostics_period``.
Services: ``~/forward_shape`` (ForwardShape), ``~/inverse_design`` (InverseDesign).
Action: ``~/design_threading`` (DesignThreading: the inverse design with progress feedback
and cancel; one goal at a time, further goals are rejected while one runs).
Inverse designs are bounded: at most ``max_alternatives`` alternatives, at most
``design_timeout`` seconds from the request's arrival (queueing included), and they stop
within one step of the search on cancel or shutdown.

All science lives in :mod:`softsnap_model.predictor`, :mod:`.forward`, :mod:`.loads` and
:mod:`.inverse`; this node only converts messages and parameters (metres) to core calls
(millimetres).
"""
from __future__ import annotations

import math
import threading
import time

from geometry_msgs.msg import Pose
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.action import ActionServer
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.qos import QoSProfile
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from softsnap_ros.cdr import ModuleShapeWire, RobotShapeWire
from softsnap_ros.node import SoftSnapNode
from softsnap_ros.service_queues import action_qos_kwargs, create_queued_service
from softsnap_ros.units import MM_PER_M
from softsnap_ros.spinning import inbox_node, run_node_main
from softsnap_interfaces.msg import CableLength, ModelDiagnostics, ModuleShape, RobotShape
from softsnap_interfaces.action import DesignThreading
from softsnap_interfaces.srv import ForwardShape, InverseDesign

from .loads import DEFAULT_BENDING_STIFFNESS_NMM
from .predictor import SOURCES, RobotPredictor
from .scene import load_scene
from .design_services import DesignServices, DesignWorker
from .prediction_thread import PredictionThread
from .shape_stream import ShapeStream, _Listeners
from .standard_outputs import StandardOutputs

__all__ = ['ModelNode', 'PredictionThread', 'main']

LENGTH_TOPIC = {'commanded': 'cable_length/command', 'predicted': 'cable_length/measured'}
#: On shutdown, how long a running design may take to notice the stop before the node
#: exits without it (s); the design's worker thread is a daemon and dies with the process.
DESIGN_STOP_WAIT_S = 0.5
#: On shutdown, how long the prediction thread may take to finish its prediction (s).
TICK_STOP_WAIT_S = 0.5
#: Messages each length subscription holds in DDS until the prediction thread takes
#: them: 2 s of a 50 Hz gait. 10 left 0.2 s of headroom at 50 Hz, and a CI run of a
#: 5 Hz node fed 50 Hz counted fewer lengths taken than sent (not reproduced here under
#: four CPU hogs; a starved process is the likely reason).
LENGTH_QUEUE_DEPTH = 100


class ModelNode(ShapeStream, StandardOutputs, DesignServices, SoftSnapNode):
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
        self.declare_parameter(
            'bending_stiffness', DEFAULT_BENDING_STIFFNESS_NMM / MM_PER_M, ParameterDescriptor(
                description='Bending stiffness K of one segment (energy K a^2) for forward '
                            'solves with gravity or a load, and for cable_tension (N m/rad^2); '
                            'default: the estimate for the authors\' TPU skeleton '
                            '(docs/model.md, Physics levels)',
                floating_point_range=[FloatingPointRange(from_value=1e-6, to_value=10.0)]))
        self.declare_parameter('max_alternatives', 20, ParameterDescriptor(
            description='Most alternatives an inverse design may ask for (count); more are '
                        'refused. Memory and time grow about linearly with it (docs/inverse.md)',
            integer_range=[IntegerRange(from_value=0, to_value=1000, step=1)]))
        self.declare_parameter('design_timeout', 30.0, ParameterDescriptor(
            description='Longest an inverse design may take from its arrival, waiting in the '
                        'queue included; then it is stopped and answered as timed out (s)',
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=3600.0)]))
        self.declare_parameter('marker_rate', 10.0, ParameterDescriptor(
            description='Rate of model/markers (MarkerArray) while someone subscribes (Hz)',
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=100.0)]))
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
        # Who subscribes, cached together (_refresh_subscribers): publisher -> subscription
        # count, and the shape outputs' listeners built from those same counts.
        self._subscriber_counts: dict = {}
        self._listeners_cache: _Listeners | None = None
        self._subscribers_at = -math.inf    # monotonic s of the last refresh
        self._pose_msgs: dict[tuple, Pose] = {}
        # Shape messages are published as CDR bytes kept ready and updated in place
        # (softsnap_ros.cdr.shape_writers says why), if rclpy reads those bytes back as the
        # messages the node would build field by field; else as message objects.
        n_segments, n_ribs = self.skeleton.n_segments, self.skeleton.n_ribs
        names = list(self.scene.module_names)
        self._robot_wires = {s: RobotShapeWire(self.scene.name, s, names, n_segments, n_ribs)
                             for s in SOURCES}
        self._module_wires = {(m, s): ModuleShapeWire(self.scene.name, s, m, n_segments, n_ribs)
                              for m in names for s in SOURCES}
        self.wire_format = self._wire_matches_rclpy()

        # Lengths are a stream where only the newest matters: sensor-data QoS would drop
        # messages under load; a reliable queue keeps every command to be counted.
        qos = QoSProfile(depth=10)
        length_qos = QoSProfile(depth=LENGTH_QUEUE_DEPTH)
        # Length topics are taken by the prediction thread instead of waking the executor
        # for every message: only the newest length per module matters for a prediction,
        # and rclpy's per-message dispatch (~0.2 ms) would otherwise dominate the node's
        # CPU at 100 Hz. The subscriptions live on an inbox node that no executor spins; up
        # to `depth` messages per topic wait in DDS between two period boundaries.
        self._inbox = inbox_node(f'{self.get_name()}_inbox', self.get_namespace(),
                                 self.context)
        self._length_subscriptions = []
        # Length messages taken per length subscription since start (count), in diagnostics.
        self.lengths_taken = [0] * (len(self.scene.modules) * len(SOURCES))
        self.module_publishers = {}
        for module in self.scene.modules:
            for source in SOURCES:
                subscription = self._inbox.create_subscription(
                    CableLength, f'{module.name}/{LENGTH_TOPIC[source]}', lambda msg: None,
                    length_qos)
                self._length_subscriptions.append((module.name, source, subscription))
                self.module_publishers[(module.name, source)] = self.create_publisher(
                    ModuleShape, f'{module.name}/shape/{source}', qos)
        self.robot_publishers = {s: self.create_publisher(RobotShape, f'model/shape/{s}', qos)
                                 for s in SOURCES}
        self.diagnostics_publisher = self.create_publisher(ModelDiagnostics, 'model/diagnostics', qos)
        # Standard outputs for RViz, Foxglove and rqt: built only while subscribed.
        self.marker_publisher = self.create_publisher(MarkerArray, 'model/markers', qos)
        self.joint_state_publishers = {
            s: self.create_publisher(JointState, f'model/joint_states/{s}', qos) for s in SOURCES}
        self.ros_diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', qos)
        # Only the newest simulated shape matters: depth 1, drawn at the next marker tick.
        self._simulated = None
        self.create_subscription(RobotShape, 'model/shape/simulated',
                                 self.simulated_shape_callback, 1)
        # (module, source) -> (shape, base pose, its markers);
        # ('', 'simulated') -> (the RobotShape drawn, its markers).
        self._marker_cache: dict[tuple[str, str], tuple] = {}
        self.marker_arrays_published = 0
        self.joint_states_published = 0
        self._health_reported = None
        create_queued_service(self, ForwardShape, '~/forward_shape', self.forward_shape_callback)
        # An inverse design takes 0.1 s to design_timeout: it runs on a worker thread so
        # that predictions and forward solves go on meanwhile; the guard condition wakes
        # the executor when the answer is ready. The service and the action have a worker
        # each, so a long action never holds up a quick service call; service calls queue
        # in arrival order, each answered within design_timeout of its arrival.
        # While its coroutine awaits, a callback keeps its group busy: the service, the
        # action and the guard get a reentrant group of their own, so neither they nor the
        # default group (lengths, timers, forward service) are blocked by a design.
        self._stopping = threading.Event()  # set on shutdown: every design stops
        self._design_group = ReentrantCallbackGroup()
        self._service_worker = DesignWorker('inverse_design')
        self._action_worker = DesignWorker('design_threading')
        self._design_done = self.create_guard_condition(lambda: None,
                                                        callback_group=self._design_group)
        create_queued_service(self, InverseDesign, '~/inverse_design', self.inverse_design_callback,
                              callback_group=self._design_group)
        self._active_goal = None  # (goal handle, accepted at monotonic s) while one runs
        self._design_action = ActionServer(
            self, DesignThreading, '~/design_threading', self.design_execute_callback,
            goal_callback=self.design_goal_callback,
            cancel_callback=self.design_cancel_callback,
            callback_group=self._design_group, **action_qos_kwargs())
        self.diagnostics_timer = self.create_timer(
            self.get_parameter('diagnostics_period').value, self.diagnostics_callback)
        # Markers are built on the prediction thread when due (a 10 Hz executor timer
        # woke the executor 10 times a second for a subscription count); a new
        # marker_rate applies at once.
        self._marker_period_s = 1.0 / self.get_parameter('marker_rate').value
        self._next_marker_at = time.monotonic()
        self._next_greeting_at = time.monotonic()  # see _greet_new_listeners
        self._robot_listeners_seen = dict.fromkeys(SOURCES, 0)
        # Predictions run on their own thread, woken by the lengths (PredictionThread says
        # why); only that thread touches the predictor, the inbox's subscriptions and the
        # shape publishers' caches.
        self._length_keys = [(module, source) for module, source, _ in self._length_subscriptions]
        self.prediction_thread = PredictionThread(
            'prediction', 1.0 / self.get_parameter('rate').value, self.context,
            [subscription for _, _, subscription in self._length_subscriptions], CableLength,
            on_length=self.length_callback, predict=self.predict_callback,
            chores=self.chores_callback, on_error=self.prediction_error_callback)
        self.prediction_thread.start()  # last: the node is complete
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
            if param.name in ('rate', 'length_tolerance', 'diagnostics_period', 'marker_rate'):
                value = param.value
                if not isinstance(value, (int, float)) or not math.isfinite(value):
                    return SetParametersResult(successful=False,
                                               reason=f'{param.name} must be a finite number')
            if param.name == 'design_timeout' and not (
                    isinstance(param.value, (int, float)) and math.isfinite(param.value)):
                return SetParametersResult(successful=False,
                                           reason=f'design_timeout must be a finite number of '
                                                  f'seconds, got {param.value!r}')
        # Apply after validation (ranges are enforced by the descriptors).
        for param in params:
            if param.name == 'rib_centers':
                self.rib_centers_mode = param.value
                self._listeners_cache = None  # built again with the new mode
            elif param.name == 'length_tolerance':
                self.predictor.length_tol_mm = float(param.value) * MM_PER_M
            elif param.name == 'rate':
                self.prediction_thread.period_s = 1.0 / float(param.value)
            elif param.name == 'marker_rate':
                self._marker_period_s = 1.0 / float(param.value)
                self._next_marker_at = min(self._next_marker_at,
                                           time.monotonic() + self._marker_period_s)
                self.prediction_thread.wake()
        return SetParametersResult(successful=True)

    def destroy_node(self):
        # Stop every design (they poll this between steps), then give the workers a
        # bounded moment: SIGINT must end the node within 2 s whatever it is doing.
        self._stopping.set()
        if not self.prediction_thread.stop(TICK_STOP_WAIT_S):
            self.get_logger().warning('the prediction thread did not stop in time')
        end = time.monotonic() + DESIGN_STOP_WAIT_S
        for worker in (self._service_worker, self._action_worker):
            if not worker.stop(max(0.0, end - time.monotonic())):
                self.get_logger().warning('a design did not stop in time; exiting without it')
        self._design_action.destroy()
        self._inbox.destroy_node()
        return super().destroy_node()


def main(args=None) -> int:
    # One thread runs every callback (lower latency than the multi-threaded executor);
    # predictions run on the node's prediction thread and inverse designs on its worker
    # threads, which destroy_node stops within TICK_STOP_WAIT_S and DESIGN_STOP_WAIT_S.
    return run_node_main(args, 'model_node', ModelNode, fast_exit=True)


if __name__ == '__main__':
    raise SystemExit(main())
