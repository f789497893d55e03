"""The robot graph's drivers as real processes: one driver_container gives every module's
driver its own parameters (read back over ROS), as separate driver_node processes would.

The demo runner and the launch files pass the container's drivers their parameters in a
file keyed by each driver's fully qualified name (softsnap_gaits.graph.NodeSpec). A
mistake there (a bare node name, which rcl never matches in a namespace; a global rule;
one module's values for all) would leave the drivers on their defaults or on another
module's values: each driver here is read back over its parameter service and must be
online on its own simulated module's port.
"""
from __future__ import annotations

import dataclasses

import pytest

from parameter_client import ParameterClient

pytestmark = [pytest.mark.ros, pytest.mark.slow]

CHECKED = ('port', 'host', 'counts_per_mm', 'straight_length_m', 'max_contraction_m',
           'poll_rate_hz')


def _graph(scene_name: str, slot_port, drivers: str):
    from softsnap_gaits.graph import robot_graph
    from softsnap_model.scene import load_scene
    scene = load_scene(scene_name)
    ports = {m.name: slot_port() for m in scene.modules}
    specs = robot_graph(scene, rerun=False, sim_ports=ports, poll_rate_hz=7.0, drivers=drivers)
    # The scenes' modules share one counts_per_mm: give each its own, so a driver that
    # got another module's value (or the default) is seen.
    out = []
    for spec in specs:
        if spec.executable == 'driver_container':
            spec = dataclasses.replace(spec, node_parameters={
                node: params if node == 'driver_container'
                else {**params, 'counts_per_mm': 80.0 + i}
                for i, (node, params) in enumerate(spec.node_parameters.items())})
        elif spec.executable == 'driver_node':
            index = [m.name for m in scene.modules].index(spec.parameters['module'])
            spec = dataclasses.replace(spec, parameters={**spec.parameters,
                                                         'counts_per_mm': 81.0 + index})
        out.append(spec)
    return scene, out


@pytest.mark.parametrize('drivers', ['container', 'separate'])
def test_each_driver_gets_its_own_modules_parameters(drivers, start_node, ros_node, tmp_path,
                                                     slot_port):
    from rcl_interfaces.msg import ParameterType
    from softsnap_gaits.graph import driver_parameters
    from softsnap_interfaces.msg import ModuleState
    scene, specs = _graph('brittle_star', slot_port, drivers)
    ns = f'/{scene.name}'
    expected = driver_parameters(specs)
    # Distinct per module, so a mix-up cannot pass.
    for key in ('port', 'counts_per_mm', 'straight_length_m'):
        assert len({p[key] for p in expected.values()}) > 1, key
    procs = {}
    for spec in specs:
        if spec.executable in ('sim_module', 'driver_node', 'driver_container'):
            procs[spec.name] = start_node(spec.package, spec.executable,
                                          *spec.ros_args(spec.write_node_params(tmp_path)))
    started = {s.executable for s in specs if s.name in procs}
    assert ('driver_container' in started) == (drivers == 'container')
    assert ('driver_node' in started) == (drivers == 'separate')
    states = {m: [] for m in expected}
    for m in expected:
        ros_node.create_subscription(ModuleState, f'{ns}/{m}/state', states[m].append, 10)

    def online():
        dead = {n: p.output()[-1500:] for n, p in procs.items() if not p.alive()}
        assert not dead, dead
        return all(s and s[-1].online for s in states.values())

    assert ros_node.spin_until(online, 120.0), {m: s[-1:] for m, s in states.items()}
    # A node's name reaches a peer's graph on its own (the participant's node list), not
    # with its first message: a driver whose states arrived may not be listed yet.
    wanted = {(f'{module}_driver', ns) for module in expected}
    assert ros_node.spin_until(
        lambda: wanted <= set(ros_node.get_node_names_and_namespaces()), 30.0), \
        sorted(ros_node.get_node_names_and_namespaces())
    for module, params in expected.items():
        assert states[module][-1].module == module
        got = ParameterClient(ros_node, f'{ns}/{module}_driver').get('module', *CHECKED)
        assert got['module'] == (ParameterType.PARAMETER_STRING, module)
        for key in CHECKED:
            kind, value = got[key]
            assert kind != ParameterType.PARAMETER_NOT_SET, (module, key)
            want = pytest.approx(params[key]) if isinstance(params[key], float) else params[key]
            assert value == want, (module, key, value, params[key])
    for name, proc in procs.items():
        assert proc.stop() == 0, f'{name}: {proc.output()[-2000:]}'
