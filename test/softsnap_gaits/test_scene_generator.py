"""Generated scenes of any size (issue 37): they load, chain, walk and fit the graph."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import yaml

from softsnap_gaits.gaits import make_gait
from softsnap_gaits.graph import robot_graph
from softsnap_gaits.scene_generator import lattice_scene, snake_scene
from softsnap_model.scene import SceneError, load_scene, straight_tip_pose


def _write(tmp_path, data, name='scene.yaml'):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_fifty_module_snake_loads_as_a_chain_longer_than_the_old_5_m_cap(tmp_path):
    scene = load_scene(_write(tmp_path, snake_scene(50)))
    assert len(scene.modules) == 50
    # The head's base lies 49 pitches from the tail: 12.2 m, past the old 5 m limit.
    head = scene.modules[0]
    assert math.dist(head.base_position_m, (0.0, 0.0, 0.0)) == pytest.approx(49 * 0.248)
    # Every module sits on the tip of the one behind it: load_scene checks each stated base
    # against the parent's straight tip pose; recompute one pair here from the skeleton.
    for child, parent in zip(scene.modules[:-1], scene.modules[1:]):
        assert child.parent == parent.name
        tip_position, _ = straight_tip_pose(parent, scene.skeleton)
        assert child.base_position_m[0] == pytest.approx(tip_position[0] + 0.050, abs=1e-9)


def test_the_snake_wave_fits_one_period_and_respects_the_winches(tmp_path):
    scene = load_scene(_write(tmp_path, snake_scene(50)))
    gait = make_gait('concertina', scene)   # GaitError if a module outruns its winch
    lengths = np.array([gait.contraction_mm(t) for t in np.linspace(0.0, 3.0, 301)])
    assert lengths.shape[1] == 50
    assert lengths.max() == pytest.approx(25.0, rel=1e-6)
    # Head and tail both move within one cycle: the wave spans at most half of it.
    moved = (lengths > 1e-9).any(axis=0)
    assert moved.all()


def test_a_lattice_walks_in_two_checkerboard_groups(tmp_path):
    data = lattice_scene(5, 10)
    scene = load_scene(_write(tmp_path, data))
    assert len(scene.modules) == 50
    groups = data['gaits']['walk']['groups']
    assert sorted(groups[0] + groups[1]) == sorted(m.name for m in scene.modules)
    position = {m.name: np.asarray(m.base_position_m) for m in scene.modules}
    group_of = {name: g for g, names in enumerate(groups) for name in names}
    # Nearest neighbours (one pitch apart in a row or a column) always move against each other.
    for a in position:
        for b in position:
            d = np.linalg.norm(position[a] - position[b])
            if a != b and d < 0.13:
                assert group_of[a] != group_of[b]
    make_gait('walk', scene)


def test_generated_scenes_refuse_empty_robots():
    with pytest.raises(ValueError, match='at least one module'):
        snake_scene(0)
    with pytest.raises(ValueError, match='at least 1 x 1'):
        lattice_scene(0, 3)


def test_a_base_farther_than_a_kilometre_is_still_a_unit_mistake(tmp_path):
    data = lattice_scene(1, 1)
    data['modules'][0]['base']['position_mm'] = [2.0e6, 0.0, 0.0]
    with pytest.raises(SceneError, match='within 1e\\+06 mm'):
        load_scene(_write(tmp_path, data))


def test_the_command_line_writes_a_scene_that_loads(tmp_path):
    out = tmp_path / 'lattice.yaml'
    run = subprocess.run([sys.executable, '-m', 'softsnap_gaits.scene_generator', 'lattice', '3x4',
                          '-o', str(out)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert 'lattice_3x4, 12 modules' in run.stdout
    assert len(load_scene(out).modules) == 12
    bad = subprocess.run([sys.executable, '-m', 'softsnap_gaits.scene_generator', 'lattice', '3by4',
                          '-o', str(out)], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and 'ROWSxCOLUMNS' in bad.stderr


def test_shared_simulated_modules_are_one_process_on_consecutive_ports(tmp_path):
    scene = load_scene(_write(tmp_path, snake_scene(40)))
    ports = {m.name: 21000 + i for i, m in enumerate(scene.modules)}
    specs = robot_graph(scene, sim_ports=ports, sim_modules='shared')
    sims = [s for s in specs if s.executable == 'sim_module']
    assert len(sims) == 1
    assert sims[0].name == 'sim_modules'
    assert sims[0].parameters == {'host': '127.0.0.1', 'port': 21000, 'count': 40}
    # Each driver still talks to its own module's port.
    container = next(s for s in specs if s.executable == 'driver_container')
    assert [container.node_parameters[f'{m.name}_driver']['port'] for m in scene.modules] == \
        list(range(21000, 21040))
    # Separate processes stay the default.
    assert sum(s.executable == 'sim_module' for s in robot_graph(scene, sim_ports=ports)) == 40


def test_shared_simulated_modules_need_consecutive_ports(tmp_path):
    scene = load_scene(_write(tmp_path, snake_scene(3)))
    ports = {m.name: 21000 + 2 * i for i, m in enumerate(scene.modules)}
    with pytest.raises(ValueError, match='consecutive ports'):
        robot_graph(scene, sim_ports=ports, sim_modules='shared')
    with pytest.raises(ValueError, match='sim_modules must be one of'):
        robot_graph(scene, sim_modules='pooled')
