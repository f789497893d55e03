"""ModuleLink at its edges (no ROS, a simulated module over loopback): shutdown budgets,
throttled warnings and errors, retries spaced by their backoff, heartbeats while offline,
a worker whose shutdown fails, reboots caught by speed alone, calibration that
is not a reboot, and the latest command winning over failed sets and unconfirmed stops."""
import math
import threading
import time

import pytest

from softsnap_driver.firmware import Faults
from softsnap_driver.link import ModuleLink
from softsnap_driver.link_config import LinkConfig
from softsnap_driver.link_report import NeedsCalibration
from softsnap_driver.protocol import ModuleClient

from test_link import ABANDONED_M, CAL, SLOW_PWM, FailingClient, targets, wait_for


class TimedLog:
    """A logger keeping (monotonic time, level, text) of every line."""

    def __init__(self):
        self.lines = []

    def _add(self, level, text):
        self.lines.append((time.monotonic(), level, text))

    def info(self, text):
        self._add('info', text)

    def warning(self, text):
        self._add('warning', text)

    def error(self, text):
        self._add('error', text)

    def text(self):
        return '\n'.join(text for _, _, text in self.lines)

    def count(self, part, level=None):
        return sum(part in text and (level is None or lvl == level) for _, lvl, text in self.lines)


def make_link(port, client_factory=ModuleClient, logger=None, report=None, **overrides):
    values = dict(host='127.0.0.1', port=port, calibration=CAL, pwm_power=255,
                  poll_period_s=0.02, command_timeout_s=0.0, request_timeout_s=0.2,
                  max_backoff_s=0.2)
    values.update(overrides)
    reports = []
    log = TimedLog() if logger is None else logger
    link = ModuleLink(LinkConfig(**values), reports.append if report is None else report, log,
                      client_factory=client_factory)
    link.reports, link.log = reports, log
    return link


@pytest.fixture
def links():
    made = []
    yield made
    for link in made:
        link.stop()


def started(links, *args, **kwargs):
    link = make_link(*args, **kwargs)
    links.append(link)
    link.start()
    return link


def test_a_worker_never_started_answers_requests_with_a_timeout_and_stops(free_port):
    link = make_link(free_port, request_timeout_s=0.1, stop_deadline_s=0.2)
    answer = []
    caller = threading.Thread(target=lambda: answer.append(link.request('pause')), daemon=True)
    caller.start()
    caller.join(5.0)
    assert not caller.is_alive(), 'request() waited for ever on a worker that never ran'
    ok, message = answer[0]
    assert not ok and 'no result within 1.4 s' in message
    link.stop()                                   # never started: nothing to join, no error
    assert link.shutdown_stop is None


def test_the_shutdown_budget_bounds_the_shutdown_stop(sim_server, links):
    # Every reach is lost: the shutdown stop cannot be confirmed and must end within the
    # budget given to stop(), not within the (longer) stop deadline.
    server = sim_server(Faults(drop_first_reach=10_000))
    link = make_link(server.port, pwm_power=SLOW_PWM, stop_deadline_s=1.0)
    link.start()
    link.command(ABANDONED_M)
    assert wait_for(lambda: targets(server))
    begin = time.monotonic()
    link.stop(timeout=0.4)
    assert time.monotonic() - begin <= 0.6
    link._thread.join(1.0)                   # (a loaded machine may need a moment more)
    assert not link._thread.is_alive()
    outcome = link.shutdown_stop
    # Its round ends at the budget (0.3 s of the 0.4 s), not at the 1 s stop deadline.
    assert outcome is not None and not outcome.confirmed and outcome.elapsed_s <= 0.6
    assert link.log.count('stop NOT confirmed') == 1
    assert '; still trying' not in link.log.text()          # the shutdown stop does not


def test_warnings_are_throttled_to_one_a_second_per_kind(free_port):
    link = make_link(free_port)
    for _ in range(3):
        with pytest.raises(ValueError):
            link.command(math.nan)
    assert link.log.count('command refused', 'warning') == 1
    time.sleep(1.05)
    with pytest.raises(ValueError):
        link.command(-1.0)
    assert link.log.count('command refused', 'warning') == 2
    link.command(0.117)                           # clamped: its own kind, warned at once
    assert link.log.count('clamped', 'warning') == 1


def test_an_unconfirmed_watchdog_stop_retries_after_backoff_and_counts_once(sim_server, links):
    server = sim_server(Faults(drop_first_reach=10_000))      # every reach lost
    link = started(links, server.port, pwm_power=SLOW_PWM, command_timeout_s=0.3,
                   stop_deadline_s=0.3, poll_period_s=0.05, max_backoff_s=0.4,
                   offline_after_failures=1000)
    link.command(ABANDONED_M)
    assert wait_for(lambda: link.log.count('stop NOT confirmed') >= 3, 8.0)
    report = link.reports[-1]
    assert report.counters.stale_stops == 1                   # one stale stream, one decision
    assert report.counters.stops_unconfirmed == 1             # one wanted stop, many rounds
    assert 'still trying' in report.last_error
    lines = link.log.lines
    ends = [t for t, _, text in lines if 'stop NOT confirmed' in text]
    starts = [t for t, _, text in lines if text.startswith('stop sent')]
    assert all('; still trying' in text for _, _, text in lines if 'stop NOT confirmed' in text)
    # Each round starts only after the failure backoff (at least one poll period).
    for end in ends[:-1]:
        following = min(t for t in starts if t > end)
        assert following - end >= 0.045, following - end
    # Within a round the reach retries pause (doubling from 20 ms): a handful, not a spin.
    attempts = [int(text.split('after ')[1].split(' reach')[0]) for _, _, text in lines
                if 'stop NOT confirmed' in text]
    assert all(2 <= n <= 8 for n in attempts), attempts


def test_reports_keep_coming_while_the_module_is_offline(free_port, links):
    link = started(links, free_port, poll_period_s=0.02, max_backoff_s=0.3,
                   offline_after_failures=2, request_timeout_s=0.1)
    assert wait_for(lambda: not link.reports[-1].online, 3.0)
    time.sleep(0.6)
    begin = time.monotonic() - 0.5
    recent = [r for r in link.reports if r.stamp >= begin]
    assert len(recent) >= 10                                  # heartbeats every poll period
    assert link.reports[-1].counters.internal_errors == 0
    assert link.log.count('answers again') == 0


class ExplodingReach(ModuleClient):
    def reach(self, timeout_s=None):
        raise RuntimeError('injected bug in reach')


def test_a_shutdown_that_raises_still_ends_the_worker(sim_server):
    server = sim_server()
    link = make_link(server.port, client_factory=ExplodingReach)
    link.start()
    link.command(0.15)
    assert wait_for(lambda: targets(server))
    link.stop(timeout=1.0)
    assert not link._thread.is_alive()
    assert link.log.count('shutdown failed', 'error') == 1


class FlakyStatus(FailingClient):
    """Polls 3 to 6 raise an unexpected (non-module) error."""

    failing_polls = range(3, 7)


def test_internal_errors_are_logged_once_per_period_and_reported_as_not_fresh(sim_server, links):
    server = sim_server()
    link = started(links, server.port, client_factory=FlakyStatus)
    assert wait_for(lambda: link.reports[-1].counters.internal_errors == 4, 5.0)
    assert wait_for(lambda: 'internal' not in link.reports[-1].last_error, 5.0)
    assert link.log.count('unexpected error', 'error') == 1
    for report in link.reports:
        if 'internal error' in report.last_error:
            assert not report.fresh                           # no new status came with it


def test_a_reboot_while_driven_home_is_caught_by_speed(sim_server, links):
    # Driven towards 0, the count reaching 0 is no reboot by itself; reaching it faster
    # than the motor can is. The first report after it is fresh, uncalibrated, with no
    # known target (encoder_target 0).
    server = sim_server(Faults(reboot_after_s=1000.0, reboot_downtime_s=0.0))   # moved below
    link = started(links, server.port, pwm_power=SLOW_PWM)
    link.command(ABANDONED_M)
    assert wait_for(lambda: link.reports[-1].status.encoder_count > 2000, 3.0)
    link.command(CAL.straight_length_m)                      # home: target 0
    assert wait_for(lambda: targets(server)[-1] == 0 and link.reports[-1].encoder_target == 0)
    with server.lock:                                        # the reboot, on its way home
        assert server.module.encoder_count > 1000
        server.module.faults.reboot_after_s = server.module.since_start(server.clock()) + 0.02
    assert wait_for(lambda: link.reports[-1].counters.reboots_detected == 1, 4.0)
    first = next(r for r in link.reports if not r.calibrated)
    assert first.fresh and first.encoder_target == 0 and math.isnan(first.target_length_m)
    assert 'faster than' in first.last_error, first.last_error
    assert link.log.count('answers again') == 0


def test_stall_detection_is_off_at_a_zero_timeout(sim_server, links):
    server = sim_server(Faults(stall_after_s=0.0, stall_duration_s=math.inf))
    link = started(links, server.port, stall_timeout_s=0.0)
    link.command(0.15)
    time.sleep(0.6)
    report = link.reports[-1]
    assert report.counters.stalls_detected == 0 and 'stall' not in report.last_error


def test_offline_exactly_after_the_configured_failures(free_port, links):
    link = started(links, free_port, offline_after_failures=3, max_backoff_s=0.05,
                   request_timeout_s=0.1)
    assert wait_for(lambda: not link.reports[-1].online, 3.0)
    first = next(r for r in link.reports if not r.online)
    assert first.counters.request_failures == 3


def test_an_unchanged_target_is_not_sent_again(sim_server, links):
    server = sim_server()
    link = started(links, server.port)
    link.command(0.15)
    assert wait_for(lambda: link.reports[-1].counters.targets_sent == 1)
    link.command(0.15)
    time.sleep(0.2)
    assert targets(server) == [CAL.command(0.15).count]
    assert link.reports[-1].counters.targets_sent == 1


def test_a_newer_command_wins_over_a_failed_set(sim_server, links):
    # Every reply comes too late: each set fails although the module applies it. A
    # command that arrives while a set is in flight must be the one sent next, not the
    # failed older one again.
    server = sim_server(Faults(delay_probability=1.0, delay_s=0.15))
    link = started(links, server.port, request_timeout_s=0.1, offline_after_failures=1000)
    link.command(0.17)
    assert wait_for(lambda: targets(server), 2.0)
    link.command(0.13)
    newer = CAL.command(0.13).count
    assert wait_for(lambda: targets(server)[-1] == newer, 3.0), targets(server)
    time.sleep(0.5)
    assert targets(server)[-1] == newer and CAL.command(0.17).count not in targets(server)[-2:]


def test_a_command_during_an_unconfirmed_stop_takes_over(sim_server, links):
    server = sim_server(Faults(drop_first_reach=10_000))
    link = started(links, server.port, pwm_power=SLOW_PWM, stop_deadline_s=0.4,
                   offline_after_failures=1000)
    link.command(ABANDONED_M)
    assert wait_for(lambda: targets(server))
    answer = []
    caller = threading.Thread(target=lambda: answer.append(link.request('stop')), daemon=True)
    caller.start()
    assert wait_for(lambda: link.log.count('stop sent') == 1)
    link.command(0.15)                                        # the sender takes control again
    caller.join(5.0)
    assert answer and not answer[0][0]
    assert wait_for(lambda: targets(server)[-1] == CAL.command(0.15).count, 3.0)
    time.sleep(0.3)
    assert link.log.count('stop sent') == 1                   # the stop is not wanted any more
    assert 'stop' not in link.reports[-1].last_error


def test_a_confirmed_stop_leaves_nothing_for_shutdown(sim_server):
    server = sim_server()
    link = make_link(server.port, pwm_power=SLOW_PWM)
    link.start()
    link.command(ABANDONED_M)
    assert wait_for(lambda: targets(server))
    ok, message = link.request('stop')
    assert ok, message
    link.stop()
    assert link.shutdown_stop is None
    assert link.log.count('stop sent') == 1


def test_calibrating_a_moved_module_is_not_a_reboot(sim_server, links):
    server = sim_server()
    link = started(links, server.port)
    link.command(0.16)
    count = CAL.command(0.16).count
    assert wait_for(lambda: abs(link.reports[-1].status.encoder_count - count) <= 30, 3.0)
    ok, message = link.request('calibrate')
    assert ok, message
    time.sleep(0.2)
    report = link.reports[-1]
    assert report.calibrated and report.counters.reboots_detected == 0
    assert abs(report.status.encoder_count) <= 30 and report.encoder_target == 0


def test_a_failed_calibration_leaves_a_rebooted_module_uncalibrated(sim_server, links):
    server = sim_server(Faults(reboot_after_s=0.8, reboot_downtime_s=0.1))
    link = started(links, server.port, request_timeout_s=0.1)
    link.command(0.16)
    assert wait_for(lambda: link.reports[-1].counters.reboots_detected == 1, 4.0)
    server.stop()                                              # and now it is gone
    ok, message = link.request('calibrate')
    assert not ok and message
    assert not link.reports[-1].calibrated
    with pytest.raises(NeedsCalibration):
        link.command(0.15)


def test_after_a_confirmed_stop_the_next_target_goes_at_once(sim_server, links):
    # A confirmed stop is no failure: it leaves no backoff behind, so the next command's
    # target goes out at once, not a poll period later. Its closing report repeats the
    # stop check's status and does not claim to be fresh.
    server = sim_server()
    link = started(links, server.port, pwm_power=SLOW_PWM, poll_period_s=1.0, max_backoff_s=2.0)
    link.command(ABANDONED_M)
    assert wait_for(lambda: targets(server))
    ok, message = link.request('stop')
    assert ok, message
    begin = time.monotonic()
    link.command(0.15)
    assert wait_for(lambda: targets(server)[-1] == CAL.command(0.15).count, 3.0)
    assert time.monotonic() - begin < 0.5
    for before, report in zip(link.reports, link.reports[1:]):
        if report.status is before.status:
            assert not report.fresh                   # nothing new came with it


def test_a_jammed_motor_stopped_before_its_stall_timeout_is_no_stall(sim_server, links):
    # The stop's own requests do not run the stall check: a jammed motor whose stop is
    # asked for at once and confirmed only after nine lost reach requests (1.3 s, past
    # the 1 s stall timeout) was stopped, not found stalled.
    server = sim_server(Faults(stall_after_s=0.0, stall_duration_s=math.inf,
                               drop_first_reach=9))
    link = started(links, server.port, stall_timeout_s=1.0, stop_deadline_s=3.0,
                   offline_after_failures=1000)
    link.command(0.15)
    assert wait_for(lambda: link.reports[-1].counters.targets_sent == 1)
    ok, message = link.request('stop')
    assert ok, message
    assert server.fault_counts.get('drop_head') == 9
    time.sleep(0.3)
    report = link.reports[-1]
    assert report.counters.stalls_detected == 0 and 'stall' not in report.last_error


def test_a_module_resting_at_its_deadband_is_no_stall(sim_server, links):
    # The firmware ends every move exactly its 30-count deadband short of the target:
    # resting there for longer than the stall timeout is arrival, not a stall.
    server = sim_server()
    link = started(links, server.port, stall_timeout_s=0.3)
    link.command(0.17)
    count = CAL.command(0.17).count
    assert wait_for(lambda: link.reports[-1].fresh
                    and abs(link.reports[-1].status.encoder_count - count) <= 30, 3.0)
    time.sleep(1.0)
    report = link.reports[-1]
    assert abs(report.status.encoder_count - count) == 30     # the firmware's own rest
    assert report.counters.stalls_detected == 0 and 'stall' not in report.last_error
