"""The model node's live shapes: lengths in, predictions out to whoever subscribes.

A mixin of :class:`~softsnap_model.model_node.ModelNode`; its methods run on the
prediction thread (:mod:`.prediction_thread`), the only thread that touches the
predictor, the length subscriptions and the shape publishers' caches.
"""
from __future__ import annotations

import array
import dataclasses
import time

import numpy as np
from geometry_msgs.msg import Point, Pose
from rclpy.time import Time

from softsnap_ros.cdr import (ModuleShapeWire, RobotShapeWire, check_wire, decode_cable_length,
                              read_cable_length)
from softsnap_ros.units import MM_PER_M
from softsnap_interfaces.msg import CableLength, ModuleShape, RobotShape

from .predictor import SOURCES, ModulePrediction
from . import standard_messages as standard

#: How long a publisher's subscription count is trusted before DDS is asked again (s).
SUBSCRIBERS_REFRESH_S = 0.25
#: Pose messages kept for reuse (fixed module bases hit it every prediction).
POSE_CACHE_SIZE = 1024


@dataclasses.dataclass(frozen=True)
class _Listeners:
    """Who listens to the shape outputs, per source ('commanded', 'predicted')."""

    rib_centers: dict    # source -> whether shapes carry rib centres
    modules: dict        # source -> {module: its ModuleShape publisher, if subscribed}
    robot: dict          # source -> RobotShape topic subscribed
    joint_states: dict   # source -> JointState topic subscribed


def points_m(points_mm) -> list[Point]:
    """(N, 2) or (N, 3) array in mm -> geometry_msgs/Point list in metres.

    Built without the generated per-field type checks (``check_fields=False``): every
    value is a Python float made here, and the checks were most of the cost. (Live
    shapes go out as bytes, see softsnap_ros.cdr; this serves the services and the fallback.)
    """
    rows = (np.asarray(points_mm, dtype=float) / MM_PER_M).tolist()
    return [Point(x=p[0], y=p[1], z=p[2] if len(p) > 2 else 0.0, check_fields=False)
            for p in rows]


class ShapeStream:
    """Lengths to predicted shapes on the shape topics (RobotShape, ModuleShape, JointState)."""

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
            if not self.context.ok():
                return False  # the shutdown came during the publish: not a failure
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
            msg.rib_centers = points_m(shape.rib_centers_mm)
        msg.tension = float(shape.tension) * MM_PER_M  # rad^2/mm -> rad^2/m
        msg.energy = float(shape.energy)
        msg.converged = bool(shape.converged)
        msg.residual = float(shape.residual)
        msg.solve_time = float(shape.solve_time_s)
        return msg
