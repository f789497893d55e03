"""The simulated camera: MuJoCo's renderer against our pinhole model of it.

The markers' pixel positions are found in the rendered image with OpenCV (colour
threshold, connected components, centroids) and compared with the rib centres the
physics reports, projected through the intrinsics the camera publishes (K from fovy and
the resolution) by a formula written out here: an error in the published intrinsics,
the principal point convention, the image orientation or the marker placement moves the
two apart.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from softsnap_driver.sim_camera import (ORANGE_RGB, PINK_RGB, CameraError, CameraSettings,
                                        SimCamera, capture_frame_state)

# MuJoCo reads MUJOCO_GL once, when first imported (test/conftest.py sets it too).
os.environ.setdefault('MUJOCO_GL', 'egl')
TOP_FACE_M = 0.0045     # half the 9 mm skeleton: the markers' face above the rib centre


def _blobs(image: np.ndarray, rgb, tolerance: int = 40) -> np.ndarray:
    """Centroids (n, 2) px of the connected regions within `tolerance` of colour `rgb`."""
    import cv2
    mask = np.all(np.abs(image.astype(int) - np.array(rgb)) <= tolerance, axis=2)
    count, _labels, stats, centroids = cv2.connectedComponentsWithStats(
        mask.astype(np.uint8), connectivity=8)
    keep = stats[1:, cv2.CC_STAT_AREA] >= 4
    return centroids[1:][keep]


def _project(point_world, camera_xyz, k):
    # Optical frame: x = world x, y = -world y, z = -world z (looking down).
    x = point_world[..., 0] - camera_xyz[0]
    y = -(point_world[..., 1] - camera_xyz[1])
    z = camera_xyz[2] - point_world[..., 2]
    return np.stack([k[0, 0] * x / z + k[0, 2], k[1, 1] * y / z + k[1, 2]], axis=-1)


@pytest.fixture(scope='module')
def bent_brittle_star():
    from softsnap_driver.sim_robot import build_simulation
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    sim = build_simulation(scene, gravity=False, links_per_segment=2)
    # Two legs bent, in opposite senses' worth of cable: markers off the image axes.
    for name, haul_mm in zip(sim.module_names[:2], (25.0, 15.0)):
        sim.set_cable_length(name, sim.straight_cable_length(name) - haul_mm * 1e-3)
    sim.step(1.5)
    # mj_step leaves the body positions of its step's start; the camera renders the
    # final qpos: the reference positions are of that qpos too.
    import mujoco
    mujoco.mj_kinematics(sim.model, sim.data)
    return sim


def test_markers_are_where_the_published_intrinsics_project_the_rib_centres(bent_brittle_star):
    sim = bent_brittle_star
    camera = SimCamera(sim, CameraSettings(width_px=1280, height_px=960, fovy_deg=45.0))
    try:
        image = camera.render(capture_frame_state(sim))
    finally:
        camera.close()
    assert image.shape == (960, 1280, 3) and image.dtype == np.uint8
    k = camera.view.intrinsics.matrix
    # Honest intrinsics: MuJoCo's fovy is the vertical angle of the whole image.
    f = 480.0 / math.tan(math.radians(22.5))
    assert k[0, 0] == pytest.approx(f) and k[1, 1] == pytest.approx(f)
    assert (k[0, 2], k[1, 2]) == (639.5, 479.5)
    pink = _blobs(image, PINK_RGB)
    orange = _blobs(image, ORANGE_RGB)
    assert len(pink) == 60 and len(orange) == 5, (len(pink), len(orange))
    errors = []
    for name in sim.module_names:
        ribs = np.asarray(sim.rib_centers_world(name))
        up = np.asarray(sim.data.xmat[sim._base_id[name]]).reshape(3, 3)[:, 2]
        expected = _project(ribs + TOP_FACE_M * up, camera.view.position_m, k)
        for uv in expected:
            errors.append(np.min(np.linalg.norm(pink - uv, axis=1)))
    errors = np.array(errors)
    # A 6 mm disc (a 16-gon) is ~8.5 px across here (0.7 mm/px); the centroid of its
    # pixel mask is off by the pixel grid only: within 0.35 px (0.25 mm), 0.15 px on average.
    assert errors.max() < 0.35 and errors.mean() < 0.15, (errors.max(), errors.mean())
    # The bent legs really bent (the test is not of a straight star only).
    tip = np.asarray(sim.rib_centers(sim.module_names[0]))[-1]
    assert abs(tip[1]) > 0.03
    # The markers keep their nominal colour (FACTS.md) under the camera's lights.
    centre = np.round(pink[0]).astype(int)
    assert np.all(np.abs(image[centre[1], centre[0]].astype(int) - PINK_RGB) <= 3)


def test_a_fixed_camera_height_and_place_are_kept(bent_brittle_star):
    sim = bent_brittle_star
    settings = CameraSettings(width_px=640, height_px=480, height_m=0.9, center_x_m=0.1,
                              center_y_m=-0.05)
    camera = SimCamera(sim, settings)
    try:
        image = camera.render(capture_frame_state(sim))
    finally:
        camera.close()
    assert camera.view.position_m == (0.1, -0.05, 0.9)
    assert image.shape == (480, 640, 3)
    assert len(_blobs(image, ORANGE_RGB, tolerance=60)) == 5


@pytest.mark.parametrize('changes, message', [
    ({'width_px': 8}, 'image size'),
    ({'fovy_deg': 170.0}, 'camera_fovy_deg'),
    ({'height_m': -1.0}, 'camera_height_m'),
])
def test_bad_camera_settings_are_refused_with_the_name(changes, message):
    with pytest.raises(ValueError, match=message):
        CameraSettings(**changes)


def test_a_camera_that_cannot_render_offscreen_is_refused_in_one_line():
    # MuJoCo's window backend without a display: the camera says what it needs.
    code = ('from softsnap_driver.sim_camera import offscreen_backend, CameraError\n'
            'try:\n    offscreen_backend()\nexcept CameraError as exc:\n'
            '    print("REFUSED", exc)\n')
    env = {k: v for k, v in os.environ.items() if k != 'DISPLAY'}
    env['MUJOCO_GL'] = 'glfw'
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.stdout.startswith('REFUSED') and len(out.stdout.strip().splitlines()) == 1
    assert 'MUJOCO_GL=egl or osmesa' in out.stdout, out.stdout + out.stderr
    assert CameraError.__mro__[1] is RuntimeError


def test_tagged_modules_carry_their_aruco_tag_instead_of_the_orange_marker(bent_brittle_star):
    import cv2
    from softsnap_driver.sim_camera import MarkerLayout
    sim = bent_brittle_star
    names = sim.module_names
    tags = {name: 7 + 3 * i for i, name in enumerate(names[:4])}    # the fifth keeps its dot
    camera = SimCamera(sim, CameraSettings(), MarkerLayout(tags=tags))
    try:
        image = camera.render(capture_frame_state(sim))
    finally:
        camera.close()
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _rejected = detector.detectMarkers(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
    assert ids is not None and sorted(ids.ravel()) == sorted(tags.values())
    k = camera.view.intrinsics.matrix
    for corner, tag_id in zip(corners, ids.ravel()):
        name = next(n for n, t in tags.items() if t == tag_id)
        base = np.asarray(sim.data.xpos[sim._base_id[name]])
        rot = np.asarray(sim.data.xmat[sim._base_id[name]]).reshape(3, 3)
        centre = base + rot @ np.array([-0.035, 0.0, TOP_FACE_M])
        assert np.linalg.norm(corner.reshape(4, 2).mean(axis=0)
                              - _project(centre, camera.view.position_m, k)) < 0.5
    assert len(_blobs(image, ORANGE_RGB)) == 1
    assert len(_blobs(image, PINK_RGB)) == 60


@pytest.fixture(scope='module')
def hanging_finger():
    """The gripper's front_left module clamped as it hangs in the scene, under gravity,
    20 mm of cable hauled in: it bends in a vertical plane."""
    from softsnap_model.physics.simulation import RobotSimulation
    from softsnap_model.scene import load_scene
    module = load_scene('gripper').module('front_left')
    x, y, z, w = module.base_orientation_xyzw
    sim = RobotSimulation.single_module(module.holes, gravity=True,
                                        base_orientation_wxyz=(w, x, y, z))
    sim.set_cable_length('module', sim.straight_cable_length('module') - 0.020)
    sim.step(1.5)
    import mujoco
    mujoco.mj_kinematics(sim.model, sim.data)
    return sim


def test_the_module_view_faces_the_bending_plane_and_projects_as_published(hanging_finger):
    """view='module': MuJoCo's image of a hanging finger from its marked side against the
    published pose and intrinsics (camera/pose and camera_info carry the same numbers)."""
    sim = hanging_finger
    camera = SimCamera(sim, CameraSettings(width_px=640, height_px=480, view='module',
                                           margin_m=0.03))
    try:
        image = camera.render(capture_frame_state(sim))
    finally:
        camera.close()
    base = np.asarray(sim.data.xmat[sim._base_id['module']]).reshape(3, 3)
    bending_axis = base[:, 2]
    # The finger hangs: its bending axis is horizontal, so the camera looks sideways.
    assert abs(bending_axis[2]) < 0.1
    view = camera.view
    r = np.array(view.optical_in_world)
    assert np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) == pytest.approx(1.0)
    assert r[:, 2] @ bending_axis == pytest.approx(-1.0)      # looking at the marked face
    assert r[:, 1] @ np.array([0.0, 0.0, 1.0]) < -0.99         # image up = world up
    # The published quaternion is the same rotation (w, x, y, z).
    w, x, y, z = view.orientation_wxyz()
    q = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    assert np.allclose(q, r, atol=1e-9)
    k = view.intrinsics.matrix
    ribs = np.asarray(sim.rib_centers_world('module')) + TOP_FACE_M * bending_axis
    optical = (ribs - np.asarray(view.position_m)) @ r
    expected = np.stack([k[0, 0] * optical[:, 0] / optical[:, 2] + k[0, 2],
                         k[1, 1] * optical[:, 1] / optical[:, 2] + k[1, 2]], axis=1)
    pink = _blobs(image, PINK_RGB)
    assert len(pink) == 12 and len(_blobs(image, ORANGE_RGB)) == 1, len(pink)
    errors = np.array([np.min(np.linalg.norm(pink - uv, axis=1)) for uv in expected])
    assert errors.max() < 0.5, errors
    # Every marker in the image with room to bend further, the plane at one distance.
    assert np.all((expected > 20) & (expected < [620, 460]))
    assert np.ptp(optical[:, 2]) < 1e-4
    # (the discs sit 0.1 mm above the face)
    assert camera.marker_distance_m() == pytest.approx(float(optical[:, 2].mean()), abs=2e-4)
    # The finger really bent sideways in the image (not a straight line of dots).
    assert np.ptp(expected[:, 0]) > 40 and np.ptp(expected[:, 1]) > 40


def test_an_unknown_view_is_refused():
    with pytest.raises(ValueError, match='camera view'):
        CameraSettings(view='sideways')
