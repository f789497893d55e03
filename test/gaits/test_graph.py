"""The robot graph shared by the demo runner and the launch files."""
import py_compile
from pathlib import Path

import pytest

from softsnap_gaits.graph import robot_graph
from softsnap_gaits.launching import graph_from_arguments, node_action_kwargs
from softsnap_model.forward import reachable_range
from softsnap_model.scene import list_scenes, load_scene

LAUNCH_DIR = Path(__file__).resolve().parents[2] / 'src' / 'softsnap_gaits' / 'launch'
SCENES = ['brittle_star', 'starfish', 'snake', 'gripper', 'ring']


@pytest.mark.parametrize('name', SCENES)
def test_graph_has_a_sim_and_driver_per_module_and_the_three_nodes(name):
    scene = load_scene(name)
    specs = robot_graph(scene)
    names = [s.name for s in specs]
    assert len(names) == len(set(names))
    for m in scene.modules:
        sim = specs[names.index(f'sim_{m.name}')]
        driver = specs[names.index(f'driver_{m.name}')]
        assert sim.parameters['port'] == driver.parameters['port'] == m.port
        assert driver.parameters['module'] == m.name
        low, straight = reachable_range(scene.skeleton, m.threading_mm)
        assert driver.parameters['straight_length_m'] == pytest.approx(straight / 1000.0)
        # The driver's range never exceeds what the model can reach.
        assert driver.parameters['max_contraction_m'] <= (straight - low) / 1000.0 + 1e-12
        assert driver.parameters['max_contraction_m'] <= m.max_contraction_mm / 1000.0 + 1e-12
    assert {'model_node', 'gait_node', 'rerun_logger'} <= set(names)
    assert all(s.namespace == f'/{scene.name}' for s in specs)
    gait = specs[names.index('gait_node')]
    assert gait.parameters['gait'] == scene.default_gait


def test_real_modules_use_scene_addresses_and_no_simulator():
    scene = load_scene('gripper')
    specs = robot_graph(scene, simulate=False, rerun=False)
    assert not [s for s in specs if s.executable in ('sim_module', 'rerun_logger')]
    drivers = [s for s in specs if s.executable == 'driver_node']
    assert [d.parameters['host'] for d in drivers] == [m.host for m in scene.modules]


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


def test_launch_arguments_map_to_the_same_graph_as_the_demo():
    scene = load_scene('brittle_star')
    from_launch = graph_from_arguments('brittle_star', {'simulate': 'false', 'rerun': 'false',
                                                        'gait_rate': '20'})
    direct = robot_graph(scene, simulate=False, rerun=False, gait_rate_hz=20.0)
    assert from_launch == direct
    kwargs = node_action_kwargs(direct[0])
    assert kwargs['executable'] == 'driver_node'
    assert kwargs['parameters'] == [direct[0].parameters]
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
    drivers = {s.parameters['module']: s.parameters['port'] for s in specs
               if s.executable == 'driver_node'}
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


def test_physics_graph_runs_every_node_but_the_simulator_and_the_recorder_on_sim_time():
    scene = load_scene('brittle_star')
    graph = robot_graph(scene, physics=True, bag=Path('/tmp/bag-not-written'))
    on_sim_time = {n.name for n in graph if n.parameters.get('use_sim_time') is True}
    assert on_sim_time == {*(f'driver_{m.name}' for m in scene.modules), 'model_node',
                           'gait_node', 'rerun_logger'}
    sim_robot = next(n for n in graph if n.executable == 'sim_robot')
    assert 'use_sim_time' not in sim_robot.parameters            # it makes the clock
    assert '-p' in sim_robot.ros_args() and 'use_sim_time:=true' not in sim_robot.ros_args()
    assert 'use_sim_time:=true' in next(n for n in graph if n.name == 'gait_node').ros_args()
    # Without physics (sim_module or real modules) every node keeps the wall clock.
    assert not any('use_sim_time' in n.parameters for n in robot_graph(scene, bag=Path('/tmp/b')))
    launched = graph_from_arguments('brittle_star', {'physics': 'true'})
    assert {n.name for n in launched if n.parameters.get('use_sim_time')} == on_sim_time
