"""sim_robot's simulation clock handed to its listener (the node's /clock), no ROS."""
from __future__ import annotations

import argparse
import threading

import numpy as np
import pytest

from softsnap_driver.sim_robot import (OPTIONS, SimRobot, SimRobotError, build_simulation,
                                       check_options)
from softsnap_model.scene import load_scene


def _robot(**kwargs) -> SimRobot:
    scene = load_scene('gripper')
    return SimRobot(scene, build_simulation(scene, links_per_segment=1), **kwargs)


def test_the_clock_is_handed_out_at_its_rate_of_simulated_time_after_each_step():
    robot = _robot(clock_rate_hz=100.0)
    times = []

    def listener(t):
        # Never a time the firmware has not reached: the step is done when it is called.
        assert robot.clock() == t
        times.append(t)

    stop = threading.Event()
    # Unpaced, until 0.5 s of simulated time (then stop from the listener itself).
    robot.clock_listener = lambda t: (listener(t), stop.set() if t >= 0.5 else None)
    robot.run(stop, time_factor=0.0)
    assert robot.fault is None, robot.fault
    times = np.array(times)
    assert len(times) == 50 and np.all(np.diff(times) > 0)
    # Each is the first control step at or after a multiple of 10 ms (4 ms steps).
    steps = times / robot.control_period_s
    assert np.allclose(steps, np.round(steps), atol=1e-9)
    ticks = np.arange(1, 51) * 0.01
    assert np.all(times >= ticks - 1e-12) and np.all(times < ticks + robot.control_period_s)


def test_a_slower_clock_rate_skips_nothing_and_a_faster_one_gives_every_step():
    for rate, expected in ((10.0, 10), (1000.0, 250)):   # over 1 s: 250 steps of 4 ms
        robot = _robot(clock_rate_hz=rate)
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
