"""Each launch file's nodes, started with exactly the command lines launch_ros builds.

``launch`` is not on PyPI, so the launch files' graphs (softsnap_gaits.launching) are
started here with :func:`launch_command.launch_ros_command`, which reproduces
``launch_ros.actions.Node``: ``--ros-args -r __node:=NAME -r __ns:=/NS --params-file
launch_params_XXXX`` with the parameters in a temporary YAML file (and, for the
driver_container, ``--params-file <its drivers' file>``). Then the graph must come up:
every node under its name and namespace (each driver as ``<module>_driver``, in the
container or not), every driver reporting its module online, and (for the scene
started whole) the model node publishing shapes.

The launch argument ``sim_port_base`` gives the simulated modules this session's free
ports instead of the scenes' fixed ones, so the test can run beside a demo.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import yaml

from launch_command import launch_ros_command
from softsnap_gaits.graph import driver_parameters
from softsnap_gaits.launching import LAUNCH_ARGUMENTS, graph_from_arguments, node_action_kwargs

pytestmark = [pytest.mark.ros, pytest.mark.slow]

LAUNCH_DIR = Path(__file__).resolve().parents[2] / 'src' / 'softsnap_gaits' / 'launch'
SCENES = ['brittle_star', 'starfish', 'snake', 'gripper', 'ring']


def launch_file_scene(scene: str) -> str:
    """The scene a launch file starts: read from the file itself (its one call)."""
    text = (LAUNCH_DIR / f'{scene}.launch.py').read_text()
    assert f"generate_robot_launch_description('{scene}')" in text
    return scene


def start_launch_graph(start_node, tmp_path, scene, arguments, only=None):
    """Start the launch file's nodes (those whose executable is in `only`, or all)."""
    from ament_index_python.packages import get_package_prefix
    specs = graph_from_arguments(launch_file_scene(scene), arguments)
    if only is not None:
        specs = [s for s in specs if s.executable in only]
    params_dir = tmp_path / 'launch_params'
    params_dir.mkdir(exist_ok=True)
    started = []
    for spec in specs:
        kwargs = node_action_kwargs(spec, params_dir)
        cmd = launch_ros_command(kwargs, Path(get_package_prefix(kwargs['package'])), params_dir)
        proc = start_node(kwargs['package'], kwargs['executable'], *cmd[1:])
        started.append((spec, cmd, proc))
    return started


def wait_for_graph(ros_node, started, scene, need_shapes: bool, timeout=120.0):
    from softsnap_interfaces.msg import ModuleShape, ModuleState
    ns = f'/{scene}'
    modules = list(driver_parameters([s for s, _, _ in started]))
    assert modules
    online = {m: False for m in modules}
    shapes = {m: 0 for m in modules}
    subs = []
    for m in modules:
        subs.append(ros_node.create_subscription(
            ModuleState, f'{ns}/{m}/state', lambda msg, m=m: online.__setitem__(m, online[m] or msg.online), 10))
        if need_shapes:
            for source in ('commanded', 'predicted'):
                subs.append(ros_node.create_subscription(
                    ModuleShape, f'{ns}/{m}/shape/{source}',
                    lambda msg, m=m: shapes.__setitem__(m, shapes[m] + 1), 10))
    wanted = {(s.name, ns) for s, _, _ in started} | {(f'{m}_driver', ns) for m in modules}

    def present():
        return wanted <= set(ros_node.get_node_names_and_namespaces())

    def up():
        dead = [s.name for s, _, p in started if not p.alive()]
        assert not dead, {name: p.output()[-1500:] for s, _, p in started for name in dead if s.name == name}
        return present() and all(online.values()) and (not need_shapes or all(
            n >= 2 for n in shapes.values()))

    ok = ros_node.spin_until(up, timeout)
    in_ns = [n for n in ros_node.get_node_names_and_namespaces() if n[1] == ns]
    # `-r __node:=NAME` renames every node of a process: no two may end up with one name.
    assert len(in_ns) == len(set(in_ns)), sorted(in_ns)
    report = {'missing nodes': sorted(wanted - set(ros_node.get_node_names_and_namespaces())),
              'online': online, 'shapes': shapes}
    for sub in subs:
        ros_node.destroy_subscription(sub)
    assert ok, report


def assert_sims_serve_their_ports(started):
    """Each simulated module answers on the port its params file gave it (not the default)."""
    from softsnap_driver.protocol import ModuleClient
    for spec, _, proc in started:
        if spec.executable == 'sim_module':
            port = spec.parameters['port']
            assert port != 8101
            status = ModuleClient('127.0.0.1', port, timeout_s=5.0).status()
            assert status.encoder_count is not None, proc.output()[-1000:]


def test_launch_commands_match_launch_ros(tmp_path, slot_port):
    """The reproduced command: flag order, the params file's node key and YAML values."""
    base = slot_port()
    spec = graph_from_arguments('gripper', {'sim_port_base': str(base)})[0]
    cmd = launch_ros_command(node_action_kwargs(spec), Path('/prefix'), tmp_path)
    assert cmd[:6] == ['/prefix/lib/softsnap_driver/sim_module', '--ros-args',
                       '-r', f'__node:={spec.name}', '-r', '__ns:=/gripper']
    assert cmd[6] == '--params-file' and Path(cmd[7]).name.startswith('launch_params_')
    assert yaml.safe_load(Path(cmd[7]).read_text()) == {
        f'/gripper/{spec.name}': {'ros__parameters': {'host': '127.0.0.1', 'port': base}}}
    assert set(LAUNCH_ARGUMENTS) >= {'simulate', 'gait', 'recording', 'sim_port_base', 'drivers'}
    # The drivers' container: its own (empty) dict file, then its drivers' file as is.
    specs = graph_from_arguments('gripper', {'sim_port_base': str(base)})
    container = next(s for s in specs if s.executable == 'driver_container')
    cmd = launch_ros_command(node_action_kwargs(container, tmp_path), Path('/prefix'), tmp_path)
    assert cmd[:6] == ['/prefix/lib/softsnap_driver/driver_container', '--ros-args',
                       '-r', '__node:=driver_container', '-r', '__ns:=/gripper']
    assert cmd[6] == '--params-file' and cmd[8:] == [
        '--params-file', str(tmp_path / 'driver_container.params.yaml')]
    drivers = yaml.safe_load(Path(cmd[9]).read_text())
    assert drivers['/gripper/front_left_driver']['ros__parameters']['port'] == base
    assert drivers['/gripper/driver_container']['ros__parameters']['modules'] == [
        'front_left', 'back_left', 'back_right', 'front_right']


def test_brittle_star_launch_graph_comes_up_whole(start_node, ros_node, tmp_path, slot_port):
    base = slot_port(5)  # the scene's five consecutive ports
    started = start_launch_graph(start_node, tmp_path, 'brittle_star', {
        'sim_port_base': str(base), 'recording': str(tmp_path / 'launch.rrd')})
    assert {s.executable for s, _, _ in started} == {
        'sim_module', 'driver_container', 'model_node', 'gait_node', 'rerun_logger',
        'robot_state'}
    wait_for_graph(ros_node, started, 'brittle_star', need_shapes=True)
    assert_sims_serve_their_ports(started)


@pytest.mark.parametrize('scene, drivers', [
    ('starfish', 'container'), ('snake', 'separate'), ('gripper', 'container'),
    ('ring', 'container')])
def test_launch_graph_modules_come_up(scene, drivers, start_node, ros_node, tmp_path, slot_port):
    """Every simulated module binds its own port and every driver sees it online, the
    drivers in one container or (drivers:=separate) one driver_node each."""
    base = slot_port(5)
    started = start_launch_graph(start_node, tmp_path, scene, {
        'sim_port_base': str(base), 'drivers': drivers},
        only=('sim_module', 'driver_node', 'driver_container'))
    executables = [s.executable for s, _, _ in started]
    if drivers == 'container':
        assert executables.count('driver_container') == 1 and 'driver_node' not in executables
    else:
        assert executables.count('driver_node') == executables.count('sim_module')
    ports = [s.parameters['port'] for s, _, _ in started if s.executable == 'sim_module']
    assert len(ports) == len(set(ports)) >= 4
    wait_for_graph(ros_node, started, scene, need_shapes=False)
    assert_sims_serve_their_ports(started)


def test_launch_files_import_only_softsnap_launching():
    """Each launch file is the thin wrapper the test reproduces (no other nodes, no logic)."""
    for scene in SCENES:
        path = LAUNCH_DIR / f'{scene}.launch.py'
        spec = importlib.util.spec_from_file_location(f'launch_{scene}', path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)  # imports softsnap_gaits.launching only
        assert callable(module.generate_launch_description)
        assert launch_file_scene(scene) == scene


def test_physics_launch_graph_runs_on_the_simulated_clock(start_node, ros_node, tmp_path, slot_port):
    """physics:=true: every node but sim_robot gets use_sim_time in its params file, and
    the gait's stamps are sim_robot's /clock, not the wall clock."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from softsnap_interfaces.msg import GaitPhase
    base = slot_port(4)
    started = start_launch_graph(start_node, tmp_path, 'gripper', {
        'sim_port_base': str(base), 'physics': 'true'},
        only=('sim_robot', 'driver_container', 'gait_node'))
    assert {s.executable for s, _, _ in started} == {'sim_robot', 'driver_container', 'gait_node'}
    for spec, cmd, _ in started:
        files = [Path(cmd[i + 1]) for i, arg in enumerate(cmd) if arg == '--params-file']
        params = {}
        for path in files:
            params.update(yaml.safe_load(path.read_text()))
        if spec.executable == 'driver_container':
            # Each driver's own, in the second file, under its fully qualified name.
            assert len(files) == 2
            for m in driver_parameters([spec]):
                assert params[f'/gripper/{m}_driver']['ros__parameters']['use_sim_time'] is True
            continue
        params = params[f'/gripper/{spec.name}']['ros__parameters']
        expected = None if spec.executable == 'sim_robot' else True
        assert params.get('use_sim_time') is expected, (spec.name, params)
    clocks, phases = [], []
    ros_node.create_subscription(Clock, '/clock', lambda m: clocks.append(m.clock),
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    ros_node.create_subscription(GaitPhase, '/gripper/gait/phase',
                                 lambda m: phases.append(m) if m.running else None, 100)
    wait_for_graph(ros_node, started, 'gripper', need_shapes=False)
    assert ros_node.spin_until(lambda: len(phases) >= 20 and clocks, 120.0), (len(phases), len(clocks))
    ros_node.spin_until(lambda: False, 0.5)    # the /clock of the newest phase has come

    def seconds(t):
        return t.sec + t.nanosec * 1e-9

    latest = max(seconds(c) for c in clocks)
    stamps = [seconds(p.header.stamp) for p in phases]
    # Simulated time since sim_robot started (the wall clock would be ~1.7e9 s).
    assert 0.0 < stamps[0] <= stamps[-1] <= latest + 0.05, (stamps[0], stamps[-1], latest)
    assert latest < 1e5
