"""The ROS side of ``bag record`` and ``bag play`` (the core is :mod:`softsnap_gaits.bag`).

``BagRecorder`` looks for topics the filter selects every discovery period (so topics
that appear later are recorded from their first matched message on), subscribes with
``raw=True`` (the CDR bytes as they came over DDS, nothing deserialised) and a QoS that
matches every publisher, and writes each message with its receive time. ``BagPlayer``
publishes a bag's stored bytes on their topics with the recorded gaps divided by the
rate: header stamps are untouched, so nodes downstream (model_node, rerun_logger) see
the session as it was.

SIGINT and SIGTERM stop both cleanly: the recorder closes its bag (MCAP summary and
metadata.yaml written) before it exits. The handlers only set a flag; the single thread
that spins also writes, so a signal never lands in the middle of a write.
"""
from __future__ import annotations

import importlib
import shutil
import signal
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from softsnap_ros.spinning import init_ros

from .bag import (BagError, BagWriter, PlaybackClock, TopicFilter, bag_info,
                  playback_qos, read_messages, recording_qos)

#: The executor's wait per spin, s: how late a stop request or a due discovery may be seen.
SPIN_STEP_S = 0.05


def message_class(type_name: str):
    """The Python class of ``package/msg/Type``; BagError if that package is not installed."""
    package, _, name = type_name.split('/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError):
        raise BagError(f'message type {type_name} is not installed (no Python module '
                       f'{package}.msg with {name})') from None


# ---------------------------------------------------------------- QoS conversion
def _to_rosbags(profile):
    """rclpy QoSProfile -> rosbags Qos (what the bag stores as offered_qos_profiles)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)

    def duration(d):
        sec, nsec = divmod(int(d.nanoseconds), 1_000_000_000)
        return QosTime(sec, nsec)

    return Qos(QosHistory(int(profile.history)), int(profile.depth),
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               duration(profile.deadline), duration(profile.lifespan),
               QosLiveliness(int(profile.liveliness)), duration(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def _to_rclpy(qos) -> QoSProfile:
    """rosbags Qos (of recording_qos/playback_qos) -> the rclpy profile to use."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=qos.depth,
                      reliability=ReliabilityPolicy(qos.reliability.value),
                      durability=DurabilityPolicy(qos.durability.value))


class _StopFlag:
    """SIGINT/SIGTERM/SIGHUP set it; the spin loop checks it."""

    def __init__(self):
        self.signal = None
        self._old = {sig: signal.signal(sig, self._handle)
                     for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}

    def _handle(self, signum, _frame):
        self.signal = signum

    def __bool__(self) -> bool:
        return self.signal is not None

    def restore(self) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)


# ---------------------------------------------------------------- recorder
class BagRecorder(Node):
    """Subscribes (raw) to every topic the filter selects and writes it to a bag."""

    def __init__(self, writer: BagWriter, selection: TopicFilter, discovery_period_s: float, **kwargs):
        super().__init__('bag_recorder', **kwargs)
        self.writer = writer
        try:
            self.selection = selection.resolved(self.resolve_topic_name)
        except Exception as error:  # rclpy's invalid-name exceptions
            raise BagError(f'bad topic or namespace name: {error}') from None
        self.received: dict[str, int] = {}
        self._skipped: set[str] = set()  # topics that cannot be recorded (logged once)
        self._recorded = {}
        self.discover_timer = self.create_timer(discovery_period_s, self.discover_callback)
        self.get_logger().info(f'recording to {writer.path}')

    def discover_callback(self) -> None:
        try:
            self.discover()
        except Exception as error:  # a discovery failure must not stop the recording
            self.get_logger().error(f'topic discovery failed: {error!r}', throttle_duration_sec=5.0)

    def discover(self) -> None:
        """Subscribe to the selected topics that have a publisher and are not yet recorded."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or topic in self._skipped or not self.selection.matches(topic):
                continue
            if len(types) != 1:
                self._skip(topic, f'it has {len(types)} types ({", ".join(types)}); a bag topic has one')
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: wait for a publisher to learn its QoS
            offered = [_to_rosbags(p.qos_profile) for p in publishers]
            try:
                msg_type = message_class(types[0])
                self.writer.add_topic(topic, types[0], offered)
            except BagError as error:
                self._skip(topic, str(error))
                continue
            self.received[topic] = 0
            self._recorded[topic] = self.create_subscription(
                msg_type, topic, lambda data, info, topic=topic: self.message_callback(topic, data, info),
                _to_rclpy(recording_qos(offered)), raw=True)
            self.get_logger().info(f'recording {topic} ({types[0]})')

    def _skip(self, topic: str, reason: str) -> None:
        self._skipped.add(topic)
        self.get_logger().warning(f'not recording {topic}: {reason}')

    def message_callback(self, topic: str, data: bytes, info: dict) -> None:
        # The middleware's receive time (system clock, ns) is when the message arrived,
        # not when this callback got round to it; fall back to now if it gives none.
        stamp = info.get('received_timestamp') or self.get_clock().now().nanoseconds
        try:
            self.writer.write(topic, stamp, data)
        except Exception as error:  # a bad write (disk full) is reported, the others go on
            self.get_logger().error(f'could not write a message of {topic}: {error!r}',
                                    throttle_duration_sec=5.0)
            return
        self.received[topic] += 1


def record(output: Path, selection: TopicFilter, discovery_period_s: float,
           ros_args: list[str]) -> int:
    """Record until SIGINT/SIGTERM; the bag is closed (metadata.yaml written) on the way out."""
    writer = BagWriter(output)  # refuses an existing path before ROS starts
    stop = _StopFlag()
    context = rclpy.Context()
    node = None
    recording = False
    try:
        # rclpy's own handlers would shut the context down under the writer; ours set a flag.
        init_ros(args=['bag', *ros_args], context=context,
                 signal_handler_options=SignalHandlerOptions.NO)
        node = BagRecorder(writer, selection, discovery_period_s, context=context)
        node.discover_callback()
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        recording = True
        while not stop and context.ok():
            executor.spin_once(timeout_sec=SPIN_STEP_S)
            writer.flush_if_due()   # a chunk a second, also when messages stop coming
    finally:
        summary = writer.close()
        if not recording and summary.message_count == 0:
            shutil.rmtree(output, ignore_errors=True)  # never started: leave no empty bag
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        stop.restore()
    print(f'bag: wrote {summary.message_count} messages on {len(summary.message_counts)} topics '
          f'to {summary.path}', flush=True)
    return 0


# ---------------------------------------------------------------- player
class BagPlayer(Node):
    """One publisher per played topic, with the recorded reliability, durability and depth."""

    def __init__(self, bag: Path, topics: tuple[str, ...] | None, **kwargs):
        super().__init__('bag_player', **kwargs)
        self.info = bag_info(bag)
        self.publishers_: dict[str, object] = {}
        for topic in self.info.topics:
            if topics is not None and topic.name not in topics:
                continue
            try:
                msg_type = message_class(topic.type_name)
            except BagError as error:
                self.get_logger().warning(f'not playing {topic.name}: {error}')
                continue
            self.publishers_[topic.name] = self.create_publisher(
                msg_type, topic.name, _to_rclpy(playback_qos(topic.offered_qos)))
        if topics is not None:
            missing = sorted(set(topics) - {t.name for t in self.info.topics})
            if missing:
                self.get_logger().warning(f'not in the bag: {", ".join(missing)}')
        self.published = {name: 0 for name in self.publishers_}


def play(bag: Path, rate: float, topics: tuple[str, ...] | None, loop: bool, delay_s: float,
         ros_args: list[str], wait_for_subscribers_s: float = 0.0) -> int:
    """Publish the bag's messages with their recorded timing (scaled by `rate`)."""
    stop = _StopFlag()
    context = rclpy.Context()
    node = None
    try:
        init_ros(args=['bag', *ros_args], context=context,
                 signal_handler_options=SignalHandlerOptions.NO)
        node = BagPlayer(bag, topics, context=context)
        if not node.publishers_:
            raise BagError(f'nothing to play from {bag}: no selected topic with an installed type')
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def wait_until(deadline: float) -> bool:
            """Spin until the monotonic deadline; False if asked to stop first."""
            while not stop and context.ok():
                left = deadline - time.monotonic()
                if left <= 0:
                    return True
                executor.spin_once(timeout_sec=min(left, SPIN_STEP_S))
            return False

        playing = True
        if wait_for_subscribers_s > 0:
            deadline = time.monotonic() + wait_for_subscribers_s
            while playing and time.monotonic() < deadline and not all(
                    p.get_subscription_count() for p in node.publishers_.values()):
                playing = wait_until(min(deadline, time.monotonic() + SPIN_STEP_S))
            lonely = sorted(t for t, p in node.publishers_.items() if not p.get_subscription_count())
            if lonely:
                node.get_logger().warning(f'playing without a subscriber on: {", ".join(lonely)}')
        playing = playing and wait_until(time.monotonic() + delay_s)
        passes = 0
        damaged: list[str] = []

        def skip_damage(lines: list[str]) -> None:
            # Played from the intact chunks; named once, and the exit status says so.
            if not damaged:
                for line in lines:
                    node.get_logger().warning(f'damaged, skipped: {line}')
            damaged[:] = lines

        while playing:
            clock = None
            for topic, _type, stamp, data in read_messages(bag, node.publishers_,
                                                           on_damage=skip_damage):
                if clock is None:
                    clock = PlaybackClock(rate, stamp, time.monotonic())
                if not wait_until(clock.due(stamp)):
                    playing = False
                    break
                node.publishers_[topic].publish(data)
                node.published[topic] += 1
            passes += 1
            playing = playing and loop
        print(f'bag: played {sum(node.published.values())} messages on {len(node.published)} '
              f'topics from {bag} ({passes} pass{"es" if passes != 1 else ""})', flush=True)
        # Reliable subscribers get what is still queued before the publishers go away.
        wait_until(time.monotonic() + 0.2)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        stop.restore()
    return 1 if damaged else 0
