"""shape_controller in its own process over real DDS: a reach on the MuJoCo physics robot
(hosted in the test process), cancel, stale measurements, refusals, and the hand-over
with gait_node."""
import math
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

NS = '/gripper'
MODULE = 'front_left'
TIMEOUT_S = 30.0   # discovery and start-up on a loaded 2-core machine


def controller_args(*extra):
    return ['--ros-args', '-r', f'__ns:={NS}', '-p', 'scene:=gripper',
            '-p', f'modules:=[{MODULE}]', '-p', 'measured_topic:=shape/ground_truth', *extra]


def tip_point(xy):
    from geometry_msgs.msg import Point
    return Point(x=float(xy[0]), y=float(xy[1]), z=0.0)


def send_goal(ros_node, client, goal, feedback=None):
    assert ros_node.spin_until(client.server_is_ready, TIMEOUT_S), 'no reach_shape server'
    sent = client.send_goal_async(goal, feedback_callback=feedback)
    assert ros_node.spin_until(sent.done, TIMEOUT_S)
    handle = sent.result()
    assert handle.accepted
    return handle


def test_reaches_a_target_on_the_physics_robot(ros_node, start_node, tmp_path, read_rrd):
    """20 g on the tip the model does not know: open loop misses by > 3 mm, the
    controller gets within 1 mm and holds it; the steady correction is logged, and the
    rerun recording shows target, measured and predicted shapes and the error falling."""
    from softsnap_gaits.closed_loop_run import run_case
    from softsnap_model.scene import load_scene
    log = tmp_path / 'corrections.jsonl'
    proc = start_node('softsnap_gaits', 'shape_controller',
                      *controller_args('-p', "gait_node:=''", '-p', f'correction_log:={log}',
                                       '-p', f'rerun_recording:={tmp_path / "c.rrd"}'))
    # run_case names topics relative to its node: a node of its own in NS.
    import rclpy
    node = rclpy.create_node('reach_client', namespace=NS, context=ros_node.context)
    ros_node.executor_.add_node(node)
    try:
        result = run_case(node, ros_node.executor_, load_scene('gripper'), MODULE, 'payload',
                          contraction_m=0.03, physics={'tip_mass_kg': 0.02},
                          open_loop_s=2.5, observe_s=6.0)
    finally:
        ros_node.executor_.remove_node(node)
        node.destroy_node()
    print(result)
    assert result.open_loop_tip_error_m > 0.003
    assert result.closed_loop_tip_error_m < 0.001
    assert result.stable and result.stop_reason == 'reached'
    assert ros_node.spin_until(log.exists, TIMEOUT_S), proc.output()[-2000:]
    import json
    record = json.loads(log.read_text().splitlines()[0])
    # The load straightens the finger: the robot needs a shorter cable than the model said.
    assert record['module'] == MODULE and record['correction_m'] < -0.002
    assert proc.stop() == 0, proc.output()[-2000:]
    rec = read_rrd(tmp_path / 'c.rrd')
    for entity in ('target', 'measured', 'predicted', 'error_mm', 'command_mm',
                   'correction_mm'):
        assert f'control/{MODULE}/{entity}' in rec.entities, rec.entities
    errors = rec.scalars(f'control/{MODULE}/error_mm')
    assert max(errors[:5]) > 3.0 and errors[-1] < 1.0


def test_cancel_stops_the_commands(ros_node, start_node):
    """A goal never reached (no measurements at all, long timeout) is cancelled: the
    result says canceled and the controller stops publishing commands."""
    from rclpy.action import ActionClient
    from softsnap_interfaces.action import ReachShape
    from softsnap_interfaces.msg import CableLength
    start_node('softsnap_gaits', 'shape_controller', *controller_args('-p', "gait_node:=''"))
    commands = []
    ros_node.create_subscription(CableLength, f'{NS}/{MODULE}/cable_length/command',
                                 lambda m: commands.append(time.monotonic()), 50)
    client = ActionClient(ros_node, ReachShape, f'{NS}/shape_controller/reach_shape')
    feedback = []
    handle = send_goal(ros_node, client, ReachShape.Goal(
        modules=[MODULE], target_kind='named', shape_name='grasp', timeout=120.0),
        feedback=lambda f: feedback.append(f.feedback))
    # No measurement: after its first (feedforward) command the controller holds it.
    assert ros_node.spin_until(lambda: len(commands) >= 5 and feedback
                               and feedback[-1].state == ['stale'], TIMEOUT_S)
    cancel = handle.cancel_goal_async()
    assert ros_node.spin_until(cancel.done, TIMEOUT_S)
    result = handle.get_result_async()
    assert ros_node.spin_until(result.done, TIMEOUT_S)
    assert result.result().result.stop_reason == 'canceled'
    # Commands stop: none published 1 s after the result (a few may be in flight).
    ros_node.spin_until(lambda: False, 1.0)
    count = len(commands)
    ros_node.spin_until(lambda: False, 2.0)
    assert len(commands) == count


def test_stale_measurements_hold_and_warn(ros_node, start_node):
    """Measurements that stop arriving: the command is held (all equal), /diagnostics
    warns with the age, and the goal ends 'stale' at its timeout. No gait node runs,
    though one is configured: the controller proceeds (there is nobody to hand over from)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import Point
    from rclpy.action import ActionClient
    from softsnap_interfaces.action import ReachShape
    from softsnap_interfaces.msg import CableLength, MeasuredShape
    from softsnap_gaits.shape_control import module_model
    from softsnap_model.scene import load_scene
    model = module_model(load_scene('gripper'), MODULE)
    ribs = model.rib_centers_m(model.range_m[1] - 0.02)
    start_node('softsnap_gaits', 'shape_controller', *controller_args('-p', 'stale_after:=0.5'))
    commands, warnings = [], []
    ros_node.create_subscription(CableLength, f'{NS}/{MODULE}/cable_length/command',
                                 lambda m: commands.append(m.cable_length), 50)
    ros_node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda a: warnings.extend(s for s in a.status if s.name.endswith(
            f'{MODULE}/shape_controller') and s.level == DiagnosticStatus.WARN), 10)
    pub = ros_node.create_publisher(MeasuredShape, f'{NS}/{MODULE}/shape/ground_truth', 10)

    def publish(offset_m):
        msg = MeasuredShape(module=MODULE, source='simulator')
        msg.header.stamp = ros_node.get_clock().now().to_msg()
        msg.rib_centers = [Point(x=x, y=y + offset_m) for x, y in ribs]
        msg.visible = [True] * len(ribs)
        pub.publish(msg)

    client = ActionClient(ros_node, ReachShape, f'{NS}/shape_controller/reach_shape')
    handle = send_goal(ros_node, client, ReachShape.Goal(
        modules=[MODULE], target_kind='ribs', target_points=[tip_point(p) for p in ribs],
        tolerance=0.0005, timeout=8.0))
    # Measurements 3 mm off the target for a while: the controller corrects (commands
    # move). It first waits handover_timeout (3 s) for the absent gait node.
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline and len(commands) < 30:
        publish(0.003)
        ros_node.spin_until(lambda: False, 0.05)
    assert len(commands) >= 30
    moving = np.ptp(commands[-10:])
    # Then none: held.
    assert ros_node.spin_until(lambda: any('old' in w.message for w in warnings), TIMEOUT_S)
    held_from = len(commands)
    ros_node.spin_until(lambda: False, 1.5)
    assert len(commands) > held_from + 5
    assert np.ptp(commands[held_from:]) == 0.0
    assert moving > 0.0
    result = handle.get_result_async()
    assert ros_node.spin_until(result.done, TIMEOUT_S)
    assert result.result().result.stop_reason == 'stale'
    assert not result.result().result.success


def test_refusals_say_why(ros_node, start_node):
    from rclpy.action import ActionClient
    from softsnap_interfaces.action import ReachShape
    from softsnap_interfaces.srv import SetShapeTarget
    start_node('softsnap_gaits', 'shape_controller', *controller_args('-p', "gait_node:=''"))
    srv = ros_node.create_client(SetShapeTarget, f'{NS}/shape_controller/set_target')
    nan = ros_node.call(srv, SetShapeTarget.Request(
        modules=[MODULE], target_kind='tip', target_points=[tip_point((math.nan, 0.0))]))
    assert not nan.success and 'finite' in nan.message
    far = ros_node.call(srv, SetShapeTarget.Request(
        modules=[MODULE], target_kind='tip', target_points=[tip_point((1.0, 1.0))]))
    assert not far.success and 'unreachable' in far.message
    unknown = ros_node.call(srv, SetShapeTarget.Request(modules=['nope'], target_kind='tip',
                                                        target_points=[tip_point((0.1, 0))]))
    assert not unknown.success and 'unknown module' in unknown.message
    client = ActionClient(ros_node, ReachShape, f'{NS}/shape_controller/reach_shape')
    handle = send_goal(ros_node, client, ReachShape.Goal(modules=[MODULE], target_kind='tip',
                                                         target_points=[]))
    result = handle.get_result_async()
    assert ros_node.spin_until(result.done, TIMEOUT_S)
    assert result.result().result.stop_reason == 'refused'
    # A measurement with 5 ribs is refused and counted; the node goes on.
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Point
    from softsnap_interfaces.msg import MeasuredShape
    refused = []
    ros_node.create_subscription(DiagnosticArray, '/diagnostics', lambda a: refused.extend(
        kv.value for st in a.status if st.name.endswith(f'{MODULE}/shape_controller')
        for kv in st.values if kv.key == 'measurements_refused'), 10)
    pub = ros_node.create_publisher(MeasuredShape, f'{NS}/{MODULE}/shape/ground_truth', 10)

    def publish_bad():
        pub.publish(MeasuredShape(module=MODULE, rib_centers=[Point()] * 5))
        return refused and refused[-1] != '0'
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline and not publish_bad():
        ros_node.spin_until(lambda: False, 0.2)
    assert refused and refused[-1] != '0', refused
    again = ros_node.call(srv, SetShapeTarget.Request(modules=[MODULE], target_kind='clear'))
    assert again.success


def test_hand_over_with_the_gait_node(ros_node, start_node):
    """gait_node plays the grasp on all four fingers; a standing target for one finger
    makes gait_node release it (its sent count for that finger stops while the others
    go on) and the controller command it; a restarted gait node is told again; clearing
    hands it back."""
    from softsnap_interfaces.msg import CableLength, GaitPhase
    from softsnap_interfaces.srv import SetShapeTarget
    gait = start_node('softsnap_gaits', 'gait_node', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=gripper', '-p', 'rate:=50.0')
    start_node('softsnap_gaits', 'shape_controller', *controller_args())
    phases, commands = [], []
    ros_node.create_subscription(GaitPhase, f'{NS}/gait/phase', phases.append, 50)
    ros_node.create_subscription(CableLength, f'{NS}/{MODULE}/cable_length/command',
                                 commands.append, 100)
    assert ros_node.spin_until(lambda: len(phases) > 10, TIMEOUT_S)

    def sent(name):
        p = phases[-1]
        return p.commands_sent[list(p.modules).index(name)]

    srv = ros_node.create_client(SetShapeTarget, f'{NS}/shape_controller/set_target')
    reply = ros_node.call(srv, SetShapeTarget.Request(modules=[MODULE], target_kind='named',
                                                      shape_name='straight'))
    assert reply.success, reply.message
    ros_node.spin_until(lambda: False, 0.5)
    before = (sent(MODULE), sent('back_left'))
    n = len(commands)
    ros_node.spin_until(lambda: False, 2.0)
    assert sent(MODULE) == before[0]                  # the gait no longer commands it
    assert sent('back_left') > before[1] + 20         # but still the others
    straight = reply.feedforward_cable_length[0]
    assert len(commands) > n + 10 and all(m.cable_length == pytest.approx(straight, abs=1e-6)
                                          for m in commands[n:])
    # A gait node restarted meanwhile is told again (every 2 s) and stops commanding it.
    gait.stop()
    start_node('softsnap_gaits', 'gait_node', '--ros-args', '-r', f'__ns:={NS}',
               '-p', 'scene:=gripper', '-p', 'rate:=50.0')
    phases.clear()
    assert ros_node.spin_until(lambda: len(phases) > 10, TIMEOUT_S)

    def released_again():
        first = sent(MODULE)
        ros_node.spin_until(lambda: False, 1.0)
        return sent(MODULE) == first and sent('back_left') > 0
    assert ros_node.spin_until(released_again, TIMEOUT_S)
    reply = ros_node.call(srv, SetShapeTarget.Request(modules=[MODULE], target_kind='clear'))
    assert reply.success
    back = sent(MODULE)
    assert ros_node.spin_until(lambda: sent(MODULE) > back + 20, TIMEOUT_S)


def test_reaches_a_pose_through_the_drivers_on_sim_robot(ros_node, start_node, slot_port):
    """The whole chain: sim_robot (the gripper in MuJoCo, its ground truth on
    shape/ground_truth, simulated time), a driver_node over loopback HTTP and the
    firmware's deadband, and the controller on /clock. The target is a pose the finger
    was in (so the robot can take it); the controller brings it back from straight."""
    from rclpy.action import ActionClient
    from softsnap_interfaces.action import ReachShape
    from softsnap_interfaces.msg import CableLength, MeasuredShape
    from softsnap_model.scene import load_scene
    scene = load_scene('gripper')
    module = scene.module(MODULE)
    port_base = slot_port(len(scene.modules))
    start_node('softsnap_driver', 'sim_robot', '--ros-args', '-r', f'__ns:={NS}',
               '-p', 'scene:=gripper', '-p', f'port_base:={port_base}',
               '-p', 'ground_truth_rate_hz:=25.0')
    start_node('softsnap_driver', 'driver_node', '--ros-args', '-r', f'__ns:={NS}',
               '-r', f'__node:={MODULE}_driver', '-p', f'module:={MODULE}',
               '-p', f'port:={port_base + module.index}',
               '-p', f'counts_per_mm:={module.counts_per_mm}',
               '-p', f'straight_length_m:={module.straight_length_mm / 1000.0}',
               '-p', 'max_contraction_m:=0.06', '-p', 'use_sim_time:=true')
    start_node('softsnap_gaits', 'shape_controller',
               *controller_args('-p', "gait_node:=''", '-p', 'use_sim_time:=true'))
    shapes = []
    ros_node.create_subscription(MeasuredShape, f'{NS}/{MODULE}/shape/ground_truth',
                                 shapes.append, 50)
    command = ros_node.create_publisher(CableLength, f'{NS}/{MODULE}/cable_length/command', 10)

    def tip(msg):
        return np.array([msg.rib_centers[-1].x, msg.rib_centers[-1].y])

    def drive_until_still(length_m, min_move_m=0.0, start=None):
        """Command `length_m` until the tip moved `min_move_m` from `start` and is still."""
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            command.publish(CableLength(cable_length=length_m))
            ros_node.spin_until(lambda: False, 0.05)
            if len(shapes) < 15 or (start is not None
                                    and np.linalg.norm(tip(shapes[-1]) - start) < min_move_m):
                continue
            recent = [tip(s) for s in shapes[-12:]]
            if max(np.linalg.norm(r - recent[-1]) for r in recent) < 3e-4:
                return np.mean(recent, axis=0)
        raise AssertionError(f'the finger did not settle at {length_m} m')

    assert ros_node.spin_until(lambda: len(shapes) > 5, TIMEOUT_S * 4)
    straight = module.straight_length_mm / 1000.0
    target = drive_until_still(straight - 0.035, 0.02, tip(shapes[-1]))
    start = drive_until_still(straight, 0.02, target)
    ros_node.destroy_publisher(command)
    print(f'target tip {target * 1e3} mm, from {start * 1e3} mm')
    client = ActionClient(ros_node, ReachShape, f'{NS}/shape_controller/reach_shape')
    handle = send_goal(ros_node, client, ReachShape.Goal(
        modules=[MODULE], target_kind='tip', target_points=[tip_point(target)],
        tolerance=0.0015, timeout=30.0, hold=True))
    result = handle.get_result_async()
    assert ros_node.spin_until(result.done, 180.0)
    r = result.result().result
    print(r.stop_reason, r.message, r.final_tip_error, r.correction)
    assert r.success and r.stop_reason == 'reached', r.message
    assert r.final_tip_error[0] < 0.0015
    assert np.linalg.norm(tip(shapes[-1]) - target) < 0.002


def test_the_docs_client_snippet_reaches_its_target(ros_node, start_node, tmp_path):
    """The README's ReachShape snippet, run as it is in its own process, against a
    shape_controller and the MuJoCo finger (default physics)."""
    import re
    import subprocess
    import sys
    from pathlib import Path
    import rclpy
    from softsnap_gaits.physics_plant import MujocoModulePlant
    from softsnap_model.scene import load_scene
    text = (Path(__file__).resolve().parents[2] / 'README.md').read_text()
    snippet = re.search(r'#### ReachShape from Python\n\n.*?```python\n(.*?)```', text,
                        re.S).group(1)
    start_node('softsnap_gaits', 'shape_controller', *controller_args('-p', "gait_node:=''"))
    node = rclpy.create_node('snippet_plant', namespace=NS, context=ros_node.context)
    ros_node.executor_.add_node(node)
    plant = MujocoModulePlant(node, load_scene('gripper'), MODULE)
    try:
        script = tmp_path / 'snippet.py'
        script.write_text(snippet)
        proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, env=start_node.env)
        assert ros_node.spin_until(lambda: proc.poll() is not None, 120.0)
        output = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        plant.close()
        ros_node.executor_.remove_node(node)
        node.destroy_node()
    print(output)
    assert proc.returncode == 0, output
    last = output.strip().splitlines()[-1]
    assert last.startswith('reached'), output
    assert plant.commands > 10


@pytest.mark.parametrize('bad, reason', [('modules:=[nope]', "no module(s) 'nope'"),
                                         ('integral_gain:=-1.0', 'integral_gain_per_s'),
                                         ('rate:=0.5', 'rate must be')])
def test_bad_start_up_parameters_exit_2_with_the_reason(start_node, bad, reason):
    proc = start_node('softsnap_gaits', 'shape_controller', '--ros-args',
                      '-p', 'scene:=gripper', '-p', bad)
    assert proc.proc.wait(120) == 2, proc.output()
    assert 'cannot start' in proc.output() and reason in proc.output()


def test_reaches_a_target_measured_by_the_simulated_camera(ros_node, start_node, tmp_path):
    """The loop closed through the camera: MuJoCo renders the finger from its marked side
    (640x480, 15 Hz, a tag on its case), a marker_tracker process measures the images
    with OpenCV, and the controller follows those measurements only (source 'camera')
    to within 1 mm of a tip the model misses by > 3 mm."""
    import rclpy
    from softsnap_gaits.closed_loop_run import camera_tracker_args, run_case, tagged_scene_file
    from softsnap_interfaces.msg import MeasuredShape
    from softsnap_model.scene import load_scene
    controller = start_node('softsnap_gaits', 'shape_controller',
                            *controller_args('-p', "gait_node:=''",
                                             '-p', 'measured_topic:=shape/measured'))
    scene_file = tagged_scene_file('gripper', MODULE, 0, tmp_path)
    node = rclpy.create_node('camera_reach_client', namespace=NS, context=ros_node.context)
    ros_node.executor_.add_node(node)
    sources = []
    node.create_subscription(MeasuredShape, f'{MODULE}/shape/measured',
                             lambda m: sources.append((m.source, sum(m.visible))), 10)
    procs = {}

    def start_tracker(plant):
        procs['tracker'] = start_node(
            'softsnap_vision', 'marker_tracker', '--ros-args',
            *camera_tracker_args(NS, scene_file, plant.camera_plane_distance_m()))
        assert ros_node.spin_until(lambda: len(sources) >= 3, TIMEOUT_S), \
            procs['tracker'].output()[-2000:]

    try:
        result = run_case(node, ros_node.executor_, load_scene('gripper'), MODULE, 'camera',
                          contraction_m=0.03, physics={'tip_mass_kg': 0.02},
                          camera_rate_hz=15.0, on_plant=start_tracker,
                          open_loop_s=2.5, observe_s=6.0)
    finally:
        ros_node.executor_.remove_node(node)
        node.destroy_node()
    print(result, len(sources))
    assert {s for s, _ in sources} == {'camera'}
    assert np.median([n for _, n in sources]) == 12     # every rib seen
    assert result.open_loop_tip_error_m > 0.003
    assert result.closed_loop_tip_error_m < 0.001
    assert result.stable and result.stop_reason == 'reached'
    assert procs['tracker'].stop() == 0, procs['tracker'].output()[-2000:]
    assert controller.stop() == 0, controller.output()[-2000:]
