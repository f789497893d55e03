"""End-to-end demo: run a whole robot as separate ROS 2 processes, then summarise.

``make demo`` (or ``.venv/bin/python -m softsnap_gaits.demo --scene snake --seconds 20``,
or ``ros2 run softsnap_gaits demo``) starts the graph of :func:`softsnap_gaits.graph.robot_graph`:
one simulated module per module, one ``driver_container`` driving every module (or, with
``--drivers separate``, one ``driver_node`` per module), the model node, the gait node and
the rerun logger, each its own OS process talking over ROS 2. It runs the scene's gait for a
fixed time, stops every process (also on Ctrl-C or when a node crashes; no orphans:
each child runs in its own process group, which is signalled and reaped), and prints a
summary: commands sent by the gait node and received by each driver by their own
counters (so "lost" is the true difference, and what this process's observer missed is
shown apart), shapes predicted, tracking error between the commanded and the predicted
shape, solver time, and the paths of the ``.rrd`` recording and of the ROS 2 bag (a
rosbag2 directory with the robot's topics, every topic with ``--bag-all``;
:mod:`softsnap_gaits.bag`; ``bag play`` replays it).

Each demo claims a private slot (:mod:`softsnap_gaits.isolation`): a ROS domain id no
other demo or test on this machine uses (unless ``ROS_DOMAIN_ID`` is set) and free
loopback ports for its simulated modules, so several demos can run at once. A robot that
does not start (a process exits, a module never comes online) is reported with the
failing process's log and exit code 1, never with a table of zeros; what the observer
did not see of a module is shown as ``-`` (``null`` in JSON).

With ``--physics`` the robot runs on ``sim_robot`` (the whole robot in MuJoCo, serving
every module's firmware protocol) instead of one ``sim_module`` per module; the gripper
gets a 10 g ball of 45 mm radius between its fingers and the ring a puck to cage (:data:`PHYSICS_PAYLOADS`).
The summary then adds, from ``sim/base_pose``, ``sim/payload_pose`` and
``model/shape/simulated``: the distance the robot travelled per gait cycle, where the
payload went (the gripper: whether it held it through the first grasp), the simulated
versus predicted shape error per module (root mean square over the 12 rib centres, mm,
against ``solve_forward`` at each snapshot's own cable length; also with the winch at
rest) and sim_robot's real-time factor; the recording shows the simulated shapes beside the
commanded and predicted ones, with the robot moving in the world. Every node then runs on
sim_robot's ``/clock`` (``use_sim_time``, :func:`softsnap_gaits.graph.robot_graph`), and
so does the observer: ``--seconds`` counts simulated seconds, and every rate, stamp and
distance per gait cycle of the summary is in simulated time, whatever the real-time
factor (the wall time the run took is shown beside it).

The runner observes the robot with its own rclpy node; it holds no science itself (tip
positions come from :func:`softsnap_model.geometry.rib_centers`, predicted shapes for
simulated ones from :func:`softsnap_model.forward.solve_forward`).

``--camera`` (with ``--physics``) adds sim_robot's camera and the marker tracker, and the
summary's ``camera`` entry (:mod:`softsnap_gaits.demo_camera`).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from softsnap_ros.lifeline import Lifeline
from softsnap_ros.processes import ChildProcess
from softsnap_model.geometry import rib_centers
from softsnap_model.scene import SceneError, load_scene

from .demo_camera import CameraObserver, print_camera, with_camera
from .graph import DRIVER_MODES, SIM_MODULE_MODES, NodeSpec, robot_graph
from .isolation import Slot, claim_slot
from .supervision import shutdown_problems, stop_in_order

STOP_TIMEOUT_S = 10.0  # per process, after SIGINT, before SIGKILL
#: --physics: the run ends early (and says so) if the simulated time stood still this long
#: in wall seconds (sim_robot stalled or its /clock lost).
CLOCK_STALL_S = 30.0
#: Robots larger than this get one shared sim_module process by default: the paper's
#: robots keep one process per module (as one ESP32 each), while 30 or more processes
#: outrun localhost-only discovery (docs/scaling.md).
SHARED_SIMS_ABOVE = 10
READY_TIMEOUT_S = 60.0  # the whole graph up: discovery + first predicted shapes
#: After the run (gait node stopped): the observer takes what is still queued for it, at
#: most this long; it stops as soon as it has everything stamped in the run (a 4 s run:
#: 7-26 s with two demos at once on 2 cores kept busy, load average 20-24).
DRAIN_TIMEOUT_S = 60.0
DRAIN_IDLE_S = 2.0  # ... or once no command or gait phase arrived for this long
#: Queue depth of the observer's command, measured-length, driver-state and gait-phase
#: subscriptions: 20 s of 50 Hz commands, so an observer that falls behind on a loaded
#: machine catches up afterwards instead of having its queue overwritten (which DDS does
#: not report as lost; the command counts need the states and phases of the whole run).
STREAM_DEPTH = 1000
#: Two commanded lengths closer than this (m) are the same length: the gait is holding.
#: Holds are exact (the gait library computes a held value from the same numbers), so
#: the tolerance only guards against float noise; a cosine ease moves far more per tick.
SETTLED_HOLD_TOL_M = 1e-9
#: sim_robot parameters per scene with --physics (radii in m). The gripper holds a 10 g
#: ball of 45 mm radius: its closed fingers cage balls of 40-50 mm radius and hold up to
#: 20 g at 45 mm with the estimated bending stiffness; a 20 g ball of 20 mm radius (the
#: issue's question) falls between the fingertips (docs/sim_robot.md). The ring cages a
#: 20 g puck standing on the ground, 85 mm radius and 30 mm tall: lying flat, 9 mm tall,
#: its ribs reach the wall of a puck where they reach a ball only at its bottom (a 40 mm
#: ball is never touched), and 85 mm is inside what the gripping pair's 60 mm contraction
#: closes on (docs/sim_robot.md, benchmarks/ring_transport.py).
PHYSICS_PAYLOADS = {
    'gripper': {'payload': 'ball', 'payload_mass_kg': 0.01, 'payload_size_m': 0.045},
    'ring': {'payload': 'cylinder', 'payload_mass_kg': 0.02, 'payload_size_m': 0.085,
             'payload_height_m': 0.03},
}
#: The gripper holds its payload through a grasp if the payload sinks less than this
#: (mm) between the start and the end of the hold and stays clear of the ground.
PAYLOAD_HOLD_TOL_MM = 10.0
#: sim_robot's snapshot rate (Hz of simulated time; its default, which the demo keeps).
SNAPSHOT_RATE_HZ = 30.0
#: A simulated shape counts as settled when its winch's cable length has not changed for
#: this many snapshots before it (0.5 s of simulated time): the shape error then holds
#: no lag behind a moving winch (docs/sim_robot.md, "What the physics shows").
SETTLED_SNAPSHOTS = 15


@dataclasses.dataclass
class ModuleStats:
    """What the observer saw of one module (counts; errors in mm; times in s, stamps in ns).

    Commands and measured lengths are kept by header stamp (the publisher's clock), so
    what the summary reports about them is what the gait node and the driver published
    during the run, not when this process got round to taking the messages.
    """

    command_stamps_ns: list = dataclasses.field(default_factory=list)
    lost: int = 0
    last_command_arrival_s: float = math.nan
    measured_stamps_ns: list = dataclasses.field(default_factory=list)
    commanded_shapes: int = 0
    predicted_shapes: int = 0
    # Running tip error: (index into predicted_tips, index into commanded_tips) of each
    # predicted shape and the commanded shape in force when it came; the distances are
    # computed after the run (running_tip_errors_mm), keeping the callbacks cheap.
    tip_error_pairs: list = dataclasses.field(default_factory=list)
    solve_times_s: list = dataclasses.field(default_factory=list)
    command_to_shape_ms: list = dataclasses.field(default_factory=list)
    measured_to_shape_ms: list = dataclasses.field(default_factory=list)
    last_commanded_angles: np.ndarray | None = None
    state: object = None
    # For the settled tip error: commanded lengths (m, parallel to command_stamps_ns),
    # and (stamp ns, cable length m, angles rad) of every commanded / predicted shape.
    command_lengths_m: list = dataclasses.field(default_factory=list)
    commanded_tips: list = dataclasses.field(default_factory=list)
    predicted_tips: list = dataclasses.field(default_factory=list)
    # The driver's own counts, from every state message: (state stamp ns, commands
    # received, stamp ns of the latest command received); see commands_counted.
    driver_counts: list = dataclasses.field(default_factory=list)
    # --physics: (simulated rib centres (12, 3) m, the winch's cable length m at that
    # snapshot) of every simulated shape; errors computed after the run against the shape
    # predicted for that same length (simulated_shape_errors_mm).
    simulated_shapes: list = dataclasses.field(default_factory=list)


class Process(ChildProcess):
    """A node of the demo in its own process group, its output in ``<log_dir>/<name>.log``."""

    def __init__(self, spec: NodeSpec, log_dir: Path, env: dict[str, str], pass_fds=()):
        from ament_index_python.packages import get_package_prefix
        self.spec = spec
        exe = Path(get_package_prefix(spec.package)) / 'lib' / spec.package / spec.executable
        # pass_fds: the slot's lock (isolation.py) stays held while any child lives.
        # A driver_container's drivers get their parameters from a file beside the log.
        ros_args = spec.ros_args(spec.write_node_params(log_dir))
        # Untagged: each node stops with its own lifeline and the ordered shutdown
        # (supervision.py); the demo's own runner is what tests tag.
        super().__init__([str(exe), *spec.arguments, *ros_args], log_dir / f'{spec.name}.log',
                         env, tagged=False, pass_fds=pass_fds)


def recorder_topics(scene, physics: bool) -> list[str]:
    """The topics (relative to the robot's namespace) whose messages must reach
    rerun_logger before the run starts: everything the recording shows."""
    topics = ['model/shape/commanded', 'model/shape/predicted']
    if physics:
        topics += ['model/shape/simulated', 'sim/base_pose']
    for m in scene.modules:
        topics += [f'{m.name}/cable_length/command', f'{m.name}/cable_length/measured',
                   f'{m.name}/state']
    return topics


def recorder_missing(observer: Observer, physics: bool) -> list[str]:
    """The topics of `recorder_topics` rerun_logger has taken nothing from yet, by its
    latest /diagnostics status (every topic until one arrives).

    Its subscriptions in the observer's ROS graph prove nothing about the publishers:
    on a loaded machine they discovered them up to 3 s later, and a CI run's 4 s
    recording had no commanded shape of a module.
    """
    namespace = observer.node.get_namespace().rstrip('/')
    taken = observer.recorder_taken
    return [t for t in recorder_topics(observer.scene, physics)
            if taken.get(f'{namespace}/{t}', 0) <= 0]


def stop_gait(processes: list[Process]) -> None:
    """SIGINT the gait node and wait until it exited (no more commands or phases).

    One that ignores SIGINT is left to the final shutdown (which kills it and says so).
    """
    for p in processes:
        if p.spec.name == 'gait_node':
            p.signal(signal.SIGINT)
            try:
                p.popen.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                pass


class Observer:
    """An rclpy node that counts and measures what flows through the robot's topics."""

    def __init__(self, scene, namespace: str, physics: bool = False, streams: str = 'modules'):
        """`streams`: 'modules' takes every module's command, measured-length and shape
        topics; 'robot' (large robots) takes the shapes from the two RobotShape topics
        (one message a tick for all modules, not one per module) and no command or
        measured-length streams: at 50 modules those were ~7,000 messages a second,
        more than this one Python process takes, and its backlog read as latency.
        Command counts still come from the nodes' own counters either way."""
        import rclpy
        from rclpy.parameter import Parameter
        from softsnap_ros.spinning import init_ros
        from softsnap_interfaces.msg import (CableLength, GaitPhase, ModelDiagnostics, ModuleShape,
                                             ModuleState)

        self.scene = scene
        self.sim_time = physics
        self.stats = {m.name: ModuleStats() for m in scene.modules}
        self.diagnostics = None
        # The gait node's own counts: tick stamp (ns) -> {module: commands sent up to and
        # including that tick} (GaitPhase is published after the tick's commands).
        self.gait_sent: dict[int, dict[str, int]] = {}
        self.last_phase_arrival_s: float | None = None  # time.monotonic() of the latest phase
        self.context = rclpy.Context()
        init_ros(context=self.context)
        # --physics: the observer's clock is sim_robot's /clock like every node's, so its
        # run window and the stamps it judges are on one time line.
        overrides = [Parameter('use_sim_time', Parameter.Type.BOOL, True)] if physics else []
        self.node = rclpy.create_node('demo_observer', namespace=namespace, context=self.context,
                                      parameter_overrides=overrides)
        from rclpy.executors import SingleThreadedExecutor
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spacing_mm = scene.skeleton.spacing_mm
        from rclpy.event_handler import SubscriptionEventCallbacks

        def subscribe(msg_type, topic, callback, s, depth=100):
            # DDS reports messages it lost on the way (message_lost event): "dropped".
            events = SubscriptionEventCallbacks(
                message_lost=lambda status, s=s: setattr(s, 'lost', s.lost + status.total_count_change))
            self.node.create_subscription(msg_type, topic, callback, depth, event_callbacks=events)

        self.streams = streams
        # 'robot' streams: (module, source) -> stamp (ns) of the last shape taken from a
        # RobotShape, so a module's unchanged shape in the next tick is not counted again.
        self._robot_stamps: dict[tuple[str, str], int] = {}
        if streams == 'robot':
            from softsnap_interfaces.msg import RobotShape
            for source, take in (('commanded', self._take_commanded),
                                 ('predicted', self._take_predicted)):
                self.node.create_subscription(
                    RobotShape, f'model/shape/{source}',
                    lambda data, info, source=source, take=take: self._robot_shape(
                        data, info, source, take),
                    STREAM_DEPTH, raw=True)
        for m in scene.modules:
            s = self.stats[m.name]
            if streams == 'robot':
                self.node.create_subscription(ModuleState, f'{m.name}/state',
                                              lambda msg, s=s: self._state(s, msg), STREAM_DEPTH)
                continue
            subscribe(CableLength, f'{m.name}/cable_length/command',
                      lambda msg, s=s: self._command(s, msg), s, STREAM_DEPTH)
            subscribe(CableLength, f'{m.name}/cable_length/measured',
                      lambda msg, s=s: s.measured_stamps_ns.append(_stamp_ns(msg)), s,
                      STREAM_DEPTH)
            subscribe(ModuleShape, f'{m.name}/shape/commanded',
                      lambda msg, info, s=s: self._commanded(s, msg, info), s)
            subscribe(ModuleShape, f'{m.name}/shape/predicted',
                      lambda msg, info, s=s: self._predicted(s, msg, info), s)
            self.node.create_subscription(ModuleState, f'{m.name}/state',
                                          lambda msg, s=s: self._state(s, msg), STREAM_DEPTH)
        self.node.create_subscription(ModelDiagnostics, 'model/diagnostics',
                                      lambda msg: setattr(self, 'diagnostics', msg), 10)
        self.node.create_subscription(GaitPhase, 'gait/phase', self._phase, STREAM_DEPTH)
        # rerun_logger's status: messages taken per topic (full name -> count).
        from diagnostic_msgs.msg import DiagnosticArray
        self.recorder_taken: dict[str, int] = {}
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._diagnostics, 50)
        # --physics: the world poses of the robot and its payload, (stamp ns, x, y, z) m,
        # and the gait's phases (stamp ns, cycle, phase); kept over the whole run.
        self.base_positions: list = []
        self.payload_positions: list = []
        self.phases: list = []
        if physics:
            from geometry_msgs.msg import PoseStamped
            from softsnap_interfaces.msg import RobotShape
            self.node.create_subscription(
                PoseStamped, 'sim/base_pose',
                lambda msg: self.base_positions.append(_pose_sample(msg)), STREAM_DEPTH)
            self.node.create_subscription(
                PoseStamped, 'sim/payload_pose',
                lambda msg: self.payload_positions.append(_pose_sample(msg)), STREAM_DEPTH)
            self.node.create_subscription(RobotShape, 'model/shape/simulated', self._simulated, 100)

    def _simulated(self, msg) -> None:
        for shape in msg.modules:
            s = self.stats.get(shape.module)
            if s is not None and len(shape.rib_centers):
                centres = np.array([(p.x, p.y, p.z) for p in shape.rib_centers])
                s.simulated_shapes.append((centres, float(shape.cable_length)))

    def _diagnostics(self, msg) -> None:
        name = f'softsnap/{self.scene.name}/rerun_logger'
        for status in msg.status:
            if status.name == name:
                self.recorder_taken = {kv.key: int(kv.value) for kv in status.values
                                       if kv.key.startswith('/') and kv.value.isdigit()}

    def _phase(self, msg) -> None:
        self.last_phase_arrival_s = time.monotonic()
        if msg.running:
            self.phases.append((_stamp_ns(msg), int(msg.cycle), float(msg.phase)))
        if len(msg.modules) == len(msg.commands_sent):
            self.gait_sent[_stamp_ns(msg)] = dict(zip(msg.modules, (int(n) for n in msg.commands_sent)))

    @staticmethod
    def _state(s: ModuleStats, msg) -> None:
        s.state = msg
        last = msg.last_command_stamp.sec * 1_000_000_000 + msg.last_command_stamp.nanosec
        s.driver_counts.append((_stamp_ns(msg), int(msg.commands_received), last))

    def _command(self, s: ModuleStats, msg) -> None:
        s.command_stamps_ns.append(_stamp_ns(msg))
        s.command_lengths_m.append(float(msg.cable_length))
        s.last_command_arrival_s = time.monotonic()

    def _tip_mm(self, angles) -> np.ndarray:
        return rib_centers(np.asarray(angles, dtype=float), self.spacing_mm)[-1]

    def _age_ms(self, stamp_ns: int, info=None) -> float:
        """Arrival time minus the stamp of the length the shape was solved from, ms.

        Arrival is when DDS received the shape for this process (its message info), so a
        backlog in this observer's own callbacks is not counted as the graph's latency;
        on simulated time (stamps on /clock, not the system clock) it is the callback's
        ROS time."""
        if info is not None and not self.sim_time:
            received = info.get('received_timestamp') or 0
            if received > 0:
                return (received - stamp_ns) / 1e6
        return (self.node.get_clock().now().nanoseconds - stamp_ns) / 1e6

    def _commanded(self, s: ModuleStats, msg, info=None) -> None:
        self._take_commanded(s, _stamp_ns(msg), msg.cable_length, msg.angles, msg.solve_time,
                             info)

    def _predicted(self, s: ModuleStats, msg, info=None) -> None:
        self._take_predicted(s, _stamp_ns(msg), msg.cable_length, msg.angles, msg.solve_time,
                             info)

    def _take_commanded(self, s: ModuleStats, stamp_ns: int, cable_length_m: float, angles,
                        solve_time_s: float, info=None) -> None:
        s.commanded_shapes += 1
        s.command_to_shape_ms.append(self._age_ms(stamp_ns, info))
        s.last_commanded_angles = np.asarray(angles, dtype=float)
        if len(angles):
            s.commanded_tips.append((stamp_ns, float(cable_length_m), s.last_commanded_angles))
        if solve_time_s > 0.0:
            s.solve_times_s.append(solve_time_s)

    def _take_predicted(self, s: ModuleStats, stamp_ns: int, cable_length_m: float, angles,
                        solve_time_s: float, info=None) -> None:
        s.predicted_shapes += 1
        s.measured_to_shape_ms.append(self._age_ms(stamp_ns, info))
        if solve_time_s > 0.0:
            s.solve_times_s.append(solve_time_s)
        if len(angles):
            s.predicted_tips.append((stamp_ns, float(cable_length_m),
                                     np.asarray(angles, dtype=float)))
            if s.commanded_tips:
                s.tip_error_pairs.append((len(s.predicted_tips) - 1, len(s.commanded_tips) - 1))

    def _robot_shape(self, data: bytes, info, source: str, take) -> None:
        """Every module shape of a raw RobotShape that is new since the last one taken
        (read from its bytes: rclpy's deserialisation of a 50-module shape took ~9 ms)."""
        from softsnap_ros.cdr import read_robot_shape
        robot = read_robot_shape(data)
        for shape in robot.modules:
            s = self.stats.get(shape.module)
            key = (shape.module, source)
            if s is None or self._robot_stamps.get(key) == shape.stamp_ns:
                continue
            self._robot_stamps[key] = shape.stamp_ns
            take(s, shape.stamp_ns, shape.cable_length, shape.angles, shape.solve_time, info)

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            # The same timeout every call: rclpy keeps its list of ready callbacks across
            # spin_once calls only while the arguments stay the same. A new timeout each
            # call made it wait again and run the first ready subscription every time (the
            # first module's), starving the other modules on a busy machine.
            self.executor.spin_once(timeout_sec=0.05)

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def drain(self, end_ns: int, keep_going=lambda: True) -> None:
        """Spin until every module's commands and driver states, and the gait's phases,
        stamped up to `end_ns` have been taken.

        Messages of one topic arrive in order, so a command stamped after `end_ns` means
        all earlier ones are in (likewise a phase, a state). On a starved machine the
        phases can lag the commands by seconds. Bounded: DRAIN_TIMEOUT_S in all, and it
        stops once no command or phase came for DRAIN_IDLE_S (the gait node stopped, or a
        gait played once stopped commanding, and the queues are empty), or once
        `keep_going()` is false (Ctrl-C).
        """
        start = time.monotonic()
        deadline = start + DRAIN_TIMEOUT_S
        while time.monotonic() < deadline and keep_going():
            stats = self.stats.values()
            if (all(s.command_stamps_ns and s.command_stamps_ns[-1] > end_ns
                    and s.driver_counts and s.driver_counts[-1][0] > end_ns for s in stats)
                    and (not self.phases or self.phases[-1][0] > end_ns)):
                return
            # Idle from the drain's start at the earliest: the seconds this process spent
            # not spinning before it (stopping the gait node) are no sign of empty queues.
            arrivals = [start] + [s.last_command_arrival_s for s in stats if s.command_stamps_ns]
            if self.last_phase_arrival_s is not None:
                arrivals.append(self.last_phase_arrival_s)
            if time.monotonic() - max(arrivals) > DRAIN_IDLE_S:
                return
            self.spin_for(0.05)

    def ready(self) -> bool:
        """Every module has both shapes: drivers, model node and gait node are all up.

        (Predicted shapes alone only prove the drivers and the model node; the gait node
        may start seconds later on a loaded machine.)
        """
        return all(s.predicted_shapes > 0 and s.commanded_shapes > 0 for s in self.stats.values())

    def missing(self) -> dict[str, list[str]]:
        """What the observer has not seen yet, per module (empty when ready)."""
        out = {}
        for name, s in self.stats.items():
            lacks = []
            if s.state is None:
                lacks.append('driver state')
            elif not s.state.online:
                lacks.append('module online')
            if not s.command_stamps_ns and not s.commanded_shapes:
                lacks.append('gait commands')
            if not s.commanded_shapes:
                lacks.append('commanded shapes')
            if not s.predicted_shapes:
                lacks.append('predicted shapes')
            if lacks:
                out[name] = lacks
        return out

    def reset(self) -> None:
        """Start counting afresh (after the start-up phase)."""
        # In place: the subscription callbacks hold these very objects.
        for stats in self.stats.values():
            kept = stats.last_commanded_angles, stats.state
            # The shapes in force when counting starts: a hold may end before the next solve
            # (the running error pairs start afresh with them).
            tips = stats.commanded_tips[-1:], stats.predicted_tips[-1:]
            stats.__init__()
            stats.last_commanded_angles, stats.state = kept
            stats.commanded_tips, stats.predicted_tips = (list(t) for t in tips)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _pose_sample(msg) -> tuple:
    p = msg.pose.position
    return (_stamp_ns(msg), p.x, p.y, p.z)


def simulated_shape_errors_mm(s: ModuleStats, skeleton, threading_mm) -> tuple[list, list]:
    """Simulated versus predicted shape, one value per simulated shape, mm: the root mean
    square over the rib centres of their distances (the paper's measure against its
    experiments), the predicted shape being ``solve_forward``'s for the cable length of
    that very snapshot, so what remains is gravity, contact and dynamics.

    (Pairing a snapshot with the latest predicted shape received instead compared shapes
    of different cable lengths while a winch moved: the measured length, its solve and
    the snapshot reach the demo at different times.)

    Returns the errors and, parallel to them, whether the snapshot's winch had been at
    rest (the same cable length) for ``SETTLED_SNAPSHOTS`` snapshots before it.
    """
    from softsnap_model.forward import solve_forward
    errors, settled = [], []
    cache: dict[float, np.ndarray] = {}
    run = 0
    previous = None
    for centres_m, length_m in s.simulated_shapes:
        run = run + 1 if length_m == previous else 0
        previous = length_m
        if length_m not in cache:
            try:
                planar = np.asarray(solve_forward(skeleton, threading_mm, length_m * 1000.0).rib_centers)
            except ValueError:   # a length the model refuses: no predicted shape to compare
                planar = np.empty((0, 2))
            cache[length_m] = np.column_stack((planar, np.zeros(len(planar))))
        predicted = cache[length_m]
        if len(predicted) != len(centres_m):
            continue
        distance = np.linalg.norm(centres_m * 1000.0 - predicted, axis=1)
        errors.append(float(np.sqrt(np.mean(distance ** 2))))
        settled.append(run >= SETTLED_SNAPSHOTS)
    return errors, settled


def travel(samples, window_ns) -> dict | None:
    """Straight-line travel in the ground plane between the first and last position
    sample stamped inside `window_ns`: distance (mm), heading (deg), over seconds."""
    inside = [x for x in samples if window_ns[0] <= x[0] <= window_ns[1]]
    if len(inside) < 2:
        return None
    (t0, x0, y0, _), (t1, x1, y1, _) = inside[0], inside[-1]
    dx, dy = (x1 - x0) * 1000.0, (y1 - y0) * 1000.0
    return {'distance_mm': float(math.hypot(dx, dy)),
            'heading_deg': float(math.degrees(math.atan2(dy, dx))),
            'seconds': (t1 - t0) * 1e-9}


def first_grasp_hold(scene, gait_name: str, phases, payload_samples) -> dict | None:
    """Did the gripper hold its payload through the first grasp? None if not observed.

    The hold of cycle 0 runs from phase ``close_s / period`` to ``(close_s + hold_s) /
    period`` of a ``grasp`` gait (its spec in the scene); the payload holds if it sank
    less than PAYLOAD_HOLD_TOL_MM over it and ends clear of the ground.
    """
    spec = scene.gaits.get(gait_name, {})
    if spec.get('type') != 'grasp' or not phases or not payload_samples:
        return None
    period = sum(float(spec.get(k, 0.0)) for k in ('close_s', 'hold_s', 'open_s', 'rest_s'))
    start_phase = float(spec['close_s']) / period
    end_phase = (float(spec['close_s']) + float(spec['hold_s'])) / period
    hold = [t for t, cycle, phase in phases if cycle == 0 and start_phase <= phase <= end_phase]
    if len(hold) < 2:
        return None
    stamps = [x[0] for x in payload_samples]

    def z_at(t):
        i = int(np.searchsorted(stamps, t, side='right')) - 1
        return payload_samples[i][3] if i >= 0 else None

    z0, z1 = z_at(hold[0]), z_at(hold[-1])
    if z0 is None or z1 is None:
        return None
    size_m = PHYSICS_PAYLOADS.get(scene.name, {}).get('payload_size_m', 0.0)
    drop_mm = (z0 - z1) * 1000.0
    clear_mm = (z1 - size_m) * 1000.0
    return {'held': bool(drop_mm < PAYLOAD_HOLD_TOL_MM and clear_mm > PAYLOAD_HOLD_TOL_MM),
            'drop_mm': float(drop_mm), 'height_mm': float(z1 * 1000.0)}


def physics_summary(scene, gait_name: str, observer: Observer, window_ns, sim_log: str) -> dict:
    """The --physics part of the summary (distances in mm, per gait cycle).

    Stamps and `window_ns` are simulated time (every node runs on sim_robot's /clock), so
    a cycle is the gait's period of simulated time, whatever the real-time factor;
    ``gait_cycles`` counts the cycles the gait node reported playing in the window.
    """
    from .gaits import make_gait
    period = make_gait(gait_name, scene).period_s
    base = travel(observer.base_positions, window_ns)
    payload = travel(observer.payload_positions, window_ns)
    per_cycle = (lambda t: None if t is None or t['seconds'] <= 0
                 else t['distance_mm'] * period / t['seconds'])
    shape_error = {}
    for name, s in observer.stats.items():
        module = scene.module(name)
        errors, settled = simulated_shape_errors_mm(s, scene.skeleton, module.threading_mm)
        at_rest = [e for e, ok in zip(errors, settled) if ok]
        shape_error[name] = ({'mean': float(np.mean(errors)), 'max': float(np.max(errors)),
                              'n': len(errors),
                              'settled_mean': float(np.mean(at_rest)) if at_rest else None,
                              'settled_n': len(at_rest)} if errors else None)
    factor = None
    for line in sim_log.splitlines():
        if 'real-time factor' in line:
            try:
                factor = float(line.split('real-time factor')[1].split()[0])
            except (IndexError, ValueError):
                pass
    # Gait cycles played inside the window, by the gait's own phase (simulated time).
    played = [(t, c + ph) for t, c, ph in observer.phases if window_ns[0] <= t <= window_ns[1]]
    cycles = float(played[-1][1] - played[0][1]) if len(played) > 1 else None
    # The simulated seconds those cycles took (a gait node started late on a loaded
    # machine plays fewer cycles in the window, but each still takes its period).
    gait_seconds = (played[-1][0] - played[0][0]) * 1e-9 if len(played) > 1 else None
    return {'gait': gait_name, 'gait_period_s': period, 'gait_cycles': cycles,
            'gait_seconds': gait_seconds,
            'base_travel': base, 'base_mm_per_cycle': per_cycle(base),
            'payload_travel': payload, 'payload_mm_per_cycle': per_cycle(payload),
            'payload_first_grasp': first_grasp_hold(scene, gait_name, observer.phases,
                                                    observer.payload_positions),
            'shape_error_mm': shape_error, 'real_time_factor': factor,
            'gait_phases_observed': len(observer.phases)}


def print_physics(p: dict) -> None:
    print(f"physics (sim_robot, MuJoCo; real-time factor while stepping: "
          f"{_cell(p['real_time_factor'], '.2f')}), gait {p['gait']} ({p['gait_period_s']:g} s cycle):")
    base = p['base_travel']
    if base is None:
        print('  robot travel: not observed')
    else:
        print(f"  robot travelled {base['distance_mm']:.1f} mm (heading {base['heading_deg']:.0f} deg) "
              f"in {base['seconds']:.1f} s of simulated time: {p['base_mm_per_cycle']:.1f} mm "
              'per gait cycle')
    grasp = p['payload_first_grasp']
    if p['payload_travel'] is not None:
        pay = p['payload_travel']
        if grasp is not None:
            # A grasp is not locomotion: say what the number is (where the payload ended,
            # seen from above, against where it started), not a travel per cycle.
            print(f"  payload {pay['distance_mm']:.1f} mm from where it started, in the ground "
                  f"plane, after {pay['seconds']:.1f} s (first to last sample of the run)")
        else:
            print(f"  payload travelled {pay['distance_mm']:.1f} mm: "
                  f"{p['payload_mm_per_cycle']:.1f} mm per cycle")
    if grasp is not None:
        print(f"  payload {'HELD' if grasp['held'] else 'NOT held'} through the first grasp "
              f"(sank {grasp['drop_mm']:.1f} mm during the hold, centre {grasp['height_mm']:.0f} mm "
              'above the ground at its end)')
    cells = ', '.join(f"{name} {e['mean']:.1f}/{e['max']:.1f} ({_cell(e['settled_mean'], '.1f')})"
                      if e else f'{name} -' for name, e in p['shape_error_mm'].items())
    print('  simulated vs predicted shape at the same cable length, rib-centre RMS mean/max mm '
          f'(mean with the winch at rest >= {SETTLED_SNAPSHOTS / SNAPSHOT_RATE_HZ:g} s): {cells}')


def _in_window(stamps_ns, window_ns) -> list:
    return sorted(t for t in stamps_ns if window_ns[0] <= t <= window_ns[1])


def running_tip_errors_mm(s: ModuleStats, tip_mm=lambda x: x) -> list:
    """Tip error at every predicted shape, mm: its tip against the tip of the commanded
    shape that was the latest when it arrived. `tip_mm` maps a stored shape (angles) to
    its tip point."""
    c_tips, p_tips = {}, {}
    errors = []
    for p, c in s.tip_error_pairs:
        if c not in c_tips:
            c_tips[c] = tip_mm(s.commanded_tips[c][2])
        if p not in p_tips:
            p_tips[p] = tip_mm(s.predicted_tips[p][2])
        errors.append(float(np.linalg.norm(p_tips[p] - c_tips[c])))
    return errors


def settled_tip_errors_mm(s: ModuleStats, window_ns, tip_mm=lambda x: x) -> list:
    """Tip error at the end of every step the gait held, mm (the "settled" error).

    A step ends at the last command of a hold: a command equal (within
    `SETTLED_HOLD_TOL_M`) to the one before it, followed by one that differs, i.e. the
    last commanded sample before the commanded contraction changes again; only ends
    stamped inside `window_ns` count. There, the error is the distance between the tip
    of the commanded shape (the latest commanded shape stamped at or before that command,
    solved for the held length) and the tip of the predicted shape (the latest predicted
    shape whose measured length was stamped at or before it). The winch has had the whole
    hold to get there, so this measures the model and the motor at rest, not the lag.
    `tip_mm` maps a stored shape (the observer stores angles) to its tip point.
    """
    if len(s.command_stamps_ns) < 3:
        return []
    order = np.argsort(s.command_stamps_ns, kind='stable')
    t = np.asarray(s.command_stamps_ns, dtype=np.int64)[order]
    length = np.asarray(s.command_lengths_m, dtype=float)[order]
    held = np.abs(np.diff(length)) <= SETTLED_HOLD_TOL_M        # held[i]: i -> i + 1 equal
    ends = np.nonzero(held[:-1] & ~held[1:])[0] + 1             # held into i, changes after
    commanded = sorted(s.commanded_tips, key=lambda e: e[0])
    predicted = sorted(s.predicted_tips, key=lambda e: e[0])
    c_stamps = [e[0] for e in commanded]
    p_stamps = [e[0] for e in predicted]
    errors = []
    for i in ends:
        if not window_ns[0] <= t[i] <= window_ns[1]:
            continue
        c = np.searchsorted(c_stamps, t[i], side='right') - 1
        p = np.searchsorted(p_stamps, t[i], side='right') - 1
        if c < 0 or p < 0 or abs(commanded[c][1] - length[i]) > SETTLED_HOLD_TOL_M:
            continue   # no shape solved for this hold (model node starved): no sample
        errors.append(float(np.linalg.norm(tip_mm(commanded[c][2]) - tip_mm(predicted[p][2]))))
    return errors


@dataclasses.dataclass(frozen=True)
class CommandCounts:
    """Commands of one module over one stretch of tick stamps, by each party's own count.

    The stretch runs from the latest command a driver state reported early in the run
    (exclusive) to the latest one it reported by the end (inclusive): over it the gait
    node's counts (GaitPhase of those ticks) and the driver's (ModuleState) are exact, so
    `lost` is what left the gait node and never reached the driver.
    """

    sent: int            # published by the gait node (count)
    received: int        # taken by the driver (count)
    observed: int        # taken by the demo's observer (count)
    from_ns: int         # stamps (ns of ROS time) of the stretch: (from_ns, to_ns]
    to_ns: int

    @property
    def lost(self) -> int:
        return self.sent - self.received

    @property
    def observer_shortfall(self) -> int:
        """What the observer missed: its own problem (starved by load), not a lost command."""
        return self.sent - self.observed


def commands_counted(name: str, s: ModuleStats, gait_sent: dict[int, dict[str, int]],
                     window_ns: tuple[int, int]) -> CommandCounts | None:
    """The gait node's, the driver's and the observer's counts of `name`'s commands.

    A driver state says "commands_received, the latest stamped T"; the gait node's
    GaitPhase stamped T says how many it had sent up to and including T. Two such pairs,
    the first and last whose T lies in `window_ns`, bound the stretch. None when there is
    no such pair (driver states or gait phases not observed).
    """
    usable = [(received, last) for _, received, last in s.driver_counts
              if window_ns[0] <= last <= window_ns[1] and name in gait_sent.get(last, {})]
    if len(usable) < 2:
        return None
    (r0, t0), (r1, t1) = usable[0], max(usable, key=lambda u: (u[1], u[0]))
    if t1 <= t0:
        return None
    observed = sum(1 for t in s.command_stamps_ns if t0 < t <= t1)
    return CommandCounts(sent=gait_sent[t1][name] - gait_sent[t0][name], received=r1 - r0,
                         observed=observed, from_ns=t0, to_ns=t1)


def _percentiles(values) -> dict:
    if not values:
        return {'median': math.nan, 'p99': math.nan, 'n': 0}
    v = np.asarray(values)
    return {'median': float(np.median(v)), 'p99': float(np.percentile(v, 99)), 'n': int(v.size)}


def summarise(scene, observer: Observer, seconds: float, recording: Path | None,
              exit_codes: dict[str, int | None], window_ns: tuple[int, int] = (0, 2**63)) -> dict:
    """The demo's summary as a plain dict (printed as a table, or JSON with --json).

    Commands and measured lengths count the messages stamped inside `window_ns` (the
    run, in ns of ROS time); the command rate is taken from their stamps.
    """
    modules = {}
    for name, s in observer.stats.items():
        commands = _in_window(s.command_stamps_ns, window_ns)
        span = (commands[-1] - commands[0]) * 1e-9 if len(commands) > 1 else 0.0
        running = running_tip_errors_mm(s, observer._tip_mm)
        errors = np.asarray(running) if running else None
        settled = settled_tip_errors_mm(s, window_ns, observer._tip_mm)
        state = s.state
        counted = commands_counted(name, s, observer.gait_sent, window_ns)
        measured = _in_window(s.measured_stamps_ns, window_ns)
        # What the observer never saw is None ("not observed"), never a 0 or NaN that
        # would read as a measurement.
        # (With 'robot' streams the observer takes no command or measured-length stream.)
        streams = [] if getattr(observer, 'streams', 'modules') == 'robot' else [
            ('gait commands', s.command_stamps_ns), ('measured lengths', s.measured_stamps_ns)]
        unobserved = [what for what, seen in (
            *streams,
            ('commanded shapes', s.commanded_shapes), ('predicted shapes', s.predicted_shapes),
            ('driver state', state is not None),
            ('command counters', counted is not None)) if not seen]
        modules[name] = {
            # The nodes' own counts over the same stretch of commands (CommandCounts).
            'commands_sent': counted.sent if counted else None,
            'driver_received': counted.received if counted else None,
            'commands_lost': counted.lost if counted else None,
            'observer_commands': counted.observed if counted else None,
            'observer_shortfall': counted.observer_shortfall if counted else None,
            'counted_seconds': (counted.to_ns - counted.from_ns) * 1e-9 if counted else None,
            # The driver's counts since it started (its latest state).
            'driver_refused': int(state.commands_refused) if state is not None else None,
            'driver_targets_sent': int(state.targets_sent) if state is not None else None,
            # What the observer took inside the run window, and its rate from the stamps.
            'commands_observed': len(commands) if s.command_stamps_ns else None,
            'command_rate_hz': ((len(commands) - 1) / span if span > 0 else 0.0)
                               if s.command_stamps_ns else None,
            'observer_dds_lost': s.lost,
            'measured_lengths': len(measured) if s.measured_stamps_ns else None,
            'commanded_shapes': s.commanded_shapes or None,
            'predicted_shapes': s.predicted_shapes or None,
            'tip_error_mm_mean': float(np.mean(errors)) if errors is not None else None,
            'tip_error_mm_max': float(np.max(errors)) if errors is not None else None,
            'settled_tip_error_mm_mean': float(np.mean(settled)) if settled else None,
            'settled_tip_error_mm_max': float(np.max(settled)) if settled else None,
            'settled_samples': len(settled),
            'solve_time_us_mean': float(np.mean(s.solve_times_s) * 1e6) if s.solve_times_s else None,
            'command_to_shape_ms': _percentiles(s.command_to_shape_ms),
            'measured_to_shape_ms': _percentiles(s.measured_to_shape_ms),
            'online': bool(state.online) if state is not None else None,
            'battery_v': float(state.battery_voltage) if state is not None else None,
            'request_failures': int(state.request_failures) if state is not None else None,
            'not_observed': unobserved,
        }
    diag = observer.diagnostics
    return {
        'scene': scene.name, 'seconds': seconds, 'modules': modules,
        'observer_streams': getattr(observer, 'streams', 'modules'),
        'model': None if diag is None else {
            'solves': diag.solves, 'skipped_unchanged': diag.skipped_unchanged,
            'skipped_duplicate': diag.skipped_duplicate, 'refused': diag.refused,
            # Length messages the model node took per module since it started (counts).
            'lengths_taken': {m: {'commanded': int(c), 'measured': int(r)} for m, c, r in zip(
                diag.modules, diag.commanded_lengths, diag.measured_lengths)}},
        'recording': None if recording is None else str(recording),
        'recording_bytes': recording.stat().st_size if recording and recording.exists() else 0,
        'exit_codes': exit_codes,
    }


def _cell(value, spec: str) -> str:
    """`value` formatted with `spec`, or '-' (right-aligned to its width) when None."""
    if value is None:
        width = int(''.join(c for c in spec.split('.')[0] if c.isdigit()) or 1)
        return '-'.rjust(width) if not spec.startswith('<') else '-'.ljust(width)
    return format(str(value) if spec.endswith('s') else value, spec)


def print_summary(summary: dict) -> None:
    clock = (f" of simulated time ({summary['wall_seconds']:g} s of wall time)"
             if summary.get('sim_time') else '')
    print(f"\nSoftSnap demo: {summary['scene']}, {summary['seconds']:g} s of gait{clock} "
          "(tip error: commanded shape versus the shape predicted from the measured length, "
          "all the time (running) and at the end of each step (settled: last command before "
          "the commanded contraction changes, n steps); "
          "commands by each node's own count: sent by the gait node, rcvd by the driver, "
          "lost = sent - rcvd; seen by this demo's observer, short = sent - seen (the "
          "observer's own shortfall under load, not a lost command))")
    header = (f"{'module':10s} {'sent':>5s} {'rcvd':>5s} {'lost':>4s} {'seen':>5s} {'short':>5s} {'Hz':>5s} "
              f"{'measured':>8s} {'shapes c/p':>11s} "
              f"{'tip err mean/max mm':>20s} {'settled mean/max mm (n)':>24s} {'solve µs':>9s} {'online':>6s} {'batt V':>6s}")
    print(header)
    print('-' * len(header))
    for name, m in summary['modules'].items():
        print(f"{name:10s} {_cell(m['commands_sent'], '5d')} {_cell(m['driver_received'], '5d')} "
              f"{_cell(m['commands_lost'], '4d')} {_cell(m['observer_commands'], '5d')} "
              f"{_cell(m['observer_shortfall'], '5d')} {_cell(m['command_rate_hz'], '5.1f')} "
              f"{_cell(m['measured_lengths'], '8d')} "
              f"{_cell(m['commanded_shapes'], '5d')}/{_cell(m['predicted_shapes'], '<5d')} "
              f"{_cell(m['tip_error_mm_mean'], '9.2f')}/{_cell(m['tip_error_mm_max'], '<9.2f')} "
              f"{_cell(m['settled_tip_error_mm_mean'], '9.2f')}/{_cell(m['settled_tip_error_mm_max'], '<7.2f')}"
              f"({m['settled_samples']:3d}) "
              f"{_cell(m['solve_time_us_mean'], '10.0f')} {_cell(m['online'], '>6s')} "
              f"{_cell(m['battery_v'], '6.2f')}")
    for name, m in summary['modules'].items():
        if m.get('not_observed'):
            print(f"{name}: not observed (shown as -): {', '.join(m['not_observed'])}")
    lost = {name: m['commands_lost'] for name, m in summary['modules'].items() if m['commands_lost']}
    if lost:
        print(f'WARNING: commands lost between the gait node and the drivers: {lost}')
    dds_lost = {name: m['observer_dds_lost'] for name, m in summary['modules'].items()
                if m['observer_dds_lost']}
    if dds_lost:
        print(f'observer: DDS reported messages lost to the observer: {dds_lost}')
    if summary['model']:
        d = summary['model']
        print(f"model node: {d['solves']} solves, {d['skipped_unchanged']} unchanged lengths and "
              f"{d['skipped_duplicate']} duplicate modules skipped, {d['refused']} refused")
        if d.get('lengths_taken'):
            taken = ', '.join(f"{name} {n['commanded']}/{n['measured']}"
                              for name, n in d['lengths_taken'].items())
            print(f'model node took commanded/measured lengths (since its start): {taken}')
    latency = [m['command_to_shape_ms']['median'] for m in summary['modules'].values()
               if m['command_to_shape_ms']['n']]
    if summary.get('physics'):
        # Stamps and the observer's clock are both sim_robot's /clock, which advances in
        # steps: the difference is 0 within a step, not a latency.
        print('gait command -> commanded shape: not measured on simulated time')
    elif latency:
        print(f"gait command -> commanded shape: median {np.median(latency):.2f} ms over modules")
    if summary.get('processes'):
        usage = ', '.join(f"{name} {u['cpu_percent']:.0f}%" for name, u in summary['processes'].items()
                          if not name.startswith('sim_'))
        print(f'CPU (% of one core): {usage}')
    if summary.get('physics'):
        print_physics(summary['physics'])
    problems = summary.get('shutdown_problems')
    if problems is None:   # a summary without the shutdown's account: judge by exit codes
        problems = shutdown_problems(summary['exit_codes'])
    print('processes: all stopped cleanly (in order: gait, drivers, then simulators, model '
          'and recorders)' if not problems else
          'processes with errors: ' + '; '.join(f'{k}: {v}' for k, v in problems.items()))
    if summary['recording']:
        print(f"recording: {summary['recording']} ({summary['recording_bytes'] / 1024:.0f} KiB); "
              f"open it with: .venv/bin/rerun {summary['recording']}")
    if summary.get('bag'):
        print(f"bag: {summary['bag']} ({summary['bag_messages']} messages on "
              f"{len(summary['bag_topics'])} topics, {summary['bag_bytes'] / 1024:.0f} KiB); "
              f"replay it with: .venv/lib/softsnap_gaits/bag play {summary['bag']}")
    elif summary.get('bag_error'):
        print(f"bag: {summary['bag_error']}")


def shared_sim_modules(mode: str, n_modules: int) -> str:
    """``--sim-modules`` resolved: 'auto' shares one process above SHARED_SIMS_ABOVE modules."""
    if mode != 'auto':
        return mode
    return 'shared' if n_modules > SHARED_SIMS_ABOVE else 'separate'


def run(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene)
    # A private slot: ROS domain id and loopback ports no other demo or test here uses.
    slot, warning = claim_slot()
    if warning:
        print(f'demo: warning: {warning}', file=sys.stderr)
    try:
        return _run(args, scene, slot)
    finally:
        slot.release()  # children that still live keep the lock (pass_fds)


def _run(args: argparse.Namespace, scene, slot: Slot) -> int:
    stamp = dt.datetime.now(dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')
    run_dir = Path(args.run_dir or Path('runs') / f'{scene.name}-{stamp}')
    run_dir.mkdir(parents=True, exist_ok=True)
    recording = None if args.no_rerun else (Path(args.output) if args.output
                                            else run_dir / f'{scene.name}.rrd').resolve()
    bag = None if args.no_bag else (Path(args.bag) if args.bag else _free_name(run_dir / 'bag')).resolve()
    # Simulated modules get free ports of the slot (their drivers the same ones); real
    # modules, and --scene-ports, keep the scene's addresses.
    sim_ports = None
    sim_modules = shared_sim_modules(args.sim_modules, len(scene.modules))
    if not args.real and not args.scene_ports:
        if args.physics or sim_modules == 'shared':   # one process serves consecutive ports
            first = slot.free_port(len(scene.modules))
            sim_ports = {m.name: first + i for i, m in enumerate(scene.modules)}
        else:
            sim_ports = {m.name: slot.free_port() for m in scene.modules}
    sim_robot_parameters = dict(PHYSICS_PAYLOADS.get(scene.name, {}),
                                time_factor=float(args.time_factor))
    specs = robot_graph(scene, simulate=not args.real, gait=args.gait,
                        gait_rate_hz=args.gait_rate, model_rate_hz=args.model_rate,
                        recording=recording, rerun=not args.no_rerun, sim_ports=sim_ports,
                        bag=bag, bag_all=args.bag_all, physics=args.physics,
                        sim_robot_parameters=sim_robot_parameters, drivers=args.drivers,
                        sim_modules=sim_modules)
    if args.camera:
        specs = with_camera(specs, scene)
    # The observer in this process and every child use the slot's domain.
    os.environ['ROS_DOMAIN_ID'] = str(slot.domain_id)
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    env.setdefault('ROS_HOME', str(run_dir / 'ros_home'))
    if not args.real:  # a simulated robot needs no traffic beyond this machine
        env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    stop_requested = []

    def request_stop(signum, _frame):
        stop_requested.append(signum)

    # SIGHUP (a closed terminal) like SIGTERM; if this process dies, the children see
    # their lifeline end and stop too (softsnap_ros.lifeline).
    old_handlers = {sig: signal.signal(sig, request_stop)
                    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    lifeline = Lifeline()
    env = lifeline.env(env)
    processes: list[Process] = []
    observer = camera = None
    elapsed, usage_start, usage_end = 0.0, {}, {}
    window_ns = (0, 2**63)  # ROS time of the run: set below
    startup_s = None
    crashed: list[Process] = []
    not_ready: dict[str, list[str]] = {}
    started = False
    clock_stalled = False
    try:
        ports = (', '.join(f'{p.parameters["port"]}' for p in specs if p.executable == 'sim_module')
                 or ', '.join(f'{p.parameters["port_base"] or "the scene ports"} and up (sim_robot)'
                              for p in specs if p.executable == 'sim_robot')
                 or 'the scene\'s addresses')
        print(f'starting {len(specs)} processes for {scene.name} ({len(scene.modules)} modules; '
              f'ROS domain {slot.domain_id}; modules on {ports}; logs in {run_dir})', flush=True)
        observer = Observer(scene, f'/{scene.name}', physics=args.physics,
                            streams='robot' if len(scene.modules) > SHARED_SIMS_ABOVE
                            else 'modules')
        camera = CameraObserver(observer.node, scene) if args.camera else None
        launched_at = time.monotonic()
        for spec in specs:
            processes.append(Process(spec, run_dir, env,
                                     pass_fds=(slot.lock_fd, *lifeline.pass_fds)))
            if spec.executable == 'sim_robot':
                # The robot first: the gait starts once the simulation runs, so its first
                # cycle (the gripper's first grasp) happens in the physics.
                deadline = time.monotonic() + args.ready_timeout
                while (not observer.base_positions and processes[-1].popen.poll() is None
                       and not stop_requested and time.monotonic() < deadline):
                    observer.spin_for(0.1)

        def check_children() -> bool:
            for p in processes:
                if p.popen.poll() is not None and p not in crashed:
                    crashed.append(p)
            return not crashed and not stop_requested

        def ready() -> bool:
            # The recorder too: on a loaded machine rerun_logger came up seconds after the
            # nodes it records, or took their messages seconds after it had subscribed,
            # and a short run's recording lacked shapes.
            return (observer.ready() and (camera is None or camera.ready())
                    and (args.no_rerun or not recorder_missing(observer, args.physics)))

        deadline = time.monotonic() + args.ready_timeout
        while check_children() and not ready() and time.monotonic() < deadline:
            observer.spin_for(0.1)
        if check_children() and not observer.ready():
            not_ready = observer.missing()
        elif check_children() and camera is not None and not camera.ready():
            not_ready = {'camera': camera.missing()}
        elif check_children() and not ready():
            not_ready = {'rerun_logger': ['nothing taken from ' + ', '.join(
                recorder_missing(observer, args.physics))]}
        # Started: every process alive and every module seen end to end. Otherwise stop
        # here and say what failed; a table of a robot that never ran would be zeros.
        started = check_children() and not not_ready
        startup_s = time.monotonic() - launched_at
        if started:
            observer.reset()
            start = time.monotonic()
            window_start_ns = observer.now_ns()
            usage_start = {p.spec.name: p.usage() for p in processes}
            if args.physics:
                # Simulated seconds: the gait runs on /clock, so does the run.
                clock_stalled = run_for_sim_time(observer, args.seconds, check_children)
            else:
                while check_children() and time.monotonic() - start < args.seconds:
                    observer.spin_for(0.1)
            elapsed = time.monotonic() - start
            window_ns = (window_start_ns, observer.now_ns())
            if args.physics:
                # The run is the stamps of exactly `seconds` of simulated time: the loop
                # sees the end a spin late (0.1 s of wall time, more when this process is
                # starved), which at a real-time factor of 2 is 0.2 s or more of sim time.
                window_ns = (window_start_ns,
                             min(window_ns[1], window_start_ns + round(args.seconds * 1e9)))
            usage_end = {p.spec.name: p.usage() for p in processes}
            observer.spin_for(0.2)
            if check_children():
                # The gait node first: while it publishes, an observer starved on a loaded
                # machine takes its 50 Hz streams slower than they come (rclpy serves one
                # message per subscription per wait) and never catches up; stopped, what
                # it sent stays queued (STREAM_DEPTH) and is taken afterwards.
                stop_gait(processes)
                observer.drain(window_ns[1], lambda: not stop_requested)
                if camera is not None:
                    camera.wait_for_truth(observer.spin_for, window_ns[1])
    finally:
        # Dependency order (supervision.py): gait, drivers (confirming their stops while
        # the modules answer), then simulators, model and recorders.
        stops = stop_in_order(processes, STOP_TIMEOUT_S,
                              warn=lambda text: print(text, file=sys.stderr))
        for p in processes:
            p.close()
        lifeline.close()
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
    exit_codes = {p.spec.name: p.popen.returncode for p in processes}
    problems = shutdown_problems(exit_codes, {p.spec.name: p.spec.executable for p in processes},
                                 {r.name for r in stops if r.killed})
    for p in crashed:
        print(f'\n{p.spec.name} exited early with code {p.popen.returncode}'
              f'{"" if started else " (the robot did not start)"}; its last output:\n'
              f'{p.tail()}', file=sys.stderr)
    if not started and not stop_requested:
        return _report_start_failure(args, scene, processes, crashed, not_ready, exit_codes,
                                     run_dir, observer)
    seconds = (window_ns[1] - window_ns[0]) * 1e-9 if args.physics else elapsed
    summary = summarise(scene, observer, round(seconds, 2), recording, exit_codes, window_ns)
    summary['wall_seconds'] = round(elapsed, 2)
    summary['sim_time'] = bool(args.physics)
    if clock_stalled:
        summary['clock_stalled'] = True
        print(f'demo: the simulated time stood still for {CLOCK_STALL_S:g} s (sim_robot '
              'stalled?): the run ended early', file=sys.stderr)
    summary.update(_bag_summary(bag))
    summary['shutdown_problems'] = problems
    summary['shutdown_order'] = [r.name for r in stops]
    summary['shutdown_seconds'] = {r.name: r.seconds for r in stops}  # from its stage's SIGINT
    summary['started'] = started
    # First process launched -> every module seen end to end (and the recorder taking).
    summary['startup_seconds'] = startup_s
    summary['ros_domain_id'] = slot.domain_id
    if args.physics:
        sim = next((p for p in processes if p.spec.executable == 'sim_robot'), None)
        summary['physics'] = physics_summary(scene, args.gait or scene.default_gait, observer,
                                             window_ns, sim.tail(50) if sim else '')
    if camera is not None:
        summary['camera'] = camera.summary(window_ns)
    summary['processes'] = {
        name: {'cpu_percent': 100.0 * (usage_end[name][0] - usage_start[name][0]) / elapsed,
               'rss_mib': usage_end[name][1] / 2**20}
        for name in usage_start if usage_start[name] and usage_end.get(name)}
    observer.close()
    if args.json:
        print(json.dumps(summary, indent=2, default=float))
    else:
        print_summary(summary)
        if camera is not None:
            print_camera(summary['camera'])
    if crashed or problems:
        return 1
    return 130 if stop_requested else 0


def run_for_sim_time(observer: Observer, seconds: float, keep_going) -> bool:
    """Spin until the observer's ROS time (the simulation's) advanced by `seconds`.

    Ends early when `keep_going()` is false, or when the time stood still for
    CLOCK_STALL_S wall seconds; returns True in that last case.
    """
    start_ns = last_ns = observer.now_ns()
    moved_at = time.monotonic()
    while keep_going():
        now_ns = observer.now_ns()
        if now_ns - start_ns >= seconds * 1e9:
            return False
        if now_ns != last_ns:
            last_ns, moved_at = now_ns, time.monotonic()
        elif time.monotonic() - moved_at > CLOCK_STALL_S:
            return True
        observer.spin_for(0.1)
    return False


def _free_name(path: Path) -> Path:
    """`path`, or `path`-2, -3, ... if taken (a bag is never written over)."""
    candidate, n = path, 1
    while candidate.exists():
        n += 1
        candidate = path.with_name(f'{path.name}-{n}')
    return candidate


def _bag_summary(bag: Path | None) -> dict:
    """The bag's path, message counts per topic and size, read back from its metadata."""
    if bag is None:
        return {'bag': None}
    from .bag import BagError, bag_info
    try:
        info = bag_info(bag)
    except BagError as error:
        return {'bag': None, 'bag_error': str(error)}
    return {'bag': str(bag), 'bag_messages': info.message_count,
            'bag_topics': {t.name: t.message_count for t in info.topics},
            'bag_bytes': sum(f.stat().st_size for f in bag.iterdir())}


def _report_start_failure(args, scene, processes, crashed, not_ready, exit_codes, run_dir,
                          observer) -> int:
    """The robot never ran: say which process or module failed, with logs; exit 1."""
    if observer is not None:
        observer.close()
    if not_ready and not crashed:
        print(f'\n{scene.name} did not start within {args.ready_timeout:g} s; not seen:', file=sys.stderr)
        for module, lacks in not_ready.items():
            print(f'  {module}: {", ".join(lacks)}', file=sys.stderr)
        # The logs of the processes those modules depend on.
        names = {f'sim_{m}' for m in not_ready} | {f'{m}_driver' for m in not_ready} | {
            'driver_container', 'model_node', 'gait_node', 'sim_robot', 'sim_modules'} | (
            {'rerun_logger'} & set(not_ready))
        for p in processes:
            if p.spec.name in names:
                print(f'\n{p.spec.name} (still running); its last output:\n{p.tail()}',
                      file=sys.stderr)
    print(f'\ndemo: {scene.name} failed to start: no summary (logs in {run_dir})', file=sys.stderr)
    if args.json:
        print(json.dumps({'scene': scene.name, 'started': False,
                          'failed_processes': {p.spec.name: p.popen.returncode for p in crashed},
                          'not_seen': not_ready, 'exit_codes': exit_codes}, indent=2))
    return 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='demo', description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='brittle_star',
                        help='brittle_star, starfish, snake, gripper, ring, or a scene YAML path')
    parser.add_argument('--seconds', type=float, default=10.0,
                        help='gait run time, s (default 10; with --physics, simulated seconds)')
    parser.add_argument('--gait', default=None, help="gait name (default: the scene's default gait)")
    parser.add_argument('--gait-rate', type=float, default=50.0, help='command rate, Hz (default 50)')
    parser.add_argument('--model-rate', type=float, default=100.0, help='prediction rate, Hz (default 100)')
    parser.add_argument('--real', action='store_true',
                        help="drive real modules at the scene's addresses instead of simulated ones")
    parser.add_argument('--physics', action='store_true',
                        help='simulate the whole robot in MuJoCo (sim_robot: gravity, ground, '
                             'payloads, locomotion) instead of one sim_module per module')
    parser.add_argument('--time-factor', type=float, default=1.0,
                        help='with --physics: simulated seconds per wall second (default 1)')
    parser.add_argument('--drivers', choices=DRIVER_MODES, default='container',
                        help='container: every module\'s driver in one driver_container process '
                             '(default); separate: one driver_node process per module')
    parser.add_argument('--sim-modules', choices=('auto', *SIM_MODULE_MODES), default='auto',
                        help='separate: one sim_module process per simulated module; shared: one '
                             f'process for all; auto (default): shared above {SHARED_SIMS_ABOVE} '
                             'modules')
    parser.add_argument('--scene-ports', action='store_true',
                        help="simulated modules on the scene's fixed ports (default: free ports "
                             "of this demo's slot, so several demos can run at once)")
    parser.add_argument('--ready-timeout', type=float, default=READY_TIMEOUT_S,
                        help='how long the whole robot may take to come up, s (default '
                             f'{READY_TIMEOUT_S:g}); then the demo stops and says what is missing')
    parser.add_argument('--output', default=None, help='.rrd path (default runs/<scene>-<time>/<scene>.rrd)')
    parser.add_argument('--run-dir', default=None, help='folder for logs and the recording')
    parser.add_argument('--no-rerun', action='store_true', help='do not record the .rrd')
    parser.add_argument('--bag', default=None,
                        help="ROS 2 bag directory to record the robot's topics to (default "
                             'runs/<scene>-<time>/bag; must not exist)')
    parser.add_argument('--bag-all', action='store_true',
                        help='record every topic of the ROS domain in the bag, not only '
                             "the robot's (its namespace, TF, robot_description, "
                             'joint_states, diagnostics, clock, rosout)')
    parser.add_argument('--no-bag', action='store_true', help='do not record a ROS 2 bag')
    parser.add_argument('--json', action='store_true', help='print the summary as JSON')
    parser.add_argument('--closed-loop', action='store_true', help='with --physics: the shape '
                        'controller reaching a target on a MuJoCo gripper finger (docs/control.md)')
    parser.add_argument('--camera', action='store_true',
                        help="with --physics: sim_robot's camera and the marker tracker")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.closed_loop:   # its own module (closed_loop_demo.py), its own summary
        from softsnap_gaits.closed_loop_demo import main as closed_loop_main
        return closed_loop_main(argv)
    if not (args.seconds > 0 and math.isfinite(args.seconds)):
        build_parser().error(f'--seconds must be positive, got {args.seconds}')
    if args.physics and args.real:
        build_parser().error('--physics simulates the robot; it cannot drive --real modules')
    if args.camera and not args.physics:
        build_parser().error('--camera renders the physics simulation: add --physics')
    if not (0 < args.time_factor <= 100 and math.isfinite(args.time_factor)):
        build_parser().error(f'--time-factor must be in (0, 100], got {args.time_factor}')
    if not (args.ready_timeout > 0 and math.isfinite(args.ready_timeout)):
        build_parser().error(f'--ready-timeout must be positive, got {args.ready_timeout}')
    if args.bag and Path(args.bag).exists():
        build_parser().error(f'--bag {args.bag} exists: a bag is never written over')
    try:
        return run(args)
    except (SceneError, ValueError, RuntimeError) as error:  # bad scene, ROS_DOMAIN_ID, no slot
        print(f'demo: {error}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
