"""model_node's prediction thread: woken by the lengths, rate-limited, silent when idle.

The node runs in its own process, lengths come from the test process over Fast DDS.
Judged by counters and stamps, never by wall time (both cores may be busy).
"""
import threading
import time

import pytest

from softsnap_model.scene import load_scene

pytestmark = pytest.mark.ros

NS = '/wakeup'


def start_model(start_node, *params: str):
    return start_node('softsnap_model', 'model_node', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', 'diagnostics_period:=0.2',
                      *(arg for param in params for arg in ('-p', param)))


def length_msg(ros_node, length_m: float):
    from softsnap_interfaces.msg import CableLength
    msg = CableLength(cable_length=length_m)
    msg.header.stamp = ros_node.get_clock().now().to_msg()
    return msg


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def yellow_model(start_node, ros_node, rate_hz: float, shape_depth: int):
    """A model node at ``rate_hz`` and, in the test process, its yellow commanded shapes,
    its diagnostics and a yellow command publisher, once the node is seen and sees it:
    (node, yellow module, shapes, diagnostics, publisher)."""
    from softsnap_interfaces.msg import CableLength, ModelDiagnostics, ModuleShape
    node = start_model(start_node, f'rate:={rate_hz}')
    yellow = load_scene('brittle_star').module('yellow')
    shapes, diagnostics = [], []
    ros_node.create_subscription(ModuleShape, f'{NS}/yellow/shape/commanded', shapes.append,
                                 shape_depth)
    ros_node.create_subscription(ModelDiagnostics, f'{NS}/model/diagnostics',
                                 diagnostics.append, 50)
    # Deep enough to hold every length a test sends: a sample the transport dropped on a
    # loaded machine is sent again from the writer's history, if it is still there.
    pub = ros_node.create_publisher(CableLength, f'{NS}/yellow/cable_length/command', 200)
    assert ros_node.spin_until(lambda: pub.get_subscription_count() > 0 and diagnostics,
                               20.0), node.output()
    return node, yellow, shapes, diagnostics, pub


def test_a_length_after_a_long_idle_gap_is_predicted(start_node, ros_node):
    # Regression guard for the event-driven thread: idle, it blocks in a wait set over
    # the length subscriptions; a length must wake it (not only a fixed tick).
    node, yellow, shapes, diagnostics, pub = yellow_model(start_node, ros_node, 100.0, 10)
    for gap_s, contraction in ((3.0, 20.0), (2.0, 35.0)):
        # Idle for longer than the thread's longest blind wait (IDLE_WAIT_MAX_S, 1 s).
        n_diagnostics = len(diagnostics)
        ros_node.spin_until(lambda: False, gap_s)
        assert len(diagnostics) > n_diagnostics  # the node ran meanwhile
        sent = length_msg(ros_node, (yellow.straight_length_mm - contraction) / 1000.0)
        pub.publish(sent)
        assert ros_node.spin_until(lambda: shapes and stamp_ns(shapes[-1]) == stamp_ns(sent),
                                   15.0), node.output()
        assert shapes[-1].cable_length == pytest.approx(sent.cable_length, abs=1e-12)
    assert len(shapes) == 2  # one length, one prediction each time
    assert node.alive()


def test_a_burst_on_all_ten_length_topics_is_taken_whole(start_node, ros_node):
    from softsnap_interfaces.msg import CableLength, ModelDiagnostics, RobotShape
    node = start_model(start_node, 'rate:=100.0')
    scene = load_scene('brittle_star')
    diagnostics, robots = [], {'commanded': [], 'predicted': []}
    ros_node.create_subscription(ModelDiagnostics, f'{NS}/model/diagnostics',
                                 diagnostics.append, 50)
    for source, received in robots.items():
        ros_node.create_subscription(RobotShape, f'{NS}/model/shape/{source}',
                                     received.append, 50)
    topics = {'commanded': 'cable_length/command', 'predicted': 'cable_length/measured'}
    pubs = {(m.name, source): ros_node.create_publisher(
                CableLength, f'{NS}/{m.name}/{topic}', 10)
            for m in scene.modules for source, topic in topics.items()}
    assert ros_node.spin_until(
        lambda: all(p.get_subscription_count() for p in pubs.values()) and diagnostics,
        20.0), node.output()
    ros_node.spin_until(lambda: False, 1.0)  # the node sees our subscriptions too
    before = diagnostics[-1]
    burst = 4  # per topic, within the subscriptions' queue depth (LENGTH_QUEUE_DEPTH)
    newest = {}
    for i in range(burst):
        for (module, source), pub in pubs.items():
            contraction = 10.0 + 3.0 * i + scene.module_names.index(module)
            newest[(module, source)] = contraction
            straight = scene.module(module).straight_length_mm
            pub.publish(length_msg(ros_node, (straight - contraction) / 1000.0))

    def all_counted() -> bool:
        d = diagnostics[-1]
        return ([a - b for a, b in zip(d.commanded_lengths, before.commanded_lengths)]
                == [burst] * 5 and
                [a - b for a, b in zip(d.measured_lengths, before.measured_lengths)]
                == [burst] * 5)
    assert ros_node.spin_until(all_counted, 20.0), (diagnostics[-1], node.output())
    # Every module's newest length was predicted, for both sources.
    for source, received in robots.items():
        def newest_shown() -> bool:
            return received and all(
                abs(shape.cable_length * 1000.0
                    - (scene.module(shape.module).straight_length_mm
                       - newest[(shape.module, source)])) < 1e-9
                for shape in received[-1].modules)
        assert ros_node.spin_until(newest_shown, 15.0), (source, node.output())
    # Nothing more arrived: the counters stay put.
    ros_node.spin_until(lambda: False, 1.0)
    assert all_counted()


def test_the_rate_limit_holds_with_lengths_faster_than_the_rate(start_node, ros_node):
    rate_hz = 5.0
    node, yellow, shapes, diagnostics, pub = yellow_model(start_node, ros_node, rate_hz, 100)
    ros_node.spin_until(lambda: False, 1.0)  # the node sees our subscription too
    taken_before = diagnostics[-1].commanded_lengths[0]
    # 50 Hz of new lengths for 3 s of the test's clock: ten times the rate.
    sent = []
    end = time.monotonic() + 3.0
    while time.monotonic() < end:
        msg = length_msg(ros_node, (yellow.straight_length_mm - 10.0 - len(sent) * 0.05) / 1000.0)
        pub.publish(msg)
        sent.append(msg)
        ros_node.spin_until(lambda: False, 0.02)
    # The newest length is predicted in the end, and every length was counted.
    assert ros_node.spin_until(lambda: shapes and stamp_ns(shapes[-1]) == stamp_ns(sent[-1]),
                               15.0), node.output()
    assert ros_node.spin_until(
        lambda: diagnostics[-1].commanded_lengths[0] - taken_before == len(sent), 15.0), (
        f'{diagnostics[-1].commanded_lengths[0] - taken_before} lengths taken of '
        f'{len(sent)} sent', node.output())
    # Judged by the stamps of the lengths the shapes came from: a node solving every
    # length would publish about len(sent) shapes (10x the rate).
    span_s = (stamp_ns(shapes[-1]) - stamp_ns(shapes[0])) / 1e9
    assert len(sent) >= 30
    assert 2 <= len(shapes) <= rate_hz * span_s * 1.5 + 3, (len(shapes), span_s, len(sent))
    stamps = [stamp_ns(s) for s in shapes]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)


def test_an_idle_node_publishes_no_shapes(start_node, ros_node):
    from softsnap_interfaces.msg import ModelDiagnostics, ModuleShape, RobotShape
    node = start_model(start_node, 'rate:=100.0', 'rib_centers:=always')
    received, diagnostics = [], []
    for source in ('commanded', 'predicted'):
        ros_node.create_subscription(RobotShape, f'{NS}/model/shape/{source}',
                                     received.append, 10)
        ros_node.create_subscription(ModuleShape, f'{NS}/yellow/shape/{source}',
                                     received.append, 10)
    ros_node.create_subscription(ModelDiagnostics, f'{NS}/model/diagnostics',
                                 diagnostics.append, 50)
    assert ros_node.spin_until(lambda: len(diagnostics) >= 3, 20.0), node.output()
    ros_node.spin_until(lambda: False, 2.0)
    assert len(diagnostics) >= 5  # alive and reporting all along
    assert received == []
    d = diagnostics[-1]
    assert d.solves == 0 and sum(d.commanded_lengths) == 0 and sum(d.measured_lengths) == 0


# ------------------------------------------------------------------ the thread alone
@pytest.fixture
def rcl_node():
    """A node of its own context, for a PredictionThread over real DDS subscriptions."""
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('prediction_thread_test', context=context,
                             start_parameter_services=False, enable_rosout=False)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_prediction_thread_follows_a_new_period_at_once_and_stops(rcl_node):
    from softsnap_interfaces.msg import CableLength
    from softsnap_model.model_node import PredictionThread

    subs = [rcl_node.create_subscription(CableLength, f'pt/length{i}', lambda m: None, 10)
            for i in range(3)]
    pubs = [rcl_node.create_publisher(CableLength, f'pt/length{i}', 10) for i in range(3)]
    taken, predictions, errors = [], [], []
    lock = threading.Lock()
    pending = [False]

    def on_length(index, data):
        with lock:
            taken.append((index, data))
            pending[0] = True

    def predict():
        with lock:
            had, pending[0] = pending[0], False
        if had:
            predictions.append(len(taken))
        return had

    thread = PredictionThread('test_prediction', 3600.0, rcl_node.context, subs, CableLength,
                              on_length=on_length, predict=predict,
                              chores=lambda: time.monotonic() + 3600.0,
                              on_error=errors.append)
    thread.start()
    deadline = time.monotonic() + 20.0
    while not all(p.get_subscription_count() for p in pubs) and time.monotonic() < deadline:
        time.sleep(0.05)

    def wait_for(predicate, timeout=20.0) -> bool:
        end = time.monotonic() + timeout
        while not predicate() and time.monotonic() < end:
            time.sleep(0.01)
        return predicate()

    # A period of an hour: a length wakes the thread, which then holds it to the next
    # boundary of its grid (up to an hour away): taken, not predicted.
    pubs[1].publish(CableLength(cable_length=0.1))
    assert wait_for(lambda: len(taken) == 1)
    assert taken[0][0] == 1 and isinstance(taken[0][1], bytes)
    time.sleep(0.3)
    assert predictions == []
    # A new period applies at once: the held length is predicted well within an hour.
    thread.period_s = 0.01
    assert wait_for(lambda: predictions == [1])
    # Several messages on every subscription: all taken, in one or a few predictions
    # (never one per message burst member beyond what the period allows).
    for i in range(4):
        for pub in pubs:
            pub.publish(CableLength(cable_length=0.1 + i))
    assert wait_for(lambda: len(taken) == 13 and predictions and predictions[-1] == 13)
    assert sorted(index for index, _ in taken[1:]) == [0] * 4 + [1] * 4 + [2] * 4
    assert errors == []
    # Stop ends the idle thread's blocking wait at once (well before the hour of chores).
    assert thread.stop(5.0)
    n = len(taken)
    pubs[0].publish(CableLength(cable_length=0.2))
    time.sleep(0.3)
    assert len(taken) == n
