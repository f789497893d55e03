"""The robot graph shared by the demo runner and the launch files."""
import py_compile
from pathlib import Path

import pytest

import yaml

from softsnap_gaits.graph import driver_parameters, robot_graph
from softsnap_gaits.launching import graph_from_arguments, node_action_kwargs
from softsnap_model.forward import reachable_range
from softsnap_model.scene import list_scenes, load_scene

LAUNCH_DIR = Path(__file__).resolve().parents[2] / 'src' / 'softsnap_gaits' / 'launch'
SCENES = ['brittle_star', 'starfish', 'snake', 'gripper', 'ring']


@pytest.mark.parametrize('drivers', ['container', 'separate'])
@pytest.mark.parametrize('name', SCENES)
def test_graph_has_a_sim_and_driver_per_module_and_the_three_nodes(name, drivers):
    scene = load_scene(name)
    specs = robot_graph(scene, drivers=drivers)
    names = [s.name for s in specs]
    assert len(names) == len(set(names))
    params = driver_parameters(specs)
    assert list(params) == [m.name for m in scene.modules]
    for m in scene.modules:
        sim = specs[names.index(f'sim_{m.name}')]
        driver = params[m.name]
        assert sim.parameters['port'] == driver['port'] == m.port
        assert driver['module'] == m.name
        low, straight = reachable_range(scene.skeleton, m.threading_mm)
        assert driver['straight_length_m'] == pytest.approx(straight / 1000.0)
        assert driver['counts_per_mm'] == m.counts_per_mm
        # The driver's range never exceeds what the model can reach.
        assert driver['max_contraction_m'] <= (straight - low) / 1000.0 + 1e-12
        assert driver['max_contraction_m'] <= m.max_contraction_mm / 1000.0 + 1e-12
    executables = [s.executable for s in specs]
    if drivers == 'container':
        assert executables.count('driver_container') == 1 and 'driver_node' not in executables
    else:
        # One driver_node per module, each named as the container names its drivers.
        assert [s.name for s in specs if s.executable == 'driver_node'] == [
            f'{m.name}_driver' for m in scene.modules]
        assert 'driver_container' not in executables
    assert {'model_node', 'gait_node', 'rerun_logger'} <= set(names)
    assert all(s.namespace == f'/{scene.name}' for s in specs)
    gait = specs[names.index('gait_node')]
    assert gait.parameters['gait'] == scene.default_gait


def test_real_modules_use_scene_addresses_and_no_simulator():
    scene = load_scene('gripper')
    specs = robot_graph(scene, simulate=False, rerun=False)
    assert not [s for s in specs if s.executable in ('sim_module', 'rerun_logger')]
    drivers = driver_parameters(specs).values()
    assert [d['host'] for d in drivers] == [m.host for m in scene.modules]
    assert [d['port'] for d in drivers] == [m.port for m in scene.modules]


def test_container_parameters_file_keys_each_driver_by_its_full_name(tmp_path):
    """The drivers' parameters reach the container as one file, each under the driver's
    fully qualified name (a bare name would miss a node in a namespace)."""
    scene = load_scene('gripper')
    specs = robot_graph(scene, rerun=False)
    container = next(s for s in specs if s.executable == 'driver_container')
    with pytest.raises(ValueError, match='parameters file'):
        container.ros_args()
    path = container.write_node_params(tmp_path)
    args = container.ros_args(path)
    assert args[:5] == ['--ros-args', '-r', '__node:=driver_container', '-r', '__ns:=/gripper']
    assert args[5:] == ['--params-file', str(path)]
    written = yaml.safe_load(path.read_text())
    assert written['/gripper/driver_container'] == {
        'ros__parameters': {'modules': [m.name for m in scene.modules]}}
    params = driver_parameters(specs)
    for m in scene.modules:
        expected = {k: v for k, v in params[m.name].items() if k != 'module'}
        assert written[f'/gripper/{m.name}_driver'] == {'ros__parameters': expected}
    assert len(written) == len(scene.modules) + 1
    # Processes without other nodes write no file.
    assert next(s for s in specs if s.name == 'gait_node').write_node_params(tmp_path) is None


def test_a_bad_drivers_value_is_refused_with_the_choices():
    scene = load_scene('snake')
    with pytest.raises(ValueError, match=r"drivers must be one of container, separate, got 'threads'"):
        robot_graph(scene, drivers='threads')
    with pytest.raises(ValueError, match=r"launch argument drivers must be one of container, "
                                         r"separate, got 'one'"):
        graph_from_arguments('snake', {'drivers': 'one'})


def test_ros_args_encode_names_namespaces_and_parameters():
    spec = robot_graph(load_scene('snake'), recording='/tmp/x.rrd')[-1]
    args = spec.ros_args()
    assert args[:5] == ['--ros-args', '-r', '__node:=rerun_logger', '-r', '__ns:=/snake']
    assert '-p' in args and 'output:=/tmp/x.rrd' in args
    gait_args = [s for s in robot_graph(load_scene('snake')) if s.name == 'gait_node'][0].ros_args()
    assert 'autostart:=true' in gait_args


def test_launch_files_exist_for_every_scene_and_use_the_shared_graph():
    assert set(SCENES) <= set(list_scenes())
    for name in SCENES:
        path = LAUNCH_DIR / f'{name}.launch.py'
        py_compile.compile(str(path), doraise=True)
        text = path.read_text()
        assert f"generate_robot_launch_description('{name}')" in text


def test_launch_arguments_map_to_the_same_graph_as_the_demo(tmp_path):
    scene = load_scene('brittle_star')
    from_launch = graph_from_arguments('brittle_star', {'simulate': 'false', 'rerun': 'false',
                                                        'gait_rate': '20'})
    direct = robot_graph(scene, simulate=False, rerun=False, gait_rate_hz=20.0)
    assert from_launch == direct
    kwargs = node_action_kwargs(direct[0], tmp_path)
    assert kwargs['executable'] == 'driver_container'
    # The container's own (none) as launch_ros's dict, its drivers' as the same file
    # the demo runner passes.
    assert kwargs['parameters'] == [{}, tmp_path / 'driver_container.params.yaml']
    assert kwargs['parameters'][1].read_text() == direct[0].node_params_yaml()
    separate = graph_from_arguments('brittle_star', {'simulate': 'false', 'rerun': 'false',
                                                     'gait_rate': '20', 'drivers': 'separate'})
    assert separate == robot_graph(scene, simulate=False, rerun=False, gait_rate_hz=20.0,
                                   drivers='separate')
    kwargs = node_action_kwargs(separate[0])
    assert kwargs['executable'] == 'driver_node'
    assert kwargs['parameters'] == [separate[0].parameters]
    with pytest.raises(ValueError, match='true or false'):
        graph_from_arguments('brittle_star', {'simulate': 'maybe'})


def test_physics_graph_has_one_sim_robot_on_consecutive_ports():
    scene = load_scene('brittle_star')
    ports = {m.name: 21000 + i for i, m in enumerate(scene.modules)}
    specs = robot_graph(scene, physics=True, sim_ports=ports,
                        sim_robot_parameters={'time_factor': 2.0})
    sims = [s for s in specs if s.executable.startswith('sim_')]
    assert [s.executable for s in sims] == ['sim_robot'] and specs[0] is sims[0]
    assert sims[0].parameters['port_base'] == 21000 and sims[0].parameters['time_factor'] == 2.0
    assert sims[0].parameters['scene'] == str(scene.path)
    drivers = {module: p['port'] for module, p in driver_parameters(specs).items()}
    assert drivers == ports
    logger = [s for s in specs if s.executable == 'rerun_logger'][0]
    assert logger.parameters['world_view'] is True
    # The scene's own ports (consecutive in every scene) when none are given.
    assert robot_graph(scene, physics=True)[0].parameters['port_base'] == 0


def test_physics_graph_refuses_scattered_ports_and_real_modules():
    scene = load_scene('gripper')
    scattered = {m.name: 21000 + 2 * i for i, m in enumerate(scene.modules)}
    with pytest.raises(ValueError, match='consecutive ports'):
        robot_graph(scene, physics=True, sim_ports=scattered)
    with pytest.raises(ValueError, match='physics needs simulated modules'):
        robot_graph(scene, physics=True, simulate=False)


def test_launch_argument_physics_starts_sim_robot():
    specs = graph_from_arguments('snake', {'physics': 'true', 'sim_port_base': '21000',
                                           'rerun': 'false'})
    assert specs[0].executable == 'sim_robot' and specs[0].parameters['port_base'] == 21000
    assert not [s for s in specs if s.executable == 'sim_module']
    with pytest.raises(ValueError, match='physics needs simulated modules'):
        graph_from_arguments('snake', {'physics': 'true', 'simulate': 'false'})


@pytest.mark.parametrize('drivers', ['container', 'separate'])
def test_physics_graph_runs_every_node_but_the_simulator_and_the_recorder_on_sim_time(drivers):
    scene = load_scene('brittle_star')
    graph = robot_graph(scene, physics=True, bag=Path('/tmp/bag-not-written'), drivers=drivers)

    def on_sim_time_of(specs):
        return {n.name for n in specs if n.parameters.get('use_sim_time') is True} | {
            f'{m}_driver' for m, p in driver_parameters(specs).items() if p.get('use_sim_time')}

    on_sim_time = on_sim_time_of(graph)
    assert on_sim_time == {*(f'{m.name}_driver' for m in scene.modules), 'model_node',
                           'gait_node', 'rerun_logger', 'robot_state'}
    sim_robot = next(n for n in graph if n.executable == 'sim_robot')
    assert 'use_sim_time' not in sim_robot.parameters            # it makes the clock
    assert '-p' in sim_robot.ros_args() and 'use_sim_time:=true' not in sim_robot.ros_args()
    assert 'use_sim_time:=true' in next(n for n in graph if n.name == 'gait_node').ros_args()
    # Without physics (sim_module or real modules) every node keeps the wall clock.
    wall = robot_graph(scene, bag=Path('/tmp/b'), drivers=drivers)
    assert not any('use_sim_time' in n.parameters for n in wall)
    assert not any('use_sim_time' in p for p in driver_parameters(wall).values())
    launched = graph_from_arguments('brittle_star', {'physics': 'true', 'drivers': drivers})
    assert on_sim_time_of(launched) == on_sim_time


def test_demo_option_drivers_takes_the_two_modes_and_refuses_others(capsys):
    from softsnap_gaits.demo import build_parser
    assert build_parser().parse_args([]).drivers == 'container'
    assert build_parser().parse_args(['--drivers', 'separate']).drivers == 'separate'
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args(['--drivers', 'threads'])
    assert exit_info.value.code == 2
    assert "--drivers: invalid choice: 'threads' (choose from 'container', 'separate')" \
        in capsys.readouterr().err
