"""`softsnap`, the command line for pip users, against a running robot over real DDS.

model_node, gait_node, a simulated module and its driver run as processes; every command
runs as its own process (`python -m softsnap_gaits.command_line`, what .venv/bin/softsnap
execs) and its YAML answer is checked against the core solver or the nodes' state.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml

from softsnap_model.forward import solve_forward
from softsnap_model.scene import load_scene

pytestmark = pytest.mark.ros

NS = '/brittle_star'
SCENE = load_scene('brittle_star')


def softsnap(env, *args, timeout=180):
    done = subprocess.run([sys.executable, '-m', 'softsnap_gaits.command_line', *args],
                          capture_output=True, text=True, timeout=timeout, env=env)
    return done.returncode, done.stdout, done.stderr


@pytest.fixture
def robot(start_node, slot_port):
    port = slot_port()
    nodes = [
        start_node('softsnap_model', 'model_node', '--ros-args', '-r', f'__ns:={NS}',
                   '-p', 'scene:=brittle_star'),
        start_node('softsnap_gaits', 'gait_node', '--ros-args', '-r', f'__ns:={NS}',
                   '-p', 'scene:=brittle_star', '-p', 'autostart:=false'),
        start_node('softsnap_driver', 'sim_module', '--ros-args', '-r', f'__ns:={NS}',
                   '-r', '__node:=sim_yellow', '-p', f'port:={port}'),
        start_node('softsnap_driver', 'driver_node', '--ros-args', '-r', f'__ns:={NS}',
                   '-r', '__node:=yellow_driver', '-p', 'module:=yellow', '-p', f'port:={port}',
                   '-p', f'straight_length_m:={SCENE.module("yellow").straight_length_mm / 1000.0}'),
    ]
    return start_node.env, nodes


def test_every_service_and_action_answers_from_the_command_line(robot):
    env, nodes = robot
    logs = lambda: '\n'.join(n.output()[-2000:] for n in nodes)  # noqa: E731
    yellow = SCENE.module('yellow')
    length_m = (yellow.straight_length_mm - 25.0) / 1000.0

    code, out, err = softsnap(env, 'forward', '--module', 'yellow', f'{{cable_length: {length_m}}}')
    assert code == 0, err + logs()
    answer = yaml.safe_load(out)
    reference = solve_forward(SCENE.skeleton, yellow.threading_mm, length_m * 1000.0)
    assert answer['success'] is True
    np.testing.assert_allclose(answer['angles'], reference.angles, atol=1e-9)
    assert len(answer['rib_centers']) == SCENE.skeleton.n_ribs
    assert answer['rib_centers'][-1]['x'] == pytest.approx(reference.rib_centers[-1][0] / 1000.0)

    target = [float(a) for a in reference.angles]
    code, out, err = softsnap(env, 'inverse', yaml.safe_dump({'target_angles': target},
                                                             default_flow_style=True))
    assert code == 0, err
    answer = yaml.safe_load(out)
    assert answer['success'] is True and answer['fit_error'] < 1e-3
    assert len(answer['best']['holes']) == SCENE.skeleton.n_ribs

    code, out, err = softsnap(env, 'design', yaml.safe_dump(
        {'target_angles': target, 'alternatives': 2}, default_flow_style=True))
    assert code == 0, err
    result = yaml.safe_load(out[out.index('result:'):])['result']
    assert result['success'] is True and result['fit_error'] < 1e-3

    code, out, err = softsnap(env, 'gait', 'set', 'walk', '--period', '4.0')
    assert code == 0, err
    assert "gait 'walk': period 4 s" in yaml.safe_load(out)['message']
    code, out, err = softsnap(env, 'gait', 'set', 'no_such_gait')
    assert code == 1 and yaml.safe_load(out)['success'] is False     # refused, with a reason
    assert yaml.safe_load(out)['message']
    code, out, err = softsnap(env, 'gait', 'start')
    assert code == 0, err
    code, out, err = softsnap(env, 'gait', 'pause')
    assert code == 0 and yaml.safe_load(out)['success'] is True, out + err

    for command in ('stop', 'calibrate'):
        code, out, err = softsnap(env, command, 'yellow')
        assert code == 0, out + err + logs()
        assert yaml.safe_load(out)['yellow']['success'] is True

    code, out, err = softsnap(env, 'call', f'{NS}/gait_node/resume', 'std_srvs/srv/Trigger')
    assert code == 0 and yaml.safe_load(out)['success'] is True, out + err


def test_a_bad_request_or_a_missing_service_is_one_clear_line(robot):
    env, _ = robot
    code, out, err = softsnap(env, 'forward', '{cable_lenght: 0.17}')
    assert code == 2 and 'no field' in err and 'cable_length' in err
    code, out, err = softsnap(env, '--robot', 'nobody_here', '--timeout', '3', 'gait', 'pause')
    assert code == 2 and 'not available after 3 s' in err
    code, out, err = softsnap(env, 'call', '/x', 'no_pkg/srv/Nope')
    assert code == 2 and 'unknown interface type' in err
