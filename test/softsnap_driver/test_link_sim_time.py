"""ModuleLink with a simulated module time (docs/safety.md, "Simulated time"), no ROS.

The module runs on a simulated clock that goes at a chosen factor of the wall clock, or
stands still (a paused or dead simulator): the firmware's motion follows it, and the
link is given it as its ``motion_clock``, as the driver node does with ``use_sim_time``.
Stall detection must follow the module's time; the link's own timeouts (stale commands,
stop confirmation, offline) must run on the wall clock whatever the simulated time does.
"""
import math
import threading
import time

from softsnap_driver.firmware import Faults, SimModule
from softsnap_driver.link import ModuleLink
from softsnap_driver.link_config import LinkConfig
from softsnap_driver.sim_module import SimServer

from test_link import CAL, Log, last, wait_for


class SimTime:
    """Seconds of a simulated time running at `factor` x the wall clock (0: stopped)."""

    def __init__(self, factor: float = 1.0):
        self._lock = threading.Lock()
        self._base, self._since, self._factor = 0.0, time.monotonic(), factor

    def __call__(self) -> float:
        with self._lock:
            return self._base + self._factor * (time.monotonic() - self._since)

    def set_factor(self, factor: float) -> None:
        with self._lock:
            now = time.monotonic()
            self._base += self._factor * (now - self._since)
            self._since, self._factor = now, factor


def start(sim_time, faults=None, use_motion_clock=True, **overrides):
    server = SimServer(SimModule(faults=faults, start_time=sim_time()), clock=sim_time)
    server.start()
    values = dict(host='127.0.0.1', port=server.port, calibration=CAL, pwm_power=255,
                  poll_period_s=0.02, command_timeout_s=0.0, request_timeout_s=0.3,
                  max_backoff_s=0.2)
    values.update(overrides)
    reports, log = [], Log()
    link = ModuleLink(LinkConfig(**values), reports.append, log,
                      motion_clock=sim_time if use_motion_clock else None)
    link.reports, link.log = reports, log
    link.start()
    return server, link


def test_a_simulation_slower_than_real_time_is_not_a_stall():
    # 2 % of real time at PWM 25 (~1000 counts/s of module time): ~20 counts per wall
    # second, under STALL_PROGRESS_COUNTS per 0.2 s of wall time, far over it per 0.2 s
    # of the module's time.
    results, moves = {}, {}
    for use_motion_clock in (True, False):
        sim_time = SimTime(0.02)
        server, link = start(sim_time, use_motion_clock=use_motion_clock,
                             stall_timeout_s=0.2, pwm_power=25)
        try:
            link.command(0.118)
            time.sleep(2.5)
            results[use_motion_clock] = last(link).counters.stalls_detected
            with server.lock:
                moved = server.module.encoder_count
        finally:
            link.stop()
            server.stop()
        moves[use_motion_clock] = moved
    assert moves[True] > 20, moves      # the winch did turn, slowly
    assert results[True] == 0, results
    # The control: timed on the wall clock, the same slow simulation looks stalled.
    assert results[False] >= 1, (results, moves)


def test_a_stopped_simulated_time_freezes_stall_detection_but_not_the_watchdog():
    sim_time = SimTime(1.0)
    # A jammed winch: stall detection must fire, but only as the module's time runs.
    server, link = start(sim_time, faults=Faults(stall_after_s=0.0, stall_duration_s=math.inf),
                         stall_timeout_s=0.3, command_timeout_s=1.0)
    try:
        assert wait_for(lambda: last(link).online, 5.0)
        sim_time.set_factor(0.0)                     # the simulator pauses
        link.command(0.15)
        time.sleep(2.5)                              # 8 stall timeouts of wall time
        state = last(link)
        assert state.counters.stalls_detected == 0, state
        # The stale-command watchdog ran on the wall clock: the module was stopped and the
        # stop confirmed (the count holds still while the simulated time stands still).
        assert state.counters.stale_stops == 1, state
        assert wait_for(lambda: 'stop confirmed' in link.log.text()
                        and '(stale command stream)' in link.log.text(), 5.0), link.log.text()
        assert last(link).counters.stops_unconfirmed == 0
        ok, message = link.request('stop')           # a stop service call is confirmed too
        assert ok and 'confirmed' in message, message
        # The simulation runs again with a jammed winch: the stall is found in its time.
        sim_time.set_factor(1.0)
        link.command(0.14)
        assert wait_for(lambda: last(link).counters.stalls_detected >= 1, 5.0), last(link)
        # A dead simulator: the link finds the module offline on the wall clock.
        sim_time.set_factor(0.0)
        server.stop()
        assert wait_for(lambda: not last(link).online, 10.0), last(link)
    finally:
        link.stop()
        server.stop()
