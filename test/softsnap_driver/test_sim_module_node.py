"""sim_module started with --ros-args is an rclpy node: params files, -p and remaps work."""
from __future__ import annotations

import time

import pytest
import yaml

from softsnap_driver.protocol import ModuleClient

pytestmark = pytest.mark.ros


def test_params_file_remaps_and_plain_defaults(start_node, ros_node, tmp_path, slot_port):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import DescribeParameters, SetParameters
    port = slot_port(2)
    params = tmp_path / 'sim.yaml'
    # The layout launch_ros writes: the fully qualified node name, then ros__parameters.
    params.write_text(yaml.safe_dump({'/lab/sim_a': {'ros__parameters': {
        'port': port, 'seed': 3, 'battery_full_v': 4.0}}}))
    # A plain option before --ros-args (two modules) is the parameter's default.
    sim = start_node('softsnap_driver', 'sim_module', '--count', '2', '--ros-args',
                     '-r', '__node:=sim_a', '-r', '__ns:=/lab', '--params-file', str(params),
                     '-p', 'no_load_rpm:=200')
    assert ros_node.spin_until(
        lambda: ('sim_a', '/lab') in ros_node.get_node_names_and_namespaces(), 30), sim.output()
    deadline = time.monotonic() + 30
    while f'127.0.0.1:{port + 1}' not in sim.output():
        assert sim.alive() and time.monotonic() < deadline, sim.output()
        time.sleep(0.05)
    for p in (port, port + 1):  # the params file's port, and the next for the second module
        assert ModuleClient('127.0.0.1', p, timeout_s=2.0).status().battery_voltage < 4.05
    describe = ros_node.create_client(DescribeParameters, '/lab/sim_a/describe_parameters')
    response = ros_node.call(describe, DescribeParameters.Request(names=['port', 'drop_probability']), 30)
    port_d, drop_d = response.descriptors
    assert port_d.read_only and port_d.integer_range[0].to_value == 65535
    assert not drop_d.read_only and drop_d.floating_point_range[0].to_value == 1.0
    setter = ros_node.create_client(SetParameters, '/lab/sim_a/set_parameters')
    result = ros_node.call(setter, SetParameters.Request(parameters=[Parameter(
        name='port', value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=1))]), 30)
    assert not result.results[0].successful and 'read-only' in result.results[0].reason
    assert sim.stop() == 0


def test_a_port_in_use_ends_the_node_with_the_address(start_node, slot_port):
    import socket
    port = slot_port()
    with socket.socket() as squatter:
        squatter.bind(('127.0.0.1', port))
        squatter.listen(1)
        sim = start_node('softsnap_driver', 'sim_module', '--ros-args', '-p', f'port:={port}')
        assert sim.proc.wait(60) == 2
    assert f'cannot listen on 127.0.0.1:{port}' in sim.output()
    assert 'Address already in use' in sim.output() and 'Traceback' not in sim.output()
