"""driver_node across processes: tracking, services, bad inputs, faults, parameters."""
import math
import time

import pytest

from softsnap_driver.firmware import DEADBAND_COUNTS, Faults

pytestmark = pytest.mark.ros

COUNTS_PER_MM = 89.13
STRAIGHT_M = 0.198
MAX_CONTRACTION_M = 0.080
NS = '/robot'


def driver_args(port, module='m1', **params):
    values = dict(module=module, port=port, counts_per_mm=COUNTS_PER_MM,
                  straight_length_m=STRAIGHT_M, max_contraction_m=MAX_CONTRACTION_M,
                  pwm_power=255, poll_rate_hz=20.0, command_timeout_s=0.0, request_timeout_s=0.3)
    values.update(params)
    args = ['--ros-args', '-r', f'__ns:={NS}']
    for name, value in values.items():
        if value is not None:   # None: left to the caller (e.g. driver_container's lists)
            args += ['-p', f'{name}:={value}']
    return args


class ModuleProbe:
    """In-test view of one driven module: its topics and services."""

    def __init__(self, node, module='m1'):
        from softsnap_interfaces.msg import CableLength, ModuleState
        from std_srvs.srv import Trigger
        self.node = node
        self.states = []
        self.measured = []
        base = f'{NS}/{module}'
        node.create_subscription(ModuleState, f'{base}/state', self.states.append, 50)
        node.create_subscription(CableLength, f'{base}/cable_length/measured', self.measured.append, 50)
        self.publisher = node.create_publisher(CableLength, f'{base}/cable_length/command', 10)
        self.clients = {kind: node.create_client(Trigger, f'{base}/{kind}')
                        for kind in ('calibrate', 'pause', 'resume', 'stop')}
        self.CableLength = CableLength
        self.Trigger = Trigger

    def wait_ready(self, timeout=20.0):
        assert self.node.spin_until(
            lambda: self.states and self.publisher.get_subscription_count() > 0, timeout), \
            'driver not up: no state or command subscription'

    def command(self, length_m):
        msg = self.CableLength()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.cable_length = float(length_m)
        self.publisher.publish(msg)

    def call(self, kind):
        return self.node.call(self.clients[kind], self.Trigger.Request(), 15.0)

    def last(self):
        return self.states[-1]

    def wait_state(self, predicate, timeout=10.0):
        return self.node.spin_until(lambda: bool(self.states) and predicate(self.states[-1]), timeout)


def within_deadband(measured_m, commanded_m):
    return abs(measured_m - commanded_m) <= (DEADBAND_COUNTS + 0.5) / COUNTS_PER_MM / 1000


def test_tracks_commands_and_serves_services_with_sim_module_process(start_node, ros_node, free_port):
    sim = start_node('softsnap_driver', 'sim_module', '--ros-args', '-p', f'port:={free_port}')
    driver = start_node('softsnap_driver', 'driver_node', *driver_args(free_port))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    # Both processes start together: a first poll before the simulated module listens is
    # refused and reported offline; the driver must then come online by itself.
    assert probe.wait_state(lambda state: state.online, 20.0), probe.last()
    assert probe.last().module == 'm1'
    for length in (0.19, 0.14, 0.16, 0.125):          # a changing command
        probe.command(length)
        assert ros_node.spin_until(lambda: probe.measured and within_deadband(
            probe.measured[-1].cable_length, length), 10.0), f'did not reach {length} m'
    state = probe.last()
    assert state.encoder_target == round((STRAIGHT_M - 0.125) * 1000 * COUNTS_PER_MM)
    assert 3.0 < state.battery_voltage < 4.3 and state.motor_power == 255
    assert probe.measured[-1].header.frame_id == 'm1'

    response = probe.call('pause')
    assert response.success, response.message
    assert probe.wait_state(lambda s: s.paused)
    assert probe.call('resume').success
    probe.command(0.19)
    assert probe.call('stop').success
    assert probe.call('calibrate').success
    assert probe.wait_state(lambda s: s.encoder_count == 0 and s.measured_cable_length == pytest.approx(STRAIGHT_M))

    assert driver.alive() and sim.alive()
    assert driver.stop() == 0          # SIGINT: clean exit
    assert sim.stop() == 0


def test_bad_inputs_never_reach_the_module_nor_crash_the_node(start_node, ros_node, sim_server):
    server = sim_server()
    driver = start_node('softsnap_driver', 'driver_node', *driver_args(server.port))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    # 0.0 is what a default-constructed CableLength holds: refused, never driven to full
    # contraction. 0.117 is 1 mm beyond the range (within clamp_margin_m): clamped.
    probe.publisher.publish(probe.CableLength())
    assert probe.wait_state(lambda s: s.commands_refused == 1), probe.last()   # (depth 10 below)
    for length in (math.nan, math.inf, -math.inf, 5.0, -1.0, 0.0, 0.117, 1e308, -1e308, 0.15):
        probe.command(length)
    assert probe.wait_state(lambda s: s.commands_refused == 9 and s.commands_clamped == 1), \
        probe.last()
    # Every command taken is counted, refused or not; the latest one's stamp is reported.
    last_stamp = ros_node.get_clock().now().nanoseconds
    probe.command(0.15)
    assert probe.wait_state(lambda s: s.commands_received == 12), probe.last()
    stamp = probe.last().last_command_stamp
    assert stamp.sec * 10**9 + stamp.nanosec >= last_stamp  # the 0.15 m command's own stamp
    assert probe.wait_state(lambda s: s.targets_sent >= 1), probe.last()
    assert ros_node.spin_until(lambda: probe.measured and within_deadband(probe.measured[-1].cable_length, 0.15), 10)
    with server.lock:
        sent = [r.target for r in server.module.received_targets]
    high = math.floor(MAX_CONTRACTION_M * 1000 * COUNTS_PER_MM + 1e-9)
    assert sent and all(0 <= t <= high for t in sent), sent
    assert sent.count(high) <= 1                       # only the clamped 0.117, never the 0.0s
    # The last command was accepted as it is: last_error has cleared, its time is kept.
    assert probe.wait_state(lambda s: s.last_error == '' and s.last_error_time.sec > 0), probe.last()
    age_s = ros_node.get_clock().now().nanoseconds * 1e-9 - (
        probe.last().last_error_time.sec + probe.last().last_error_time.nanosec * 1e-9)
    assert 0 <= age_s < 60
    assert driver.alive()
    assert 'refused' in driver.output()


def test_faults_are_survived_and_reported(start_node, ros_node, sim_server):
    server = sim_server(Faults(drop_probability=0.1, garbage_probability=0.1,
                               delay_probability=0.05, delay_s=0.5, seed=5))
    driver = start_node('softsnap_driver', 'driver_node',
                        *driver_args(server.port, offline_after_failures=3, max_backoff_s=0.5))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    probe.command(0.15)
    assert ros_node.spin_until(lambda: probe.measured and within_deadband(probe.measured[-1].cable_length, 0.15), 10)
    assert probe.wait_state(lambda s: s.request_failures > 0)

    # Reboot: the count falls back to 0 far from the target.
    with server.lock:
        server.module.faults.drop_probability = server.module.faults.garbage_probability = 0.0
        server.module.faults.delay_probability = 0.0
        server.module.reboot(server.clock())
        sent_before = len(server.module.received_targets)
    assert probe.wait_state(lambda s: s.reboots_detected == 1)
    assert 'reboot' in probe.last().last_error
    assert math.isnan(probe.last().measured_cable_length)
    probe.command(0.14)                                 # refused until calibrated
    assert probe.wait_state(lambda s: s.commands_refused >= 1)
    with server.lock:
        assert len(server.module.received_targets) == sent_before    # nothing re-sent
        assert server.module.target == server.module.encoder_count == 0
    assert 'reboot detected' in driver.output()
    assert probe.call('calibrate').success
    probe.command(0.14)
    assert ros_node.spin_until(lambda: within_deadband(probe.measured[-1].cable_length, 0.14), 10)

    # Outage: offline with backoff, then back.
    with server.lock:
        server.module.faults.outage_after_s = server.module.since_start(server.clock())
        server.module.faults.outage_duration_s = 2.0
    assert probe.wait_state(lambda s: not s.online, 10)
    assert probe.wait_state(lambda s: s.online, 10)

    # Stall: no progress toward the target -> reported and stopped.
    with server.lock:
        server.module.faults.stall_after_s = 0.0
    probe.command(0.19)
    assert probe.wait_state(lambda s: 'stalled' in s.last_error and s.stalls_detected >= 1, 10)
    assert ros_node.spin_until(lambda: '(stalled motor): module holds' in driver.output(), 10)
    with server.lock:
        assert server.module.target == server.module.encoder_count
    assert driver.alive()


def test_stale_command_stream_stops_the_module(start_node, ros_node, sim_server):
    server = sim_server()
    driver = start_node('softsnap_driver', 'driver_node',
                        *driver_args(server.port, command_timeout_s=0.5, pwm_power=40))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    probe.command(0.118)
    assert probe.wait_state(lambda s: s.stale_stops == 1, 10)
    assert ros_node.spin_until(lambda: 'stop confirmed' in driver.output(), 10), driver.output()
    with server.lock:
        assert server.module.target == server.module.encoder_count
    assert 'no command' in probe.last().last_error


def test_state_and_measured_come_at_the_poll_rate_while_commands_stream(start_node, ros_node, sim_server):
    """50 Hz commands give 25-50 replies a second; state and measured are published at
    the 10 Hz poll rate (before: after every reply), and the latest state is not lost."""
    server = sim_server()
    start_node('softsnap_driver', 'driver_node', *driver_args(server.port, poll_rate_hz=10.0))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    probe.command(0.19)
    assert probe.wait_state(lambda s: s.commands_received == 1 and s.targets_sent == 1)
    probe.states.clear()
    probe.measured.clear()
    commands = 100
    for i in range(commands):                       # 50 Hz, 0.5 mm (45 counts): each one sent
        probe.command(0.19 - 0.0005 * (i + 1))
        ros_node.spin_until(lambda: False, 0.02)
    final = 0.19 - 0.0005 * commands
    assert probe.wait_state(lambda s: s.commands_received == commands + 1), probe.last()
    assert ros_node.spin_until(lambda: within_deadband(probe.measured[-1].cable_length, final), 10)
    with server.lock:
        replies = len(server.module.received_targets)
    assert replies > 50, replies                     # the link sent more than the polls
    stamps = [s.header.stamp.sec + s.header.stamp.nanosec * 1e-9 for s in probe.states]
    span = stamps[-1] - stamps[0]
    # About one state per 0.09-0.1 s (nothing in the event fields changes here); before,
    # one per reply.
    assert len(probe.states) <= span / 0.085 + 3, (len(probe.states), span, replies)
    measured = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in probe.measured]
    assert len(measured) <= (measured[-1] - measured[0]) / 0.085 + 3, len(measured)
    assert probe.last().last_error == '' and probe.last().online


def test_a_subscriber_joining_later_gets_measured_lengths_and_states(start_node, ros_node, sim_server):
    """Topics nobody subscribes to are not published: a reader that joins later (the
    driver has polled for a while with none) gets them from then on."""
    from softsnap_interfaces.msg import CableLength, ModuleState
    server = sim_server()
    start_node('softsnap_driver', 'driver_node', *driver_args(server.port))
    base = f'{NS}/m1'
    # First only a state reader, until the driver has polled with no measured reader.
    states = []
    ros_node.create_subscription(ModuleState, f'{base}/state', states.append, 50)
    assert ros_node.spin_until(lambda: len(states) >= 5 and states[-1].online, 20.0)
    measured = []
    ros_node.create_subscription(CableLength, f'{base}/cable_length/measured', measured.append, 50)
    assert ros_node.spin_until(lambda: len(measured) >= 3, 10.0), 'no measured length'
    assert measured[-1].header.frame_id == 'm1'
    assert measured[-1].cable_length == pytest.approx(STRAIGHT_M, abs=1e-3)
    # And a second state reader that joins late gets states too.
    late = []
    ros_node.create_subscription(ModuleState, f'{base}/state', late.append, 50)
    assert ros_node.spin_until(lambda: len(late) >= 3, 10.0), 'no state for a late reader'


def test_parameters_are_validated(start_node, ros_node, sim_server, tmp_path):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    server = sim_server()
    start_node('softsnap_driver', 'driver_node', *driver_args(server.port, module='yellow'))
    probe = ModuleProbe(ros_node, 'yellow')
    probe.wait_ready()
    client = ros_node.create_client(SetParameters, f'{NS}/yellow_driver/set_parameters')

    def set_param(name, kind, **value):
        request = SetParameters.Request(parameters=[
            Parameter(name=name, value=ParameterValue(type=kind, **value))])
        return ros_node.call(client, request, 15.0).results[0]

    assert not set_param('pwm_power', ParameterType.PARAMETER_INTEGER, integer_value=300).successful
    result = set_param('max_contraction_m', ParameterType.PARAMETER_DOUBLE, double_value=0.5)
    assert not result.successful and 'max_contraction_m' in result.reason
    assert not set_param('port', ParameterType.PARAMETER_INTEGER, integer_value=81).successful
    assert set_param('max_contraction_m', ParameterType.PARAMETER_DOUBLE, double_value=0.01).successful
    probe.command(0.1)                                  # 88 mm beyond the new range: refused
    assert probe.wait_state(lambda s: s.commands_refused == 1 and 'clamp_margin_m' in s.last_error)
    assert not set_param('clamp_margin_m', ParameterType.PARAMETER_DOUBLE, double_value=-0.1).successful
    assert set_param('clamp_margin_m', ParameterType.PARAMETER_DOUBLE, double_value=0.1).successful
    probe.command(0.1)                                  # now clamped to 10 mm contraction
    assert ros_node.spin_until(lambda: probe.measured and within_deadband(probe.measured[-1].cable_length, 0.188), 10)

    bad = start_node('softsnap_driver', 'driver_node', *driver_args(server.port, module='bad',
                                                                    max_contraction_m=0.5))
    deadline = time.monotonic() + 20
    while bad.alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not bad.alive() and bad.proc.returncode == 2
    assert 'max_contraction_m' in bad.output()


SLOW_PWM = 40          # about 1650 counts/s in the sim: full contraction takes over 4 s
ABANDONED_M = 0.118    # full contraction, 7130 counts


def abandoned_count():
    return round((STRAIGHT_M - ABANDONED_M) * 1000 * COUNTS_PER_MM)


def assert_module_stopped_near(server, decided_count, slack=1000):
    with server.lock:
        target, count = server.module.target, server.module.encoder_count
    assert target == count, (target, count)
    assert count < abandoned_count() - 2000, count
    assert abs(count - decided_count) <= slack, (count, decided_count)


@pytest.mark.parametrize('lost', [1, 2])
def test_sigint_stop_is_confirmed_when_reach_is_lost(start_node, ros_node, sim_server, lost):
    server = sim_server(Faults(drop_first_reach=lost))
    driver = start_node('softsnap_driver', 'driver_node', *driver_args(server.port, pwm_power=SLOW_PWM))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    probe.command(ABANDONED_M)
    assert probe.wait_state(lambda s: s.encoder_count > 300)
    decided = probe.last().encoder_count
    started = time.monotonic()
    assert driver.stop() == 0                           # SIGINT, clean exit
    print(f'driver_node exited {time.monotonic() - started:.3f} s after SIGINT')
    output = driver.log_path.read_text(errors='replace')      # the process has ended
    assert 'stop sent' in output and 'stop confirmed' in output and '(shutdown)' in output, output
    assert server.fault_counts.get('drop_head') == lost
    assert_module_stopped_near(server, decided)


def test_watchdog_and_stop_service_confirm_lost_stops_over_dds(start_node, ros_node, sim_server):
    server = sim_server(Faults(drop_first_reach=1))
    driver = start_node('softsnap_driver', 'driver_node', *driver_args(
        server.port, pwm_power=SLOW_PWM, command_timeout_s=1.0))
    probe = ModuleProbe(ros_node)
    probe.wait_ready()
    probe.command(ABANDONED_M)
    assert probe.wait_state(lambda s: s.stale_stops == 1, 10)
    assert ros_node.spin_until(lambda: 'stop confirmed' in driver.output(), 10), driver.output()
    assert server.fault_counts.get('drop_head') == 1
    with server.lock:
        assert server.module.target == server.module.encoder_count < abandoned_count() - 2000

    with server.lock:
        server.module.faults.drop_first_reach = 2       # one more reach will be lost
    first_stop = probe.last().encoder_count
    deadline = time.monotonic() + 15                    # a new stream, kept fresh
    while probe.last().encoder_count < first_stop + 300:
        assert time.monotonic() < deadline, probe.last()
        probe.command(ABANDONED_M)
        ros_node.spin_until(lambda: False, 0.1)
    decided = probe.last().encoder_count
    response = probe.call('stop')
    assert response.success and '(confirmed)' in response.message, response.message
    assert server.fault_counts.get('drop_head') == 2
    assert_module_stopped_near(server, decided)
    assert probe.wait_state(lambda s: s.stops_unconfirmed == 0 and s.internal_errors == 0)
    assert driver.alive()


def test_command_decoding_equals_rclpy_deserialisation():
    """The inbox decodes serialised commands by hand: bit-equal to rclpy's own decoding
    for every frame_id length (every padding) and odd values; None (rclpy decodes) for
    bytes it does not know."""
    import random
    import struct
    from rclpy.serialization import deserialize_message, serialize_message
    from softsnap_interfaces.msg import CableLength
    from softsnap_ros.cdr import CdrError, decode_cable_length
    rng = random.Random(5)
    for text in range(12):
        for value in (0.15, 0.0, -1.0, math.nan, math.inf, -math.inf, 5e-324, 1e308):
            msg = CableLength(cable_length=value)
            msg.header.frame_id = 'yellow'[:text] + 'x' * max(text - 6, 0)
            msg.header.stamp.sec = rng.randint(-2**31, 2**31 - 1)
            msg.header.stamp.nanosec = rng.randint(0, 10**9 - 1)
            raw = serialize_message(msg)
            back = deserialize_message(raw, CableLength)
            stamp_ns, length = decode_cable_length(raw)
            assert stamp_ns == back.header.stamp.sec * 10**9 + back.header.stamp.nanosec
            assert struct.pack('<d', length) == struct.pack('<d', back.cable_length), (text, value)
    # Big-endian CDR, laid out by hand: sec 3, nanosec 4, frame_id 'a', 0.25 m.
    big = b'\x00\x00\x00\x00' + struct.pack('>iII', 3, 4, 2) + b'a\x00' + b'\x00' * 2 + struct.pack('>d', 0.25)
    assert decode_cable_length(big) == (3_000_000_004, 0.25)
    for unknown in (b'', b'\x00\x01', b'\x00\x07' + raw[2:], raw[:-1],
                    raw[:12] + struct.pack('<I', 2**32 - 1) + raw[16:]):
        with pytest.raises(CdrError):
            decode_cable_length(unknown)
