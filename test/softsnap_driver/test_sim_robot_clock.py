"""sim_robot's simulation clock handed to its listener (the node's /clock), no ROS."""
from __future__ import annotations

import argparse
import math
import threading

import numpy as np
import pytest

from softsnap_driver.sim_robot import SimRobot, SimRobotError, build_simulation
from softsnap_driver.sim_robot_runner import OPTIONS, check_options
from softsnap_model.scene import load_scene


def _robot(**kwargs) -> SimRobot:
    scene = load_scene('gripper')
    return SimRobot(scene, build_simulation(scene, links_per_segment=1), **kwargs)


def test_the_clock_is_handed_out_at_its_rate_of_simulated_time_after_each_step():
    robot = _robot(clock_rate_hz=100.0)
    times = []

    def listener(t):
        # Never a time the firmware has not reached: the step is done when it is called,
        # and the time handed out is the clock tick that step reached.
        assert t <= robot.clock() < t + robot.control_period_s
        times.append(t)

    stop = threading.Event()
    # Unpaced, until 0.5 s of simulated time (then stop from the listener itself).
    robot.clock_listener = lambda t: (listener(t), stop.set() if t >= 0.5 - 1e-9 else None)
    robot.run(stop, time_factor=0.0)
    assert robot.fault is None, robot.fault
    # Every multiple of 10 ms, each once: an exact grid whatever the control period.
    assert np.allclose(times, np.arange(1, 51) * 0.01, atol=1e-12), times


def test_a_slower_clock_rate_skips_nothing_and_a_faster_one_gives_every_step():
    for rate in (10.0, 1000.0):
        robot = _robot(clock_rate_hz=rate)
        # Over 1 s: every tick of a slow clock; one per control step of a fast one.
        expected = 10 if rate == 10.0 else math.ceil(1.0 / robot.control_period_s - 1e-9)
        times = []
        stop = threading.Event()

        def listener(t, times=times, stop=stop):
            times.append(t)
            if t >= 1.0 - 1e-9:
                stop.set()

        robot.clock_listener = listener
        robot.run(stop, time_factor=0.0)
        assert len(times) == expected, (rate, len(times))


@pytest.mark.parametrize('rate', [0.0, 0.5, 2000.0, float('nan')])
def test_a_bad_clock_rate_is_refused_with_the_range(rate):
    values = {name: default for name, (_kind, default, _text) in OPTIONS.items()}
    with pytest.raises(SimRobotError, match=r'clock_rate_hz must be in \[1, 1000\]'):
        check_options(argparse.Namespace(**{**values, 'clock_rate_hz': rate}))
