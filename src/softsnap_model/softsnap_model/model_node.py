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

import array
import dataclasses
import math
import queue
import threading
import time

import numpy as np
import rclpy
from geometry_msgs.msg import Point, Pose
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.executors import SingleThreadedExecutor
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.qos import QoSProfile
from rclpy.task import Future
from rclpy.time import Time
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from softsnap_ros.cdr import (ModuleShapeWire, RobotShapeWire, check_wire, decode_cable_length,
                              read_cable_length)
from softsnap_ros.node import SoftSnapNode
from softsnap_ros.service_queues import action_qos_kwargs, create_queued_service
from softsnap_ros.units import MM_PER_M
from softsnap_ros.wait_loop import SubscriptionWaiter
from softsnap_ros.spinning import (exit_without_teardown, hold_signals, inbox_node,
                                   init_ros, spin_until_shutdown)
from softsnap_interfaces.msg import CableLength, Design, ModelDiagnostics, ModuleShape, RobotShape
from softsnap_interfaces.action import DesignThreading
from softsnap_interfaces.srv import ForwardShape, InverseDesign

from .forward import solve_forward
from .friction import solve_friction
from .inverse import DesignCancelled, DesignTimedOut, design_threading
from .loads import DEFAULT_BENDING_STIFFNESS_NMM, Loads, solve_loaded
from .predictor import SOURCES, ModulePrediction, RobotPredictor
from .scene import SceneError, load_scene
from . import standard_messages as standard

LENGTH_TOPIC = {'commanded': 'cable_length/command', 'predicted': 'cable_length/measured'}
#: On shutdown, how long a running design may take to notice the stop before the node
#: exits without it (s); the design's worker thread is a daemon and dies with the process.
DESIGN_STOP_WAIT_S = 0.5
#: Period of DesignThreading feedback while a goal runs (s).
FEEDBACK_PERIOD_S = 0.1
#: On shutdown, how long the prediction thread may take to finish its prediction (s).
TICK_STOP_WAIT_S = 0.5
#: After a length wakes the idle prediction thread, the fraction of a period it waits
#: for more (lengths published together are solved together).
GATHER_FRACTION = 0.5
#: Longest the idle prediction thread blocks without checking the context (s).
IDLE_WAIT_MAX_S = 1.0
#: Messages each length subscription holds in DDS until the prediction thread takes
#: them: 2 s of a 50 Hz gait. 10 left 0.2 s of headroom at 50 Hz, and a CI run of a
#: 5 Hz node fed 50 Hz counted fewer lengths taken than sent (not reproduced here under
#: four CPU hogs; a starved process is the likely reason).
LENGTH_QUEUE_DEPTH = 100
#: While a long period runs, how often the length queues are taken (s): the queues then
#: never overflow below LENGTH_QUEUE_DEPTH / DRAIN_S messages a second.
DRAIN_S = 0.05
#: How long a publisher's subscription count is trusted before DDS is asked again (s).
SUBSCRIBERS_REFRESH_S = 0.25
#: Pose messages kept for reuse (fixed module bases hit it every prediction).
POSE_CACHE_SIZE = 1024


class DesignWorker:
    """One daemon thread running inverse designs in arrival order.

    A daemon (unlike a ThreadPoolExecutor's worker, which the interpreter joins at exit)
    so that a design can never hold the process up after SIGINT.
    """

    def __init__(self, name: str):
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job) -> None:
        self._jobs.put(job)

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            job()  # jobs catch their own exceptions (see ModelNode._design_job)

    def stop(self, timeout: float) -> bool:
        """Ask the thread to end after its current job; True if it ended within timeout (s)."""
        self._jobs.put(None)
        self._thread.join(timeout)
        return not self._thread.is_alive()


class PredictionThread:
    """Takes the length messages and predicts on a daemon thread, woken by the lengths.

    Why not an rclpy timer or executor subscriptions: every executor wake rebuilds the
    wait set over all of the node's entities in Python (0.5 ms against 0.04 ms for a
    whole idle tick, measured on the development machine), and rclpy's per-message
    dispatch (~0.2 ms) would dominate at 100 Hz. Why not a fixed tick: an idle node then
    still wakes ``rate`` times a second to find nothing.

    Two states:

    - idle: the thread blocks in one rcl wait set over the length subscriptions (and a
      guard condition for :meth:`stop` and :meth:`wake`), until a length arrives or the
      next chore is due (``chores()`` says when; at most ``IDLE_WAIT_MAX_S``). It takes
      only from the subscriptions the wait reports ready, then turns active with its
      next prediction ``GATHER_FRACTION`` of a period later (the mean delay of a fixed
      tick; lengths published together, such as a gait's five commands, are solved
      together), and at least a period after the last prediction.
    - active: predictions follow on a grid of ``period_s`` from there (in phase with the
      arrivals; at most one prediction per period, a late wake skips to the next
      boundary). Between two boundaries the thread sleeps without asking DDS: lengths
      wait in the subscriptions' queues (``LENGTH_QUEUE_DEPTH``) and are taken at the
      boundary from every subscription (ten takes that find nothing cost a third of one
      wait-set round, measured), and every ``DRAIN_S`` while a long period runs, so that
      no queue overflows below LENGTH_QUEUE_DEPTH / DRAIN_S messages a second. A boundary
      that finds nothing to solve turns the thread idle.

    ``on_length(index, data)`` gets every message of ``subscriptions[index]`` as bytes,
    oldest first; ``predict()`` solves what is pending and returns False if nothing was;
    ``chores()`` does what is due (markers) and returns the monotonic time (s) of the
    next. None of them may raise: ``on_error(exception)`` reports what escapes, and the
    loop goes on (never a dead thread). The thread ends on :meth:`stop` or when the
    context shuts down.
    """

    def __init__(self, name: str, period_s: float, context, subscriptions, msg_type, *,
                 on_length, predict, chores, on_error):
        self._period_s = float(period_s)
        self._context = context
        self._waiter = SubscriptionWaiter(context, subscriptions)
        self._count = len(subscriptions)
        self._msg_type = msg_type
        self._on_length, self._predict, self._chores = on_length, predict, chores
        self._on_error = on_error
        self._stop = threading.Event()
        self._wake = threading.Event()  # a new period or a stop, for the active state
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    @property
    def period_s(self) -> float:
        return self._period_s

    @period_s.setter
    def period_s(self, value: float) -> None:
        """A new period applies at once: a sleeping thread wakes and computes again."""
        self._period_s = float(value)
        self.wake()

    def wake(self) -> None:
        """Wake the thread to look again at the period and at when chores are due."""
        self._wake.set()
        self._waiter.wake()

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        last = time.monotonic()  # the boundary of the last prediction (the grid's origin)
        active = False
        drained = last           # when the queues were last taken while active
        while not self._stop.is_set():
            try:
                if not self._context.ok():
                    return  # shut down (SIGINT) before stop(): no chores, no spin until it
                due = self._chores()
                now = time.monotonic()
                if not active:
                    ready = self._waiter.wait(min(due - now, IDLE_WAIT_MAX_S))
                    if not ready:
                        continue  # a chore, the guard, the safety timeout or a shutdown
                    arrived = time.monotonic()
                    self._take(ready)
                    # Half a period after the first arrival (the mean delay of a fixed
                    # tick), and at least a period after the last prediction: lengths
                    # published together (a gait's five commands) are solved together.
                    period = self._period_s
                    last = max(last, arrived - period * (1.0 - GATHER_FRACTION))
                    active = True
                    continue
                period = self._period_s
                boundary = last + period  # read again after every wake: a new rate applies
                if now < boundary:
                    if now - drained >= DRAIN_S:
                        self._take(range(self._count))
                        drained = now
                    if self._wake.wait(min(boundary, due, drained + DRAIN_S) - now):
                        self._wake.clear()
                    continue
                self._take(range(self._count))
                drained = now
                if self._predict():
                    # On the grid (in phase with the lengths' arrivals); after a late
                    # wake, the next boundary of the grid (no catch-up predictions).
                    last = boundary + math.floor((now - boundary) / period) * period
                else:
                    active = False  # a whole period without a length
            except Exception as error:  # noqa: BLE001 - report and go on; never die silently
                if self._stop.is_set() or not self._context.ok():
                    return  # shutting down: the context or a handle is gone
                self._on_error(error)
                self._stop.wait(0.01)  # no busy loop if the error repeats

    def _take(self, indices) -> None:
        """Every waiting message of the given subscriptions, oldest first, to on_length.

        Taken as bytes: reading the two fields needed costs a quarter of building the
        message object (see :func:`softsnap_ros.cdr.decode_cable_length`).
        """
        msg_type, on_length, take_all = self._msg_type, self._on_length, self._waiter.take_all
        for index in indices:
            take_all(index, msg_type, on_length)

    def stop(self, timeout: float) -> bool:
        """Stop after the current prediction; True if the thread ended within timeout (s)."""
        self._stop.set()
        self.wake()
        if self._thread.is_alive():
            self._thread.join(timeout)
        if self._thread.is_alive():
            return False
        self._waiter.close()
        return True


@dataclasses.dataclass(frozen=True)
class _Listeners:
    """Who listens to the shape outputs, per source ('commanded', 'predicted')."""

    rib_centers: dict    # source -> whether shapes carry rib centres
    modules: dict        # source -> {module: its ModuleShape publisher, if subscribed}
    robot: dict          # source -> RobotShape topic subscribed
    joint_states: dict   # source -> JointState topic subscribed


def _points_m(points_mm) -> list[Point]:
    """(N, 2) or (N, 3) array in mm -> geometry_msgs/Point list in metres.

    Built without the generated per-field type checks (``check_fields=False``): every
    value is a Python float made here, and the checks were most of the cost. (Live
    shapes go out as bytes, see shape_wire; this serves the services and the fallback.)
    """
    rows = (np.asarray(points_mm, dtype=float) / MM_PER_M).tolist()
    return [Point(x=p[0], y=p[1], z=p[2] if len(p) > 2 else 0.0, check_fields=False)
            for p in rows]


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
        # (shape_wire says why), if rclpy reads those bytes back as the messages the
        # node would build field by field; else as message objects.
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

    # ------------------------------------------------------------------ topics
    def length_callback(self, index: int, data: bytes) -> None:
        """A serialised CableLength taken from length subscription ``index`` (see
        ``_length_keys``): submit it to the predictor."""
        self.lengths_taken[index] += 1
        module, source = self._length_keys[index]
        try:
            stamp_ns, length_m = read_cable_length(data)
        except Exception as error:  # undecodable bytes must not stop the predictions
            self.get_logger().warning(f'could not read a {source} length message for '
                                      f'{module!r}: {error!r}', throttle_duration_sec=1.0)
            return
        try:
            self.predictor.submit(source, module, length_m * MM_PER_M, stamp_ns)
        except ValueError as error:
            self.get_logger().warning(
                f'refused {source} length for {module!r}: {error}; keeping the last valid shape',
                throttle_duration_sec=1.0)

    def _refresh_subscribers(self) -> None:
        """Forget the subscription counts and the listeners built from them once they are
        SUBSCRIBERS_REFRESH_S old; both are asked again when next needed.

        Asking DDS costs a few microseconds a publisher, and every prediction asked it for
        the robot's and every module's publishers. One refresh for both caches: a
        subscriber that joins or leaves is seen within SUBSCRIBERS_REFRESH_S (discovery
        itself takes longer), by the counts and the listeners alike.
        """
        now = time.monotonic()
        if now - self._subscribers_at > SUBSCRIBERS_REFRESH_S:
            self._subscribers_at = now
            self._subscriber_counts.clear()
            self._listeners_cache = None

    def _subscribers(self, publisher) -> int:
        """Subscription count of one of our publishers (cached, see _refresh_subscribers)."""
        self._refresh_subscribers()
        count = self._subscriber_counts.get(publisher)
        if count is None:
            count = self._subscriber_counts[publisher] = publisher.get_subscription_count()
        return count

    def _listeners(self) -> _Listeners:
        """Who listens to the shape outputs (one look-up a prediction instead of one per
        topic and shape; cached with the counts, see _refresh_subscribers)."""
        self._refresh_subscribers()
        listeners = self._listeners_cache
        if listeners is None:  # refreshed, or the rib_centers mode changed
            modules = {source: {m.name: self.module_publishers[(m.name, source)]
                                for m in self.scene.modules
                                if self._subscribers(self.module_publishers[(m.name, source)])}
                       for source in SOURCES}
            robot = {source: self._subscribers(self.robot_publishers[source]) > 0
                     for source in SOURCES}
            if self.rib_centers_mode == 'auto':
                rib_centers = {source: robot[source] or bool(modules[source])
                               for source in SOURCES}
            else:
                rib_centers = dict.fromkeys(SOURCES, self.rib_centers_mode == 'always')
            listeners = self._listeners_cache = _Listeners(
                rib_centers=rib_centers, modules=modules, robot=robot,
                joint_states={source: self._subscribers(self.joint_state_publishers[source]) > 0
                              for source in SOURCES})
        return listeners

    def predict_callback(self) -> bool:
        """Solve and publish what is pending (called on a period boundary by the
        prediction thread); False if nothing was pending."""
        if not self.predictor.has_pending:
            return False
        if not self.context.ok():
            return False  # shutting down: the publishers may be gone
        try:
            self._predict()
        except Exception as error:  # never let one bad prediction stop the predictions
            self.get_logger().error(f'prediction failed: {error!r}', throttle_duration_sec=1.0)
        return True

    def chores_callback(self) -> float:
        """Publish markers when due (on the prediction thread); when the next are due
        (monotonic s)."""
        now = time.monotonic()
        if now >= self._next_marker_at and self.context.ok():
            # On schedule; after a slow prediction the next is a whole period away (no
            # second array at once, no burst of catch-up arrays).
            following = self._next_marker_at + self._marker_period_s
            self._next_marker_at = following if following > now else now + self._marker_period_s
            self.marker_callback()
        if self.context.ok():
            self._greet_new_listeners(now)
        return min(self._next_marker_at, self._next_greeting_at)

    def prediction_error_callback(self, error: Exception) -> None:
        self.get_logger().error(f'prediction thread: {error!r}', throttle_duration_sec=1.0)

    def _predict(self) -> None:
        """Solve the pending lengths and publish the new shapes to whoever subscribes."""
        listeners = self._listeners()
        updated = self.predictor.tick(listeners.rib_centers)
        for module, source, reason in self.predictor.errors:
            self.get_logger().warning(f'could not solve the {source} shape of {module!r}: '
                                      f'{reason}; keeping the last valid shape',
                                      throttle_duration_sec=1.0)
        self.predictor.errors.clear()
        clock = self.get_clock().handle  # the node's clock (ROS time, simulated or not)
        with clock:
            stamp_ns = clock.get_now().nanoseconds
        stamp = None  # its message, built only for the message-object fallback
        for source in SOURCES:
            if not updated[source]:
                continue
            if listeners.joint_states[source]:
                for joint_state in standard.joint_states(updated[source]):
                    self.joint_state_publishers[source].publish(joint_state)
                    self.joint_states_published += 1
            if not self.wire_format and stamp is None:
                stamp = Time(nanoseconds=stamp_ns).to_msg()
            # Serialising costs ~0.1 ms a message: topics nobody listens to are skipped.
            subscribed = listeners.modules[source]
            if subscribed:
                for shape in updated[source]:
                    publisher = subscribed.get(shape.module)
                    if publisher is not None:
                        publisher.publish(
                            self._module_wires[(shape.module, source)].serialize(shape, stamp_ns)
                            if self.wire_format else self._message_for(shape, stamp))
            if listeners.robot[source]:
                self._publish_robot(source, stamp_ns, stamp)

    def _publish_robot(self, source: str, stamp_ns: int, stamp=None) -> None:
        """The RobotShape of one source from the predictor's current shapes."""
        shapes, poses = self.predictor.shapes(source), self.predictor.base_poses(source)
        if not self.wire_format and stamp is None:
            stamp = Time(nanoseconds=stamp_ns).to_msg()
        self.robot_publishers[source].publish(
            self._robot_wires[source].serialize(shapes, poses, stamp_ns)
            if self.wire_format else self._robot_msg(source, shapes, poses, stamp))

    def _greet_new_listeners(self, now: float) -> None:
        """Send the current RobotShape of a source whose subscribers grew since the last
        look: a robot_state or RViz that joins after the last change of length would
        otherwise get no shape until a length changes (unchanged lengths are skipped)."""
        if now < self._next_greeting_at:
            return
        self._next_greeting_at = now + SUBSCRIBERS_REFRESH_S
        for source in SOURCES:
            count = self._subscribers(self.robot_publishers[source])
            seen, self._robot_listeners_seen[source] = self._robot_listeners_seen[source], count
            if count > seen and any(shape is not None for shape in self.predictor.shapes(source)):
                clock = self.get_clock().handle
                with clock:
                    stamp_ns = clock.get_now().nanoseconds
                self._publish_robot(source, stamp_ns)

    def _robot_msg(self, source: str, shapes, poses, stamp) -> RobotShape:
        """The RobotShape of one source built as a message object (the fallback, and the
        reference the wire format is checked against)."""
        robot = RobotShape(check_fields=False)  # its parts are built and checked here
        robot.header.stamp = stamp
        robot.header.frame_id = self.scene.name
        robot.robot = self.scene.name
        robot.modules = [self._message_for(shape, stamp) if shape is not None
                         else ModuleShape(module=module.name, source=source)
                         for module, shape in zip(self.scene.modules, shapes)]
        robot.base_poses = [self._pose_msg(pose) for pose in poses]
        return robot

    def _wire_matches_rclpy(self) -> bool:
        """True if rclpy reads the wire-format shapes (and a length) back as the messages
        built field by field, for sample shapes of this scene; else False, with a warning.

        Run once at start: a middleware with another encoding then costs CPU, not
        correctness.
        """
        try:
            written = []
            n = self.skeleton.n_segments
            angles = np.linspace(-0.3, 0.2, n)
            centers = np.cumsum(np.full((n + 1, 2), [self.skeleton.spacing_mm, 0.7]), axis=0)
            layouts = ('points', 'no points', None)
            for source in SOURCES:
                shapes = []
                for i, module in enumerate(self.scene.modules):
                    layout = layouts[i % len(layouts)]
                    shapes.append(None if layout is None else ModulePrediction(
                        module=module.name, source=source, cable_length_mm=171.25 + i,
                        angles=angles + i, tension=0.0125 * i, energy=0.5 + i,
                        rib_centers_mm=centers * (i + 1) if layout == 'points' else None,
                        converged=bool(i % 2), residual=1e-12 * i, solve_time_s=1e-4 * i,
                        stamp_ns=(1_700_000_000_123_456_789 + i) * (i % 2)))
                stamp_ns = 1_800_000_000_987_654_321
                stamp = Time(nanoseconds=stamp_ns).to_msg()
                poses = self.predictor.base_poses(source)
                wire = RobotShapeWire(self.scene.name, source, list(self.scene.module_names),
                                      n, self.skeleton.n_ribs)
                written.append((wire.serialize(shapes, poses, stamp_ns),
                                self._robot_msg(source, shapes, poses, stamp)))
                for shape in shapes:
                    if shape is None:
                        continue
                    module_wire = ModuleShapeWire(self.scene.name, source, shape.module, n,
                                                  self.skeleton.n_ribs)
                    written.append((module_wire.serialize(shape, stamp_ns),
                                    self._shape_msg(shape, stamp)))
            length = CableLength(cable_length=0.1234567)
            length.header.stamp.sec, length.header.stamp.nanosec = 17, 42
            length.header.frame_id = 'abc'
            check_wire(written, read=[(decode_cable_length, length, (17_000_000_042, 0.1234567))])
            self._last_msgs.clear()
        except Exception as error:
            self.get_logger().warning(
                f'publishing shapes as message objects (costs more CPU): the wire format '
                f'does not match this middleware\'s: {error!r}')
            return False
        return True

    def _pose_msg(self, pose) -> Pose:
        """Pose message of a (position m, quaternion xyzw) pair; fixed bases reuse theirs."""
        msg = self._pose_msgs.get(pose)
        if msg is None:
            msg = Pose()
            msg.position.x, msg.position.y, msg.position.z = pose[0]
            (msg.orientation.x, msg.orientation.y,
             msg.orientation.z, msg.orientation.w) = pose[1]
            if len(self._pose_msgs) > POSE_CACHE_SIZE:  # moving chains: do not grow forever
                self._pose_msgs.clear()
            self._pose_msgs[pose] = msg
        return msg

    def _message_for(self, shape, stamp) -> ModuleShape:
        """The message of a shape, built on first use and reused while the shape is current."""
        key = (shape.module, shape.source)
        cached = self._last_msgs.get(key)
        if cached is None or cached[0] is not shape:
            cached = (shape, self._shape_msg(shape, stamp))
            self._last_msgs[key] = cached
        return cached[1]

    def _shape_msg(self, shape, stamp) -> ModuleShape:
        msg = ModuleShape(check_fields=False)  # fields set here from typed values
        # A shape is the state at the time its length was commanded or measured: keep
        # that stamp (end-to-end latency is then arrival time minus stamp).
        if shape.stamp_ns > 0:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(shape.stamp_ns, 1_000_000_000)
        else:
            msg.header.stamp = stamp
        msg.header.frame_id = f'{self.scene.name}/{shape.module}'
        msg.module = shape.module
        msg.source = shape.source
        msg.cable_length = float(shape.cable_length_mm) / MM_PER_M
        msg.angles = array.array('d', shape.angles)
        if shape.rib_centers_mm is not None:
            msg.rib_centers = _points_m(shape.rib_centers_mm)
        msg.tension = float(shape.tension) * MM_PER_M  # rad^2/mm -> rad^2/m
        msg.energy = float(shape.energy)
        msg.converged = bool(shape.converged)
        msg.residual = float(shape.residual)
        msg.solve_time = float(shape.solve_time_s)
        return msg

    # ------------------------------------------------------------------ standard outputs
    def simulated_shape_callback(self, msg: RobotShape) -> None:
        self._simulated = msg  # drawn (and checked) at the next marker tick, if watched

    def marker_callback(self) -> None:
        """Publish model/markers if someone subscribes (called by the prediction thread when
        due)."""
        if self._subscribers(self.marker_publisher) == 0:
            return  # nobody watches: build nothing
        try:
            markers = self._model_markers() + self._simulated_markers()
        except Exception as error:  # never let a marker bug stop the node
            self.get_logger().error(f'markers failed: {error!r}', throttle_duration_sec=1.0)
            return
        self.marker_publisher.publish(MarkerArray(markers=markers))
        self.marker_arrays_published += 1

    def _model_markers(self) -> list:
        """Markers of every solved shape; a (module, source)'s markers are updated only
        when its shape (a new object for every solve) or its base pose changed, in place
        (the previous array was serialised when published)."""
        markers = []
        for source in SOURCES:
            for index, (module, shape, pose) in enumerate(zip(
                    self.scene.modules, self.predictor.shapes(source),
                    self.predictor.base_poses(source))):
                if shape is None:
                    continue
                cached = self._marker_cache.get((module.name, source))
                if cached is None or cached[0] is not shape or cached[1] != pose:
                    cached = (shape, pose, standard.prediction_markers(
                        shape, module_index=index, threading_mm=module.threading_mm,
                        base_pose_m=pose, frame_id=self.scene.name,
                        spacing_mm=self.skeleton.spacing_mm,
                        rib_length_mm=self.skeleton.rib_length_mm,
                        reuse=cached[2] if cached is not None else ()))
                    self._marker_cache[(module.name, source)] = cached
                markers += cached[2]
        return markers

    def _simulated_markers(self) -> list:
        msg = self._simulated
        if msg is None:
            return []
        cached = self._marker_cache.get(('', 'simulated'))
        if cached is not None and cached[0] is msg:
            return cached[1]
        markers, problems = standard.robot_shape_markers(
            msg, default_frame_id=self.scene.name, module_names=self.scene.module_names,
            threadings_mm={m.name: m.threading_mm for m in self.scene.modules},
            spacing_mm=self.skeleton.spacing_mm, rib_length_mm=self.skeleton.rib_length_mm)
        for problem in problems:
            self.get_logger().warning(f'simulated {problem}', throttle_duration_sec=5.0)
        self._marker_cache[('', 'simulated')] = (msg, markers)
        return markers

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
        health = standard.ModelHealth(
            solves=c.solves, skipped_unchanged=c.skipped_unchanged,
            skipped_duplicate=c.skipped_duplicate, skipped_rib_points=c.skipped_rib_points,
            refused=c.refused, service_calls=self.service_calls,
            service_failures=self.service_failures, mean_solve_time_s=msg.mean_solve_time,
            marker_arrays_published=self.marker_arrays_published,
            joint_states_published=self.joint_states_published)
        diagnostics = DiagnosticArray(status=[standard.model_status(
            f'softsnap/{self.scene.name}/model', health, self._health_reported,
            1.0 / self.get_parameter('rate').value)])
        diagnostics.header.stamp = self.get_clock().now().to_msg()
        self._health_reported = health
        self.ros_diagnostics_publisher.publish(diagnostics)
        msg.modules = [m.name for m in self.scene.modules]
        taken = dict(zip(self._length_keys, self.lengths_taken))
        msg.commanded_lengths = [taken[(m, 'commanded')] for m in msg.modules]
        msg.measured_lengths = [taken[(m, 'predicted')] for m in msg.modules]
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
            loads = self._request_loads(request)
            friction = self._request_friction(request, loads)
            start = time.perf_counter()
            if friction is not None:
                result = solve_friction(self.skeleton, threading, request.cable_length * MM_PER_M,
                                        friction=friction[0], direction=friction[1])
            elif loads.is_zero:
                result = solve_forward(self.skeleton, threading, request.cable_length * MM_PER_M,
                                       initial=initial)
            else:
                result = solve_loaded(self.skeleton, threading,
                                      request.cable_length * MM_PER_M, loads)
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
        k_nmm = loads.bending_stiffness_nmm
        n_segments = len(response.angles)
        response.tip_tension_ratio = 1.0
        if friction is not None:
            # The winch's tension is the one the motor feels; per-segment tensions decay
            # (pull) or grow (release) towards the tip.
            response.energy = float(np.sum(self.skeleton.stiffness_array * result.angles ** 2))
            response.tension = float(result.winch_tension) * MM_PER_M
            response.residual = max(float(result.constraint_residual) / MM_PER_M,
                                    float(result.stationarity_residual))
            response.segment_tensions = (np.asarray(result.segment_tensions, dtype=float)
                                         * MM_PER_M).tolist()
            response.wrap_angles = np.asarray(result.wrap_angles, dtype=float).tolist()
            response.tip_tension_ratio = float(result.tip_tension_ratio)
        elif loads.is_zero:
            response.energy = float(result.energy)
            response.tension = float(result.tension) * MM_PER_M
            response.residual = float(result.residual)
            response.segment_tensions = [response.tension] * n_segments
        else:
            # Unit-stiffness fields stay comparable with the unloaded solve's.
            response.energy = float(np.sum(self.skeleton.stiffness_array * result.angles ** 2))
            response.tension = float(result.tension_n) / k_nmm * MM_PER_M
            response.residual = max(float(result.constraint_residual_mm) / MM_PER_M,
                                    float(result.stationarity_residual_rad))
            response.segment_tensions = [response.tension] * n_segments
        response.cable_tension = float(response.tension) / MM_PER_M * k_nmm
        response.converged = bool(result.converged)
        response.iterations = int(result.iterations)
        return response

    @staticmethod
    def _request_friction(request, loads: Loads):
        """(friction coefficient, direction) of a ForwardShape request, or None without
        friction (ValueError if bad or combined with a load)."""
        mu = float(request.friction_coefficient)
        direction = request.direction or 'pull'
        if not (math.isfinite(mu) and 0.0 <= mu <= 2.0):
            raise ValueError(f'friction_coefficient must be in [0, 2], got {mu!r}')
        if direction not in ('pull', 'release'):
            raise ValueError(f"direction must be 'pull' or 'release' (or empty), got {direction!r}")
        if mu == 0.0:
            return None
        if not loads.is_zero:
            raise ValueError('friction_coefficient > 0 cannot be combined with gravity or a load '
                             '(no solver couples them yet): give one or the other')
        return mu, direction

    def _request_loads(self, request) -> Loads:
        """Loads of a ForwardShape request (SI) in the core's units (ValueError if bad)."""
        k_si = float(request.bending_stiffness)
        if k_si == 0.0:
            k_si = float(self.get_parameter('bending_stiffness').value)
        rib = int(request.load_rib)
        if not (math.isfinite(k_si) and k_si > 0.0):
            raise ValueError(f'bending_stiffness must be finite and > 0 N m/rad^2 (0: the '
                             f'node parameter), got {request.bending_stiffness!r}')
        if rib > self.skeleton.n_ribs - 1 or rib < -1:
            raise ValueError(f'load_rib must be 1..{self.skeleton.n_ribs - 1}, or -1 or 0 '
                             f'for the tip; got {rib}')
        g, f = request.gravity, request.load
        return Loads(gravity_mps2=(g.x, g.y, g.z), bending_stiffness_nmm=k_si * MM_PER_M,
                     load_n=(f.x, f.y, f.z), load_rib=-1 if rib == 0 else rib)

    # ------------------------------------------------------------------ inverse design
    def _design_kwargs(self, request) -> dict:
        """Validate an InverseDesign request or DesignThreading goal (same fields) and
        convert it to design_threading arguments (mm); ValueError quoting the bad value."""
        cap = self.get_parameter('max_alternatives').value
        if request.alternatives > cap:
            raise ValueError(f'alternatives {request.alternatives} is above max_alternatives '
                             f'{cap}: ask for at most {cap} (memory and time grow about '
                             'linearly with the alternatives, see docs/inverse.md)')
        has_angles, has_points = len(request.target_angles) > 0, len(request.target_points) > 0
        if has_angles == has_points:
            raise ValueError('give exactly one of target_angles and target_points')
        # 0 means "no bound"; anything else must be a finite, non-negative length.
        bounds = {'min_cable_length': request.min_cable_length,
                  'max_cable_length': request.max_cable_length}
        for name, value in bounds.items():
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f'{name} must be a finite length >= 0 m (0 for no bound), '
                                 f'got {value!r} m')
        low, high = request.min_cable_length, request.max_cable_length
        if low > 0.0 and high > 0.0 and low > high:
            raise ValueError(f'min_cable_length {low!r} m is above max_cable_length {high!r} m')
        kwargs = {'k': int(request.alternatives)}
        if request.allowed_holes:
            kwargs['allowed_holes'] = list(request.allowed_holes)
        if request.forbidden_holes:
            kwargs['forbidden_holes'] = list(request.forbidden_holes)
        if request.fixed_holes:
            kwargs['fixed_holes'] = [h or None for h in request.fixed_holes]
        if low > 0.0 or high > 0.0:
            kwargs['cable_length_range'] = (low * MM_PER_M,
                                            (high if high > 0.0 else math.inf) * MM_PER_M)
        # Tolerances in m on the interface, mm in the core (which checks the range).
        kwargs['hole_tolerance_mm'] = float(request.hole_tolerance) * MM_PER_M
        kwargs['length_tolerance_mm'] = float(request.length_tolerance) * MM_PER_M
        if has_angles:
            kwargs['target_angles'] = list(request.target_angles)
        else:
            kwargs['target_points'] = [(p.x * MM_PER_M, p.y * MM_PER_M)
                                       for p in request.target_points]
        return kwargs

    def _design_job(self, kwargs, arrived, timeout, should_stop, done: Future, progress=None):
        """A worker's job: run one design, never raise, fill ``done`` with
        (outcome, DesignResult or reason) and wake the executor.

        The design must end by ``arrived + timeout`` (monotonic s), waiting included.
        outcome is 'succeeded', 'refused', 'cancelled', 'timed out' or 'failed'."""
        def job():
            try:
                remaining = arrived + timeout - time.monotonic()
                if remaining <= 0.0:
                    answer = ('timed out', f'design_timeout {timeout:g} s passed while the '
                                           'request waited behind another design')
                else:
                    answer = ('succeeded', design_threading(
                        self.skeleton, should_stop=should_stop, time_limit_s=remaining,
                        progress=progress, **kwargs))
            except DesignCancelled as error:
                answer = ('cancelled', str(error))
            except DesignTimedOut as error:
                answer = ('timed out', f'design_timeout {timeout:g} s exceeded: {error}')
            except (ValueError, TypeError) as error:
                answer = ('refused', str(error))
            except Exception as error:  # a solver bug must not kill the worker thread
                answer = ('failed', f'internal error: {error!r}')
            done.set_result(answer)
            try:
                self._design_done.trigger()
            except Exception:  # the node was destroyed meanwhile (shutdown): nobody waits
                pass
        return job

    def _fill_design(self, outcome, answer, out):
        """Fill an InverseDesign.Response or DesignThreading.Result (same fields)."""
        out.success = outcome == 'succeeded'
        if not out.success:
            out.message = f'{outcome}: {answer}'
            return out
        out.message = answer.message or 'ok'
        out.best = self._design_msg(answer)
        out.alternatives = [self._design_msg(alt) for alt in answer.alternatives]
        out.fit_error = float(answer.fit_error) / MM_PER_M
        return out

    async def inverse_design_callback(self, request, response):
        self.service_calls += 1
        arrived = time.monotonic()
        try:
            kwargs = self._design_kwargs(request)
        except (ValueError, TypeError) as error:
            outcome, answer = 'refused', str(error)
        else:
            done = Future()
            self._service_worker.submit(self._design_job(
                kwargs, arrived, self.get_parameter('design_timeout').value,
                self._stopping.is_set, done))
            outcome, answer = await done
        response = self._fill_design(outcome, answer, InverseDesign.Response())
        response.solve_time = time.monotonic() - arrived
        if not response.success:
            self.service_failures += 1
            self.get_logger().warning(f'inverse_design {response.message}')
        return response

    def design_goal_callback(self, goal_request) -> GoalResponse:
        # One goal at a time: a second would only compete for the CPU with the first.
        # Bad goals are accepted and then aborted with the reason (a rejection has none).
        if self._stopping.is_set():
            return GoalResponse.REJECT
        if self._active_goal is not None:
            self.get_logger().warning(
                'design_threading goal rejected: busy with a goal accepted '
                f'{time.monotonic() - self._active_goal[1]:.1f} s ago (one goal at a time; '
                'cancel it, wait, or call ~/inverse_design)')
            return GoalResponse.REJECT
        self._active_goal = (None, time.monotonic())  # reserved until execute runs
        return GoalResponse.ACCEPT

    def design_cancel_callback(self, goal_handle) -> CancelResponse:
        # The design polls the goal's cancel flag between steps of the search.
        return CancelResponse.ACCEPT

    async def design_execute_callback(self, goal_handle):
        accepted = self._active_goal[1] if self._active_goal else time.monotonic()
        self._active_goal = (goal_handle, accepted)
        self.service_calls += 1
        # (fraction, stage): replaced whole by the worker, read by the feedback timer.
        progress = [(0.0, 'queued')]

        def report(fraction, stage):
            progress[0] = (fraction, stage)

        def feedback_callback():
            fraction, stage = progress[0]
            goal_handle.publish_feedback(DesignThreading.Feedback(
                fraction=float(fraction), stage=stage, elapsed=time.monotonic() - accepted))

        feedback_timer = None
        try:
            try:
                kwargs = self._design_kwargs(goal_handle.request)
            except (ValueError, TypeError) as error:
                outcome, answer = 'refused', str(error)
            else:
                done = Future()
                feedback_timer = self.create_timer(FEEDBACK_PERIOD_S, feedback_callback,
                                                   callback_group=self._design_group)
                self._action_worker.submit(self._design_job(
                    kwargs, accepted, self.get_parameter('design_timeout').value,
                    lambda: self._stopping.is_set() or goal_handle.is_cancel_requested,
                    done, report))
                outcome, answer = await done
                if outcome == 'succeeded':
                    feedback_callback()  # the final 'done' at fraction 1
            result = self._fill_design(outcome, answer, DesignThreading.Result())
            result.solve_time = time.monotonic() - accepted
            if outcome == 'succeeded':
                goal_handle.succeed()
            elif outcome == 'cancelled' and goal_handle.is_cancel_requested:
                goal_handle.canceled()
                self.get_logger().info(f'design_threading {result.message}')
            else:  # refused, timed out, failed, or stopped by shutdown
                goal_handle.abort()
                self.get_logger().warning(f'design_threading aborted: {result.message}')
            if not result.success:
                self.service_failures += 1
            return result
        finally:
            if feedback_timer is not None:
                self.destroy_timer(feedback_timer)
            self._active_goal = None

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

    @staticmethod
    def _design_msg(result) -> Design:
        sens = getattr(result, 'sensitivity', None)
        return Design(
            holes=list(result.holes),
            threading=(np.asarray(result.threading, dtype=float) / MM_PER_M).tolist(),
            cable_length=float(result.cable_length) / MM_PER_M,
            angles=np.asarray(result.angles, dtype=float).tolist(),
            rib_centers=_points_m(result.rib_centers),
            error=float(result.error),
            position_error=float(result.position_error) / MM_PER_M,
            tolerance_median_error=sens.median_error if sens is not None else math.nan,
            tolerance_p90_error=sens.p90_error if sens is not None else math.nan)


def main(args=None):
    # rclpy.init() is a context manager only from Kilted on; this form also runs on Jazzy.
    init_ros(args=args)
    try:
        node = ModelNode()
    except (SceneError, ValueError) as error:
        # A bad configuration is reported once, clearly, instead of a traceback.
        rclpy.logging.get_logger('model_node').fatal(f'cannot start: {error}')
        rclpy.try_shutdown()
        raise SystemExit(2)
    # One thread runs every callback (lower latency than the multi-threaded executor);
    # predictions run on the node's prediction thread and inverse designs on its worker
    # threads, which destroy_node stops within TICK_STOP_WAIT_S and DESIGN_STOP_WAIT_S.
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        spin_until_shutdown(executor)
    finally:
        stopped = time.monotonic()
        hold_signals()   # a second Ctrl-C while stopping: no traceback
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        hold_signals(final=True)   # ignored from here to the exit
    exit_without_teardown(0, node.context, stopped)


if __name__ == '__main__':
    main()
