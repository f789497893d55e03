"""Driver diagnostics and BatteryState from link reports (thresholds of docs/diagnostics.md)."""
import dataclasses
import math

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import BatteryState

from softsnap_driver import diagnostics
from softsnap_driver.diagnostics import DriverHealth, battery_state, diagnostic_name
from softsnap_driver.link_report import Counters, LinkReport
from softsnap_driver.protocol import ModuleStatus


def report(stamp=100.0, online=True, calibrated=True, battery=4.0, counters=Counters(),
           last_error='', status=True):
    module_status = ModuleStatus(encoder_count=120, motor_power=200, encoder_errors=0,
                                 battery_voltage=battery, paused=False, mac='aa:bb') if status else None
    return LinkReport(stamp=stamp, fresh=True, online=online, calibrated=calibrated,
                      status=module_status, measured_length_m=0.19, target_length_m=0.19,
                      encoder_target=120, pwm_power=200, counters=counters, last_error=last_error)


def values(status):
    return {kv.key: kv.value for kv in status.values}


def test_name_follows_the_robot_namespace():
    assert diagnostic_name('/brittle_star', 'yellow') == 'softsnap/brittle_star/yellow/driver'
    assert diagnostic_name('/', 'm1') == 'softsnap/m1/driver'


def test_healthy_module_is_ok_with_its_values():
    status = DriverHealth('n', '127.0.0.1:80').status(report(), now_s=100.5)
    assert status.level == DiagnosticStatus.OK and status.message == 'ok'
    assert status.hardware_id == '127.0.0.1:80'
    v = values(status)
    assert v['battery voltage (V)'] == '4' and v['online'] == 'True'
    assert v['request failures (count)'] == '0'


@pytest.mark.parametrize('kwargs, level, text', [
    (dict(online=False), DiagnosticStatus.ERROR, 'offline'),
    (dict(calibrated=False), DiagnosticStatus.ERROR, 'calibrate'),
    (dict(battery=3.2), DiagnosticStatus.ERROR, 'battery 3.20 V below 3.3 V'),
    (dict(battery=3.4), DiagnosticStatus.WARN, 'battery 3.40 V below 3.5 V'),
    (dict(counters=Counters(stops_unconfirmed=1)), DiagnosticStatus.ERROR, 'not confirmed'),
    (dict(counters=Counters(internal_errors=2)), DiagnosticStatus.ERROR, '2 internal error'),
    (dict(counters=Counters(request_failures=1)), DiagnosticStatus.WARN, '1 failed request'),
    (dict(counters=Counters(reboots_detected=1)), DiagnosticStatus.WARN, 'reboot'),
    (dict(counters=Counters(stalls_detected=1)), DiagnosticStatus.WARN, 'stall'),
    (dict(last_error='timeout'), DiagnosticStatus.WARN, 'timeout'),
])
def test_levels_follow_the_documented_thresholds(kwargs, level, text):
    status = DriverHealth('n', 'h').status(report(**kwargs), now_s=100.0)
    assert status.level == level, status.message
    assert text in status.message


def test_an_event_stays_visible_for_the_recent_window_then_clears():
    health = DriverHealth('n', 'h')
    assert health.status(report(), 0.0).level == DiagnosticStatus.OK
    failed = Counters(request_failures=2)
    assert health.status(report(counters=failed), 1.0).level == DiagnosticStatus.WARN
    late = health.status(report(stamp=1.0 + diagnostics.RECENT_S - 0.5, counters=failed),
                         1.0 + diagnostics.RECENT_S - 0.5)
    assert late.level == DiagnosticStatus.WARN and '2 failed request(s)' in late.message
    cleared = health.status(report(stamp=1.0 + diagnostics.RECENT_S + 0.5, counters=failed),
                            1.0 + diagnostics.RECENT_S + 0.5)
    assert cleared.level == DiagnosticStatus.OK, cleared.message


def test_offline_then_back_flips_error_then_ok():
    health = DriverHealth('n', 'h')
    assert health.status(report(online=False, status=False), 1.0).level == DiagnosticStatus.ERROR
    assert health.status(report(stamp=2.0), 2.0).level == DiagnosticStatus.OK


def test_no_report_or_an_old_one_is_stale():
    health = DriverHealth('n', 'h')
    assert health.status(None, 0.0).level == DiagnosticStatus.STALE
    old = health.status(report(stamp=10.0), 10.0 + diagnostics.STALE_AFTER_S + 1.0)
    assert old.level == DiagnosticStatus.STALE and 'no report' in old.message


def test_battery_state_reports_the_voltage_and_nan_for_the_unknown():
    msg = battery_state(report(battery=3.87), 'yellow')
    assert msg.voltage == pytest.approx(3.87) and msg.present
    assert list(msg.cell_voltage) == [pytest.approx(3.87)]
    assert msg.power_supply_technology == BatteryState.POWER_SUPPLY_TECHNOLOGY_LION
    assert msg.design_capacity == pytest.approx(0.2)
    for name in ('current', 'charge', 'capacity', 'percentage', 'temperature'):
        assert math.isnan(getattr(msg, name)), name
    assert msg.location == 'yellow' and msg.serial_number == 'aa:bb'
    unknown = battery_state(None, 'yellow')
    assert math.isnan(unknown.voltage) and not unknown.present
    offline = battery_state(dataclasses.replace(report(), online=False), 'yellow')
    assert not offline.present
