"""End to end: the demo runs a robot in MuJoCo (--physics, sim_robot) and records it."""
import json
from pathlib import Path

import pytest

from test_demo import run_demo

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_demo_with_physics_runs_the_gripper_on_sim_robot(tmp_path, read_rrd):
    run_dir = tmp_path / 'run'
    proc = run_demo('--scene', 'gripper', '--physics', '--seconds', '5', '--run-dir', str(run_dir),
                    '--json', timeout=360)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index('{'):])
    modules = ('front_left', 'back_left', 'back_right', 'front_right')
    assert set(summary['modules']) == set(modules)
    # One sim_robot instead of four sim_modules, one driver_container for the four
    # drivers; every process stopped on SIGINT.
    assert set(summary['exit_codes']) == {'sim_robot', 'model_node', 'gait_node', 'rerun_logger',
                                          'bag_recorder', 'driver_container', 'robot_state'}
    assert all(code in (0, -2) for code in summary['exit_codes'].values()), summary['exit_codes']
    for name, m in summary['modules'].items():
        assert m['online'] and m['commands_lost'] == 0 and m['driver_targets_sent'] > 5, (name, m)
        assert m['predicted_shapes'], (name, m)
    physics = summary['physics']
    assert physics['gait'] == 'grasp' and physics['real_time_factor'] > 0.0
    # Every node ran on sim_robot's /clock: --seconds, the command rate and the gait's
    # cycles are simulated time, whatever the real-time factor of this loaded machine.
    assert summary['sim_time'] and summary['seconds'] == pytest.approx(5.0, abs=0.3)
    for name, m in summary['modules'].items():
        # At most the gait's 50 Hz of simulated time; a gait node starved by this loaded
        # machine misses some /clock steps and ticks (rcl timers skip missed periods).
        assert 20.0 < m['command_rate_hz'] <= 50.5, (name, m)
    # The gait's cycles took its period each in simulated time (stamps of its phase
    # messages). With both cores busy the observer may take only part of the window's
    # phases (seen: 0.5 of 5.2 s under two CPU hogs), but the gait is never fast or slow.
    assert physics['gait_seconds'] > 0.2, physics
    assert physics['gait_cycles'] == pytest.approx(
        physics['gait_seconds'] / physics['gait_period_s'], abs=0.02), physics
    # Simulated against predicted shapes, every module (rib-centre RMS, mm).
    for name in modules:
        error = physics['shape_error_mm'][name]
        assert error is not None and error['n'] > 5, (name, error)
        assert 0.0 <= error['mean'] <= error['max'] < 200.0, (name, error)
        # The grasp holds its winches still for seconds: snapshots with the winch at rest.
        assert error['settled_n'] > 0 and 0.0 <= error['settled_mean'] <= error['max'], (name, error)
    # The gripper hangs from a fixed connector: it does not travel; its ball is observed
    # and the first grasp judged (held or not is the physics' answer, not the test's).
    assert physics['base_travel']['distance_mm'] < 1.0, physics['base_travel']
    assert physics['payload_travel'] is not None
    grasp = physics['payload_first_grasp']
    assert grasp is not None and isinstance(grasp['held'], bool), physics
    # The recording: simulated shapes beside commanded and predicted ones, and the robot
    # frame's pose in the world (a Transform3D on 'robot').
    rec = read_rrd(run_dir / 'gripper.rrd')
    for module in modules:
        for source in ('commanded', 'predicted', 'simulated'):
            spines = rec.values(f'robot/{module}/{source}/spine', 'LineStrips3D:strips')
            assert len(spines) >= 3, (module, source)
            assert len(spines[-1][0]) == 12
    translations = rec.values('robot', 'Transform3D:translation')
    assert len(translations) >= 3
    assert translations[-1][0][2] == pytest.approx(0.4, abs=0.05)   # the connector, 0.4 m up
    # The bag holds the simulation's own topics too, decodable from the embedded schemas.
    from mcap_ros2.reader import read_ros2_messages
    mcap_files = sorted(Path(summary['bag']).glob('*.mcap'))
    assert len(mcap_files) == 1, summary['bag']
    simulated, poses = 0, []
    for m in read_ros2_messages(str(mcap_files[0]), topics=['/gripper/model/shape/simulated',
                                                             '/gripper/sim/base_pose']):
        if m.channel.topic.endswith('simulated'):
            simulated += 1
            assert {s.source for s in m.ros_msg.modules} == {'simulated'}
            assert all(len(s.rib_centers) == 12 for s in m.ros_msg.modules)
        else:
            poses.append(m.ros_msg.pose.position.z)
    assert simulated > 5 and len(poses) > 5
    assert poses[-1] == pytest.approx(0.4, abs=0.05)
