"""End to end: the demo runs a whole simulated robot for a few seconds in separate processes."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def demo_env():
    """The test session's environment without its ROS_DOMAIN_ID: each demo picks its own
    (its default behaviour), so it never shares a domain with another test's nodes."""
    env = dict(os.environ)
    env.pop('ROS_DOMAIN_ID', None)
    return env


@pytest.mark.parametrize('scene', ['brittle_star'])
def test_demo_runs_the_robot_and_records_it(scene, tmp_path, read_rrd):
    run_dir = tmp_path / 'run'
    proc = subprocess.run(
        [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', scene, '--seconds', '4',
         '--run-dir', str(run_dir), '--json'],
        capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL, env=demo_env())
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index('{'):])
    assert summary['scene'] == scene
    assert set(summary['modules']) == {'yellow', 'blue', 'green', 'red', 'orange'}
    for name, m in summary['modules'].items():
        # 50 Hz gait for ~4 s; on a loaded 2-core machine allow a slower timer.
        assert m['commands_received'] > 100, (name, m)
        assert m['messages_lost'] == 0, (name, m)
        assert m['measured_lengths'] > 20, (name, m)  # drivers poll the simulated modules
        assert m['commanded_shapes'] > 5 and m['predicted_shapes'] > 5, (name, m)
        assert m['online'], (name, m)
        assert 3.0 < m['battery_v'] < 4.3, (name, m)
        assert m['tip_error_mm_mean'] >= 0.0 and m['tip_error_mm_max'] < 400.0, (name, m)
    assert summary['model']['solves'] > 10
    # Every process stopped on SIGINT (no kill, no crash, no orphan).
    assert all(code in (0, -2) for code in summary['exit_codes'].values()), summary['exit_codes']
    assert len(summary['exit_codes']) == 5 * 2 + 3
    recording = run_dir / f'{scene}.rrd'
    assert summary['recording'] == str(recording.resolve())
    assert recording.stat().st_size > 10_000
    rec = read_rrd(recording)  # also checks the file was closed properly (footer)
    for module in summary['modules']:
        for source in ('commanded', 'predicted'):
            spines = rec.values(f'robot/{module}/{source}/spine', 'LineStrips3D:strips')
            assert len(spines) >= 3, (module, source)
            # 12 rib centres, in metres, within a module length of the base.
            points = spines[-1][0]
            assert len(points) == 12
            assert max(abs(c) for p in points for c in p) < 0.25
        assert len(rec.scalars(f'plots/cable_length_mm/{module}/commanded')) >= 3


def test_demo_reports_a_bad_scene(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'softsnap_gaits.demo', '--scene', 'no_such_robot',
                           '--seconds', '1', '--run-dir', str(tmp_path)],
                          capture_output=True, text=True, timeout=60, env=demo_env())
    assert proc.returncode == 2
    assert 'no_such_robot' in proc.stderr
    assert 'SoftSnap demo' not in proc.stdout  # no table


def test_demo_reports_a_bad_scene_file(tmp_path):
    scene = tmp_path / 'broken.yaml'
    scene.write_text('name: broken\nmodules: [{name: a, threading: [R9]}]\n')
    proc = subprocess.run([sys.executable, '-m', 'softsnap_gaits.demo', '--scene', str(scene),
                           '--seconds', '1', '--run-dir', str(tmp_path / 'run')],
                          capture_output=True, text=True, timeout=60, env=demo_env())
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert 'broken.yaml' in proc.stderr
    assert 'SoftSnap demo' not in proc.stdout


def gripper_scene_on_ports(tmp_path, base: int, **module_fields):
    """The gripper scene as a file whose modules' ports are base, base + 1, ..."""
    import yaml

    from softsnap_model.scene import load_scene
    scene = yaml.safe_load(load_scene('gripper').path.read_text())
    for i, module in enumerate(scene['modules']):
        module.update(port=base + i, **module_fields)
    path = tmp_path / 'gripper_here.yaml'
    path.write_text(yaml.safe_dump(scene))
    return path


def test_a_port_in_use_stops_the_demo_with_the_log_and_no_table(tmp_path, slot_port):
    import socket
    # Something else listens on the first module's port; the demo is told to use the
    # scene's fixed ports (--scene-ports), so that module cannot start. (The scene's
    # ports are this session's own, so no other run on the machine is disturbed.)
    base = slot_port(4)
    scene = gripper_scene_on_ports(tmp_path, base)
    with socket.socket() as squatter:
        squatter.bind(('127.0.0.1', base))
        squatter.listen(1)
        proc = subprocess.run(
            [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', str(scene), '--seconds', '2',
             '--scene-ports', '--no-rerun', '--run-dir', str(tmp_path / 'run')],
            capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL, env=demo_env())
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert 'sim_front_left exited early' in proc.stderr, proc.stderr[-3000:]
    assert f'127.0.0.1:{base}' in proc.stderr and 'Address already in use' in proc.stderr, \
        proc.stderr[-3000:]
    assert 'failed to start' in proc.stderr
    assert 'SoftSnap demo' not in proc.stdout and 'nan' not in proc.stdout.lower()
    assert demo_children(tmp_path / 'run') == []


def test_a_module_that_never_comes_online_stops_the_demo_with_what_is_missing(tmp_path, slot_port):
    # Real modules (--real) at loopback ports where nothing listens: the drivers run, the
    # modules never answer.
    path = gripper_scene_on_ports(tmp_path, slot_port(4), host='127.0.0.1')
    proc = subprocess.run(
        [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', str(path), '--real', '--seconds', '2',
         '--ready-timeout', '8', '--no-rerun', '--run-dir', str(tmp_path / 'run'), '--json'],
        capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL, env=demo_env())
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert 'did not start within 8 s' in proc.stderr
    assert 'front_left: ' in proc.stderr and 'module online' in proc.stderr, proc.stderr[-3000:]
    assert 'driver_front_left (still running); its last output' in proc.stderr
    assert 'SoftSnap demo' not in proc.stdout
    report = json.loads(proc.stdout[proc.stdout.index('{'):])
    assert report['started'] is False and set(report['not_seen']) == {
        'front_left', 'back_left', 'back_right', 'front_right'}
    assert demo_children(tmp_path / 'run') == []


def test_two_demos_at_once_both_report_real_numbers(tmp_path):
    runs = [tmp_path / 'a', tmp_path / 'b']
    demos = [subprocess.Popen(
        [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', 'gripper', '--seconds', '4',
         '--run-dir', str(run), '--json'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
        env=demo_env()) for run in runs]
    outputs = []
    try:
        for demo in demos:
            outputs.append(demo.communicate(timeout=280))
    finally:
        for demo in demos:
            demo.kill()
    summaries = []
    for demo, (out, err) in zip(demos, outputs):
        assert demo.returncode == 0, out[-2000:] + err[-3000:]
        summaries.append(json.loads(out[out.index('{'):]))
    assert summaries[0]['ros_domain_id'] != summaries[1]['ros_domain_id']
    for summary, run in zip(summaries, runs):
        # Real numbers: every module seen end to end (commands, measured lengths, shapes,
        # state), online on its own simulated module, with a battery voltage and a tip
        # error; the model solved; the recording has data. (How many messages the
        # observer took inside the window depends on the load: not judged here.)
        assert summary['started'] is True
        assert summary['model']['solves'] > 0
        for name, m in summary['modules'].items():
            assert m['not_observed'] == [], (name, m)
            assert m['online'] is True, (name, m)
            assert m['commands_received'] is not None and m['commanded_shapes'] > 0, (name, m)
            assert m['tip_error_mm_mean'] is not None and m['tip_error_mm_mean'] >= 0.0, (name, m)
            assert 3.0 < m['battery_v'] < 4.3, (name, m)
        assert (run / 'gripper.rrd').stat().st_size > 10_000


def test_a_module_the_observer_did_not_see_is_reported_as_not_observed(capsys):
    from types import SimpleNamespace

    from softsnap_gaits.demo import ModuleStats, print_summary, summarise
    seen, unseen = ModuleStats(), ModuleStats()
    seen.command_stamps_ns = [1_000_000_000 + i * 20_000_000 for i in range(51)]
    seen.command_lengths_m = [0.2] * 51
    seen.measured_stamps_ns = [1_000_000_000 + i * 50_000_000 for i in range(21)]
    seen.commanded_shapes = seen.predicted_shapes = 30
    # Running tip errors 1 and 3 mm: two predicted tips against one commanded tip.
    seen.commanded_tips = [(0, 0.2, np.array([0.0, 0.0]))]
    seen.predicted_tips = [(0, 0.2, np.array([1.0, 0.0])), (0, 0.2, np.array([3.0, 0.0]))]
    seen.tip_error_pairs = [(0, 0), (1, 0)]
    seen.solve_times_s = [1e-4]
    seen.state = SimpleNamespace(online=True, battery_voltage=4.05, request_failures=0)
    observer = SimpleNamespace(stats={'m1': seen, 'm2': unseen}, diagnostics=None,
                               _tip_mm=lambda tip: tip)   # stored shapes are tips already
    summary = summarise(SimpleNamespace(name='two'), observer, 1.0, None, {})
    m1, m2 = summary['modules']['m1'], summary['modules']['m2']
    assert m1['commands_received'] == 51 and m1['tip_error_mm_mean'] == 2.0 and m1['online'] is True
    assert m1['not_observed'] == []
    for key in ('commands_received', 'measured_lengths', 'commanded_shapes', 'predicted_shapes',
                'tip_error_mm_mean', 'online', 'battery_v', 'solve_time_us_mean'):
        assert m2[key] is None, (key, m2[key])
    assert set(m2['not_observed']) == {'gait commands', 'measured lengths', 'commanded shapes',
                                       'predicted shapes', 'driver state'}
    print_summary(summary)
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith('m2 '))
    assert 'nan' not in row.lower() and 'False' not in row
    assert row.split()[1:4] == ['-', '-', '0']  # cmds, Hz not observed; lost is DDS's own count
    assert 'm2: not observed' in out


def demo_children(run_dir):
    """Live processes started by the demo of this run (they carry its ROS_HOME)."""
    import psutil
    marker = str(run_dir / 'ros_home')
    found = []
    for proc in psutil.process_iter(['pid']):
        try:
            if proc.environ().get('ROS_HOME') == marker and proc.pid != os.getpid():
                found.append(proc)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    return found


def start_demo(run_dir, seconds='60'):
    return subprocess.Popen(
        [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', 'gripper', '--seconds', seconds,
         '--run-dir', str(run_dir), '--no-rerun'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
        env=demo_env())


def wait_for_children(run_dir, count, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = demo_children(run_dir)
        if len(children) >= count:
            return children
        time.sleep(0.2)
    raise AssertionError(f'demo started {len(demo_children(run_dir))} of {count} processes')


def test_ctrl_c_stops_every_process(tmp_path):
    run_dir = tmp_path / 'run'
    demo = start_demo(run_dir)
    try:
        wait_for_children(run_dir, 4 * 2 + 2)  # gripper: 4 sims + 4 drivers + model + gait
        time.sleep(2.0)  # let the gait run a little
        demo.send_signal(signal.SIGINT)
        out, err = demo.communicate(timeout=60)
    finally:
        demo.kill()
    assert demo.returncode == 130, err[-2000:]
    assert 'SoftSnap demo: gripper' in out  # the summary is still printed
    assert demo_children(run_dir) == []


def test_a_crashing_node_stops_the_demo_without_orphans(tmp_path):
    import psutil
    run_dir = tmp_path / 'run'
    demo = start_demo(run_dir)
    try:
        children = wait_for_children(run_dir, 4 * 2 + 2)
        model = next(p for p in children if 'model_node' in ' '.join(p.cmdline()))
        model.kill()  # SIGKILL: a crash, not a clean stop
        out, err = demo.communicate(timeout=60)
    finally:
        demo.kill()
    assert demo.returncode == 1
    assert 'model_node exited early' in err
    assert demo_children(run_dir) == []
    assert not psutil.pid_exists(model.pid) or model.status() == psutil.STATUS_ZOMBIE
