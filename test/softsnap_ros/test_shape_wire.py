"""shape_wire: the ready-serialised shape messages read back by rclpy as the messages
built field by field, through every layout change, and the raw CableLength reader."""
import math

import numpy as np
import pytest
from geometry_msgs.msg import Point, Pose
from rclpy.serialization import deserialize_message, serialize_message
from softsnap_interfaces.msg import CableLength, ModuleShape, RobotShape

from softsnap_model.predictor import SOURCES, RobotPredictor
from softsnap_model.scene import load_scene
from softsnap_ros.cdr import decode_cable_length
from softsnap_ros.cdr import ModuleShapeWire, RobotShapeWire


@pytest.fixture(scope='module')
def brittle_star():
    return load_scene('brittle_star')


def _expected_module(robot, source, name, shape, stamp_ns):
    """The ModuleShape as the node builds it field by field (SI units)."""
    msg = ModuleShape(module=name, source=source)
    if shape is None:
        return msg
    stamp = shape.stamp_ns if shape.stamp_ns > 0 else stamp_ns
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.header.frame_id = f'{robot}/{name}'
    msg.cable_length = shape.cable_length_mm / 1000.0
    msg.angles = shape.angles.tolist()
    if shape.rib_centers_mm is not None:
        msg.rib_centers = [Point(x=x, y=y, z=0.0)
                           for x, y in (shape.rib_centers_mm / 1000.0).tolist()]
    msg.tension = shape.tension * 1000.0
    msg.energy = shape.energy
    msg.converged = shape.converged
    msg.residual = shape.residual
    msg.solve_time = shape.solve_time_s
    return msg


def _expected_robot(scene, source, shapes, poses, stamp_ns):
    msg = RobotShape(robot=scene.name)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.header.frame_id = scene.name
    msg.modules = [_expected_module(scene.name, source, m.name, shape, stamp_ns)
                   for m, shape in zip(scene.modules, shapes)]
    for position, orientation in poses:
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = position
        (pose.orientation.x, pose.orientation.y, pose.orientation.z,
         pose.orientation.w) = orientation
        msg.base_poses.append(pose)
    return msg


@pytest.mark.parametrize('scene_name', ['brittle_star', 'snake'])
def test_robot_and_module_bytes_read_back_as_the_messages_through_layout_changes(scene_name):
    scene = load_scene(scene_name)
    skeleton = scene.skeleton
    predictor = RobotPredictor(scene)
    wires = {s: RobotShapeWire(scene.name, s, scene.module_names, skeleton.n_segments,
                               skeleton.n_ribs) for s in SOURCES}
    module_wires = {(m.name, s): ModuleShapeWire(scene.name, s, m.name, skeleton.n_segments,
                                                 skeleton.n_ribs)
                    for m in scene.modules for s in SOURCES}
    # Before any length: every module empty. Then some modules (with and without rib
    # centres, stamped and unstamped), then new lengths for a few: each step changes
    # what has to be rewritten in place, or the layout.
    steps = [
        ({}, True),
        ({0: 20.0, 2: 35.0}, True),
        ({1: 10.0}, False),
        ({0: 25.0, 1: 12.0, 3: 40.0}, True),
        ({m: 5.0 + 3 * m for m in range(len(scene.modules))}, True),
    ]
    for step, (contractions, want_points) in enumerate(steps):
        for index, contraction in contractions.items():
            module = scene.modules[index]
            for source in SOURCES:
                predictor.submit(source, module.name, module.straight_length_mm - contraction
                                 - (0.5 if source == 'predicted' else 0.0),
                                 stamp_ns=(1_700_000_000_000_000_007 + step) * (index % 2))
        updated = predictor.tick(want_points)
        stamp_ns = 1_800_000_000_000_000_000 + 123_456_789 * step
        for source in SOURCES:
            shapes, poses = predictor.shapes(source), predictor.base_poses(source)
            got = deserialize_message(wires[source].serialize(shapes, poses, stamp_ns),
                                      RobotShape)
            assert got == _expected_robot(scene, source, shapes, poses, stamp_ns), (step, source)
            for shape in updated[source]:
                data = module_wires[(shape.module, source)].serialize(shape, stamp_ns)
                assert deserialize_message(data, ModuleShape) == _expected_module(
                    scene.name, source, shape.module, shape, stamp_ns)
    # The last step moved every module: the values differ from the first shapes'.
    assert any(m.angles[0] != 0.0 for m in got.modules)


def test_random_subsets_of_new_shapes_read_back_in_one_layout(brittle_star):
    # One layout throughout (every module solved, rib centres on): each step rewrites
    # only a random subset of modules in place, so the arrays written for one subset
    # must land in those modules' places and leave the others' as they were.
    rng = np.random.default_rng(17)
    scene, skeleton = brittle_star, brittle_star.skeleton
    predictor = RobotPredictor(scene)
    wire = RobotShapeWire(scene.name, 'commanded', scene.module_names, skeleton.n_segments,
                          skeleton.n_ribs)
    n = len(scene.modules)
    subsets = [range(n)] + [rng.choice(n, size=rng.integers(1, n + 1), replace=False)
                            for _ in range(40)]
    first_stamp = {}
    for step, subset in enumerate(subsets):
        for index in subset:
            module = scene.modules[index]
            predictor.submit('commanded', module.name,
                             module.straight_length_mm - rng.uniform(5.0, 45.0),
                             stamp_ns=int(rng.integers(0, 2)) * (1_700_000_000_000_000_000 + step))
        assert len(predictor.tick(True)['commanded']) == len(subset)
        stamp_ns = 1_800_000_000_000_000_000 + 987_654_321 * step
        shapes, poses = predictor.shapes('commanded'), predictor.base_poses('commanded')
        got = deserialize_message(wire.serialize(shapes, poses, stamp_ns), RobotShape)
        want = _expected_robot(scene, 'commanded', shapes, poses, stamp_ns)
        # A shape solved from an unstamped length keeps the stamp of the message that
        # first carried it (as the node's message objects do).
        for index in subset:
            first_stamp[index] = stamp_ns
        want.modules = [_expected_module(scene.name, 'commanded', m.name, shape, first_stamp[i])
                        for i, (m, shape) in enumerate(zip(scene.modules, shapes))]
        assert got == want, step


def test_wire_rib_centres_are_the_solvers_in_metres(brittle_star):
    predictor = RobotPredictor(brittle_star)
    module = brittle_star.modules[2]
    predictor.submit('commanded', module.name, module.straight_length_mm - 30.0)
    shape = predictor.tick(True)['commanded'][0]
    wire = RobotShapeWire(brittle_star.name, 'commanded', brittle_star.module_names,
                          brittle_star.skeleton.n_segments, brittle_star.skeleton.n_ribs)
    got = deserialize_message(wire.serialize(predictor.shapes('commanded'),
                                             predictor.base_poses('commanded'), 1), RobotShape)
    points = np.array([[p.x, p.y, p.z] for p in got.modules[2].rib_centers])
    np.testing.assert_array_equal(points[:, :2], shape.rib_centers_mm / 1000.0)
    assert np.all(points[:, 2] == 0.0) and np.hypot(*points[-1, :2]) > 0.01
    assert [len(m.rib_centers) for m in got.modules] == [0, 0, 12, 0, 0]


@pytest.mark.parametrize('frame_id', ['', 'a', 'abcd', 'abcdefg', 'robot/module/x'])
def test_cable_length_is_read_from_the_bytes(frame_id):
    msg = CableLength(cable_length=0.171234)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_123, 987_654_321
    msg.header.frame_id = frame_id
    stamp_ns, length = decode_cable_length(serialize_message(msg))
    assert length == 0.171234
    assert stamp_ns == 1_700_000_123_987_654_321


def test_cable_length_reader_agrees_with_rclpy_on_random_messages():
    # The model node reads every length with this reader instead of rclpy's: random
    # stamps, frame ids of every length modulo 8 (they move the float's alignment)
    # and lengths must come out as rclpy reads the same bytes.
    rng = np.random.default_rng(1717)
    for _ in range(300):
        msg = CableLength(cable_length=float(rng.normal(0.17, 0.1)))
        msg.header.stamp.sec = int(rng.integers(-2**31, 2**31))
        msg.header.stamp.nanosec = int(rng.integers(0, 10**9))
        msg.header.frame_id = ''.join(rng.choice(list('abcxyz/_0'), size=rng.integers(0, 20)))
        data = serialize_message(msg)
        back = deserialize_message(data, CableLength)
        stamp_ns, length = decode_cable_length(data)
        assert length == back.cable_length
        assert stamp_ns == back.header.stamp.sec * 1_000_000_000 + back.header.stamp.nanosec


@pytest.mark.parametrize('data', [b'', b'\x00\x01\x00\x00', b'\x00\x00\x00\x00' + bytes(24),
                                  b'\x00\x01\x00\x00' + b'\x00' * 8 + b'\xff\xff\x00\x00'
                                  + bytes(12)])
def test_cable_length_reader_refuses_what_it_cannot_read(data):
    with pytest.raises(ValueError):
        decode_cable_length(data)


def test_non_finite_lengths_survive_the_reader():
    # The predictor refuses them with a reason: the reader must hand them on unchanged.
    for value in (math.nan, math.inf, -1.0):
        _, length = decode_cable_length(serialize_message(CableLength(cable_length=value)))
        assert length == value or (math.isnan(value) and math.isnan(length))
