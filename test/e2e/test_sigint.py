"""SIGINT (Ctrl-C, and how ros2 launch and the demo stop nodes) ends each process in 2 s.

Each process is started for real and caught mid-work: the gait node publishing, the
rerun logger recording a running gait, the simulated module (as a ROS node and as the
plain CLI) with a client connected that never sends its request (the server thread
waits on it). The measured times are printed (``pytest -s``) for the report.
"""
from __future__ import annotations

import os
import signal
import socket
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: The promise: every node exits within this long after SIGINT, s.
SIGINT_DEADLINE_S = 2.0


def sigint_exit_time(proc) -> float:
    """Send SIGINT to the process group and return the seconds until the process exited."""
    assert proc.alive(), proc.output()[-2000:]
    start = time.monotonic()
    os.killpg(proc.proc.pid, signal.SIGINT)
    try:
        proc.proc.wait(30)
    finally:
        elapsed = time.monotonic() - start
    return elapsed


def wait_output(proc, text, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in proc.output():
            return
        assert proc.alive(), proc.output()[-2000:]
        time.sleep(0.1)
    raise AssertionError(f'{text!r} not in output: {proc.output()[-2000:]}')


def test_gait_node_and_rerun_logger_stop_within_2_s_mid_work(start_node, ros_node, tmp_path):
    from softsnap_interfaces.msg import CableLength, ModuleShape
    ns = ['--ros-args', '-r', '__ns:=/sigint']
    gait = start_node('softsnap_gaits', 'gait_node', *ns, '-p', 'scene:=brittle_star',
                      '-p', 'rate:=100')
    # The model node turns the commands into shapes: the logger records 3D spines and ribs.
    model = start_node('softsnap_model', 'model_node', *ns, '-p', 'scene:=brittle_star')
    output = tmp_path / 'sigint.rrd'
    logger = start_node('softsnap_gaits', 'rerun_logger', *ns, '-p', 'scene:=brittle_star',
                        '-p', f'output:={output}', '-p', 'rate:=0')
    commands, shapes = [], []
    ros_node.create_subscription(CableLength, '/sigint/yellow/cable_length/command', commands.append, 100)
    ros_node.create_subscription(ModuleShape, '/sigint/yellow/shape/commanded', shapes.append, 100)
    assert ros_node.spin_until(lambda: len(commands) > 50 and len(shapes) > 20, 60), \
        gait.output()[-2000:] + model.output()[-2000:]
    wait_output(logger, 'recording')
    ros_node.spin_until(lambda: False, 3.0)  # let the logger record a while
    logger_s = sigint_exit_time(logger)
    gait_s = sigint_exit_time(gait)
    model.stop()
    print(f'\nSIGINT -> exit: rerun_logger {logger_s:.2f} s (recording '
          f'{output.stat().st_size // 1024} KiB), gait_node {gait_s:.2f} s')
    assert logger.proc.returncode == 0 and gait.proc.returncode == 0
    assert output.stat().st_size > 0
    assert logger_s < SIGINT_DEADLINE_S and gait_s < SIGINT_DEADLINE_S, (logger_s, gait_s)


@pytest.mark.parametrize('mode', ['ros', 'plain'])
def test_sim_module_stops_within_2_s_with_a_silent_client(mode, start_node, slot_port):
    port = slot_port()
    args = (['--ros-args', '-r', '__ns:=/sigint', '-r', '__node:=sim_silent', '-p', f'port:={port}']
            if mode == 'ros' else ['--port', str(port)])
    sim = start_node('softsnap_driver', 'sim_module', *args)
    wait_output(sim, f'127.0.0.1:{port}')
    with socket.create_connection(('127.0.0.1', port), timeout=5) as silent:
        time.sleep(0.3)  # the server thread is now waiting for this client's request
        elapsed = sigint_exit_time(sim)
        del silent
    print(f'\nSIGINT -> exit: sim_module ({mode}) {elapsed:.2f} s')
    assert sim.proc.returncode == 0, sim.output()[-2000:]
    assert 'stopped after' in sim.output()
    assert elapsed < SIGINT_DEADLINE_S, elapsed
