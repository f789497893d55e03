"""ModuleLink (the driver's worker) against a simulated module over loopback, no ROS."""
import math
import time

import pytest

from softsnap_driver.core import CableCalibration
from softsnap_driver.firmware import DEADBAND_COUNTS, Faults
from softsnap_driver.link import ModuleLink
from softsnap_driver.link_config import LinkConfig
from softsnap_driver.link_report import NeedsCalibration
from softsnap_driver.protocol import ModuleClient

CAL = CableCalibration(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.080)


class Log:
    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(('info', text))

    def warning(self, text):
        self.lines.append(('warning', text))

    def error(self, text):
        self.lines.append(('error', text))

    def text(self):
        return '\n'.join(line for _, line in self.lines)


@pytest.fixture
def link_to():
    links = []

    def start(server, **overrides):
        values = dict(host='127.0.0.1', port=server.port, calibration=CAL, pwm_power=255,
                      poll_period_s=0.02, command_timeout_s=0.0, request_timeout_s=0.3,
                      max_backoff_s=0.2)
        values.update(overrides)
        reports = []
        log = Log()
        link = ModuleLink(LinkConfig(**values), reports.append, log)
        link.reports, link.log = reports, log
        link.start()
        links.append(link)
        return link

    yield start
    for link in links:
        link.stop()


def wait_for(predicate, timeout=5.0):
    deadline = time.monotonic() + timeout
    while True:
        try:
            if predicate():
                return True
        except (IndexError, AttributeError, TypeError):
            pass  # no report yet
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)


def last(link):
    return link.reports[-1]


def targets(server):
    with server.lock:
        return [r.target for r in server.module.received_targets]


def test_tracks_a_changing_command_within_the_deadband(sim_server, link_to):
    server = sim_server()
    link = link_to(server)
    deadband_m = (DEADBAND_COUNTS + 0.5) / CAL.counts_per_mm / 1000   # + rounding to a count
    for length in (0.19, 0.15, 0.17, 0.125):
        link.command(length)
        assert wait_for(lambda: last(link).fresh and abs(last(link).measured_length_m - length) <= deadband_m + 1e-6)
    assert targets(server)[-1] == CAL.command(0.125).count


def test_commands_coalesce_latest_wins(sim_server, link_to):
    server = sim_server(Faults(delay_probability=1.0, delay_s=0.05))
    link = link_to(server)
    for i in range(200):
        link.command(0.198 - i * 0.0003, stamp_ns=1000 + i)
    final = CAL.command(0.198 - 199 * 0.0003).count
    assert wait_for(lambda: targets(server) and targets(server)[-1] == final)
    assert len(targets(server)) < 20        # not 200 requests queued up
    # Its own counts: every command received, each acknowledged target sent once, and
    # the stamp of the latest command (what a sender matches its sent count against).
    assert wait_for(lambda: last(link).counters.targets_sent == len(targets(server)))
    report = last(link)
    assert report.counters.commands_received == 200 and report.last_command_stamp_ns == 1199
    assert report.counters.commands_refused == 0


def test_nothing_beyond_the_range_reaches_the_module(sim_server, link_to):
    server = sim_server()
    link = link_to(server)
    for length in (0.117, 0.199, 0.15):             # within clamp_margin_m: clamped
        link.command(length)
        time.sleep(0.03)
    # Non-physical: refused and counted, never clamped and sent. 0.0 is a default-constructed
    # CableLength (regression: it was clamped to full contraction and sent).
    for bad in (0.0, -0.0, -1.0, 0.5, 0.112, 0.2041, 1e9, -1e9, math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError):
            link.command(bad)
    assert wait_for(lambda: targets(server) and targets(server)[-1] == CAL.command(0.15).count)
    time.sleep(0.1)
    low, high = CAL.count_range
    assert all(low <= t <= high for t in targets(server))
    assert targets(server) == [high, low, CAL.command(0.15).count]
    assert wait_for(lambda: last(link).counters.commands_refused == 11)
    assert last(link).counters.commands_clamped == 2
    assert 'command refused' in last(link).last_error and '-inf' in last(link).last_error
    link.command(0.16)                                                 # accepted as it is
    assert wait_for(lambda: last(link).last_error == '')
    assert math.isfinite(last(link).last_error_stamp)


def test_stale_stream_stops_where_it_is(sim_server, link_to):
    server = sim_server()
    link = link_to(server, command_timeout_s=0.3, pwm_power=40)   # slow motion
    link.command(0.118)
    assert wait_for(lambda: last(link).counters.stale_stops == 1, 3.0)
    assert wait_for(lambda: 'stop confirmed' in link.log.text())
    with server.lock:
        assert server.module.target == server.module.encoder_count   # reach
        assert 0 < server.module.encoder_count < CAL.command(0.118).count - 100
    assert 'no command' in last(link).last_error
    assert any('no command' in text for level, text in link.log.lines if level == 'warning')
    assert 'stop sent' in link.log.text() and 'stop confirmed' in link.log.text()
    time.sleep(0.5)
    assert last(link).counters.stale_stops == 1        # once per stream
    link.command(0.19)                                 # a new stream moves again
    assert wait_for(lambda: targets(server)[-1] == CAL.command(0.19).count)


def test_offline_backoff_and_recovery(sim_server, link_to):
    server = sim_server(Faults(outage_after_s=0.5, outage_duration_s=1.5))
    link = link_to(server, request_timeout_s=0.1)
    assert wait_for(lambda: not last(link).online, 3.0)
    assert last(link).counters.request_failures >= 3
    assert 'offline' in link.log.text()
    offline_attempts = server.connections
    link.command(0.17)                                 # queued while offline
    assert wait_for(lambda: last(link).online and last(link).fresh, 5.0)
    assert 'answers again' in link.log.text()
    assert wait_for(lambda: targets(server) and targets(server)[-1] == CAL.command(0.17).count)
    # last_error clears once the module answers normally; its time is kept.
    assert wait_for(lambda: last(link).fresh and last(link).last_error == '')
    assert 0 < time.monotonic() - last(link).last_error_stamp < 10
    # Backoff: far fewer attempts than one per poll period during 1.5 s.
    assert offline_attempts < 1.5 / 0.02 / 2


def test_reboot_is_reported_and_the_module_held_until_calibrate(sim_server, link_to):
    server = sim_server(Faults(reboot_after_s=1.0, reboot_downtime_s=0.2))
    link = link_to(server)
    link.command(0.16)
    count = CAL.command(0.16).count
    assert wait_for(lambda: last(link).status and abs(last(link).status.encoder_count - count) <= 30, 3)
    assert wait_for(lambda: last(link).counters.reboots_detected == 1, 4.0)
    report = last(link)
    assert not report.calibrated and math.isnan(report.measured_length_m)
    assert 'reboot' in report.last_error
    assert any('reboot' in text for level, text in link.log.lines if level == 'warning')
    sent_before = len(targets(server))
    with pytest.raises(NeedsCalibration):
        link.command(0.15)
    time.sleep(0.3)
    assert len(targets(server)) == sent_before          # old target not re-sent
    with server.lock:
        assert server.module.target == server.module.encoder_count == 0   # held
    ok, message = link.request('calibrate')
    assert ok and 'calibrated' in message
    link.command(0.15)
    assert wait_for(lambda: targets(server)[-1] == CAL.command(0.15).count)
    assert last(link).counters.reboots_detected == 1


def test_services_pause_resume_stop_calibrate(sim_server, link_to):
    server = sim_server()
    link = link_to(server, pwm_power=60)
    assert link.request('pause') == (True, 'paused: module paused=True')
    assert server.module.paused
    ok, _ = link.request('resume')
    assert ok and not server.module.paused
    link.command(0.118)
    assert wait_for(lambda: last(link).status.encoder_count > 500)
    ok, message = link.request('stop')
    assert ok and message.startswith('stopped at count')
    with server.lock:
        assert server.module.target == server.module.encoder_count
    with pytest.raises(ValueError):
        link.request('explode')


def test_service_on_a_dead_module_fails_with_reason(free_port, link_to):
    class Dead:
        port = free_port

    link = link_to(Dead(), request_timeout_s=0.1)
    ok, message = link.request('pause')
    assert not ok and 'refused' in message


def test_random_faults_are_survived_and_counted(sim_server, link_to):
    server = sim_server(Faults(drop_probability=0.15, garbage_probability=0.15,
                               delay_probability=0.1, delay_s=0.4, seed=11))
    link = link_to(server, request_timeout_s=0.2, offline_after_failures=20)
    deadband_m = (DEADBAND_COUNTS + 0.5) / CAL.counts_per_mm / 1000   # + rounding to a count
    for length in (0.17, 0.13):
        link.command(length)
        assert wait_for(lambda: last(link).fresh
                        and abs(last(link).measured_length_m - length) <= deadband_m + 1e-6, 8.0)
    assert last(link).counters.request_failures > 0
    assert set(server.fault_counts) >= {'drop', 'garbage'}
    assert link._thread.is_alive()
    assert last(link).counters.reboots_detected == 0


def test_stall_is_detected_reported_and_stopped(sim_server, link_to):
    server = sim_server(Faults(stall_after_s=0.0, stall_duration_s=math.inf))
    link = link_to(server, stall_timeout_s=0.4)
    link.command(0.15)
    assert wait_for(lambda: 'stalled' in last(link).last_error, 3.0)
    assert any('stalled' in text for level, text in link.log.lines if level == 'warning')
    assert last(link).counters.stalls_detected >= 1
    assert wait_for(lambda: '(stalled motor): module holds' in link.log.text())
    with server.lock:
        assert server.module.target == server.module.encoder_count == 0    # reach: motor off
        server.module.faults.stall_duration_s = 0.0                        # unjammed
    link.command(0.16)                                                     # a new target moves
    assert wait_for(lambda: last(link).status.encoder_count > 1000, 3.0)


def test_slow_but_moving_is_not_a_stall(sim_server, link_to):
    server = sim_server()
    link = link_to(server, stall_timeout_s=0.2, pwm_power=25)              # ~1000 counts/s
    link.command(0.118)
    time.sleep(1.0)
    assert 'stall' not in last(link).last_error
    with server.lock:
        assert server.module.target == CAL.command(0.118).count


def test_stop_sends_reach_on_shutdown(sim_server):
    server = sim_server()
    config = LinkConfig(host='127.0.0.1', port=server.port, calibration=CAL, pwm_power=40,
                        poll_period_s=0.02, command_timeout_s=0.0)
    reports = []
    link = ModuleLink(config, reports.append, Log())
    link.start()
    link.command(0.118)
    assert wait_for(lambda: len(targets(server)) == 1)
    time.sleep(0.1)
    link.stop()
    with server.lock:
        assert server.module.target == server.module.encoder_count != CAL.command(0.118).count


# -- safety: confirmed stops, internal errors, retry backoff ----------------------------

ABANDONED_M = 0.118                                    # full contraction: 7130 counts
ABANDONED = CAL.command(ABANDONED_M).count
SLOW_PWM = 40                                          # about 1650 counts/s in the sim


def module_state(server):
    with server.lock:
        return server.module.target, server.module.encoder_count


def count_when(link, predicate):
    """Encoder count in the last report before the first report matching predicate."""
    for before, report in zip(link.reports, link.reports[1:]):
        if predicate(report):
            return before.status.encoder_count
    raise AssertionError('no report matched')


def assert_stopped_near(server, decided_count, slack=800):
    target, count = module_state(server)
    assert target == count, (target, count)                       # reach took effect
    assert count < ABANDONED - 3000, count                        # never at the abandoned target
    assert abs(count - decided_count) <= slack, (count, decided_count)
    time.sleep(0.2)
    assert module_state(server) == (target, count)                # and it stays there


@pytest.mark.parametrize('lost', [1, 2])
def test_watchdog_stop_is_retried_until_confirmed_when_reach_is_lost(sim_server, link_to, lost):
    server = sim_server(Faults(drop_first_reach=lost))
    link = link_to(server, command_timeout_s=0.3, pwm_power=SLOW_PWM)
    link.command(ABANDONED_M)
    assert wait_for(lambda: last(link).counters.stale_stops == 1, 3.0)
    assert wait_for(lambda: 'stop confirmed' in link.log.text(), 3.0)
    assert server.fault_counts.get('drop_head') == lost           # the lost reach requests
    decided = count_when(link, lambda r: r.counters.stale_stops == 1)
    assert_stopped_near(server, decided)
    text = link.log.text()
    assert text.index('stop sent') < text.index('stop not yet confirmed') < text.index('stop confirmed')
    assert last(link).counters.stops_unconfirmed == 0
    assert link._thread.is_alive()


@pytest.mark.parametrize('lost', [1, 2])
def test_stop_service_is_confirmed_when_reach_is_lost(sim_server, link_to, lost):
    server = sim_server(Faults(drop_first_reach=lost))
    link = link_to(server, pwm_power=SLOW_PWM)
    link.command(ABANDONED_M)
    assert wait_for(lambda: last(link).status.encoder_count > 300)
    decided = last(link).status.encoder_count
    ok, message = link.request('stop')
    assert ok and message.startswith('stopped at count') and '(confirmed)' in message, message
    assert server.fault_counts.get('drop_head') == lost
    assert_stopped_near(server, decided)


def test_failed_stop_service_keeps_trying_and_the_watchdog_stays_armed(sim_server, link_to):
    server = sim_server()
    link = link_to(server, pwm_power=SLOW_PWM, command_timeout_s=5.0, request_timeout_s=0.1,
                   stop_deadline_s=0.3, offline_after_failures=50)
    link.command(ABANDONED_M)
    assert wait_for(lambda: last(link).status.encoder_count > 300)
    with server.lock:                                  # Wi-Fi gone for 0.8 s, motor still running
        server.module.faults.outage_after_s = server.module.since_start(server.clock())
        server.module.faults.outage_duration_s = 0.8
    ok, message = link.request('stop')
    assert not ok and 'stop NOT confirmed' in message and 'keeps trying' in message, message
    assert last(link).counters.stops_unconfirmed == 1
    assert 'stop NOT confirmed' in last(link).last_error
    # Not given up: once the module answers again the stop is confirmed.
    assert wait_for(lambda: 'stop confirmed' in link.log.text(), 5.0)
    target, count = module_state(server)
    assert target == count < ABANDONED - 1000
    assert wait_for(lambda: 'stop' not in last(link).last_error)
    assert last(link).counters.stale_stops == 0        # 5 s watchdog not needed, still armed
    assert link._stale_handled                         # disarmed only by the confirmed stop


@pytest.mark.parametrize('lost', [1, 2])
def test_stop_on_shutdown_is_confirmed_when_reach_is_lost(sim_server, lost):
    server = sim_server(Faults(drop_first_reach=lost))
    config = LinkConfig(host='127.0.0.1', port=server.port, calibration=CAL, pwm_power=SLOW_PWM,
                        poll_period_s=0.02, command_timeout_s=0.0)
    reports, log = [], Log()
    link = ModuleLink(config, reports.append, log)
    link.start()
    link.command(ABANDONED_M)
    assert wait_for(lambda: reports and reports[-1].status.encoder_count > 300)
    decided = reports[-1].status.encoder_count
    link.stop()
    assert not link._thread.is_alive()
    assert server.fault_counts.get('drop_head') == lost
    assert 'stop confirmed' in log.text() and '(shutdown)' in log.text()
    assert_stopped_near(server, decided)


class FailingClient(ModuleClient):
    """A real client whose status polls numbered in ``failing_polls`` (the third by
    default) raise an unexpected (non-module) error."""

    failing_polls = (3,)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.polls = 0

    def status(self, timeout_s=None):
        self.polls += 1
        if self.polls in self.failing_polls:
            raise RuntimeError('injected bug in the I/O loop')
        return super().status(timeout_s)


def test_unexpected_error_in_the_loop_is_counted_logged_and_survived(sim_server):
    server = sim_server()
    config = LinkConfig(host='127.0.0.1', port=server.port, calibration=CAL, pwm_power=SLOW_PWM,
                        poll_period_s=0.02, command_timeout_s=0.5)
    reports, log = [], Log()
    link = ModuleLink(config, reports.append, log, client_factory=FailingClient)
    link.start()
    try:
        link.command(ABANDONED_M)
        assert wait_for(lambda: reports[-1].counters.internal_errors == 1)
        errors = [text for level, text in log.lines if level == 'error']
        assert any('injected bug' in text and 'Traceback' in text for text in errors), errors
        assert any('internal error' in r.last_error for r in reports)
        assert link._thread.is_alive()
        polled = link._client.polls
        assert wait_for(lambda: link._client.polls > polled + 5)        # polling goes on
        # ... and so does the watchdog: the stream goes stale and the module is stopped.
        assert wait_for(lambda: reports[-1].counters.stale_stops == 1, 3.0)
        assert wait_for(lambda: 'stop confirmed' in log.text(), 3.0)
        target, count = module_state(server)
        assert target == count < ABANDONED - 3000
        assert wait_for(lambda: 'internal' not in reports[-1].last_error)
        assert reports[-1].counters.internal_errors == 1
    finally:
        link.stop()


def test_failed_set_is_retried_after_a_growing_pause(sim_server):
    server = sim_server(Faults(drop_probability=1.0))   # every connection closed unanswered
    config = LinkConfig(host='127.0.0.1', port=server.port, calibration=CAL, pwm_power=200,
                        poll_period_s=0.05, command_timeout_s=0.0, offline_after_failures=3,
                        max_backoff_s=0.4)
    reports, log = [], Log()
    link = ModuleLink(config, reports.append, log)
    link.command(0.15)                                   # queued before the first request
    link.start()
    try:
        assert wait_for(lambda: reports and reports[-1].counters.request_failures >= 6, 10.0)
    finally:
        link.stop()
    failures = [(r.stamp, r.last_error) for before, r in zip([None] + reports, reports)
                if r.counters.request_failures > (before.counters.request_failures if before else 0)]
    assert all('set failed' in error for _, error in failures[:3])   # the set, three times
    gaps = [b[0] - a[0] for a, b in zip(failures, failures[1:])]
    # Regression: three failures and "offline" within 1 ms. Now each pause doubles from the
    # poll period (0.05, 0.1, 0.2 s) up to max_backoff_s (0.4 s).
    for gap, pause in zip(gaps, (0.05, 0.1, 0.2, 0.4, 0.4)):
        assert gap >= pause * 0.95, gaps
    print(f'pauses between failed requests: {[round(g, 3) for g in gaps]} s')


def received(server):
    with server.lock:
        return list(server.module.received_targets)


def first_target_sent(server, link):
    """Command the first target (it goes out at once) and wait until the module has it;
    its count."""
    base = CAL.command(0.19).count
    link.command(CAL.length_m(base))
    assert wait_for(lambda: targets(server) == [base])
    return base


def test_small_target_change_waits_for_the_poll_slot_and_a_large_one_goes_at_once(sim_server, link_to):
    """Target deadband: a change within target_deadband_counts of the module's target is
    sent as the next poll, never earlier (by the sim's own stamps); a larger one at once."""
    poll = 2.0
    server = sim_server()
    link = link_to(server, poll_period_s=poll, target_deadband_counts=DEADBAND_COUNTS)
    base = first_target_sent(server, link)
    link.command(CAL.length_m(base + DEADBAND_COUNTS))  # within the deadband: waits
    assert wait_for(lambda: targets(server)[-1] == base + DEADBAND_COUNTS, 4 * poll)
    first, small = received(server)
    # Causal, so it holds under any load: the waiting target left one poll period after
    # the reply to the first set, as the poll (no status request went out in between).
    assert small.time_s - first.time_s >= poll
    far = base + 2 * DEADBAND_COUNTS + 1               # 31 counts from the module's target
    link.command(CAL.length_m(far))
    assert wait_for(lambda: targets(server)[-1] == far, 4 * poll)
    assert received(server)[-1].time_s - small.time_s < poll    # before the next poll slot
    assert wait_for(lambda: last(link).counters.targets_sent == 3)


def test_stream_of_small_steps_needs_fewer_requests_and_ends_on_its_final_target(sim_server, link_to):
    poll = 0.1
    server = sim_server()
    link = link_to(server, poll_period_s=poll)          # default deadband: the firmware's
    base = first_target_sent(server, link)
    steps, step = 75, 12                                # 50 Hz for 1.5 s, 0.13 mm a step
    for i in range(1, steps + 1):
        link.command(CAL.length_m(base + step * i), stamp_ns=i)
        time.sleep(0.02)
    final = base + step * steps
    assert wait_for(lambda: targets(server)[-1] == final)          # the final target, always
    sent = received(server)
    assert len(sent) <= steps // 2, [s.target for s in sent]
    # Every set either moved the target beyond the deadband or took a poll's place (sent
    # a poll period or more after the one before: causal, by the sim's stamps).
    for a, b in zip(sent, sent[1:]):
        assert abs(b.target - a.target) > DEADBAND_COUNTS or b.time_s - a.time_s >= poll, (a, b)
    deadband_m = (DEADBAND_COUNTS + 0.5) / CAL.counts_per_mm / 1000
    assert wait_for(lambda: last(link).fresh
                    and abs(last(link).measured_length_m - CAL.length_m(final)) <= deadband_m + 1e-9)
    assert last(link).counters.commands_received == steps + 1
    assert last(link).counters.targets_sent == len(received(server))


def test_a_waiting_target_is_derived_again_with_a_calibration_changed_meanwhile(sim_server, link_to):
    """A set derives its count with the calibration current when it goes out: a target
    waiting for its poll slot goes out in a changed calibration's counts, or is refused
    if the new range excludes it."""
    poll = 2.0
    server = sim_server()
    link = link_to(server, poll_period_s=poll)
    base = first_target_sent(server, link)
    length = CAL.length_m(base + DEADBAND_COUNTS)       # within the deadband: waits
    link.command(length)
    finer = CableCalibration(counts_per_mm=89.13 * 1.01, straight_length_m=0.198,
                             max_contraction_m=0.080)
    link.update_config(LinkConfig(**{**link.config.__dict__, 'calibration': finer}))
    want = finer.command(length).count
    assert want != CAL.command(length).count
    assert wait_for(lambda: targets(server)[-1] == want, 4 * poll), targets(server)
    # A range that no longer holds the waiting length: refused when it would go out.
    link.command(finer.length_m(want + 10))             # within the deadband: waits
    short = CableCalibration(counts_per_mm=89.13, straight_length_m=0.198,
                             max_contraction_m=0.001, clamp_margin_m=0.0)
    link.update_config(LinkConfig(**{**link.config.__dict__, 'calibration': short}))
    assert wait_for(lambda: last(link).counters.commands_refused == 1, 4 * poll)
    assert targets(server)[-1] == want
    assert 'command refused' in last(link).last_error


def test_zero_target_deadband_sends_every_changed_target(sim_server, link_to):
    server = sim_server()
    link = link_to(server, poll_period_s=2.0, target_deadband_counts=0)
    base = CAL.command(0.19).count
    for i in range(5):
        link.command(CAL.length_m(base + i))
        assert wait_for(lambda: targets(server)[-1:] == [base + i], 1.5)   # not the 2 s slot
    assert targets(server) == [base + i for i in range(5)]


def test_stop_is_not_delayed_by_a_waiting_target_and_drops_it(sim_server, link_to):
    poll = 1.5
    server = sim_server()
    link = link_to(server, poll_period_s=poll)
    base = first_target_sent(server, link)
    link.command(CAL.length_m(base + 10))               # waits for the poll slot
    time.sleep(0.3)                                     # (sent by now without the deadband)
    ok, message = link.request('stop')
    confirmed_at = time.monotonic()                     # the sim's clock too
    assert ok and 'confirmed' in message, message
    assert confirmed_at < received(server)[0].time_s + poll   # before the waiting target's slot
    time.sleep(poll + 0.3)
    assert targets(server) == [base]                    # the stop won: never sent after it
    with server.lock:
        assert server.module.target == server.module.encoder_count   # held where it stopped
