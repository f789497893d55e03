"""standard_messages: markers, joint states and model diagnostics from real solves."""
import math

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from visualization_msgs.msg import Marker

from softsnap_model import standard_messages as standard
from softsnap_model.forward import solve_forward
from softsnap_model.predictor import RobotPredictor
from softsnap_model.scene import load_scene


@pytest.fixture(scope='module')
def brittle_star():
    return load_scene('brittle_star')


def _xyz(points):
    return np.array([[p.x, p.y, p.z] for p in points])


def test_parts_equal_the_solvers_rib_centres_and_cable_in_metres(brittle_star):
    skeleton = brittle_star.skeleton
    module = brittle_star.modules[0]
    result = solve_forward(skeleton, module.threading_mm, module.straight_length_mm - 30.0)
    for given in (None, result.rib_centers):   # from the angles, or the solver's own points
        parts = standard.module_parts_m(result.angles, module.threading_mm,
                                        spacing_mm=skeleton.spacing_mm,
                                        rib_length_mm=skeleton.rib_length_mm,
                                        rib_centers_mm=given)
        np.testing.assert_allclose(parts.spine[:, :2], np.asarray(result.rib_centers) / 1000.0,
                                   atol=1e-12)
        np.testing.assert_allclose(parts.cable[:, :2], np.asarray(result.cable_path) / 1000.0,
                                   atol=1e-12)
        assert np.all(parts.spine[:, 2] == 0.0)
    # Each rib is a segment of the rib length centred on its rib centre.
    lengths = np.linalg.norm(parts.ribs[:, 0] - parts.ribs[:, 1], axis=1)
    np.testing.assert_allclose(lengths, skeleton.rib_length_mm / 1000.0, atol=1e-12)
    np.testing.assert_allclose(parts.ribs.mean(axis=1), parts.spine, atol=1e-12)


def test_bad_geometry_is_refused_with_the_numbers():
    with pytest.raises(ValueError, match='expected 3 hole offsets'):
        standard.module_parts_m([0.0, 0.1], [0.0, 1.0], spacing_mm=18.0, rib_length_mm=25.0)
    with pytest.raises(ValueError, match='finite'):
        standard.module_parts_m([0.0, math.nan], None, spacing_mm=18.0, rib_length_mm=25.0)
    with pytest.raises(ValueError, match=r'expected 3 rib centres.*\(2, 2\)'):
        standard.module_parts_m([0.0, 0.1], None, spacing_mm=18.0, rib_length_mm=25.0,
                                rib_centers_mm=np.zeros((2, 2)))


def test_markers_carry_the_base_pose_namespaces_stable_ids_and_source_colours(brittle_star):
    skeleton = brittle_star.skeleton
    markers = []
    for index, module in enumerate(brittle_star.modules):
        for source in ('commanded', 'predicted', 'simulated'):
            parts = standard.module_parts_m(np.full(skeleton.n_segments, 0.05), module.threading_mm,
                                            spacing_mm=skeleton.spacing_mm,
                                            rib_length_mm=skeleton.rib_length_mm)
            pose = standard.pose_msg(module.base_position_m, module.base_orientation_xyzw)
            markers += standard.module_markers(
                parts, frame_id='brittle_star', stamp=standard.stamp_msg(1_500_000_007),
                module=module.name, module_index=index, source=source, base_pose=pose)
    assert len(markers) == len(brittle_star.modules) * 3 * 3
    assert len({m.id for m in markers}) == len(markers)          # unique ids
    assert len({m.ns for m in markers}) == len(markers)
    first = markers[0]
    assert first.ns == f'{brittle_star.modules[0].name}/commanded/spine'
    assert first.type == Marker.LINE_STRIP and first.header.frame_id == 'brittle_star'
    assert (first.header.stamp.sec, first.header.stamp.nanosec) == (1, 500_000_007)
    assert first.pose.position.x == pytest.approx(brittle_star.modules[0].base_position_m[0])
    ribs = [m for m in markers if m.ns.endswith('/ribs')]
    assert all(m.type == Marker.LINE_LIST and len(m.points) == 2 * skeleton.n_ribs for m in ribs)
    # Same (module, source, part) -> same id in any later message.
    assert standard.marker_id(2, 'predicted', 'cable') == standard.marker_id(2, 'predicted', 'cable')
    colours = {m.ns.split('/')[1]: (m.color.r, m.color.g, m.color.b)
               for m in markers if m.ns.endswith('/spine')}
    assert len(set(colours.values())) == 3                        # one colour per source
    cable = next(m for m in markers if m.ns.endswith('/cable'))
    assert cable.color.b < standard.SOURCE_COLORS['commanded'][2]  # darker shade


def test_joint_states_group_shapes_by_their_length_stamp(brittle_star):
    predictor = RobotPredictor(brittle_star)
    names = brittle_star.module_names
    for i, name in enumerate(names):
        stamp = 5_000_000_000 if i < 3 else 6_000_000_001
        predictor.submit('predicted', name, brittle_star.module(name).straight_length_mm - 5 * (i + 1),
                         stamp_ns=stamp)
    shapes = predictor.tick()['predicted']
    messages = standard.joint_states(shapes)
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in messages] == [(5, 0), (6, 1)]
    n = brittle_star.skeleton.n_segments
    assert messages[0].name[:n] == [f'{names[0]}/segment_{i}' for i in range(n)]
    assert len(messages[0].name) == 3 * n and len(messages[1].name) == (len(names) - 3) * n
    positions = dict(zip(messages[0].name + messages[1].name,
                         messages[0].position.tolist() + messages[1].position.tolist()))
    for shape in shapes:
        for i, angle in enumerate(shape.angles):
            assert positions[f'{shape.module}/segment_{i}'] == angle
    assert not messages[0].velocity and not messages[0].effort


def _health(**changes):
    values = dict(solves=10, skipped_unchanged=0, skipped_duplicate=0, skipped_rib_points=0,
                  refused=0, service_calls=0, service_failures=0, mean_solve_time_s=0.001,
                  marker_arrays_published=0, joint_states_published=0)
    values.update(changes)
    return standard.ModelHealth(**values)


def test_model_status_levels_follow_the_thresholds():
    ok = standard.model_status('softsnap/r/model', _health(), None, 0.01)
    assert ok.level == DiagnosticStatus.OK and ok.message == 'ok'
    values = {kv.key: kv.value for kv in ok.values}
    assert values['solves'] == '10' and values['mean solve time (s)'] == '0.001'
    refused = standard.model_status('softsnap/r/model', _health(refused=3), _health(refused=1), 0.01)
    assert refused.level == DiagnosticStatus.WARN and '2 length(s) refused' in refused.message
    # Refusals of earlier periods are not news.
    assert standard.model_status('n', _health(refused=3), _health(refused=3), 0.01).level == \
        DiagnosticStatus.OK
    slow = standard.model_status('n', _health(mean_solve_time_s=0.006), None, 0.01)
    assert slow.level == DiagnosticStatus.WARN and 'mean solve time' in slow.message
    failed = standard.model_status('n', _health(service_failures=1), _health(), 0.01)
    assert failed.level == DiagnosticStatus.WARN


def test_prediction_markers_show_the_predictors_own_rib_centres(brittle_star):
    predictor = RobotPredictor(brittle_star)
    module = brittle_star.module('blue')
    predictor.submit('predicted', 'blue', module.straight_length_mm - 25.0, stamp_ns=7)
    shape = predictor.tick(rib_centers=True)['predicted'][0]
    pose = ((0.1, 0.2, 0.0), (0.0, 0.0, 0.0, 1.0))
    markers = standard.prediction_markers(
        shape, module_index=1, threading_mm=module.threading_mm, base_pose_m=pose,
        frame_id='brittle_star', spacing_mm=brittle_star.skeleton.spacing_mm,
        rib_length_mm=brittle_star.skeleton.rib_length_mm)
    spine = markers[0]
    assert spine.ns == 'blue/predicted/spine' and spine.header.stamp.nanosec == 7
    np.testing.assert_allclose(_xyz(spine.points)[:, :2], shape.rib_centers_mm / 1000.0, atol=0)
    assert (spine.pose.position.x, spine.pose.position.y) == (0.1, 0.2)


def test_robot_shape_markers_draw_good_modules_and_report_bad_ones(brittle_star):
    from geometry_msgs.msg import Point, Pose
    from softsnap_interfaces.msg import ModuleShape, RobotShape
    skeleton = brittle_star.skeleton
    kwargs = dict(default_frame_id='brittle_star', module_names=brittle_star.module_names,
                  threadings_mm={m.name: m.threading_mm for m in brittle_star.modules},
                  spacing_mm=skeleton.spacing_mm, rib_length_mm=skeleton.rib_length_mm)
    angles = [0.05] * skeleton.n_segments
    msg = RobotShape()
    msg.header.frame_id = 'world'
    msg.modules = [ModuleShape(module='red', source='simulated', angles=angles),
                   ModuleShape(module='stranger', angles=angles),               # not in the scene
                   ModuleShape(module='green', angles=angles[:3],              # inconsistent
                               rib_centers=[Point()] * 12)]
    msg.base_poses = [Pose(), Pose(), Pose()]
    markers, problems = standard.robot_shape_markers(msg, **kwargs)
    assert len(problems) == 1 and "'green'" in problems[0]
    by_ns = {m.ns: m for m in markers}
    assert set(by_ns) == {'red/simulated/spine', 'red/simulated/ribs', 'red/simulated/cable',
                          'stranger/simulated/spine', 'stranger/simulated/ribs'}  # no threading
    assert all(m.header.frame_id == 'world' for m in markers)
    expected = standard.module_parts_m(angles, None, spacing_mm=skeleton.spacing_mm,
                                       rib_length_mm=skeleton.rib_length_mm).spine
    np.testing.assert_allclose(_xyz(by_ns['red/simulated/spine'].points), expected, atol=1e-15)
    assert by_ns['stranger/simulated/spine'].id not in {m.id for m in markers
                                                        if m.ns.startswith('red')}
    msg.base_poses = [Pose()]
    markers, problems = standard.robot_shape_markers(msg, **kwargs)
    assert markers == [] and 'base poses' in problems[0]
