"""A 50-module robot through the whole demo graph (issue 37).

Before, 30 or more modules never started (one simulator process per module outran
localhost-only discovery). Here a generated 50-module snake runs: every module seen end
to end, no command lost by the nodes' own counts, a handful of processes, well under
3 GiB. Start-up time and latency are figures of benchmarks/scaling_bench.py, not of a
test (they depend on what else the machine runs).
"""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from test_demo import run_demo

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_a_fifty_module_snake_runs_through_the_whole_graph(tmp_path):
    scene = tmp_path / 'snake50.yaml'
    subprocess.run([sys.executable, '-m', 'softsnap_gaits.scene_generator', 'snake', '50',
                    '-o', str(scene)], check=True, capture_output=True, timeout=120)
    out = run_demo('--scene', str(scene), '--seconds', '6', '--no-rerun', '--no-bag', '--json',
                   '--run-dir', str(tmp_path / 'run'), timeout=400)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    summary = json.loads(out.stdout[out.stdout.index('\n{') + 1:])
    assert summary['started'] and summary['observer_streams'] == 'robot'
    modules = summary['modules']
    assert len(modules) == 50
    not_seen = {m: s['not_observed'] for m, s in modules.items() if s['not_observed']}
    assert not not_seen, not_seen
    for name, s in modules.items():
        assert s['commanded_shapes'] and s['predicted_shapes'], name
        assert s['commands_sent'] and s['commands_sent'] > 0, name
        assert s['commands_lost'] == 0, (name, s['commands_sent'], s['driver_received'])
        assert s['driver_refused'] == 0, name
    processes = summary['processes']
    # One shared simulator, the driver container, model, gait, robot_state (no recorder or bag).
    assert set(processes) == {'sim_modules', 'driver_container', 'model_node', 'gait_node',
                              'robot_state'}
    assert sum(p['rss_mib'] for p in processes.values()) < 3 * 1024
