"""Scene files: schema of the five robots, geometry conventions, and refusal of bad files."""
import math

import numpy as np
import pytest
import yaml

from softsnap_model.scene import (SceneError, compose_base_pose, find_scene, list_scenes,
                                  load_scene, quaternion_to_matrix, straight_tip_pose)

SCENES = ['brittle_star', 'starfish', 'snake', 'gripper', 'ring']

# Threadings of the paper's robots (FACTS.md table), the reference for the files.
STAR = {
    'yellow': 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3',
    'blue': 'R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2',
    'green': 'R1 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3',
    'red': 'R3 R3 R3 R3 R3 R2 R1 L3 L3 L3 L3 L3',
    'orange': 'R3 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3',
}
GRIPPER = 'R1 R2 R2 L1 L3 L3 L3 L3 L3 L3 L3 L3'
SNAKE_RING = 'R2 R3 R3 R3 L3 L3 L3 L3 R3 R3 R3 R3'
OFFSETS = {'L0': -0.5, 'L1': -3, 'L2': -6.5, 'L3': -10, 'R0': 0.5, 'R1': 3, 'R2': 6.5, 'R3': 10}


def rot(q):
    return np.array(quaternion_to_matrix(q))


def expected_threading(scene, module):
    if scene in ('brittle_star', 'starfish'):
        return STAR[module].split()
    return (GRIPPER if scene == 'gripper' else SNAKE_RING).split()


@pytest.mark.parametrize('name', SCENES)
def test_scene_schema(name):
    scene = load_scene(name)
    assert scene.name == scene.robot == name
    assert scene.path == find_scene(name) and scene.path.stem == name
    assert len(scene.modules) == {'brittle_star': 5, 'starfish': 5, 'snake': 5,
                                  'gripper': 4, 'ring': 4}[name]
    assert scene.description and scene.default_gait in scene.gaits
    # Connector geometry stated with units and a source.
    assert scene.connector['type'] and scene.connector['source']
    dims = {k: v for k, v in scene.connector.items() if k.endswith('_mm')}
    assert dims and all(v > 0 for v in dims.values())
    ports = [m.port for m in scene.modules]
    assert len(set(ports)) == len(ports)
    for i, m in enumerate(scene.modules):
        assert m.index == i and scene.module(m.name) is m
        assert list(m.holes) == expected_threading(name, m.name)
        assert m.threading_mm == pytest.approx([OFFSETS[h] for h in m.holes])
        straight = sum(math.hypot(18.0, b - a) for a, b in zip(m.threading_mm, m.threading_mm[1:]))
        assert m.straight_length_mm == pytest.approx(straight)
        assert m.host == '127.0.0.1' and m.counts_per_mm > 0
        assert 0 < m.max_contraction_mm <= 80.0
        assert len(m.base_position_m) == 3 and max(map(abs, m.base_position_m)) < 1.5
        assert np.linalg.norm(m.base_orientation_xyzw) == pytest.approx(1.0)
        r = rot(m.base_orientation_xyzw)
        assert r @ r.T == pytest.approx(np.eye(3), abs=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
    for g, spec in scene.gaits.items():
        assert isinstance(spec['type'], str)
    with pytest.raises(KeyError, match='modules are'):
        scene.module('nobody')


def test_scene_list_and_ports_are_distinct_across_scenes():
    assert set(SCENES) <= set(list_scenes())
    ports = [m.port for name in SCENES for m in load_scene(name).modules]
    assert len(set(ports)) == len(ports)
    assert [m.port for m in load_scene('brittle_star').modules] == list(range(8101, 8106))


def test_brittle_star_legs_radiate_in_the_ground_plane():
    scene = load_scene('brittle_star')
    azimuths = []
    for m in scene.modules:
        r = rot(m.base_orientation_xyzw)
        pos = np.array(m.base_position_m)
        spine = r[:, 0]
        assert r[:, 2] == pytest.approx([0, 0, 1], abs=1e-9)           # bends in the ground plane
        assert spine == pytest.approx(pos / np.linalg.norm(pos), abs=1e-3)  # radial
        assert np.linalg.norm(pos) == pytest.approx(0.0725, abs=1e-4)
        azimuths.append(math.degrees(math.atan2(pos[1], pos[0])) % 360)
    assert np.diff(sorted(azimuths)) == pytest.approx([72.0] * 4, abs=0.05)


def test_starfish_has_perpendicular_and_parallel_legs():
    scene = load_scene('starfish')
    vertical_normal, in_plane_normal = [], []
    for m in scene.modules:
        r = rot(m.base_orientation_xyzw)
        pos = np.array(m.base_position_m)
        assert r[:, 0] == pytest.approx(pos / np.linalg.norm(pos), abs=1e-3)
        normal = r[:, 2]
        if abs(normal[2]) == pytest.approx(1.0):
            in_plane_normal.append(m.name)          # bends parallel to the connector
        else:
            assert normal[2] == pytest.approx(0.0, abs=1e-9)
            assert r[:, 1] == pytest.approx([0, 0, 1], abs=1e-9)   # R threading curls down
            vertical_normal.append(m.name)          # bends perpendicular to the connector
    assert sorted(vertical_normal) == ['green', 'red', 'yellow']
    assert sorted(in_plane_normal) == ['blue', 'orange']


def test_snake_is_a_chain_along_x_and_composes_from_tips():
    scene = load_scene('snake')
    xs = [m.base_position_m[0] for m in scene.modules]
    assert xs == sorted(xs, reverse=True)            # head first, at the front (+x)
    assert all(m.base_position_m[1:] == (0.0, 0.0) for m in scene.modules)
    assert np.diff(xs[::-1]) == pytest.approx([0.248] * 4)
    assert [m.parent for m in scene.modules] == ['body2', 'body3', 'body4', 'tail', None]
    # Straight parent tip -> the stated base pose.
    body4 = scene.module('body4')
    pos, q = compose_base_pose(*straight_tip_pose(scene.module('tail'), scene.skeleton), body4)
    assert pos == pytest.approx(body4.base_position_m)
    # A parent tip turned 90 degrees CCW: the child continues along +y, 50 mm further.
    half = math.sqrt(0.5)
    pos, q = compose_base_pose((0.1, 0.2, 0.0), (0.0, 0.0, half, half), body4)
    assert pos == pytest.approx((0.1, 0.25, 0.0))
    assert rot(q)[:, 0] == pytest.approx([0, 1, 0], abs=1e-12)


def test_gripper_modules_hang_in_an_x_and_bend_toward_the_axis():
    scene = load_scene('gripper')
    for m in scene.modules:
        r = rot(m.base_orientation_xyzw)
        x, y, z = m.base_position_m
        assert abs(x) == pytest.approx(abs(y)) and z < 0
        assert r[:, 0] == pytest.approx([0, 0, -1], abs=1e-6)          # spine down
        toward_axis = -np.array([x, y, 0.0]) / math.hypot(x, y)
        assert r[:, 1] == pytest.approx(toward_axis, abs=1e-6)        # CCW (L) bends inward


def test_ring_modules_form_a_closed_square():
    scene = load_scene('ring')
    for m, nxt in zip(scene.modules, scene.modules[1:] + scene.modules[:1]):
        tip, _ = straight_tip_pose(m, scene.skeleton)
        gap = np.array(nxt.base_position_m) - np.array(tip)
        assert np.linalg.norm(gap) == pytest.approx(0.050, abs=1e-6)    # the link length
        r = rot(m.base_orientation_xyzw)
        centre_dir = -np.array(m.base_position_m)
        assert r[:, 1] @ centre_dir > 0                                  # module y into the ring
        assert r[:, 2] == pytest.approx([0, 0, 1], abs=1e-9)


def test_scene_found_by_path_and_unknown_name_refused(tmp_path):
    path = find_scene('ring')
    assert load_scene(str(path)).name == 'ring'
    with pytest.raises(SceneError, match="unknown scene 'dragon'.*brittle_star"):
        load_scene('dragon')
    with pytest.raises(SceneError, match='not found'):
        load_scene(tmp_path / 'missing.yaml')


# ----------------------------------------------------------------- invalid scene files

def _base_scene():
    return yaml.safe_load(find_scene('brittle_star').read_text())


def _set(data, path, value):
    *head, last = path
    for k in head:
        data = data[k]
    if value is _DELETE:
        del data[last]
    else:
        data[last] = value


_DELETE = object()

# (case id, key path to change, new value, key path the error must name, words it must contain)
INVALID = [
    ('missing-modules', ['modules'], _DELETE, '', "key 'modules'"),
    ('unknown-top-key', ['colour'], 'x', 'colour', 'known keys'),
    ('bad-format', ['format'], 2, 'format', 'expected 1'),
    ('short-threading', ['modules', 2, 'threading'], ['R1'] * 11, 'modules[2].threading',
     'expected 12 hole names'),
    ('unknown-hole', ['modules', 1, 'threading', 4], 'X9', 'modules[1].threading[4]',
     'a hole name'),
    ('duplicate-name', ['modules', 3, 'name'], 'yellow', 'modules[3].name', 'unique'),
    ('duplicate-port', ['modules', 4, 'port'], 8101, 'modules[4].port', 'not used by another'),
    ('port-range', ['modules', 0, 'port'], 70000, 'modules[0].port', 'integer from 1 to 65535'),
    ('name-not-identifier', ['modules', 0, 'name'], 'leg 1', 'modules[0].name', 'letters'),
    ('position-length', ['modules', 0, 'base', 'position_mm'], [1, 2], 'modules[0].base.position_mm',
     'expected 3 numbers'),
    # 2 km: micrometres taken for millimetres (robots of any size fit within 1 km).
    ('position-in-micrometres', ['modules', 0, 'base', 'position_mm'], [2.0e6, 0, 0],
     'modules[0].base.position_mm', 'millimetres'),
    ('two-orientations', ['modules', 0, 'base', 'orientation_xyzw'], [0, 0, 0, 1],
     'modules[0].base', 'exactly one orientation'),
    ('axes-not-perpendicular', ['modules', 0, 'base'],
     {'position_mm': [0, 0, 0], 'axes': {'x': [1, 0, 0], 'y': [1, 1, 0]}},
     'modules[0].base.axes', 'perpendicular'),
    ('quaternion-not-unit', ['modules', 0, 'base'],
     {'position_mm': [0, 0, 0], 'orientation_xyzw': [0, 0, 0, 2]},
     'modules[0].base.orientation_xyzw', 'unit quaternion'),
    ('counts-negative', ['modules', 0, 'counts_per_mm'], -5, 'modules[0].counts_per_mm', '> 0'),
    ('contraction-limit-nan', ['defaults', 'max_contraction_mm'], float('nan'),
     'defaults.max_contraction_mm', 'finite'),
    ('winch-speed-zero', ['defaults', 'winch_speed_mm_s'], 0.0, 'defaults.winch_speed_mm_s', '> 0'),
    ('winch-speed-in-counts', ['modules', 2, 'winch_speed_mm_s'], 8235.0 * 89.13,
     'modules[2].winch_speed_mm_s', '<= 10000'),
    ('connector-no-unit', ['connector', 'side'], 40, 'connector.side', 'unit'),
    ('connector-no-source', ['connector', 'source'], _DELETE, 'connector.source', 'non-empty string'),
    ('default-gait-unknown', ['default_gait'], 'fly', 'default_gait', 'one of the gaits'),
    ('gait-without-type', ['gaits', 'walk', 'type'], _DELETE, 'gaits.walk.type', 'string'),
    ('parent-unknown', ['modules', 0, 'parent'], 'nobody', 'modules[0]', 'parent_offset'),
    ('skeleton-bad', ['skeleton'], {'n_ribs': 1}, 'skeleton', 'n_ribs'),
]


@pytest.mark.parametrize('case, path, value, key, words', INVALID, ids=[c[0] for c in INVALID])
def test_invalid_scene_refused_with_file_key_and_reason(tmp_path, case, path, value, key, words):
    data = _base_scene()
    _set(data, path, value)
    file = tmp_path / f'{case}.yaml'
    file.write_text(yaml.safe_dump(data))
    with pytest.raises(SceneError) as err:
        load_scene(file)
    message = str(err.value)
    assert message.startswith(str(file))
    assert f': {key}:' in message or (key == '' and 'required keys' in message)
    assert words in message
    assert isinstance(err.value, ValueError)


def test_not_yaml_and_not_a_mapping(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('modules: [unclosed\n')
    with pytest.raises(SceneError, match='not valid YAML'):
        load_scene(bad)
    bad.write_text('- just\n- a list\n')
    with pytest.raises(SceneError, match='top level'):
        load_scene(bad)


def test_chained_pose_inconsistent_with_parent_refused(tmp_path):
    data = yaml.safe_load(find_scene('snake').read_text())
    data['modules'][3]['base']['position_mm'] = [240.0, 0.0, 0.0]   # body4 8 mm off
    file = tmp_path / 'snake.yaml'
    file.write_text(yaml.safe_dump(data))
    with pytest.raises(SceneError, match=r"modules\[\d\]\.base: expected the pose given by"):
        load_scene(file)


def test_skeleton_override_changes_straight_length(tmp_path):
    data = _base_scene()
    data['skeleton'] = {'spacing_mm': 20.0}
    file = tmp_path / 'wide.yaml'
    file.write_text(yaml.safe_dump(data))
    scene = load_scene(file)
    assert scene.skeleton.spacing_mm == 20.0
    assert scene.module('yellow').straight_length_mm > load_scene('brittle_star').module(
        'yellow').straight_length_mm + 21.0


def test_scene_is_frozen():
    scene = load_scene('gripper')
    with pytest.raises(Exception):
        scene.modules[0].port = 1
    with pytest.raises(TypeError):
        scene.gaits['grasp']['amplitude_mm'] = 80
    with pytest.raises(TypeError):
        scene.connector['side_mm'] = 1


def test_winch_speed_matches_the_driver_motor_model():
    """The scenes' winch_speed_mm_s is the simulated winch's speed at the driver's PWM.

    softsnap_model cannot import the driver, so the number is written down twice: this
    test keeps the two from drifting apart (a changed motor model, PWM or drum fails here).
    """
    from softsnap_driver.driver_node import PARAMETERS
    from softsnap_driver.firmware import MotorModel
    from softsnap_model.scene import DEFAULT_COUNTS_PER_MM, DEFAULT_WINCH_SPEED_MM_S

    motor = MotorModel()
    pwm = PARAMETERS['pwm_power'][0]
    # Beyond 60 counts from its target the firmware boosts the motor to its rated voltage.
    counts_per_s = motor.speed_counts_per_s(pwm, motor.rated_voltage_v)
    assert DEFAULT_WINCH_SPEED_MM_S == pytest.approx(counts_per_s / DEFAULT_COUNTS_PER_MM, rel=1e-9)
    assert DEFAULT_WINCH_SPEED_MM_S == pytest.approx(92.39, abs=0.01)
    for name in SCENES:
        for m in load_scene(name).modules:
            # The files round to 0.1 mm/s and counts_per_mm to 0.01 counts/mm.
            assert m.winch_speed_mm_s == pytest.approx(counts_per_s / m.counts_per_mm, abs=0.06), \
                (name, m.name)
