"""Nothing left running when the supervisor dies; every stop confirmed and reported.

Real demos and real signals: a running demo (10 processes: five simulated modules, the
drivers' container, model, gait, rerun logger, bag recorder) gets SIGKILL, SIGHUP or
SIGTERM; then no process of the robot may be alive, and every driver's last act must
have been a confirmed stop. The launch-file graph's Ctrl-C: test/softsnap_gaits/test_launch_ctrl_c.py. The measured times are printed
(``pytest -s``); the deadlines asserted are generous (loaded 2-core machine):
benchmarks/supervisor_death.py measures the "alive 5 s later" figure.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from softsnap_ros.processes import is_alive, stop_process_tree, tagged_env, tagged_processes

pytestmark = [pytest.mark.ros, pytest.mark.slow]

MODULES = ('yellow', 'blue', 'green', 'red', 'orange')
#: Generous bound for the robot's processes to be gone after the supervisor died (s).
GONE_WITHIN_S = 60.0


def _wait(predicate, timeout: float, step: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return bool(predicate())


def _start_demo(run_dir: Path, seconds: float = 600.0):
    env, tag = tagged_env(dict(os.environ))
    env.pop('ROS_DOMAIN_ID', None)   # its own slot, as a user's demo
    proc = subprocess.Popen([sys.executable, '-m', 'softsnap_gaits.demo', '--scene', 'brittle_star',
                             '--seconds', str(seconds), '--run-dir', str(run_dir), '--json'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL, env=env, start_new_session=True)
    return proc, tag


def _running(run_dir: Path, proc) -> bool:
    """The robot runs: the demo started its run (every module seen end to end) and the
    bag has taken its first second of the gait."""
    if proc.poll() is not None:
        raise AssertionError(f'demo ended early: {proc.returncode}')
    bag = run_dir / 'bag' / 'bag.mcap'
    return bag.exists() and bag.stat().st_size > 50_000


def _robot(tag: str, demo_pid: int) -> list:
    return [p for p in tagged_processes(tag) if p.pid != demo_pid]


def _last_stops(run_dir: Path) -> dict:
    """Module -> (confirmed, why) of each driver's last stop in the drivers' log: the
    shutdown's, or the watchdog's if the gait had stopped commanding a second before."""
    from softsnap_gaits.supervision import last_stop_outcomes
    return last_stop_outcomes((run_dir / 'driver_container.log').read_text(errors='replace'))


@pytest.mark.parametrize('sig', [signal.SIGKILL, signal.SIGHUP, signal.SIGTERM],
                         ids=['SIGKILL', 'SIGHUP', 'SIGTERM'])
def test_no_robot_process_outlives_the_demo(sig, tmp_path):
    run_dir = tmp_path / 'run'
    proc, tag = _start_demo(run_dir)
    try:
        assert _wait(lambda: _running(run_dir, proc), 240.0, 0.5), proc.stderr.read()[-3000:]
        robot = _robot(tag, proc.pid)
        names = sorted(' '.join(p.cmdline()[1:2]).rsplit('/', 1)[-1] for p in robot)
        # 5 sim_modules, driver_container, model_node, robot_state, gait_node, rerun_logger
        # and the bag recorder.
        assert len(robot) == 11, names
        os.kill(proc.pid, sig)
        killed_at = time.monotonic()
        out, err = proc.communicate(timeout=120)
        gone = _wait(lambda: not any(is_alive(p) for p in robot), GONE_WITHIN_S)
        seconds = time.monotonic() - killed_at
        alive = [p.pid for p in robot if is_alive(p)]
        print(f'\n{signal.Signals(sig).name} to the demo: robot processes gone after '
              f'{seconds:.2f} s (demo exit {proc.returncode})')
        assert gone, (alive, err[-3000:])
        last = _last_stops(run_dir)
        # Every driver's last act: a confirmed stop (the simulated modules serve until then).
        assert set(last) == set(MODULES) and all(ok for ok, _ in last.values()), last
        if sig == signal.SIGKILL:
            # (Which of the parent-death signal and the lifeline pipe reaches a node first
            # is a race; test_lifeline.py shows each on its own.)
            assert proc.returncode == -signal.SIGKILL
        else:   # an orderly stop of the whole graph, with its summary
            assert proc.returncode == 130, err[-3000:]
            summary = json.loads(out[out.index('{'):])
            assert summary['shutdown_problems'] == {}, summary['shutdown_problems']
            order = summary['shutdown_order']
            assert order[0] == 'gait_node' and order[1] == 'driver_container'
            assert set(order[2:]) == {f'sim_{m}' for m in MODULES} | {
                'model_node', 'robot_state', 'rerun_logger', 'bag_recorder'}
            print('seconds from each stage\'s SIGINT to the exit:', summary['shutdown_seconds'])
    finally:
        stop_process_tree(proc, tag, 15.0)


def test_a_normal_demo_confirms_every_stop(tmp_path):
    run_dir = tmp_path / 'run'
    proc, tag = _start_demo(run_dir, seconds=3.0)
    try:
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-3000:]
        summary = json.loads(out[out.index('{'):])
        assert summary['shutdown_problems'] == {}
        last = _last_stops(run_dir)
        assert set(last) == set(MODULES) and all(ok for ok, _ in last.values()), last
    finally:
        stop_process_tree(proc, tag, 15.0)
