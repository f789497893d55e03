"""ForwardShape with gravity and a point load: model_node over Fast DDS vs the core."""
import numpy as np
import pytest

from softsnap_model import solve_forward
from softsnap_model.loads import Loads, solve_loaded
from softsnap_model.scene import load_scene

pytestmark = pytest.mark.ros

NS = '/loads_under_test'
#: Per call, s: with both cores busy a node just started answered its first loaded solve
#: after more than 20 s (late, not never).
CALL_TIMEOUT_S = 120.0


@pytest.fixture
def model_node(start_node):
    return start_node('softsnap_model', 'model_node', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', 'rate:=10.0',
                      '-p', 'bending_stiffness:=0.02')


def test_loaded_forward_service_equals_the_core(model_node, ros_node):
    from geometry_msgs.msg import Vector3
    from softsnap_interfaces.srv import ForwardShape
    scene = load_scene('brittle_star')
    client = ros_node.create_client(ForwardShape, f'{NS}/model_node/forward_shape')
    m = scene.module('yellow')
    length_mm = m.straight_length_mm - 30.0
    holes = list(m.holes)

    # Lying on its left side (gravity +y), K from the request (N m/rad^2).
    response = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0, gravity=Vector3(x=0.0, y=9.81, z=0.0),
        bending_stiffness=0.015), CALL_TIMEOUT_S)
    assert response.success, response.message
    core = solve_loaded(scene.skeleton, holes, length_mm,
                        Loads(gravity_mps2=(0.0, 9.81, 0.0), bending_stiffness_nmm=15.0))
    assert core.converged
    np.testing.assert_allclose(response.angles, core.angles, rtol=0, atol=1e-12)
    points = np.array([[p.x, p.y] for p in response.rib_centers]) * 1000.0
    np.testing.assert_allclose(points, core.rib_centers, rtol=0, atol=1e-9)
    assert response.cable_tension == pytest.approx(core.tension_n, rel=1e-12)
    unloaded = solve_forward(scene.skeleton, holes, length_mm)
    assert np.max(np.abs(np.asarray(response.angles) - unloaded.angles)) > 0.01

    # A tip load with the node's bending_stiffness parameter (0.02 N m/rad^2): load_rib 0
    # and -1 both mean the tip.
    loads = Loads(load_n=(0.0, -0.2, 0.0), bending_stiffness_nmm=20.0)
    core = solve_loaded(scene.skeleton, holes, length_mm, loads)
    for rib in (0, -1, 11):
        response = ros_node.call(client, ForwardShape.Request(
            holes=holes, cable_length=length_mm / 1000.0,
            load=Vector3(x=0.0, y=-0.2, z=0.0), load_rib=rib), CALL_TIMEOUT_S)
        assert response.success, response.message
        np.testing.assert_allclose(response.angles, core.angles, rtol=0, atol=1e-12)

    # No in-plane force: the exact unloaded answer, tension in N from the parameter.
    response = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0, gravity=Vector3(x=0.0, y=0.0, z=-9.81)),
        CALL_TIMEOUT_S)
    assert response.success
    assert list(response.angles) == unloaded.angles.tolist()
    assert response.cable_tension == pytest.approx(unloaded.tension * 20.0, rel=1e-12)

    # Bad loads are refused with the reason; the node keeps serving.
    for request, words in (
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  load=Vector3(y=0.1), load_rib=12), 'load_rib'),
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  gravity=Vector3(y=9.81), bending_stiffness=-1.0),
             'bending_stiffness'),
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  gravity=Vector3(y=float('nan'))), 'gravity')):
        bad = ros_node.call(client, request, CALL_TIMEOUT_S)
        assert not bad.success and words in bad.message
    again = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0), CALL_TIMEOUT_S)
    assert again.success


def test_friction_forward_service_equals_the_core(model_node, ros_node):
    from geometry_msgs.msg import Vector3
    from softsnap_interfaces.srv import ForwardShape
    from softsnap_model.friction import solve_friction
    scene = load_scene('brittle_star')
    client = ros_node.create_client(ForwardShape, f'{NS}/model_node/forward_shape')
    m = scene.module('yellow')
    length_mm = m.straight_length_mm - 40.0
    holes = list(m.holes)
    angles = {}
    for direction in ('pull', 'release'):
        response = ros_node.call(client, ForwardShape.Request(
            holes=holes, cable_length=length_mm / 1000.0, friction_coefficient=0.1,
            direction=direction), 30.0)
        assert response.success, response.message
        core = solve_friction(scene.skeleton, holes, length_mm, friction=0.1, direction=direction)
        assert core.converged
        np.testing.assert_allclose(response.angles, core.angles, rtol=0, atol=1e-12)
        np.testing.assert_allclose(response.segment_tensions,
                                   np.asarray(core.segment_tensions) * 1000.0, rtol=1e-12)
        np.testing.assert_allclose(response.wrap_angles, core.wrap_angles, rtol=0, atol=1e-12)
        assert response.tip_tension_ratio == pytest.approx(core.tip_tension_ratio, rel=1e-12)
        angles[direction] = np.asarray(response.angles)
    # Pulling, the tension decays towards the tip; the two branches differ (hysteresis).
    pull = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0, friction_coefficient=0.1), 30.0)
    assert pull.tip_tension_ratio < 1.0
    assert np.max(np.abs(angles['pull'] - angles['release'])) > 1e-3
    # Frictionless: uniform tensions, ratio 1, no wrap angles reported.
    plain = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0), 30.0)
    assert plain.success and plain.tip_tension_ratio == 1.0 and len(plain.wrap_angles) == 0
    np.testing.assert_allclose(plain.segment_tensions, [plain.tension] * 11, rtol=0)
    # Bad values and combinations are refused with the reason; the node answers on.
    for request, reason in (
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  friction_coefficient=float('nan')), 'friction_coefficient'),
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  friction_coefficient=3.0), 'friction_coefficient'),
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  friction_coefficient=0.1, direction='sideways'), 'direction'),
            (ForwardShape.Request(holes=holes, cable_length=length_mm / 1000.0,
                                  friction_coefficient=0.1,
                                  gravity=Vector3(x=0.0, y=9.81, z=0.0)), 'cannot be combined')):
        response = ros_node.call(client, request, 30.0)
        assert not response.success and reason in response.message, response.message
    assert ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0), 30.0).success
