"""End to end: the demo runs a whole simulated robot for a few seconds in separate processes."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.mark.parametrize('scene', ['brittle_star'])
def test_demo_runs_the_robot_and_records_it(scene, tmp_path, read_rrd):
    run_dir = tmp_path / 'run'
    proc = subprocess.run(
        [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', scene, '--seconds', '4',
         '--run-dir', str(run_dir), '--json'],
        capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
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
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'no_such_robot' in proc.stderr


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
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)


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
