"""Standard outputs in a running graph: MarkerArray, JointState, /diagnostics, BatteryState.

Every node runs in its own process over real DDS (sim_module, driver_node, model_node);
the test subscribes like RViz, Foxglove or rqt_robot_monitor would and checks the content
against the core solver.
"""
import time

import numpy as np
import pytest

from softsnap_driver.firmware import DEADBAND_COUNTS
from softsnap_model.forward import reachable_range, solve_forward
from softsnap_model.scene import load_scene

pytestmark = pytest.mark.ros

NS = '/brittle_star'
SCENE = load_scene('brittle_star')


def _stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _xyz(points):
    return np.array([[p.x, p.y, p.z] for p in points])


def _values(status):
    return {kv.key: kv.value for kv in status.values}


class Diagnostics:
    """Latest /diagnostics status per name, as rqt_robot_monitor shows them."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticArray
        self.latest = {}
        self.history = []
        node.create_subscription(DiagnosticArray, '/diagnostics', self._callback, 50)

    def _callback(self, msg):
        for status in msg.status:
            self.latest[status.name] = status
            self.history.append(status)


def _publish_lengths(node, publishers, lengths_m, sent):
    """Publish one length per module with a fresh stamp; remember stamp -> length (m)."""
    from softsnap_interfaces.msg import CableLength
    stamp = node.get_clock().now().to_msg()
    for name, publisher in publishers.items():
        msg = CableLength(cable_length=float(lengths_m[name]))
        msg.header.stamp = stamp
        publisher.publish(msg)
        sent[(name, _stamp_ns(stamp))] = float(lengths_m[name])


def test_markers_and_joint_states_equal_the_solved_shapes(start_node, ros_node):
    from sensor_msgs.msg import JointState
    from softsnap_interfaces.msg import CableLength, ModuleShape, RobotShape
    from visualization_msgs.msg import MarkerArray
    from geometry_msgs.msg import Point, Pose
    model = start_node('softsnap_model', 'model_node', '--ros-args', '-r', f'__ns:={NS}',
                       '-p', 'scene:=brittle_star', '-p', 'diagnostics_period:=0.2',
                       '-p', 'marker_rate:=20')
    diagnostics = Diagnostics(ros_node)
    joint_states = {'commanded': [], 'predicted': []}
    for source in joint_states:
        ros_node.create_subscription(JointState, f'{NS}/model/joint_states/{source}',
                                     joint_states[source].append, 50)
    topics = {'commanded': 'cable_length/command', 'predicted': 'cable_length/measured'}
    publishers = {source: {m.name: ros_node.create_publisher(
        CableLength, f'{NS}/{m.name}/{topic}', 10) for m in SCENE.modules}
        for source, topic in topics.items()}
    status_name = f'softsnap/{SCENE.name}/model'
    assert ros_node.spin_until(lambda: status_name in diagnostics.latest, 30.0), model.output()

    # Lengths of both sources until both joint-state topics delivered (discovery under
    # load takes a while); each round a new contraction, so every round is solved.
    sent = {'commanded': {}, 'predicted': {}}
    deadline = time.monotonic() + 60.0
    rounds = 0
    while not all(joint_states.values()) and time.monotonic() < deadline:
        rounds += 1
        for source, base in (('commanded', 20.0), ('predicted', 35.0)):
            contraction = base + 0.5 * (rounds % 20)
            lengths = {m.name: (m.straight_length_mm - contraction - 2.0 * i) / 1000.0
                       for i, m in enumerate(SCENE.modules)}
            _publish_lengths(ros_node, publishers[source], lengths, sent[source])
        ros_node.spin_until(lambda: False, 0.3)
    assert all(joint_states.values()), model.output()

    # Joint angles equal the core's solve of the length with the message's stamp (a
    # message holds the modules solved from lengths of one stamp, whole modules only).
    n = SCENE.skeleton.n_segments
    for source, messages in joint_states.items():
        for msg in messages[-10:]:
            stamp = _stamp_ns(msg.header.stamp)
            names = list(msg.name)
            assert names and len(names) % n == 0 and len(msg.position) == len(names)
            for k in range(0, len(names), n):
                module = names[k].split('/')[0]
                assert names[k:k + n] == [f'{module}/segment_{i}' for i in range(n)]
                direct = solve_forward(SCENE.skeleton, SCENE.module(module).threading_mm,
                                       sent[source][(module, stamp)] * 1000.0)
                np.testing.assert_allclose(msg.position[k:k + n], direct.angles, atol=1e-7)

    # Nobody subscribes to the markers yet: the node built and published none.
    count = len(diagnostics.history)
    assert ros_node.spin_until(lambda: len(diagnostics.history) >= count + 3, 30.0)
    for status in diagnostics.history:
        assert _values(status)['marker arrays published'] == '0', _values(status)
    assert int(_values(diagnostics.history[-1])['solves']) > 0
    assert int(_values(diagnostics.history[-1])['joint states published']) > 0

    # A simulated shape (as the physics simulator publishes it): yellow bent, at a pose.
    simulated = RobotShape(robot=SCENE.name)
    simulated.header.frame_id = SCENE.name
    yellow = SCENE.module('yellow')
    sim_solve = solve_forward(SCENE.skeleton, yellow.threading_mm, yellow.straight_length_mm - 42.0)
    sim_shape = ModuleShape(module='yellow', source='simulated', angles=list(sim_solve.angles),
                            rib_centers=[Point(x=x / 1000.0, y=y / 1000.0, z=0.0)
                                         for x, y in np.asarray(sim_solve.rib_centers)[:, :2]])
    simulated.modules.append(sim_shape)
    sim_pose = Pose()
    sim_pose.position.x, sim_pose.position.y, sim_pose.position.z = 0.0725, 0.001, -0.002
    sim_pose.orientation.w = 1.0
    simulated.base_poses.append(sim_pose)
    sim_publisher = ros_node.create_publisher(RobotShape, f'{NS}/model/shape/simulated', 1)

    # A late subscriber gets markers; the node counts what it published.
    arrays = []
    ros_node.create_subscription(MarkerArray, f'{NS}/model/markers', arrays.append, 10)

    def has_simulated():
        sim_publisher.publish(simulated)
        return arrays and any(m.ns == 'yellow/simulated/spine' for m in arrays[-1].markers)
    assert ros_node.spin_until(has_simulated, 60.0), model.output()
    assert ros_node.spin_until(
        lambda: int(_values(diagnostics.history[-1])['marker arrays published']) > 0, 30.0)

    markers = {m.ns: m for m in arrays[-1].markers}
    assert len(markers) == len(arrays[-1].markers)                        # one per namespace
    last = {source: max(stamp for (_, stamp) in sent[source]) for source in sent}
    for source in ('commanded', 'predicted'):
        for m in SCENE.modules:
            spine = markers[f'{m.name}/{source}/spine']
            assert spine.header.frame_id == SCENE.name
            assert _stamp_ns(spine.header.stamp) == last[source]
            direct = solve_forward(SCENE.skeleton, m.threading_mm,
                                   sent[source][(m.name, last[source])] * 1000.0)
            # Marker points equal the model's rib centres (m) in the module base frame...
            np.testing.assert_allclose(_xyz(spine.points)[:, :2],
                                       np.asarray(direct.rib_centers) / 1000.0, atol=1e-9)
            cable = markers[f'{m.name}/{source}/cable']
            np.testing.assert_allclose(_xyz(cable.points)[:, :2],
                                       np.asarray(direct.cable_path) / 1000.0, atol=1e-9)
            assert len(markers[f'{m.name}/{source}/ribs'].points) == 2 * SCENE.skeleton.n_ribs
            # ...placed on the robot by the module's base pose.
            p, q = spine.pose.position, spine.pose.orientation
            np.testing.assert_allclose([p.x, p.y, p.z], m.base_position_m, atol=1e-12)
            np.testing.assert_allclose([q.x, q.y, q.z, q.w], m.base_orientation_xyzw, atol=1e-12)
    sim_spine = markers['yellow/simulated/spine']
    np.testing.assert_allclose(_xyz(sim_spine.points)[:, :2],
                               np.asarray(sim_solve.rib_centers) / 1000.0, atol=1e-12)
    assert sim_spine.pose.position.y == pytest.approx(0.001)
    assert sim_spine.header.frame_id == SCENE.name
    # Ids are stable: the next array uses the same (ns, id) pairs.
    ids = {(m.ns, m.id) for m in arrays[-1].markers}
    count = len(arrays)
    assert ros_node.spin_until(lambda: len(arrays) > count, 30.0)
    assert {(m.ns, m.id) for m in arrays[-1].markers} == ids

    # marker_rate is validated: out of range refused with a reason, a good value applied.
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    client = ros_node.create_client(SetParameters, f'{NS}/model_node/set_parameters')

    def set_rate(value):
        request = SetParameters.Request(parameters=[Parameter(name='marker_rate', value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
        return ros_node.call(client, request).results[0]
    refused = set_rate(1000.0)
    assert not refused.successful and refused.reason
    assert set_rate(2.0).successful
    count = len(arrays)
    assert ros_node.spin_until(lambda: len(arrays) > count, 30.0)
    assert model.alive()


def test_driver_diagnostics_and_battery_follow_the_simulated_module(start_node, ros_node,
                                                                     slot_port):
    from sensor_msgs.msg import BatteryState, JointState
    from softsnap_interfaces.msg import CableLength, ModuleState
    from diagnostic_msgs.msg import DiagnosticStatus
    free_port = slot_port()
    yellow = SCENE.module('yellow')
    _, straight_mm = reachable_range(SCENE.skeleton, yellow.threading_mm)
    sim_args = ['--ros-args', '-r', f'__ns:={NS}', '-r', '__node:=sim_yellow',
                '-p', f'port:={free_port}', '-p', 'battery_full_v:=3.45']
    sim = start_node('softsnap_driver', 'sim_module', *sim_args)
    start_node('softsnap_driver', 'driver_node', '--ros-args', '-r', f'__ns:={NS}',
               '-p', 'module:=yellow', '-p', f'port:={free_port}',
               '-p', f'counts_per_mm:={yellow.counts_per_mm}',
               '-p', f'straight_length_m:={straight_mm / 1000.0}',
               '-p', 'poll_rate_hz:=20.0', '-p', 'request_timeout_s:=0.3',
               '-p', 'command_timeout_s:=0.0', '-p', 'diagnostics_period_s:=0.2')
    model = start_node('softsnap_model', 'model_node', '--ros-args', '-r', f'__ns:={NS}',
                       '-p', 'scene:=brittle_star')
    diagnostics = Diagnostics(ros_node)
    batteries, states, measured, predicted = [], [], [], []
    ros_node.create_subscription(BatteryState, f'{NS}/yellow/battery', batteries.append, 50)
    ros_node.create_subscription(ModuleState, f'{NS}/yellow/state', states.append, 50)
    ros_node.create_subscription(CableLength, f'{NS}/yellow/cable_length/measured',
                                 measured.append, 200)
    ros_node.create_subscription(JointState, f'{NS}/model/joint_states/predicted',
                                 predicted.append, 50)
    command = ros_node.create_publisher(CableLength, f'{NS}/yellow/cable_length/command', 10)
    name = f'softsnap/{SCENE.name}/yellow/driver'
    assert ros_node.spin_until(lambda: name in diagnostics.latest and batteries and states, 30.0)

    # The battery: the voltage the module reports (the sim's cell, below the WARN threshold).
    assert ros_node.spin_until(lambda: batteries[-1].present and states[-1].online, 20.0)
    battery = batteries[-1]
    assert battery.voltage == pytest.approx(states[-1].battery_voltage, abs=0.02)
    # Full 3.45 V minus the idle draw, which the module's first samples (and its mV
    # rounding) may not show yet: at most the full voltage (a float32 field).
    assert 3.3 < battery.voltage <= float(np.float32(3.45))
    assert battery.power_supply_technology == BatteryState.POWER_SUPPLY_TECHNOLOGY_LION
    assert np.isnan(battery.percentage)
    assert ros_node.spin_until(
        lambda: diagnostics.latest[name].level == DiagnosticStatus.WARN, 20.0)
    assert 'battery' in diagnostics.latest[name].message
    assert diagnostics.latest[name].hardware_id == f'127.0.0.1:{free_port}'

    # Predicted joint angles equal the solve of the measured length with the same stamp.
    # Joint states come only when a shape changes: bend the module to one of two lengths
    # in turn until the model (which may still be discovering us) sent one of a bent length.
    bent_m = straight_mm / 1000.0 - 0.014

    def moved():
        bent = {_stamp_ns(m.header.stamp) for m in measured if m.cable_length < bent_m}
        return any(_stamp_ns(p.header.stamp) in bent for p in predicted)
    deadline = time.monotonic() + 90.0
    contraction_mm = 15.0
    while not moved():
        assert time.monotonic() < deadline, (
            f'no predicted joint state of a bent measured length: {len(measured)} measured '
            f'(last {measured[-1].cable_length if measured else None} m), '
            f'{len(predicted)} predicted\n{model.output()}')
        contraction_mm = 33.0 - contraction_mm          # 15 mm, 18 mm, 15 mm, ...
        msg = CableLength(cable_length=(straight_mm - contraction_mm) / 1000.0)
        msg.header.stamp = ros_node.get_clock().now().to_msg()
        command.publish(msg)
        ros_node.spin_until(moved, 3.0)
    by_stamp = {_stamp_ns(m.header.stamp): m.cable_length for m in measured}
    checked = 0
    for joint_state in predicted:
        stamp = _stamp_ns(joint_state.header.stamp)
        if stamp in by_stamp and by_stamp[stamp] < straight_mm / 1000.0 - 1e-4:
            direct = solve_forward(SCENE.skeleton, yellow.threading_mm, by_stamp[stamp] * 1000.0)
            assert list(joint_state.name) == [f'yellow/segment_{i}' for i in range(len(direct.angles))]
            np.testing.assert_allclose(joint_state.position, direct.angles, atol=1e-7)
            checked += 1
    assert checked > 0
    # Back to straight, so that the restarted module (count 0) is not taken for a reboot.
    msg = CableLength(cable_length=straight_mm / 1000.0)
    msg.header.stamp = ros_node.get_clock().now().to_msg()
    command.publish(msg)
    # Within the firmware's deadband of 0, inside the driver's reboot zero band (60 counts).
    assert ros_node.spin_until(
        lambda: abs(states[-1].encoder_count) <= DEADBAND_COUNTS + 1, 30.0), states[-1]

    # The module goes away: ERROR "offline"; it comes back: no longer ERROR.
    sim.stop()
    assert ros_node.spin_until(
        lambda: diagnostics.latest[name].level == DiagnosticStatus.ERROR, 30.0)
    assert 'offline' in diagnostics.latest[name].message
    assert ros_node.spin_until(lambda: not batteries[-1].present, 10.0)
    start_node('softsnap_driver', 'sim_module', *sim_args)
    assert ros_node.spin_until(
        lambda: diagnostics.latest[name].level in (DiagnosticStatus.OK, DiagnosticStatus.WARN),
        60.0), diagnostics.latest[name].message
    assert 'offline' not in diagnostics.latest[name].message
    assert batteries[-1].present or ros_node.spin_until(lambda: batteries[-1].present, 10.0)
    # The model node reports on /diagnostics too.
    assert ros_node.spin_until(lambda: f'softsnap/{SCENE.name}/model' in diagnostics.latest, 30.0)
    assert model.alive()
