"""End to end: the demo runs a whole simulated robot for a few seconds in separate processes."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from softsnap_ros.processes import is_alive, stop_process_tree, tagged_env, tagged_processes

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: How long the runner may take to stop its nodes after SIGINT when a test ends, and
#: then each node left, before SIGKILL (s).
DEMO_STOP_TIMEOUT_S = 15.0


def demo_env():
    """The test session's environment without its ROS_DOMAIN_ID: each demo picks its own
    (its default behaviour), so it never shares a domain with another test's nodes."""
    env = dict(os.environ)
    env.pop('ROS_DOMAIN_ID', None)
    return env


class Demo:
    """The demo runner started by a test, and every process it starts.

    The runner puts each node in a session of its own (softsnap_gaits.demo.Process), so
    its process group does not hold them, and a runner that died (killed, or never
    reaching its own cleanup) leaves them reparented, out of its process tree. So the
    runner is started with a tag in its environment (softsnap_ros.processes.tagged_env), which
    every node inherits: stop() stops the runner, then every process still carrying the
    tag, whether the test passed or failed early.
    """

    def __init__(self, *args: str):
        env, self.tag = tagged_env(demo_env())
        self.popen = subprocess.Popen(
            [sys.executable, '-m', 'softsnap_gaits.demo', *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            stdin=subprocess.DEVNULL, env=env, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def returncode(self) -> int | None:
        return self.popen.returncode

    def communicate(self, timeout: float) -> tuple[str, str]:
        return self.popen.communicate(timeout=timeout)

    def processes(self) -> list:
        """The live processes the runner started (psutil.Process), wherever they are."""
        return [p for p in tagged_processes(self.tag) if p.pid != self.popen.pid]

    def stop(self) -> None:
        """No process of this demo left running: the runner gets SIGINT (it stops its
        nodes), then SIGKILL; then so does every process still carrying its tag."""
        try:
            stop_process_tree(self.popen, self.tag, DEMO_STOP_TIMEOUT_S)
        finally:
            for pipe in (self.popen.stdout, self.popen.stderr):
                if pipe is not None:
                    pipe.close()

    def __enter__(self) -> Demo:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def run_demo(*args: str, timeout: float) -> subprocess.CompletedProcess:
    """Like subprocess.run(capture_output=True, text=True) of the runner, but nothing it
    started outlives it (Demo.stop), also when it times out."""
    with Demo(*args) as demo:
        out, err = demo.communicate(timeout)
    return subprocess.CompletedProcess(demo.popen.args, demo.returncode, out, err)


@pytest.mark.parametrize('scene', ['brittle_star'])
def test_demo_runs_the_robot_and_records_it(scene, tmp_path, read_rrd):
    run_dir = tmp_path / 'run'
    proc = run_demo('--scene', scene, '--seconds', '4', '--run-dir', str(run_dir), '--json',
                    timeout=240)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index('{'):])
    assert summary['scene'] == scene
    assert set(summary['modules']) == {'yellow', 'blue', 'green', 'red', 'orange'}
    lengths_taken = summary['model']['lengths_taken']
    for name, m in summary['modules'].items():
        # Judged by the nodes' own counters over the same stretch of commands, not by what
        # the demo's observer managed to take (a starved observer is not a lost command).
        # 50 Hz gait for ~4 s; on a loaded 2-core machine allow a slower timer.
        assert m['commands_sent'] > 50, (name, m)
        # The stretch covers most of the run. Regression: with both cores busy the observer
        # fell seconds behind the 50 Hz streams and, the gait still publishing, never
        # caught up: 0.6-0.9 s of a 4 s run were counted (29 commands).
        assert m['counted_seconds'] > 0.5 * summary['seconds'], (name, m)
        # Reliable QoS, deep enough queues: the driver takes every command the gait sent.
        assert m['commands_lost'] == 0 and m['driver_received'] == m['commands_sent'], (name, m)
        assert m['driver_refused'] == 0 and m['driver_targets_sent'] > 5, (name, m)
        assert m['observer_shortfall'] == m['commands_sent'] - m['observer_commands'] >= 0, (name, m)
        # The model node took this module's commanded and measured lengths (its counts since
        # start, in its latest diagnostics, ~1 s old; drivers poll the simulated modules at
        # 10 Hz) and the observer saw both shapes.
        assert lengths_taken[name]['commanded'] > 50, (name, lengths_taken)
        assert lengths_taken[name]['measured'] > 20, (name, lengths_taken)
        assert m['commanded_shapes'] and m['predicted_shapes'], (name, m)
        assert m['online'], (name, m)
        assert 3.0 < m['battery_v'] < 4.3, (name, m)
        assert m['tip_error_mm_mean'] >= 0.0 and m['tip_error_mm_max'] < 400.0, (name, m)
    # Every process stopped on SIGINT (no kill, no crash, no orphan).
    assert all(code in (0, -2) for code in summary['exit_codes'].values()), summary['exit_codes']
    # Five simulated modules, one driver_container for the five drivers, model,
    # robot_state, gait, rerun, bag.
    assert len(summary['exit_codes']) == 5 + 1 + 5 and 'driver_container' in summary['exit_codes']
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
        # The run starts once rerun_logger reports messages from every topic it records,
        # so the recording spans the run. Regression: it had subscribed (the ROS graph
        # showed it) but the publishers found it up to 3 s later: a CI run's recording
        # had no commanded shape of a module, runs here only the last 1.6-2.4 s of 4.
        stamps = rec.times(f'plots/cable_length_mm/{module}/commanded')
        assert (stamps[-1] - stamps[0]) * 1e-9 > 0.8 * summary['seconds'], (module, stamps)
    check_demo_bag(run_dir / 'bag', summary)


def check_demo_bag(bag, summary):
    """The demo's ROS 2 bag: every topic of the run, decoded by mcap_ros2 from the file alone."""
    import warnings
    from collections import Counter
    import yaml
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)  # mcap_ros2 0.6's reader module
        from mcap_ros2.reader import read_ros2_messages
        decoded = list(read_ros2_messages(bag / 'bag.mcap'))
    assert summary['bag'] == str(bag.resolve())
    counts = Counter(m.channel.topic for m in decoded)
    assert summary['bag_messages'] == len(decoded)
    assert {t: n for t, n in summary['bag_topics'].items() if n} == dict(counts)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['storage_identifier'] == 'mcap' and meta['message_count'] == len(decoded)
    ns = f"/{summary['scene']}"
    for name, m in summary['modules'].items():
        # The recorder subscribes once it discovers a topic (0.5 s period): on a loaded
        # machine it may miss the first commands, not the run (exact counts: test_bag_ros).
        assert counts[f'{ns}/{name}/cable_length/command'] >= m['commands_sent'] * 0.5, name
        for topic in ('cable_length/measured', 'state', 'shape/commanded', 'shape/predicted'):
            assert counts[f'{ns}/{name}/{topic}'] > 0, (name, topic)
    for topic in ('gait/phase', 'model/diagnostics', 'model/shape/predicted'):
        assert counts[f'{ns}/{topic}'] > 0, topic
    assert counts['/rosout'] > 0 and '/parameter_events' not in counts
    states = [m.ros_msg for m in decoded if m.channel.topic == f'{ns}/yellow/state']
    assert states[-1].module == 'yellow' and states[-1].online
    # robot_state: TF as tf2_msgs/msg/TFMessage and the URDF, in the bag of the robot's
    # topics (read by mcap_ros2 from the schemas in the file).
    schemas = {m.channel.topic: m.schema.name for m in decoded}
    assert schemas['/tf'] == schemas['/tf_static'] == 'tf2_msgs/msg/TFMessage'
    frames = {t.child_frame_id for m in decoded if m.channel.topic == '/tf'
              for t in m.ros_msg.transforms}
    assert f"{summary['scene']}/yellow/rib_11" in frames
    urdf = [m.ros_msg.data for m in decoded if m.channel.topic == '/robot_description']
    assert urdf and urdf[-1].startswith('<?xml') and '<robot name=' in urdf[-1]
    assert counts['/joint_states'] > 0


def test_demo_reports_a_bad_scene(tmp_path):
    proc = run_demo('--scene', 'no_such_robot', '--seconds', '1', '--run-dir', str(tmp_path),
                    timeout=60)
    assert proc.returncode == 2
    assert 'no_such_robot' in proc.stderr
    assert 'SoftSnap demo' not in proc.stdout  # no table


def test_demo_reports_a_bad_scene_file(tmp_path):
    scene = tmp_path / 'broken.yaml'
    scene.write_text('name: broken\nmodules: [{name: a, threading: [R9]}]\n')
    proc = run_demo('--scene', str(scene), '--seconds', '1', '--run-dir', str(tmp_path / 'run'),
                    timeout=60)
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
        proc = run_demo('--scene', str(scene), '--seconds', '2', '--scene-ports', '--no-rerun',
                        '--run-dir', str(tmp_path / 'run'), timeout=240)
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
    proc = run_demo('--scene', str(path), '--real', '--seconds', '2', '--ready-timeout', '8',
                    '--no-rerun', '--run-dir', str(tmp_path / 'run'), '--json', timeout=240)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert 'did not start within 8 s' in proc.stderr
    assert 'front_left: ' in proc.stderr and 'module online' in proc.stderr, proc.stderr[-3000:]
    # The drivers' one process (driver_container), its log shown.
    assert 'driver_container (still running); its last output' in proc.stderr, proc.stderr[-3000:]
    assert 'SoftSnap demo' not in proc.stdout
    report = json.loads(proc.stdout[proc.stdout.index('{'):])
    assert report['started'] is False and set(report['not_seen']) == {
        'front_left', 'back_left', 'back_right', 'front_right'}
    assert demo_children(tmp_path / 'run') == []


def test_two_demos_at_once_both_report_real_numbers(tmp_path):
    # Two robots' slots, not their bags (test_demo_runs_the_robot_and_records_it checks
    # the bag): without the two recorders, 2 x 8 processes (4 sims, the drivers'
    # container, model, gait, rerun logger) share the 2 cores.
    runs = [tmp_path / 'a', tmp_path / 'b']
    demos = [Demo('--scene', 'gripper', '--seconds', '4', '--run-dir', str(run), '--json',
                  '--no-bag') for run in runs]
    outputs = []
    try:
        for demo in demos:
            outputs.append(demo.communicate(timeout=280))
    finally:
        for demo in demos:
            demo.stop()
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
            # Every module's command counters paired over most of the run, however far
            # behind the observer was (regression: none at all for a starved observer).
            assert m['not_observed'] == [], (name, m)
            assert m['counted_seconds'] > 0.5 * summary['seconds'], (name, m)
            assert m['online'] is True, (name, m)
            assert m['commands_lost'] == 0 and m['commanded_shapes'] > 0, (name, m)
            assert m['tip_error_mm_mean'] is not None and m['tip_error_mm_mean'] >= 0.0, (name, m)
            assert 3.0 < m['battery_v'] < 4.3, (name, m)
        assert (run / 'gripper.rrd').stat().st_size > 10_000


def test_a_module_the_observer_did_not_see_is_reported_as_not_observed(capsys):
    from types import SimpleNamespace

    import numpy as np

    from softsnap_gaits.demo import ModuleStats, print_summary, summarise
    seen, unseen = ModuleStats(), ModuleStats()
    seen.command_stamps_ns = [1_000_000_000 + i * 20_000_000 for i in range(51)]
    seen.command_lengths_m = [0.15] * 51
    seen.measured_stamps_ns = [1_000_000_000 + i * 50_000_000 for i in range(21)]
    seen.commanded_shapes = seen.predicted_shapes = 30
    # Tips as points (the observer's tip_mm below is the identity): errors 1 and 3 mm.
    seen.commanded_tips = [(0, 0.15, (0.0, 0.0, 0.0))]
    seen.predicted_tips = [(1, 0.15, (1.0, 0.0, 0.0)), (2, 0.15, (3.0, 0.0, 0.0))]
    seen.tip_error_pairs = [(0, 0), (1, 0)]
    seen.solve_times_s = [1e-4]
    seen.state = SimpleNamespace(online=True, battery_voltage=4.05, request_failures=0,
                                 commands_refused=0, targets_sent=7)
    observer = SimpleNamespace(stats={'m1': seen, 'm2': unseen}, diagnostics=None,
                               gait_sent={}, _tip_mm=np.asarray)
    summary = summarise(SimpleNamespace(name='two'), observer, 1.0, None, {})
    m1, m2 = summary['modules']['m1'], summary['modules']['m2']
    assert m1['commands_observed'] == 51 and m1['tip_error_mm_mean'] == 2.0 and m1['online'] is True
    assert m1['not_observed'] == ['command counters']  # no driver counts, no gait phases
    for key in ('commands_observed', 'commands_sent', 'driver_received', 'commands_lost',
                'observer_shortfall', 'measured_lengths', 'commanded_shapes', 'predicted_shapes',
                'tip_error_mm_mean', 'online', 'battery_v', 'solve_time_us_mean'):
        assert m2[key] is None, (key, m2[key])
    assert set(m2['not_observed']) == {'gait commands', 'measured lengths', 'commanded shapes',
                                       'predicted shapes', 'driver state', 'command counters'}
    print_summary(summary)
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith('m2 '))
    assert 'nan' not in row.lower() and 'False' not in row
    assert row.split()[1:7] == ['-'] * 6  # sent, rcvd, lost, seen, short, Hz: not observed
    assert 'm2: not observed' in out


def test_lost_is_what_the_gait_node_sent_and_the_driver_did_not_receive():
    from softsnap_gaits.demo import ModuleStats, commands_counted
    ms = 1_000_000
    # The gait node ticks every 20 ms; its phase at tick k says k + 1 commands sent so far.
    gait_sent = {(100 + 20 * k) * ms: {'m1': k + 1} for k in range(200)}
    s = ModuleStats()
    # Driver states (state stamp, commands received, stamp of the latest command): it had
    # 10 commands up to tick 10 (one lost before the run), then 88 of the 90 ticks up to 100.
    s.driver_counts = [(300 * ms, 10, 300 * ms), (1000 * ms, 30, 700 * ms),
                       (2200 * ms, 98, 2100 * ms), (3000 * ms, 98, 2100 * ms)]
    # The observer saw 74 commands of that stretch (it was starved) and some outside it.
    s.command_stamps_ns = [(100 + 20 * k) * ms for k in range(5, 85)] + [2500 * ms]
    window = (200 * ms, 2900 * ms)
    counted = commands_counted('m1', s, gait_sent, window)
    assert (counted.from_ns, counted.to_ns) == (300 * ms, 2100 * ms)
    assert counted.sent == 90 and counted.received == 88 and counted.lost == 2
    assert counted.observed == 74 and counted.observer_shortfall == 16
    # Driver states whose command stamps have no gait phase, or only one usable pair: unknown.
    assert commands_counted('m1', s, {}, window) is None
    assert commands_counted('m2', s, gait_sent, window) is None
    assert commands_counted('m1', s, gait_sent, (250 * ms, 350 * ms)) is None


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


def start_demo(run_dir, seconds='60') -> Demo:
    return Demo('--scene', 'gripper', '--seconds', seconds, '--run-dir', str(run_dir),
                '--no-rerun')


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
        # gripper: 4 sims + 1 driver_container + model + robot_state + gait + bag recorder
        wait_for_children(run_dir, 4 + 1 + 4)
        time.sleep(2.0)  # let the gait run a little
        demo.popen.send_signal(signal.SIGINT)
        out, err = demo.communicate(timeout=60)
    finally:
        demo.stop()
    assert demo.returncode == 130, out[-3000:] + err[-2000:]
    assert 'SoftSnap demo: gripper' in out  # the summary is still printed
    assert demo_children(run_dir) == []


def test_a_crashing_node_stops_the_demo_without_orphans(tmp_path):
    import psutil
    run_dir = tmp_path / 'run'
    demo = start_demo(run_dir)
    try:
        children = wait_for_children(run_dir, 4 + 1 + 4)
        model = next(p for p in children if 'model_node' in ' '.join(p.cmdline()))
        model.kill()  # SIGKILL: a crash, not a clean stop
        out, err = demo.communicate(timeout=60)
    finally:
        demo.stop()
    assert demo.returncode == 1
    assert 'model_node exited early' in err
    assert demo_children(run_dir) == []
    assert not psutil.pid_exists(model.pid) or model.status() == psutil.STATUS_ZOMBIE


def test_stop_leaves_no_process_of_a_runner_that_was_killed(tmp_path):
    """Regression: a test that failed before its SIGINT killed only the runner
    (Popen.kill()); its nodes, each in a session of its own, ran on, loaded the machine
    and broke later tests. Killed with SIGKILL, the runner cannot stop them itself."""
    run_dir = tmp_path / 'run'
    demo = start_demo(run_dir)
    try:
        # gripper: 4 sims + 1 driver_container + model + robot_state + gait + bag recorder
        children = wait_for_children(run_dir, 4 + 1 + 4)
        assert {p.pid for p in children} <= {p.pid for p in demo.processes()}
        os.kill(demo.pid, signal.SIGKILL)
        demo.popen.wait(60)
        demo.popen.kill()  # what the tests did before: nothing, once the runner is gone
        orphans = [p for p in children if is_alive(p)]
        # Precondition: the nodes outlived their runner (else this test proves nothing).
        assert orphans, 'every node exited with its runner'
    finally:
        demo.stop()
    assert [p.pid for p in orphans if is_alive(p)] == []
    # Looked up apart from the tag: no process with this run's ROS_HOME is left.
    assert demo_children(run_dir) == []
