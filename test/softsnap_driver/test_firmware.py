"""Simulated module: firmware semantics, motor model, battery, power history and faults."""
import math
import time

import pytest

from softsnap_driver.firmware import (DEADBAND_COUNTS, BatteryModel, Faults, MotorModel,
                                      ParsedRequest, SimModule, parse_request)
from softsnap_driver.protocol import (MalformedReply, ModuleClient, ModuleConnectionError,
                                      ModuleError, ModuleTimeout, encode_set_request, parse_reply)


def head(text: str) -> bytes:
    return text.encode('latin-1')


# -- request parsing ----------------------------------------------------------------------
@pytest.mark.parametrize('text, expected', [
    ('GET /?status HTTP/1.1\r\n\r\n', 'status'),
    ('GET /?calibrate HTTP/1.1\r\n\r\n', 'calibrate'),
    ('GET /?pause HTTP/1.1\r\n\r\n', 'pause'),
    ('GET /?resume HTTP/1.1\r\n\r\n', 'resume'),
    ('GET /?reach HTTP/1.1\r\n\r\n', 'reach'),
    ('GET / HTTP/1.1\r\n\r\n', 'status'),                   # anything else: status
    ('GET /?reboot HTTP/1.1\r\n\r\n', 'status'),
    ('GET /?STATUS&pause HTTP/1.1\r\n\r\n', 'pause'),       # case-sensitive
    ('GET /?pause&status HTTP/1.1\r\n\r\n', 'status'),      # search order, not position
    ('GET /?reach&calibrate HTTP/1.1\r\n\r\n', 'calibrate'),
    ('GET /?reset HTTP/1.1\r\n\r\n', 'set'),                # "reset" contains "set"
    ('GET /?pause HTTP/1.1\r\nAccept-Charset: utf-8\r\n\r\n', 'set'),  # headers count too
])
def test_keyword_search_order(text, expected):
    assert parse_request(head(text)).command == expected


@pytest.mark.parametrize('text, target, power', [
    ('GET /?set=00000BB850 HTTP/1.1', 3000, 0x50),
    ('GET /?set=FFFFFFFFFF HTTP/1.1', -1, 255),
    ('GET /?set=80000000AB HTTP/1.1', -2 ** 31, 0xAB),
    ('GET /?set=0000-0B.B8-50 HTTP/1.1', 3000, 0x50),      # other characters skipped
    # Lower case skipped: 0 0 0 0 0 8 5 0, then the power from 'HTTP/1.1': 1 1.
    ('GET /?set=00000bb8ff50 HTTP/1.1', 0x0000_0850, 0x11),
    ('GET /?x=1&set=00000BB850 HTTP/1.1', 0x1000_00BB, 0x85),  # digits start after the FIRST '='
    ('GET /?set=00000BB8501234 HTTP/1.1', 3000, 0x50),     # only the first 10 digits count
    ('GET /?set=00000BB8 HTTP/1.1', 3000, 0x11),            # fewer than 10: read on
])
def test_set_hex_parsing(text, target, power):
    assert parse_request(head(text)) == ParsedRequest('set', target, power)


def test_set_without_enough_digits_uses_what_came():
    # No '=' -> parsing starts at the head's beginning (indexOf + 1 = 0): 'E' of GET, 1, 1.
    assert parse_request(head('GET /?set HTTP/1.1')) == ParsedRequest('set', 0xE11, 0)


def test_set_reply_and_state_are_firmware_like():
    sim = SimModule(start_time=0.0)
    raw = sim.handle_request(encode_set_request(-500, 100), now=0.0)
    assert raw.startswith(b'HTTP/1.1 200 OK\r\nContent-type:application/json\r\nConnection: close\r\n\r\n')
    assert raw.endswith(b'}\r\n\r\n')
    status = parse_reply(raw)
    assert (sim.target, sim.motor_power) == (-500, 100)
    assert status.motor_power == 100 and status.encoder_count == 0
    assert len(status.power_history_w) == 256


# -- motion --------------------------------------------------------------------------------
def test_motion_stops_in_deadband_and_reach_calibrate_pause():
    sim = SimModule(start_time=0.0)
    sim.handle_request(encode_set_request(5000, 255), 0.0)
    sim.advance_to(5.0)
    assert sim.target - sim.encoder_count == DEADBAND_COUNTS    # stops at the deadband edge
    sim.handle_request(encode_set_request(4990, 255), 5.0)      # inside the deadband: no motion
    sim.advance_to(6.0)
    assert sim.encoder_count == 4970
    sim.handle_request(b'GET /?pause HTTP/1.1\r\n\r\n', 6.0)
    sim.handle_request(encode_set_request(0, 255), 6.0)
    sim.advance_to(8.0)
    assert sim.encoder_count == 4970 and sim.paused
    sim.handle_request(b'GET /?resume HTTP/1.1\r\n\r\n', 8.0)
    sim.advance_to(8.1)
    mid = sim.encoder_count
    assert 0 < mid < 4970
    sim.handle_request(b'GET /?reach HTTP/1.1\r\n\r\n', 8.1)
    sim.advance_to(9.0)
    assert sim.encoder_count == mid and sim.target == mid
    sim.handle_request(b'GET /?calibrate HTTP/1.1\r\n\r\n', 9.0)
    assert sim.encoder_count == 0 and sim.target == 0


def test_winch_speed_follows_motor_figures_and_pwm():
    motor = MotorModel()
    full = 300.0 / 60.0 * 2800.0 * (1 - motor.load_fraction)     # counts/s at 255, 6 V
    assert motor.speed_counts_per_s(255, 6.0) == pytest.approx(full)
    assert motor.speed_counts_per_s(128, 6.0) == pytest.approx(full * 128 / 255)
    assert motor.speed_counts_per_s(motor.min_pwm - 1, 6.0) == 0.0
    sim = SimModule(start_time=0.0)
    sim.handle_request(encode_set_request(10000, 255), 0.0)
    sim.advance_to(0.5)
    assert sim.encoder_count == pytest.approx(full * 0.5, abs=1)  # boosted: full 6 V
    slow = SimModule(start_time=0.0)
    slow.handle_request(encode_set_request(10000, 64), 0.0)
    slow.advance_to(0.5)
    assert slow.encoder_count == pytest.approx(full * 0.5 * 64 / 255, abs=1)


def test_battery_sags_under_load_and_power_history_records_it():
    sim = SimModule(start_time=0.0)
    sim.advance_to(1.0)
    idle_v = sim.battery_voltage
    idle_w = sim.power_history[-1] * 1e-4
    sim.handle_request(encode_set_request(100000, 255), 1.0)
    sim.advance_to(2.0)
    assert sim.battery_voltage < idle_v - 0.05
    assert sim.power_history[-1] * 1e-4 > 3 * idle_w
    assert len(sim.power_history) == 256
    status = parse_reply(sim.reply())
    assert status.power_w == pytest.approx(sim.power_history[-1] * 1e-4)
    assert status.battery_voltage == pytest.approx(sim.battery_voltage, abs=1e-3)
    # The reported battery voltage is the mean of the last 8 samples (50 ms apart).
    assert sim.battery_samples.maxlen == 8


def test_battery_discharges_over_time():
    sim = SimModule(battery=BatteryModel(capacity_mah=10.0), start_time=0.0)
    sim.advance_to(0.5)
    fresh = sim.battery_voltage
    sim.advance_to(200.0)       # idle draw 0.12 A for 200 s = 6.7 mAh of 10
    assert sim.battery_voltage < fresh - 0.4


# -- faults --------------------------------------------------------------------------------
def test_reboot_resets_count_target_and_pause():
    sim = SimModule(faults=Faults(reboot_after_s=2.0), start_time=10.0)
    sim.handle_request(encode_set_request(3000, 255), 10.0)
    sim.handle_request(b'GET /?pause HTTP/1.1\r\n\r\n', 10.5)
    sim.advance_to(11.9)
    assert sim.encoder_count > 1000
    sim.advance_to(12.1)
    assert (sim.encoder_count, sim.target, sim.paused, sim.reboots) == (0, 0, False, 1)
    assert sim.fault_for_request(12.2) == 'drop'        # still booting
    assert sim.fault_for_request(12.6) is None


def test_stall_stops_motion_and_draws_stall_current():
    sim = SimModule(faults=Faults(stall_after_s=0.0, stall_duration_s=1.0), start_time=0.0)
    sim.handle_request(encode_set_request(3000, 255), 0.0)
    sim.advance_to(0.9)
    assert sim.encoder_count == 0
    assert sim.current_a > 0.7
    sim.advance_to(1.5)
    assert sim.encoder_count > 1000


def test_server_faults_over_sockets(sim_server):
    delayed = sim_server(Faults(delay_probability=1.0, delay_s=0.3))
    with pytest.raises(ModuleTimeout):
        ModuleClient('127.0.0.1', delayed.port, timeout_s=0.1).status()
    assert ModuleClient('127.0.0.1', delayed.port, timeout_s=1.0).status().encoder_count == 0

    dropped = sim_server(Faults(drop_probability=1.0))
    with pytest.raises(ModuleConnectionError):
        ModuleClient('127.0.0.1', dropped.port, timeout_s=0.5).status()

    garbage = sim_server(Faults(garbage_probability=1.0, seed=3))
    client = ModuleClient('127.0.0.1', garbage.port, timeout_s=0.5)
    kinds = set()
    for _ in range(30):
        with pytest.raises(ModuleError) as info:
            client.status()
        kinds.add(type(info.value))
    assert MalformedReply in kinds

    outage = sim_server(Faults(outage_after_s=0.0, outage_duration_s=0.6))
    client = ModuleClient('127.0.0.1', outage.port, timeout_s=0.2)
    with pytest.raises(ModuleTimeout):
        client.status()
    time.sleep(0.5)
    assert client.status().encoder_count == 0
    assert outage.fault_counts['outage'] >= 1


def test_lost_reach_fault_drops_the_first_reach_requests_after_reading_them(sim_server):
    server = sim_server(Faults(drop_first_reach=2))
    client = ModuleClient('127.0.0.1', server.port, timeout_s=0.5)
    client.set_target(5000, 40)
    for _ in range(2):
        with pytest.raises(ModuleConnectionError):
            client.reach()                         # read, then closed without a reply
        with server.lock:
            assert server.module.target == 5000    # not applied: the module drives on
    assert client.status().encoder_count > 0       # other requests are answered
    stopped = client.reach()                       # the third reach gets through
    with server.lock:
        assert server.module.target == server.module.encoder_count
        assert abs(stopped.encoder_count - server.module.target) <= DEADBAND_COUNTS
    assert server.fault_counts == {'drop_head': 2} and server.module.reaches_dropped == 2


def test_serves_one_client_at_a_time_and_closes(sim_server):
    import socket
    server = sim_server()
    first = socket.create_connection(('127.0.0.1', server.port))
    second = socket.create_connection(('127.0.0.1', server.port))
    try:
        second.sendall(b'GET /?status HTTP/1.1\r\n\r\n')
        second.settimeout(0.3)
        with pytest.raises(socket.timeout):
            second.recv(10)               # queued behind the first client
        first.sendall(b'GET /?pause HTTP/1.1\r\n\r\n')
        first.settimeout(2)
        reply = b''
        while chunk := first.recv(4096):  # the sim closes after its reply
            reply += chunk
        assert parse_reply(reply).paused
        second.settimeout(2)
        assert second.recv(4096).startswith(b'HTTP/1.1 200 OK')
    finally:
        first.close()
        second.close()


def test_sim_module_command_line(tmp_path):
    # (With --ros-args the options are ROS parameters: test/softsnap_driver/test_sim_module_node.py.)
    from softsnap_driver.sim_module import build_parser, module_from_options
    opts = build_parser().parse_args(['--port', '8102', '--drop-probability', '0.5'])
    assert opts.port == 8102 and opts.drop_probability == 0.5
    assert build_parser().parse_args(['--reboot-after-s', '3']).reboot_after_s == 3.0
    opts = build_parser().parse_args(['--drop-first-reach', '2'])
    assert module_from_options(opts, 0.0).faults.drop_first_reach == 2


def test_bad_fault_values_are_refused():
    with pytest.raises(ValueError, match='drop_probability'):
        Faults(drop_probability=1.5)
    with pytest.raises(ValueError, match='load_fraction'):
        MotorModel(load_fraction=1.0)
    assert math.isinf(Faults().reboot_after_s)
    with pytest.raises(ValueError, match='drop_first_reach'):
        Faults(drop_first_reach=-1)


def test_sim_module_process_serves_several_modules(start_node):
    import re
    import subprocess
    import sys
    proc = start_node('softsnap_driver', 'sim_module', '--port', '0', '--count', '2', '--seed', '1')
    deadline = time.monotonic() + 15
    while len(re.findall(r'serving .* on 127\.0\.0\.1:(\d+)', proc.output())) < 2:
        assert proc.alive() and time.monotonic() < deadline, proc.output()
        time.sleep(0.05)
    ports = [int(p) for p in re.findall(r'127\.0\.0\.1:(\d+)', proc.output())]
    first, second = (ModuleClient('127.0.0.1', port, timeout_s=1.0) for port in ports)
    first.set_target(2000, 255)
    time.sleep(0.3)
    assert first.status().encoder_count > 1000          # separate modules
    assert second.status().encoder_count == 0
    assert proc.stop() == 0
    # The simulator path never imports rclpy (usable without ROS).
    check = 'import sys, softsnap_driver.sim_module; assert "rclpy" not in sys.modules'
    assert subprocess.run([sys.executable, '-c', check], timeout=60).returncode == 0


def test_idle_module_advanced_in_small_steps_matches_one_jump():
    # sim_robot advances every module each 6 ms; an idle one takes a shortcut (clock and
    # drain only) between samples. Its battery, power history and clock must come out as
    # one long advance gives them, and its replies must carry the new samples.
    stepped, jumped = SimModule(start_time=0.0), SimModule(start_time=0.0)
    for module in (stepped, jumped):
        module.handle_request(encode_set_request(400, 200), now=0.0)
        module.advance_to(1.0)                       # moved to 400 and stopped
        assert not module.moving()
    first = parse_reply(stepped.reply())
    for i in range(1, 501):
        stepped.advance_to(1.0 + i * 0.006)
    jumped.advance_to(4.0)
    assert stepped.time == jumped.time == pytest.approx(4.0)
    assert stepped.charge_used_mah == pytest.approx(jumped.charge_used_mah, rel=1e-12)
    assert list(stepped.power_history) == list(jumped.power_history)
    assert list(stepped.battery_samples) == pytest.approx(list(jumped.battery_samples), rel=1e-12)
    assert stepped.charge_used_mah > 0
    # Idle power replaced the motion's samples in the reply (no stale cached text).
    later = parse_reply(stepped.reply())
    assert later.power_history_w != first.power_history_w
    assert later.power_history_w == parse_reply(jumped.reply()).power_history_w
    assert stepped.encoder_count == jumped.encoder_count
