"""The rerun_logger node over real ROS traffic: publish shapes and states, stop it with
SIGINT like Ctrl-C, read the .rrd back and check entity paths, frame counts and values."""
from __future__ import annotations

import datetime as dt
import math
import time
import warnings

import numpy as np
import pytest

from softsnap_model import recording as rec_mod

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = '/brittle_star'
STAMP0 = 1_795_000_000_000_000_000
PERIOD = 20_000_000  # ns between ticks (50 Hz model)
SCENE_MODULES = ('yellow', 'blue', 'green', 'red', 'orange')


def stamp(msg_header, ns: int):
    msg_header.stamp.sec, msg_header.stamp.nanosec = divmod(ns, 1_000_000_000)


def angles_for(module: str, source: str, tick: int) -> list[float]:
    """A distinct known uniform bend per module, source and tick."""
    k = SCENE_MODULES.index(module) + 1 if module in SCENE_MODULES else 9
    total = (0.05 if source == 'commanded' else 0.04) * k * (tick + 1)
    return [total / 11] * 11


def robot_shape(source: str, tick: int, modules, with_centres: set[str], poses):
    from geometry_msgs.msg import Point, Pose
    from softsnap_interfaces.msg import ModuleShape, RobotShape

    msg = RobotShape(robot='brittle_star')
    stamp(msg.header, STAMP0 + tick * PERIOD)
    msg.header.frame_id = 'brittle_star'
    for module in modules:
        shape = ModuleShape(module=module, source=source, converged=True, solve_time=0.0015)
        shape.header = msg.header
        shape.angles = angles_for(module, source, tick)
        shape.cable_length = 0.2 - 0.001 * tick
        if module in with_centres:
            centres = rec_mod.rib_centres_mm(shape.angles) * 1e-3
            shape.rib_centers = [Point(x=float(x), y=float(y), z=0.0) for x, y in centres]
        msg.modules.append(shape)
        pose = Pose()
        (pose.position.x, pose.position.y, pose.position.z), q = poses[module]
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = q
        msg.base_poses.append(pose)
    return msg


def scene_poses():
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    poses = {m.name: (m.base_position_m, m.base_orientation_xyzw) for m in scene.modules}
    poses['ghost'] = ((0.3, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    return scene, poses


def rows_in_file(path, entity: str) -> int:
    """Rows of one entity in a recording that may still be being written."""
    from rerun.chunk import RrdReader
    if not path.exists() or path.stat().st_size == 0:
        return 0
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # no footer yet: expected while the node runs
        try:
            chunks = RrdReader(str(path)).stream().to_chunks()
        except Exception:  # a chunk half written at the end of the file
            return 0
    return sum(c.num_rows for c in chunks if c.entity_path.lstrip('/') == entity)


def wait_for_rows(path, entity: str, count: int, node, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if rows_in_file(path, entity) >= count:
            return
        node.spin_until(lambda: False, 0.2)
    pytest.fail(f'{entity}: fewer than {count} rows in {path} after {timeout} s')


def publishers(ros_node, modules):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from softsnap_interfaces.msg import CableLength, ModuleState, RobotShape

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {source: ros_node.create_publisher(RobotShape, f'{NS}/model/shape/{source}', qos)
            for source in ('commanded', 'predicted')}
    for m in modules:
        pubs[(m, 'command')] = ros_node.create_publisher(
            CableLength, f'{NS}/{m}/cable_length/command', qos)
        pubs[(m, 'measured')] = ros_node.create_publisher(
            CableLength, f'{NS}/{m}/cable_length/measured', qos)
        pubs[(m, 'state')] = ros_node.create_publisher(ModuleState, f'{NS}/{m}/state', qos)
    return pubs


def log_of(proc) -> str:
    """The node's output, also after it was stopped (its log file is closed then)."""
    return proc.log_path.read_text(errors='replace')


def wait_matched(ros_node, pubs, proc):
    ok = ros_node.spin_until(
        lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()) or not proc.alive(),
        timeout=30.0)
    assert proc.alive(), proc.output()
    assert ok, 'rerun_logger did not subscribe to every topic:\n' + proc.output()


def test_logger_records_scene_modules_and_completes_the_file_on_sigint(
        tmp_path, start_node, ros_node, read_rrd):
    from softsnap_interfaces.msg import CableLength, ModuleState

    output = tmp_path / 'runs' / 'walk.rrd'  # the directory does not exist yet
    proc = start_node('softsnap_gaits', 'rerun_logger', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', f'output:={output}', '-p', 'rate:=0.0', '-p', 'scene:=brittle_star')
    scene, poses = scene_poses()
    pubs = publishers(ros_node, ['yellow', 'red'])
    wait_matched(ros_node, pubs, proc)

    ticks = 6
    modules = [*SCENE_MODULES, 'ghost']  # ghost is not in the scene: must not be logged
    for tick in range(ticks):
        for source in ('commanded', 'predicted'):
            pubs[source].publish(robot_shape(source, tick, modules, {'yellow'}, poses))
        t = STAMP0 + tick * PERIOD
        for module in ('yellow', 'red'):
            for kind, length in (('command', 0.2 - 0.001 * tick), ('measured', 0.2 - 0.0008 * tick)):
                msg = CableLength(cable_length=length)
                stamp(msg.header, t)
                pubs[(module, kind)].publish(msg)
            state = ModuleState(module=module, online=True, battery_voltage=7.5 - 0.1 * tick,
                                measured_cable_length=0.2, target_cable_length=math.nan)
            stamp(state.header, t)
            pubs[(module, 'state')].publish(state)
        ros_node.spin_until(lambda: False, 0.01)

    wait_for_rows(output, 'robot/orange/predicted/spine', ticks, ros_node)
    wait_for_rows(output, 'plots/battery_v/red', ticks, ros_node)
    assert proc.stop() == 0, log_of(proc)
    log = log_of(proc)
    assert 'recording closed' in log and 'rosout' not in log, log

    rrd = read_rrd(output)  # store() inside succeeds only if the file has its footer
    assert rrd.blueprints
    assert not any('ghost' in e for e in rrd.entities)
    for module in SCENE_MODULES:
        for source in ('commanded', 'predicted'):
            for part in ('spine', 'ribs', 'cable'):
                entity = f'robot/{module}/{source}/{part}'
                assert rrd.times(entity) == [STAMP0 + i * PERIOD for i in range(ticks)], entity
        transform = rrd.rows[f'robot/{module}']
        assert len(transform) == 1  # poses never changed
        np.testing.assert_allclose(transform[0]['Transform3D:translation'][0], poses[module][0],
                                   atol=1e-7)
        np.testing.assert_allclose(transform[0]['Transform3D:quaternion'][0], poses[module][1],
                                   atol=1e-7)
        assert len(rrd.scalars(f'plots/solve_time_ms/{module}/predicted')) == ticks
    assert set(rrd.static['robot/connector']['Points3D:labels']) == set(SCENE_MODULES)

    # Spines: yellow from the message's rib centres, blue computed from the angles; both
    # must be the known shape in metres.
    for module in ('yellow', 'blue'):
        strips = rrd.values(f'robot/{module}/commanded/spine', 'LineStrips3D:strips')
        for tick, value in enumerate(strips):
            expected = rec_mod.rib_centres_mm(angles_for(module, 'commanded', tick)) * 1e-3
            np.testing.assert_allclose(np.asarray(value[0])[:, :2], expected, atol=1e-7)
    # The cable follows the scene's threading of that module.
    cable = np.asarray(rrd.values('robot/red/predicted/cable', 'LineStrips3D:strips')[-1][0])
    frames = rec_mod.rib_frames(angles_for('red', 'predicted', ticks - 1))
    red = next(m for m in scene.modules if m.name == 'red')
    np.testing.assert_allclose(cable, rec_mod.cable_points_m(frames, red.threading_mm), atol=1e-7)

    # Time series in their units.
    np.testing.assert_allclose(rrd.scalars('plots/cable_length_mm/red/commanded'),
                               [200.0 - i for i in range(ticks)], atol=1e-9)
    np.testing.assert_allclose(rrd.scalars('plots/cable_length_mm/yellow/measured'),
                               [200.0 - 0.8 * i for i in range(ticks)], atol=1e-9)
    np.testing.assert_allclose(rrd.scalars('plots/battery_v/red'),
                               [7.5 - 0.1 * i for i in range(ticks)], atol=1e-6)
    np.testing.assert_allclose(rrd.scalars('plots/solve_time_ms/green/commanded'), [1.5] * ticks)
    tip = rrd.scalars('plots/tip_error_mm/green')
    last = [rec_mod.rib_centres_mm(angles_for('green', s, ticks - 1))[-1] for s in
            ('commanded', 'predicted')]
    assert tip[-1] == pytest.approx(float(np.linalg.norm(last[0] - last[1])), abs=1e-6)
    assert tip[-1] > 1.0  # the two shapes differ by millimetres, not a rounding error


def test_rate_parameter_limits_logging_per_module_and_source(
        tmp_path, start_node, ros_node, read_rrd):
    output = tmp_path / 'limited.rrd'
    proc = start_node('softsnap_gaits', 'rerun_logger', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', f'output:={output}', '-p', 'rate:=10.0',
                      '-p', 'modules:=[yellow]')
    _, poses = scene_poses()
    pubs = publishers(ros_node, [])
    wait_matched(ros_node, pubs, proc)
    ticks = 20  # 20 ms apart in stamps: 0 .. 380 ms
    for tick in range(ticks):
        pubs['predicted'].publish(robot_shape('predicted', tick, ['yellow', 'blue'], set(), poses))
    sentinel = 100  # 2 s later: always logged, and the last message of the publisher
    pubs['predicted'].publish(robot_shape('predicted', sentinel, ['yellow', 'blue'], set(), poses))
    wait_for_rows(output, 'robot/yellow/predicted/spine', 5, ros_node)

    # At run time: a negative rate is refused, 0 (log everything) is taken.
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    client = AsyncParameterClient(ros_node, f'{NS}/rerun_logger')
    assert ros_node.spin_until(lambda: client.services_are_ready(), 20.0)
    results = {}
    for value in (-1.0, 0.0):
        future = client.set_parameters([Parameter('rate', value=value)])
        assert ros_node.spin_until(future.done, 10.0)
        results[value] = future.result().results[0].successful
    assert results == {-1.0: False, 0.0: True}
    for tick in range(sentinel + 1, sentinel + 4):  # 20 ms apart: all logged now
        pubs['predicted'].publish(robot_shape('predicted', tick, ['yellow'], set(), poses))
    wait_for_rows(output, 'robot/yellow/predicted/spine', 8, ros_node)
    assert proc.stop() == 0, log_of(proc)

    rrd = read_rrd(output)
    expected = ([STAMP0 + k * 100_000_000 for k in range(4)]
                + [STAMP0 + tick * PERIOD for tick in range(sentinel, sentinel + 4)])
    assert rrd.times('robot/yellow/predicted/spine') == expected
    assert not any('blue' in e for e in rrd.entities)  # not in the modules parameter
    # 24 yellow shapes (blue is not wanted): 8 kept, 16 dropped by the 10 Hz limit.
    assert '8 messages logged, 16 dropped by rate' in log_of(proc), log_of(proc)


def test_default_output_is_under_runs_with_robot_and_utc_time():
    from softsnap_gaits.rerun_logger import default_output
    when = dt.datetime(2026, 11, 22, 1, 2, 3, tzinfo=dt.timezone.utc)
    assert str(default_output('snake', when)) == 'runs/snake-20261122T010203Z.rrd'


def test_unknown_scene_is_refused_with_its_name(tmp_path, start_node):
    proc = start_node('softsnap_gaits', 'rerun_logger', '--ros-args',
                      '-p', f'output:={tmp_path / "x.rrd"}', '-p', 'scene:=no_such_robot')
    assert proc.proc.wait(30) == 2
    assert 'no_such_robot' in log_of(proc), log_of(proc)
    assert not (tmp_path / 'x.rrd').exists()


def test_malformed_message_bytes_are_logged_and_the_node_keeps_recording(
        tmp_path, start_node, ros_node, read_rrd):
    """The node takes its topics raw: bytes that are no RobotShape or CableLength (a
    truncated message, junk) are refused with an error line, and the next good messages
    are recorded."""
    from rclpy.serialization import serialize_message
    from softsnap_interfaces.msg import CableLength

    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    output = tmp_path / 'junk.rrd'
    proc = start_node('softsnap_gaits', 'rerun_logger', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', f'output:={output}', '-p', 'rate:=0.0', '-p', 'modules:=[yellow]')
    statuses = []  # the logger's /diagnostics statuses, as (level, message, values)
    ros_node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda msg: statuses.extend((s.level, s.message, {kv.key: kv.value for kv in s.values})
                                    for s in msg.status
                                    if s.name == 'softsnap/brittle_star/rerun_logger'), 50)
    _, poses = scene_poses()
    pubs = publishers(ros_node, ['yellow'])
    wait_matched(ros_node, pubs, proc)
    # Before any message: OK, recording to its file, every topic at 0.
    assert ros_node.spin_until(lambda: statuses, timeout=20.0), proc.output()
    level, message, values = statuses[0]
    assert level == DiagnosticStatus.OK and message == f'recording to {output}', statuses[0]
    assert values[f'{NS}/model/shape/predicted'] == '0' and values['messages logged (count)'] == '0'
    good = serialize_message(robot_shape('predicted', 0, ['yellow'], {'yellow'}, poses))
    length = CableLength(cable_length=0.19)
    stamp(length.header, STAMP0)
    # rclpy publishes bytes as they are: a serialised message, or anything else.
    pubs['predicted'].publish(good[:len(good) // 2])
    pubs['predicted'].publish(b'\x00\x01\x00\x00' + b'\xff' * 40)
    pubs[('yellow', 'command')].publish(b'\x00\x01\x00\x00\x07')
    ros_node.spin_until(lambda: False, 0.5)
    pubs['predicted'].publish(good)
    pubs[('yellow', 'command')].publish(length)
    wait_for_rows(output, 'robot/yellow/predicted/spine', 1, ros_node)
    wait_for_rows(output, 'plots/cable_length_mm/yellow/commanded', 1, ros_node)
    assert proc.alive()
    # Its status counts what it took per topic, and what it could not log (WARN).
    predicted, command = f'{NS}/model/shape/predicted', f'{NS}/yellow/cable_length/command'
    assert ros_node.spin_until(lambda: statuses and statuses[-1][2].get(predicted) == '3'
                               and statuses[-1][2].get(command) == '2', timeout=20.0), statuses
    level, message, values = statuses[-1]
    assert level == DiagnosticStatus.WARN and 'not logged' in message, statuses[-1]
    assert values['messages not logged (count)'] == '3', values
    assert values['messages logged (count)'] == '2', values
    assert values[f'{NS}/model/shape/commanded'] == '0' and values['output'] == str(output)
    assert proc.stop() == 0, log_of(proc)
    log = log_of(proc)
    assert 'message not logged' in log and 'model/shape/predicted' in log, log
    rrd = read_rrd(output)
    assert rrd.times('robot/yellow/predicted/spine') == [STAMP0]
    np.testing.assert_allclose(rrd.scalars('plots/cable_length_mm/yellow/commanded'), [190.0])


def test_a_module_the_model_has_no_length_of_yet_is_not_an_error(
        tmp_path, start_node, ros_node, read_rrd):
    """The model sends an empty-angles placeholder for a module no driver reports (the
    README's pip-only example runs one driver): regression, it was logged every 5 s as
    'blue predicted shape not logged: expected 1 hole offsets, got 12'."""
    output = tmp_path / 'placeholder.rrd'
    proc = start_node('softsnap_gaits', 'rerun_logger', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', f'output:={output}', '-p', 'scene:=brittle_star', '-p', 'rate:=0.0')
    _, poses = scene_poses()
    pubs = publishers(ros_node, [])
    wait_matched(ros_node, pubs, proc)
    for tick in range(5):
        msg = robot_shape('predicted', tick, ['yellow', 'blue'], set(), poses)
        msg.modules[1].angles = []       # blue: the model's placeholder
        pubs['predicted'].publish(msg)
    wait_for_rows(output, 'robot/yellow/predicted/spine', 5, ros_node)
    assert proc.stop() == 0, log_of(proc)
    assert 'not logged' not in log_of(proc).replace('unchanged shapes not logged again', ''), (
        log_of(proc))
    rrd = read_rrd(output)
    assert not rrd.values('robot/blue/predicted/spine', 'LineStrips3D:strips')
