"""The multi-module tracker core on rendered frames: ArUco tags on the cases say which module."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from render import Camera, ModuleDrawing, Occluder, centred_origin, render
from softsnap_model import Skeleton, solve_forward
from softsnap_vision.camera_info import CameraInfo
from softsnap_vision.tracker import MarkerTracker, TagTarget

SK = Skeleton()
DICT = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
YELLOW = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()
BLUE = 'R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2'.split()


def ribs_at(threading, contraction):
    return solve_forward(SK, threading, SK.straight_length_mm(threading) - contraction).rib_centers


def camera_info(cam):
    return CameraInfo(width=cam.width, height=cam.height, camera_matrix=cam.K, distortion=cam.D)


def drawing(ribs, yaw, at, tag_id, **kw):
    return ModuleDrawing(ribs_mm=ribs, yaw_rad=yaw, base_marker=False, tag_id=tag_id,
                         origin_mm=centred_origin(ribs, yaw, 35.0 + 13.0, at=at), **kw)


def errors(tracked, truth):
    return np.hypot(*(tracked.ribs_mm[tracked.visible] - truth[tracked.visible]).T)


def test_two_modules_in_one_frame_are_told_apart_by_their_tags():
    cam = Camera(width=800, height=600)
    yellow, blue = ribs_at(YELLOW, 25.0), ribs_at(BLUE, 20.0)
    image = render(cam, [drawing(yellow, 0.05, (0.0, 70.0), 3),
                         drawing(blue, math.pi - 0.1, (10.0, -75.0), 7)],
                   seed=31, tag_dictionary=DICT)
    tracker = MarkerTracker(camera_info(cam), cam.height_m,
                            [TagTarget('yellow', 3), TagTarget('blue', 7), TagTarget('red', 9)])
    result = tracker.track(image)
    assert set(result.modules) == {'yellow', 'blue'}          # red's tag is not in view
    assert result.tags_found == 2 and result.unknown_tags == ()
    for name, truth in (('yellow', yellow), ('blue', blue)):
        m = result.modules[name]
        assert m.error is None and m.visible.all(), (name, m.note, m.error)
        assert errors(m, truth).max() <= 0.4, name
        assert m.fit.residual_mm < 0.3


def test_swapped_tags_swap_the_shapes_not_the_names():
    cam = Camera(width=800, height=600)
    yellow, blue = ribs_at(YELLOW, 25.0), ribs_at(BLUE, 20.0)
    image = render(cam, [drawing(yellow, 0.05, (0.0, 70.0), 7),
                         drawing(blue, math.pi - 0.1, (10.0, -75.0), 3)],
                   seed=32, tag_dictionary=DICT)
    result = MarkerTracker(camera_info(cam), cam.height_m,
                           [TagTarget('yellow', 3), TagTarget('blue', 7)]).track(image)
    assert errors(result.modules['blue'], yellow).max() <= 0.4
    assert errors(result.modules['yellow'], blue).max() <= 0.4


def test_occluded_module_keeps_its_seen_ribs_and_an_unknown_tag_is_reported():
    cam = Camera(width=800, height=600)
    yellow = ribs_at(YELLOW, 35.0)
    d = drawing(yellow, 0.3, (0.0, 0.0), 1, hidden=(3,))
    w = d.world(yellow)
    occ = [Occluder(w[8, 0] - 6, w[8, 1] - 6, w[8, 0] + 6, w[8, 1] + 6)]
    stranger = drawing(ribs_at(BLUE, 5.0), 0.0, (0.0, -110.0), 12, hidden=tuple(range(12)))
    image = render(cam, [d, stranger], seed=33, occluders=occ, tag_dictionary=DICT)
    result = MarkerTracker(camera_info(cam), cam.height_m, [TagTarget('yellow', 1)]).track(image)
    m = result.modules['yellow']
    assert list(np.flatnonzero(~m.visible)) == [3, 8]
    assert errors(m, yellow).max() <= 0.4
    assert result.unknown_tags == (12,)


def test_wrong_image_size_is_refused():
    cam = Camera()
    tracker = MarkerTracker(camera_info(cam), cam.height_m, [TagTarget('a', 0)])
    with pytest.raises(ValueError, match='camera_info'):
        tracker.track(np.zeros((100, 100, 3), np.uint8))
