"""sim_robot as a process over real loopback sockets, driven by the graph's driver_container.

The gripper (four modules hanging from a fixed connector: the cheapest robot to simulate)
runs in sim_robot; its drivers are started with the parameters the demo gives them
(softsnap_gaits.graph), so the driver sees exactly what it would see in a demo.
"""
from __future__ import annotations

import numpy as np
import pytest

from softsnap_driver.firmware import DEADBAND_COUNTS

pytestmark = pytest.mark.ros

NS = '/gripper'
TIMEOUT_S = 90.0    # a model build and a simulation slower than real time on a busy machine


def _graph(port_base: int, **sim_params):
    from softsnap_gaits.graph import robot_graph
    from softsnap_model.scene import load_scene
    scene = load_scene('gripper')
    ports = {m.name: port_base + i for i, m in enumerate(scene.modules)}
    params = {'links_per_segment': 1, **sim_params}
    return robot_graph(scene, physics=True, sim_ports=ports, rerun=False,
                       sim_robot_parameters=params)


def _start(start_node, tmp_path, specs, names):
    """Start the processes named in `names` (the graph's driver_container drives every
    module)."""
    from softsnap_gaits.graph import with_driver_parameters
    procs = {}
    # One command per test, not a gait's stream: no stale-stream watchdog.
    for spec in with_driver_parameters(specs, command_timeout_s=0.0):
        if spec.name in names:
            procs[spec.name] = start_node(spec.package, spec.executable,
                                          *spec.ros_args(spec.write_node_params(tmp_path)))
    return procs


def _driver(specs, module):
    from softsnap_gaits.graph import driver_parameters
    return driver_parameters(specs)[module]


class Probe:
    """Driver state, measured lengths and simulated shapes of the gripper, as seen here."""

    def __init__(self, node, modules):
        from geometry_msgs.msg import PoseStamped
        from softsnap_interfaces.msg import CableLength, ModuleState, RobotShape
        self.node = node
        self.CableLength = CableLength
        self.states = {m: [] for m in modules}
        self.measured = {m: [] for m in modules}
        self.shapes = []
        self.poses = []
        self.commands = {}
        for m in modules:
            node.create_subscription(ModuleState, f'{NS}/{m}/state', self.states[m].append, 50)
            node.create_subscription(CableLength, f'{NS}/{m}/cable_length/measured',
                                     self.measured[m].append, 50)
            self.commands[m] = node.create_publisher(CableLength, f'{NS}/{m}/cable_length/command', 10)
        node.create_subscription(RobotShape, f'{NS}/model/shape/simulated', self.shapes.append, 50)
        node.create_subscription(PoseStamped, f'{NS}/sim/base_pose', self.poses.append, 50)

    def ready(self):
        # A measured length too: a driver's first state can be online before the module
        # is calibrated, with a NaN length (a test once commanded NaN - 30 mm from it).
        return (self.shapes and self.poses
                and all(s and s[-1].online and np.isfinite(s[-1].measured_cable_length)
                        for s in self.states.values())
                and all(p.get_subscription_count() > 0 for p in self.commands.values()))

    def command(self, module, length_m):
        msg = self.CableLength()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.cable_length = float(length_m)
        self.commands[module].publish(msg)

    def tip(self, module):
        shape = self.shapes[-1]
        i = [s.module for s in shape.modules].index(module)
        p = shape.modules[i].rib_centers[-1]
        return np.array([p.x, p.y, p.z])


def test_a_length_command_moves_the_simulated_module_and_the_encoder_follows(
        start_node, ros_node, slot_port, tmp_path):
    specs = _graph(slot_port(4))
    modules = ['front_left', 'back_left']
    procs = _start(start_node, tmp_path, specs, {'sim_robot', 'driver_container'})
    probe = Probe(ros_node, modules)
    assert ros_node.spin_until(probe.ready, TIMEOUT_S), \
        '\n'.join(p.output()[-2000:] for p in procs.values())
    shape = probe.shapes[-1]
    assert shape.header.frame_id == 'world' and shape.robot == 'gripper'
    assert [s.module for s in shape.modules] == ['front_left', 'back_left', 'back_right',
                                                 'front_right']
    assert all(s.source == 'simulated' and len(s.rib_centers) == 12 and len(s.angles) == 11
               for s in shape.modules)
    assert len(shape.base_poses) == 4 and probe.poses[-1].header.frame_id == 'world'
    tip_before = {m: probe.tip(m) for m in modules}
    straight_m = probe.states['front_left'][-1].measured_cable_length
    driver = _driver(specs, 'front_left')
    target_m = straight_m - 0.020

    probe.command('front_left', target_m)
    counts_per_mm = driver['counts_per_mm']
    target_count = round(20.0 * counts_per_mm)

    def arrived():
        s = probe.states['front_left'][-1]
        return s.encoder_target == target_count and abs(s.encoder_count - target_count) <= DEADBAND_COUNTS

    assert ros_node.spin_until(arrived, TIMEOUT_S), probe.states['front_left'][-1]
    # The measured length is the winch's, the model's cable length of the same count.
    assert ros_node.spin_until(lambda: abs(probe.measured['front_left'][-1].cable_length
                                           - target_m) <= (DEADBAND_COUNTS + 1) / counts_per_mm / 1000,
                               30.0), probe.measured['front_left'][-1]
    # The simulated module bent (its tip moved), the uncommanded one did not.
    assert ros_node.spin_until(
        lambda: np.linalg.norm(probe.tip('front_left') - tip_before['front_left']) > 0.01, 30.0)
    assert np.linalg.norm(probe.tip('back_left') - tip_before['back_left']) < 0.002
    # The simulated shape reports the winch's cable length (the shapes are sampled at
    # 30 Hz of simulated time, so wait for one taken after the winch arrived).
    def simulated_length():
        return [s for s in probe.shapes[-1].modules if s.module == 'front_left'][0].cable_length

    assert ros_node.spin_until(lambda: abs(simulated_length() - target_m) <= 0.001, 30.0), \
        (simulated_length(), target_m)
    assert probe.states['front_left'][-1].stalls_detected == 0
    # Dependency order: the drivers confirm their stops while sim_robot still serves (a
    # driver whose module is gone exits 3: its last stop not confirmed).
    for name, proc in sorted(procs.items(), key=lambda item: item[0] != 'driver_container'):
        assert proc.alive(), proc.output()[-2000:]
        assert proc.stop() == 0, f'{name}: {proc.log_path.read_text()[-2000:]}'


def test_a_winch_stalled_by_the_cable_tension_is_reported_by_its_driver(
        start_node, ros_node, slot_port, tmp_path):
    # A motor 100 times weaker than the GA12-N20: the cable stops it well before 30 mm.
    specs = _graph(slot_port(4), stall_torque_nm=0.0015)
    procs = _start(start_node, tmp_path, specs, {'sim_robot', 'driver_container'})
    probe = Probe(ros_node, ['front_left'])
    assert ros_node.spin_until(probe.ready, TIMEOUT_S), \
        '\n'.join(p.output()[-2000:] for p in procs.values())
    straight_m = probe.states['front_left'][-1].measured_cable_length
    probe.command('front_left', straight_m - 0.030)
    # Like a jammed real module: the encoder stops short of the target, the driver finds
    # no progress for stall_timeout_s and stops it (a confirmed reach).
    assert ros_node.spin_until(lambda: probe.states['front_left'][-1].stalls_detected >= 1,
                               TIMEOUT_S), probe.states['front_left'][-1]
    state = probe.states['front_left'][-1]
    assert 'stalled' in state.last_error
    assert 0 < state.encoder_count < round(30.0 * 89.13) - DEADBAND_COUNTS
    for name, proc in sorted(procs.items(), key=lambda item: item[0] != 'driver_container'):
        assert proc.stop() == 0, f'{name}: {proc.log_path.read_text()[-2000:]}'


@pytest.mark.parametrize('params, reason', [
    (['scene:=no_such_robot'], 'no_such_robot'),
    (['scene:=brittle_star', 'payload:=ball'], 'payload'),
    (['scene:=gripper', 'payload:=sphere'], "payload must be one of none, ball, box, cylinder, got 'sphere'"),
    (['scene:=gripper', 'time_factor:=-1.0'], 'time_factor'),
])
def test_bad_scene_or_payload_parameters_end_the_node_with_the_reason(start_node, params, reason):
    args = ['--ros-args']
    for p in params:
        args += ['-p', p]
    proc = start_node('softsnap_driver', 'sim_robot', *args)
    assert proc.proc.wait(120) == 2, proc.output()
    assert reason in proc.output() and 'Traceback' not in proc.output(), proc.output()


def test_plain_command_line_refuses_a_bad_payload_without_ros():
    import subprocess
    import sys
    out = subprocess.run([sys.executable, '-m', 'softsnap_driver.sim_robot_runner', '--scene', 'ring',
                          '--payload', 'ball', '--payload-mass-kg', '3'],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert 'mass_kg' in out.stderr and 'Traceback' not in out.stderr, out.stderr
