"""ForwardShape with gravity and a point load: model_node over Fast DDS vs the core."""
import numpy as np
import pytest

from softsnap_model import solve_forward
from softsnap_model.loads import Loads, solve_loaded
from softsnap_model.scene import load_scene

pytestmark = pytest.mark.ros

NS = '/loads_under_test'


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
        bending_stiffness=0.015), 20.0)
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
            load=Vector3(x=0.0, y=-0.2, z=0.0), load_rib=rib), 20.0)
        assert response.success, response.message
        np.testing.assert_allclose(response.angles, core.angles, rtol=0, atol=1e-12)

    # No in-plane force: the exact unloaded answer, tension in N from the parameter.
    response = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0, gravity=Vector3(x=0.0, y=0.0, z=-9.81)),
        20.0)
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
        bad = ros_node.call(client, request, 20.0)
        assert not bad.success and words in bad.message
    again = ros_node.call(client, ForwardShape.Request(
        holes=holes, cable_length=length_mm / 1000.0), 20.0)
    assert again.success
