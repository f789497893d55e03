"""The paper's camera measurement against images rendered with known ground truth.

The renderer (render.py) projects 3-D marker discs with cv2.projectPoints and lens
distortion; the measurement thresholds colours and undistorts centroids. Ground-truth
shapes come from the forward solver with stiffnesses the measurement's model does not
have, so the RMSE to the model is not zero.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from render import Camera, ModuleDrawing, Occluder, centred_origin, render
from softsnap_model import Skeleton, solve_forward
from softsnap_vision.camera_info import CameraInfo
from softsnap_vision.marker_config import (MarkerConfigError, config_from_dict,
                                           load_marker_config)
from softsnap_vision.measurement import MeasurementError, measure_image, model_rib_centers_mm

#: The issue's acceptance: every visible rib within 0.4 mm (under a pixel at 0.5 mm/px).
RIB_TOL_MM = 0.4
#: RMSE to the model within 0.2 mm of the truth.
RMSE_TOL_MM = 0.2

SK = Skeleton()
#: The "real" module: stiffer near the base, softer near the tip (not the model's).
TRUE_SK = Skeleton(stiffness=[1.3, 1.3, 1.3, 1.0, 1.0, 1.0, 0.8, 0.8, 0.8, 1.0, 1.0])
THREADINGS = {
    'yellow': 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split(),
    'blue': 'R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2'.split(),
    's': ['R3'] * 6 + ['L3'] * 6,
}


def camera_info(cam: Camera) -> CameraInfo:
    return CameraInfo(width=cam.width, height=cam.height, camera_matrix=cam.K, distortion=cam.D)


def true_ribs(threading, contraction_mm):
    straight = SK.straight_length_mm(threading)
    return solve_forward(TRUE_SK, threading, straight - contraction_mm).rib_centers


def check_ribs(measured, truth, hidden=()):
    for i in range(12):
        if i in hidden:
            assert not measured.visible[i], f'rib {i} is hidden but was reported'
            assert np.isnan(measured.ribs_mm[i]).all()
        else:
            assert measured.visible[i], f'rib {i} visible but missing ({measured.note})'
            err = float(np.hypot(*(measured.ribs_mm[i] - truth[i])))
            assert err <= RIB_TOL_MM, f'rib {i}: {err:.3f} mm off'


@pytest.mark.parametrize('name,contraction,yaw_deg,seed', [
    ('yellow', 0.0, 8.0, 1),
    ('yellow', 30.0, -5.0, 2),
    ('yellow', 40.0, 175.0, 6),   # curled into a hook (60 mm self-intersects in the model)
    ('blue', 25.0, 12.0, 3),
    ('s', 40.0, -20.0, 4),
    ('s', 60.0, 90.0, 5),
])
def test_every_visible_rib_within_tolerance(name, contraction, yaw_deg, seed):
    cam = Camera()
    ribs = true_ribs(THREADINGS[name], contraction)
    if yaw_deg == 90.0:
        cam = Camera(width=480, height=640)   # module along the image's long side
    origin = centred_origin(ribs, math.radians(yaw_deg))
    drawing = ModuleDrawing(ribs_mm=ribs, origin_mm=origin, yaw_rad=math.radians(yaw_deg))
    image = render(cam, [drawing], seed=seed)
    m = measure_image(image, camera_info(cam), cam.height_m)
    check_ribs(m, ribs)
    assert m.fit is not None and m.fit.residual_mm < 0.3


def test_scale_comes_from_the_plane_distance():
    """A wrong plane distance scales every rib: the measurement is not fitted to the model."""
    cam = Camera()
    ribs = true_ribs(THREADINGS['yellow'], 20.0)
    image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=(-95.0, -30.0))], seed=9)
    m = measure_image(image, camera_info(cam), cam.height_m * 1.02)
    # 2 % too far: the tip (~195 mm from rib 0) moves ~4 mm; the fit residual stays small
    # only if the shape can absorb it, which a fixed rib spacing cannot.
    assert np.nanmax(np.hypot(*(m.ribs_mm - ribs).T)) > 2.0
    assert m.fit.residual_mm > 1.0


def test_rmse_to_model_within_tolerance_of_the_truth():
    cam = Camera()
    for name, contraction, seed in (('yellow', 35.0, 11), ('blue', 20.0, 12), ('s', 50.0, 13)):
        threading = THREADINGS[name]
        length = SK.straight_length_mm(threading) - contraction
        ribs = true_ribs(threading, contraction)
        model = model_rib_centers_mm(SK, threading, length)
        truth_rmse = float(np.sqrt(np.mean(np.sum((ribs - model) ** 2, axis=1))))
        assert truth_rmse > 0.5   # the test means something: truth and model differ
        image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=centred_origin(ribs, 0.1),
                                           yaw_rad=0.1)], seed=seed)
        m = measure_image(image, camera_info(cam), cam.height_m, model_mm=model)
        assert abs(m.rmse_to_model_mm - truth_rmse) <= RMSE_TOL_MM, (name, m.rmse_to_model_mm,
                                                                   truth_rmse)


def test_hidden_and_partly_hidden_markers_are_missing_never_guessed():
    cam = Camera()
    ribs = true_ribs(THREADINGS['yellow'], 25.0)
    drawing = ModuleDrawing(ribs_mm=ribs, origin_mm=centred_origin(ribs, 0.0), hidden=(4,))
    world = drawing.world(ribs)
    # rib 7 under a cable lying across it (its left half hidden), rib 10 wholly covered
    occluders = [Occluder(world[7, 0] - 10, world[7, 1] - 10, world[7, 0] + 0.2, world[7, 1] + 10),
                 Occluder(world[10, 0] - 5, world[10, 1] - 5, world[10, 0] + 5, world[10, 1] + 5)]
    image = render(cam, [drawing], seed=21, occluders=occluders)
    m = measure_image(image, camera_info(cam), cam.height_m)
    check_ribs(m, ribs, hidden=(4, 7, 10))
    assert set(m.missing) == {4, 7, 10}
    assert m.markers_refused >= 1    # the half marker was seen and refused


def test_two_hidden_ribs_in_a_row_are_stepped_over():
    cam = Camera()
    ribs = true_ribs(THREADINGS['blue'], 15.0)
    image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=centred_origin(ribs, 0.0), hidden=(5, 6))],
                   seed=22)
    m = measure_image(image, camera_info(cam), cam.height_m)
    check_ribs(m, ribs, hidden=(5, 6))


def test_frame_without_the_base_marker_is_refused():
    cam = Camera()
    ribs = true_ribs(THREADINGS['yellow'], 10.0)
    image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=(-95.0, -20.0), base_marker=False)])
    with pytest.raises(MeasurementError, match='no base'):
        measure_image(image, camera_info(cam), cam.height_m)


def test_frame_with_rib_0_hidden_is_refused_not_shifted():
    """Without rib 0 the nearest pink is rib 1: taking it as the origin would shift every rib."""
    cam = Camera()
    ribs = true_ribs(THREADINGS['yellow'], 10.0)
    image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=(-95.0, -20.0), hidden=(0,))])
    with pytest.raises(MeasurementError, match='rib 0'):
        measure_image(image, camera_info(cam), cam.height_m)


def test_two_modules_with_base_markers_are_refused_by_the_single_module_measure():
    cam = Camera(width=800, height=600)
    ribs = true_ribs(THREADINGS['yellow'], 10.0)
    image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=(-95.0, 60.0)),
                         ModuleDrawing(ribs_mm=ribs, origin_mm=(-95.0, -60.0))])
    with pytest.raises(MeasurementError, match='2 base'):
        measure_image(image, camera_info(cam), cam.height_m)


def test_plain_table_without_lighting_or_noise_also_measures():
    cam = Camera(distortion=(0, 0, 0, 0, 0))
    ribs = true_ribs(THREADINGS['s'], 30.0)
    image = render(cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=(-90.0, 0.0))], noise_sigma=0.0,
                   lighting=False, texture=False)
    check_ribs(measure_image(image, camera_info(cam), cam.height_m), ribs)


def test_marker_colours_from_yaml(tmp_path):
    """Green rib markers and blue base markers printed instead: the YAML says so."""
    path = tmp_path / 'markers.yaml'
    path.write_text('rib_marker: {color_rgb: [40, 200, 60], diameter_mm: 8.0}\n'
                    'base_marker: {color_rgb: [30, 90, 230], diameter_mm: 8.0,'
                    ' distance_to_first_rib_mm: 40.0}\n')
    config = load_marker_config(path)
    cam = Camera()
    ribs = true_ribs(THREADINGS['yellow'], 20.0)
    drawing = ModuleDrawing(ribs_mm=ribs, origin_mm=centred_origin(ribs, 0.0, 40.0), rib_color_bgr=(60, 200, 40),
                            base_color_bgr=(230, 90, 30), base_distance_mm=40.0, diameter_mm=8.0)
    image = render(cam, [drawing], seed=5)
    check_ribs(measure_image(image, camera_info(cam), cam.height_m, config), ribs)
    # the paper's defaults see no marker in that image
    with pytest.raises(MeasurementError):
        measure_image(image, camera_info(cam), cam.height_m)


@pytest.mark.parametrize('data,message', [
    ({'rib_marker': {'color_rgb': [128, 128, 128]}}, 'too grey'),
    ({'rib_marker': {'color_rgb': [255, 64]}}, 'three integers'),
    ({'rib_marker': {'diameter_mm': -1}}, 'diameter_mm'),
    ({'base_marker': {'color_rgb': [255, 70, 170]}}, 'could not be told apart'),
    ({'rib_markers': {}}, 'unknown key'),
    ({'max_gap': 7}, 'max_gap'),
    ({'tag': {'dictionary': 'DICT_9X9'}}, 'tag.dictionary'),
])
def test_marker_yaml_is_validated(data, message):
    with pytest.raises(MarkerConfigError, match=message):
        config_from_dict(data)


def test_installed_default_marker_file_is_the_default():
    from pathlib import Path
    import softsnap_vision
    path = Path(softsnap_vision.__file__).resolve().parents[1] / 'config' / 'markers.yaml'
    assert load_marker_config(path) == load_marker_config(None)
