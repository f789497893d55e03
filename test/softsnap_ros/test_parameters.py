"""Integer values for double parameters, in every node, over real processes and DDS.

Users type ``-p rate:=50``, ``rate: 50`` in a params file and ``ros2 param set ... rate
50``: all three are INTEGER values. Each node must start with them, report the
parameters as doubles, take an integer at run time (with effect), and still refuse a
non-number with a reason (softsnap_ros.node.SoftSnapNode).
"""
from __future__ import annotations

import statistics
import time

import pytest
import yaml

from parameter_client import ParameterClient
from softsnap_driver.firmware import SimModule
from softsnap_driver.protocol import ModuleClient, ModuleError
from softsnap_driver.sim_module import SimServer

pytestmark = pytest.mark.ros

NS = '/intparams'


def params_file(tmp_path, node_fqn: str, values: dict) -> str:
    path = tmp_path / f'{node_fqn.strip("/").replace("/", "_")}.yaml'
    path.write_text(yaml.safe_dump({node_fqn: {'ros__parameters': values}}))
    return str(path)


def start_with_integers(start_node, tmp_path, package, executable, name, cli: dict,
                        in_file: dict, extra: tuple = ()):
    """Start a node with integer `cli` values as -p and `in_file` values in a params file."""
    fqn = f'{NS}/{name}'
    args = ['--ros-args', '-r', f'__node:={name}', '-r', f'__ns:={NS}',
            '--params-file', params_file(tmp_path, fqn, in_file)]
    for key, value in cli.items():
        assert isinstance(value, int)
        args += ['-p', f'{key}:={value}']
    return start_node(package, executable, *args, *extra), fqn


def assert_doubles(client, expected: dict, proc):
    from rcl_interfaces.msg import ParameterType
    assert proc.alive(), proc.output()[-2000:]
    got = client.get(*expected)
    for name, value in expected.items():
        assert got[name] == (ParameterType.PARAMETER_DOUBLE, float(value)), (name, got, proc.output()[-2000:])


def assert_non_number_refused(client, name):
    result = client.set(name, string_value='fast')
    assert not result.successful
    assert 'type' in result.reason.lower(), result.reason


def stamp_intervals_s(messages) -> list[float]:
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in messages]
    return [b - a for a, b in zip(stamps, stamps[1:])]


def test_gait_node_integer_doubles(start_node, ros_node, tmp_path):
    from softsnap_interfaces.msg import CableLength
    proc, fqn = start_with_integers(
        start_node, tmp_path, 'softsnap_gaits', 'gait_node', 'gait_node',
        cli={'rate': 50, 'period': 2},
        in_file={'scene': 'brittle_star', 'transition_time': 0, 'amplitude': 0})
    commands = []
    ros_node.create_subscription(CableLength, f'{NS}/yellow/cable_length/command', commands.append, 100)
    client = ParameterClient(ros_node, fqn)
    assert_doubles(client, {'rate': 50, 'period': 2, 'transition_time': 0, 'amplitude': 0}, proc)
    assert ros_node.spin_until(lambda: len(commands) > 20, 30), proc.output()[-2000:]
    assert client.set('rate', integer_value=5).successful          # ros2 param set ... rate 5
    assert_doubles(client, {'rate': 5}, proc)
    commands.clear()
    assert ros_node.spin_until(lambda: len(commands) > 6, 30)
    # Judged by the publisher's stamps: 5 Hz is 0.2 s apart (50 Hz was 0.02 s).
    assert statistics.median(stamp_intervals_s(commands[1:])) > 0.12
    assert_non_number_refused(client, 'rate')
    assert proc.alive()


def test_model_node_integer_doubles(start_node, ros_node, tmp_path):
    from softsnap_interfaces.msg import CableLength, ModuleShape
    from softsnap_model.scene import load_scene
    proc, fqn = start_with_integers(
        start_node, tmp_path, 'softsnap_model', 'model_node', 'model_node',
        cli={'rate': 50}, in_file={'scene': 'brittle_star', 'diagnostics_period': 3,
                                   'length_tolerance': 0})
    shapes = []
    ros_node.create_subscription(ModuleShape, f'{NS}/yellow/shape/commanded', shapes.append, 100)
    publisher = ros_node.create_publisher(CableLength, f'{NS}/yellow/cable_length/command', 10)
    straight_mm = load_scene('brittle_star').module('yellow').straight_length_mm
    sent = [0]

    def command():  # a new length every 20 ms: the model solves one per tick
        sent[0] += 1
        msg = CableLength(cable_length=(straight_mm - 10.0 - (sent[0] % 20)) / 1000.0)
        msg.header.stamp = ros_node.get_clock().now().to_msg()
        publisher.publish(msg)

    ros_node.create_timer(0.02, command)
    client = ParameterClient(ros_node, fqn)
    assert_doubles(client, {'rate': 50, 'diagnostics_period': 3, 'length_tolerance': 0}, proc)
    assert ros_node.spin_until(lambda: len(shapes) > 20, 40), proc.output()[-2000:]
    assert client.set('rate', integer_value=2).successful      # ros2 param set ... rate 2
    assert_doubles(client, {'rate': 2}, proc)
    ros_node.spin_until(lambda: False, 1.0)                     # the old tick's shapes pass
    shapes.clear()
    assert ros_node.spin_until(lambda: len(shapes) >= 4, 40), proc.output()[-2000:]
    # At 2 Hz each shape is solved from a length 0.5 s after the last one's (its stamp).
    assert statistics.median(stamp_intervals_s(shapes)) > 0.3
    assert_non_number_refused(client, 'rate')
    assert proc.alive()


def test_driver_node_integer_doubles(start_node, ros_node, tmp_path):
    from softsnap_interfaces.msg import CableLength
    with SimServer(SimModule(start_time=time.monotonic())) as server:
        proc, fqn = start_with_integers(
            start_node, tmp_path, 'softsnap_driver', 'driver_node', 'driver_yellow',
            cli={'poll_rate_hz': 20, 'counts_per_mm': 89},
            in_file={'module': 'yellow', 'port': server.port, 'command_timeout_s': 0,
                     'max_contraction_m': 0})
        measured = []
        ros_node.create_subscription(CableLength, f'{NS}/yellow/cable_length/measured', measured.append, 100)
        client = ParameterClient(ros_node, fqn)
        assert_doubles(client, {'poll_rate_hz': 20, 'counts_per_mm': 89, 'command_timeout_s': 0,
                                'max_contraction_m': 0}, proc)
        assert ros_node.spin_until(lambda: len(measured) > 10, 30), proc.output()[-2000:]
        assert client.set('poll_rate_hz', integer_value=2).successful
        assert_doubles(client, {'poll_rate_hz': 2}, proc)
        measured.clear()
        assert ros_node.spin_until(lambda: len(measured) > 4, 30)
        # 2 Hz polls are 0.5 s apart (20 Hz: 0.05 s), by the driver's stamps.
        assert statistics.median(stamp_intervals_s(measured[1:])) > 0.3
        assert_non_number_refused(client, 'poll_rate_hz')
        assert proc.alive()


def test_rerun_logger_integer_doubles(start_node, ros_node, tmp_path):
    proc, fqn = start_with_integers(
        start_node, tmp_path, 'softsnap_gaits', 'rerun_logger', 'rerun_logger',
        cli={'rate': 10}, in_file={'scene': 'brittle_star', 'output': str(tmp_path / 'p.rrd')})
    client = ParameterClient(ros_node, fqn)
    assert_doubles(client, {'rate': 10}, proc)
    assert client.set('rate', integer_value=0).successful      # 0: log every message
    assert_doubles(client, {'rate': 0}, proc)
    assert_non_number_refused(client, 'rate')
    assert proc.alive()


def test_sim_module_integer_doubles(start_node, ros_node, tmp_path, slot_port):
    port = slot_port()
    proc, fqn = start_with_integers(
        start_node, tmp_path, 'softsnap_driver', 'sim_module', 'sim_yellow',
        cli={'delay_s': 0, 'no_load_rpm': 300}, in_file={'port': port, 'battery_full_v': 4})
    client = ParameterClient(ros_node, fqn)
    assert_doubles(client, {'delay_s': 0, 'no_load_rpm': 300, 'battery_full_v': 4}, proc)
    module = ModuleClient('127.0.0.1', port, timeout_s=1.0)
    assert module.status().battery_voltage < 4.05                    # the 4 V battery, not 4.15 V
    assert client.set('drop_probability', integer_value=1).successful   # drop every reply
    with pytest.raises(ModuleError):
        module.status()
    assert client.set('drop_probability', integer_value=0).successful
    assert module.status() is not None
    assert_non_number_refused(client, 'drop_probability')
    result = client.set('drop_probability', double_value=1.5)
    assert not result.successful and 'drop_probability' in result.reason
    assert proc.alive()


@pytest.mark.parametrize('package, executable, extra', [
    ('softsnap_model', 'model_node', ['-p', 'scene:=brittle_star']),
    ('softsnap_driver', 'driver_node', ['-p', 'module:=yellow']),
    ('softsnap_gaits', 'gait_node', ['-p', 'scene:=brittle_star']),
    ('softsnap_gaits', 'rerun_logger', ['-p', 'output:=/tmp/never-written.rrd']),
    ('softsnap_driver', 'sim_module', ['-p', 'port:=0']),
])
def test_a_non_number_for_a_double_stops_the_node_with_the_reason(start_node, package, executable,
                                                                   extra):
    name = {'model_node': 'rate', 'driver_node': 'poll_rate_hz', 'gait_node': 'rate',
            'rerun_logger': 'rate', 'sim_module': 'delay_s'}[executable]
    proc = start_node(package, executable, '--ros-args', '-r', f'__ns:={NS}', *extra,
                      '-p', f'{name}:=fast')
    assert proc.proc.wait(60) != 0
    output = proc.output()
    assert name in output and 'fast' in output and 'DOUBLE' in output, output[-2000:]
    assert 'Traceback' not in output, output[-3000:]
