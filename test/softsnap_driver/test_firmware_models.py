"""The simulated module's motor, battery, time integration and faults, against figures
worked out here from their definitions (FACTS.md's firmware protocol, the GA12-N20's
numbers in MotorModel's fields) rather than read back from the code."""
from __future__ import annotations

import dataclasses
import math

import pytest

from softsnap_driver.firmware import (BOOST_COUNTS, DEADBAND_COUNTS, BatteryModel, Faults,
                                      MotorModel, SimModule)

SET = 'GET /?set={:08X}{:02X} HTTP/1.1\r\n\r\n'


def set_head(target: int, power: int) -> bytes:
    return SET.format(target & 0xFFFFFFFF, power).encode()


# -- the motor ---------------------------------------------------------------------------
def test_the_motor_model_is_frozen_and_checks_its_figures():
    with pytest.raises(dataclasses.FrozenInstanceError):
        MotorModel().min_pwm = 5
    for name in ('no_load_rpm', 'rated_voltage_v', 'counts_per_rev', 'stall_current_a'):
        for bad in (0.0, -1.0, math.nan, math.inf):
            with pytest.raises(ValueError, match=name):
                MotorModel(**{name: bad})
    for pwm in (0, 255):
        assert MotorModel(min_pwm=pwm).min_pwm == pwm       # both ends allowed
    for pwm in (-1, 256):
        with pytest.raises(ValueError, match='min_pwm'):
            MotorModel(min_pwm=pwm)


def test_winch_speed_and_current_from_the_motor_figures():
    motor = MotorModel()
    # 300 rpm x 2800 counts/rev = 14,000 counts/s unloaded at 6 V, full PWM; a quarter of
    # the stall torque as load takes a quarter of that speed.
    assert motor.speed_counts_per_s(255, 6.0) == pytest.approx(14000.0 * 0.75)
    assert motor.speed_counts_per_s(51, 3.0) == pytest.approx(14000.0 * 0.75 * 0.2 * 0.5)
    # The default drive starts at PWM 20: 19 does not turn the winch.
    assert motor.speed_counts_per_s(20, 6.0) > 0.0
    assert motor.speed_counts_per_s(19, 6.0) == 0.0
    # Current: no-load current plus the load's share of (stall - no-load), scaled by the
    # duty and the supply; stalled (or below the drive threshold) the whole stall current.
    assert motor.current_a(255, 6.0, False) == pytest.approx(0.06 + (0.75 - 0.06) * 0.25)
    assert motor.current_a(255, 6.0, True) == pytest.approx(0.75)
    assert motor.current_a(51, 3.0, True) == pytest.approx(0.75 * 0.2 * 0.5)
    # At the threshold itself the motor turns and draws its loaded current, not stall.
    assert motor.current_a(20, 6.0, False) == pytest.approx((0.06 + 0.69 * 0.25) * 20 / 255)
    assert motor.current_a(19, 6.0, False) == pytest.approx(0.75 * 19 / 255)


def test_open_circuit_voltage_falls_linearly_from_full_to_empty():
    battery = BatteryModel()
    assert battery.open_circuit_v(0.0) == pytest.approx(4.15)
    assert battery.open_circuit_v(300.0) == pytest.approx(4.15 - 0.85 * 0.5)
    assert battery.open_circuit_v(600.0) == pytest.approx(3.3)
    assert battery.open_circuit_v(900.0) == pytest.approx(3.3)     # held at empty
    assert battery.open_circuit_v(-5.0) == pytest.approx(4.15)


# -- the module's state and clock -------------------------------------------------------------
def test_a_new_module_boots_at_time_zero_and_counts_its_requests():
    module = SimModule()
    assert module.start_time == 0.0 and module.time == 0.0 and module.requests == 0
    module.handle_request(b'GET /?status HTTP/1.1\r\n\r\n', 0.01)
    module.handle_request(b'GET /?status HTTP/1.1\r\n\r\n', 0.02)
    assert module.requests == 2
    for bad in (0.0, -0.05, math.nan, math.inf):
        with pytest.raises(ValueError, match='power_sample_period_s'):
            SimModule(power_sample_period_s=bad)


def test_the_first_power_sample_comes_one_period_after_boot():
    module = SimModule(start_time=10.0)
    module.advance_to(10.049)
    assert module.power_history[-1] == 0          # nothing sampled yet
    module.advance_to(10.051)
    # One idle sample: the terminal voltage times the ESP32's current, in 0.1 mW.
    assert module.power_history[-2] == 0
    idle_w = (4.15 - 0.12 * 0.25) * 0.12
    assert module.power_history[-1] == pytest.approx(idle_w / 1e-4, abs=2)


def test_a_battery_sample_due_at_the_very_instant_is_taken_then():
    """Samples are taken every 50 ms: advancing exactly to a sample time takes it (the
    status's battery is the mean of the samples, so a missed one shows)."""
    module = SimModule(power_sample_period_s=0.07)     # no power sample due at 0.05 s
    module.advance_to(0.05)
    assert len(module.battery_samples) == 2
    assert module.battery_voltage == pytest.approx((4.15 + (4.15 - 0.12 * 0.25)) / 2)


def test_reboot_without_a_time_reboots_now_and_counts_once():
    module = SimModule()
    module.handle_request(set_head(500, 200), 0.0)
    module.advance_to(1.0)
    module.reboot()
    assert module.booted_at == 1.0 and module.reboots == 1
    assert module.target == 0 and module.encoder_count == 0


def test_a_status_request_leaves_a_moving_target_alone():
    module = SimModule()
    module.handle_request(set_head(3000, 200), 0.0)
    module.handle_request(b'GET /?status HTTP/1.1\r\n\r\n', 0.05)
    assert module.target == 3000 and module.moving()


def test_one_long_advance_drives_the_winch_into_the_deadband_exactly():
    """Through the boost band and into the deadband in one call, landing exactly on its
    edge (the bang-bang drive stops where |target - current| reaches 30 counts)."""
    module = SimModule()
    module.handle_request(set_head(3000, 255), 0.0)
    module.advance_to(5.0)
    assert module.position == float(3000 - DEADBAND_COUNTS)
    assert not module.moving()
    module.handle_request(set_head(-2000, 255), 5.0)
    module.advance_to(10.0)
    assert module.position == float(-2000 + DEADBAND_COUNTS)


def test_regime_changes_inside_a_sample_interval_lose_no_time():
    """The boosted run ends 60 counts short at 2940 / 10500 s = 0.28 s; the last 30
    counts, at the cell's voltage, take about 4 ms more: by 0.29 s (inside the same 50 ms
    sample interval) the winch is in the deadband."""
    module = SimModule()
    module.handle_request(set_head(3000, 255), 0.0)
    module.advance_to(0.279)
    assert module.position == pytest.approx(0.279 * 10500.0)
    module.advance_to(0.29)
    assert module.position == float(3000 - DEADBAND_COUNTS)


@pytest.mark.parametrize('power', [37, 101, 163, 201, 254])
def test_every_stop_lands_exactly_on_the_deadband_edge(power):
    """Speeds that are not round numbers: each move still ends exactly 30 counts short
    of its target (no rounding residue left to creep on)."""
    module = SimModule()
    now = 0.0
    for target in (1234, 95, 4321, -777, 3001, 2899, -1):
        assert abs(target - module.position) > BOOST_COUNTS
        module.handle_request(set_head(target, power), now)
        now += 5.0
        module.advance_to(now)
        assert abs(target - module.position) == DEADBAND_COUNTS, (target, module.position)


def test_the_boost_pin_drives_the_motor_at_rated_voltage_only_beyond_60_counts():
    """Beyond BOOST_COUNTS the motor runs from the boosted 6 V, within it from the cell:
    the last counts before the deadband go slower by the cell's voltage over 6 V."""
    motor = MotorModel()
    module = SimModule(motor=motor)
    module.handle_request(set_head(2000, 200), 0.0)
    module.advance_to(0.02)
    far = module.position / 0.02                       # counts/s while boosted
    assert far == pytest.approx(motor.speed_counts_per_s(200, 6.0), rel=1e-9)
    near = SimModule(motor=motor)
    near.handle_request(set_head(BOOST_COUNTS, 200), 0.0)   # within the boost band
    near.advance_to(0.001)
    slow = near.position / 0.001
    assert slow < 0.75 * far                           # a ~4 V cell against 6 V
    assert slow == pytest.approx(far * near._terminal_voltage() / 6.0, rel=0.02)


def test_an_empty_cell_at_zero_volts_does_not_break_the_boosted_drive():
    battery = BatteryModel(empty_v=0.0)
    module = SimModule(battery=battery)
    module.charge_used_mah = 10 * battery.capacity_mah      # flat: 0 V at the terminal
    module.handle_request(set_head(3000, 200), 0.0)
    module.advance_to(1.0)                                  # no division by zero
    assert module.battery_voltage == 0.0 and math.isfinite(module.position)


def test_a_power_sample_beyond_the_four_hex_digits_is_held_at_ffff():
    """A big motor stalled at full drive draws more than 6.5535 W from the cell: the
    sample is clamped to FFFF and the history stays 1024 hex characters."""
    motor = MotorModel(stall_current_a=3.0)
    module = SimModule(motor=motor, faults=Faults(stall_after_s=0.0))
    module.handle_request(set_head(5000, 255), 0.0)
    module.advance_to(0.5)
    assert max(module.power_history) == 0xFFFF
    import json
    power = json.loads(module.status_json())['power']
    assert len(power) == 1024 and 'FFFF' in power


# -- faults -------------------------------------------------------------------------------
def test_fault_windows_and_probabilities():
    assert Faults(outage_after_s=0.0).outage_duration_s == 0.0
    assert SimModule(faults=Faults(outage_after_s=0.0)).fault_for_request(0.0) is None
    module = SimModule(faults=Faults(outage_after_s=1.0, outage_duration_s=1.0))
    assert module.fault_for_request(0.999) is None
    assert module.fault_for_request(1.0) == 'outage'        # the window starts at its time
    assert module.fault_for_request(2.0) is None
    for name in ('delay_s', 'reboot_after_s', 'stall_after_s', 'outage_duration_s'):
        with pytest.raises(ValueError, match=name):
            Faults(**{name: -1.0})
    # Drop and garbage share one draw: with 0.5 each, every request is one or the other.
    module = SimModule(faults=Faults(drop_probability=0.5, garbage_probability=0.5, seed=3))
    faults = [module.fault_for_request(0.01 * i) for i in range(200)]
    assert set(faults) == {'drop', 'garbage'}
    assert 60 < faults.count('drop') < 140


def _garbage_kind(reply: bytes, good: bytes) -> str:
    if not reply.startswith(b'HTTP/1.1 '):
        return 'prefix' if good.startswith(reply) else 'bytes'
    if good.startswith(reply) and reply != good:
        return 'prefix'
    if reply.startswith(b'HTTP/1.1 500'):
        return '500'
    body = reply.split(b'\r\n\r\n', 1)[1]
    if b'"m_current":"12ab"' in body:
        return 'string count'
    if body.startswith(b'not json at all'):
        return 'not json'
    if b'"m_curr"' in body:
        return 'renamed key'
    if reply.startswith(good) and len(reply) >= len(good) + 20000:
        return 'long'
    return 'other'


def test_garbage_replies_come_in_every_kind():
    """The seven broken replies the drivers must survive, each seen in 300 draws."""
    module = SimModule(faults=Faults(seed=11))
    kinds = []
    for _ in range(300):
        good = module.reply()
        reply = module.garbage_reply()
        assert isinstance(reply, bytes) and reply != good
        kinds.append(_garbage_kind(reply, good))
    assert set(kinds) == {'bytes', 'prefix', 'string count', '500', 'not json',
                          'renamed key', 'long'}, sorted(set(kinds))
