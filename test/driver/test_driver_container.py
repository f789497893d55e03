"""driver_container across processes: several modules' drivers in one process, each as
a driver_node process would be (names, topics, services, stops), failing alone."""
import pytest

from test_driver_ros import NS, ModuleProbe, driver_args, within_deadband

pytestmark = pytest.mark.ros

MODULES = ('m1', 'm2', 'm3')


def container_args(ports, **params):
    """The drivers' shared parameters as in test_driver_ros, the modules and their ports."""
    args = driver_args(None, module=None, **params)   # from ports/modules below
    return args + ['-p', f'modules:=[{",".join(MODULES)}]',
                   '-p', f'ports:=[{",".join(str(p) for p in ports)}]']


def reach(ros_node, probe, length_m, timeout=15.0):
    probe.command(length_m)
    return ros_node.spin_until(lambda: probe.measured and within_deadband(
        probe.measured[-1].cable_length, length_m), timeout)


def test_each_module_is_driven_stopped_and_fails_on_its_own(start_node, ros_node, slot_port):
    ports = [slot_port() for _ in MODULES]
    assert len(set(ports)) == len(ports)
    sims = {m: start_node('softsnap_driver', 'sim_module', '--ros-args', '-r', f'__node:=sim_{m}',
                          '-p', f'port:={port}') for m, port in zip(MODULES, ports)}
    # A 2 s request deadline (driver_args' 0.3 s is for fast failure tests): a request
    # starved for 0.3 s on a busy machine must not count as m3's failure spilling over.
    container = start_node('softsnap_driver', 'driver_container',
                           *container_args(ports, request_timeout_s=2.0))
    probes = {m: ModuleProbe(ros_node, m) for m in MODULES}
    for probe in probes.values():
        probe.wait_ready(30.0)
    # Node names come over DDS's discovery-info topic, which can lag the data on a busy
    # machine: wait for them rather than read the graph once.
    wanted = {f'{m}_driver' for m in MODULES}

    def names():
        return {name for name, ns in ros_node.get_node_names_and_namespaces() if ns == NS}

    assert ros_node.spin_until(lambda: wanted <= names(), 30.0), names()
    assert [probes[m].last().module for m in MODULES] == list(MODULES)

    # Each module tracks its own command (different lengths: no crossed wires).
    targets = {'m1': 0.185, 'm2': 0.160, 'm3': 0.140}
    for m, length in targets.items():
        assert reach(ros_node, probes[m], length), f'{m} did not reach {length} m'
    for m, length in targets.items():
        assert within_deadband(probes[m].measured[-1].cable_length, length), m

    # A confirmed stop of one module: the others still follow their commands.
    probes['m2'].command(0.190)
    response = probes['m2'].call('stop')
    assert response.success and 'confirmed' in response.message, response.message
    assert reach(ros_node, probes['m1'], 0.170)
    assert reach(ros_node, probes['m3'], 0.150)

    # One module's link fails (its simulator gone): it alone goes offline. Failures counted
    # so far are the container's first polls racing the simulators' start on a busy
    # machine (refused connections): only new ones would be m3's failure spilling over.
    failures_before = {m: probes[m].last().request_failures for m in ('m1', 'm2')}
    assert sims['m3'].stop() == 0
    assert probes['m3'].wait_state(lambda s: not s.online, 20.0), probes['m3'].last()
    assert 'failed' in probes['m3'].last().last_error
    assert reach(ros_node, probes['m1'], 0.180)
    assert reach(ros_node, probes['m2'], 0.165)
    for m in ('m1', 'm2'):
        state = probes[m].last()
        assert state.online and not state.last_error, (m, state)
        assert state.request_failures == failures_before[m], (m, failures_before[m], state)

    # SIGINT: a clean exit, with each reachable module stopped (confirmed) on the way.
    assert container.alive()
    assert container.stop() == 0
    log = container.log_path.read_text(errors="replace")
    for port in ports[:2]:
        assert f'stop confirmed at 127.0.0.1:{port} (shutdown)' in log, log[-3000:]
    # The unreachable module's shutdown stop is reported as such, not claimed.
    assert 'stop NOT confirmed' in log and '[robot.m3_driver]' in log, log[-3000:]


def test_bad_module_lists_end_with_the_reason(start_node):
    for params, reason in ((['-p', 'modules:=[m1,m1]'], 'must differ'),
                           (['-p', 'modules:=[m1,m2]', '-p', 'ports:=[8101]'], 'one value per module'),
                           (['-p', 'modules:=[1x]'], 'module names')):
        proc = start_node('softsnap_driver', 'driver_container', '--ros-args', *params)
        proc.proc.wait(60)
        assert proc.proc.returncode == 2, proc.output()
        assert reason in proc.output(), proc.output()
