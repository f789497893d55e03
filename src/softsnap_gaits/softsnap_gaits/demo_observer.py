"""The demo's ROS observer: an rclpy node that counts and measures what flows through
the robot's topics while the demo runs (commands, lengths, states, shapes, phases)."""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from softsnap_model.geometry import rib_centers
from softsnap_ros.units import stamp_ns

from .demo_config import DRAIN_IDLE_S, DRAIN_TIMEOUT_S, STREAM_DEPTH


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
        last = stamp_ns(msg.last_command_stamp)
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
    return stamp_ns(msg.header.stamp)


def _pose_sample(msg) -> tuple:
    p = msg.pose.position
    return (_stamp_ns(msg), p.x, p.y, p.z)
