"""`python -m softsnap_vision.measure` on rendered PNG files, as a user runs it."""
from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np

from render import Camera, ModuleDrawing, centred_origin, render
from softsnap_model import Skeleton, solve_forward

SK = Skeleton()
TRUE_SK = Skeleton(stiffness=[1.3] * 4 + [1.0] * 7)
YELLOW = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'


def run(*args, cwd=None):
    return subprocess.run([sys.executable, '-m', 'softsnap_vision.measure', *map(str, args)],
                          capture_output=True, text=True, timeout=300, cwd=cwd)


def test_json_per_image_with_errors_reported_and_the_others_measured(tmp_path):
    cam = Camera()
    (tmp_path / 'camera.yaml').write_text(cam.camera_info_yaml())
    threading = YELLOW.split()
    length = SK.straight_length_mm(threading) - 30.0
    truth = solve_forward(TRUE_SK, threading, length).rib_centers
    model = solve_forward(SK, threading, length).rib_centers
    good = render(cam, [ModuleDrawing(ribs_mm=truth, origin_mm=centred_origin(truth, 0.2),
                                      yaw_rad=0.2, hidden=(6,))], seed=3)
    no_orange = render(cam, [ModuleDrawing(ribs_mm=truth, origin_mm=centred_origin(truth, 0.0),
                                           base_marker=False)], seed=4)
    cv2.imwrite(str(tmp_path / 'good.png'), good)
    cv2.imwrite(str(tmp_path / 'no_orange.png'), no_orange)
    (tmp_path / 'broken.png').write_bytes(b'not a png')
    out = run('--camera-info', tmp_path / 'camera.yaml', '--plane-distance-m', cam.height_m,
              '--threading', YELLOW, '--cable-length-mm', length, '--json',
              tmp_path / 'good.png', tmp_path / 'no_orange.png', tmp_path / 'broken.png')
    assert out.returncode == 1, out.stderr
    records = json.loads(out.stdout)
    assert [r['image'] for r in records] == [str(tmp_path / n) for n in
                                             ('good.png', 'no_orange.png', 'broken.png')]
    good_r, orange_r, broken_r = records
    assert good_r['error'] is None
    assert good_r['missing'] == [6] and good_r['ribs_mm'][6] is None
    assert len(good_r['ribs_mm']) == 12
    seen = [i for i in range(12) if i != 6]
    err = np.hypot(*(np.array([good_r['ribs_mm'][i] for i in seen]) - truth[seen]).T)
    assert err.max() <= 0.4
    true_rmse = float(np.sqrt(np.mean(np.sum((truth[seen] - model[seen]) ** 2, axis=1))))
    assert true_rmse > 0.5 and abs(good_r['rmse_to_model_mm'] - true_rmse) <= 0.2
    assert 'orange' in orange_r['error'] and orange_r['ribs_mm'] is None
    assert 'cannot read' in broken_r['error']


def test_all_good_exits_0_and_without_a_model_rmse_is_null(tmp_path):
    cam = Camera()
    (tmp_path / 'camera.yaml').write_text(cam.camera_info_yaml())
    truth = solve_forward(SK, YELLOW.split(), 180.0).rib_centers
    cv2.imwrite(str(tmp_path / 'a.png'),
                render(cam, [ModuleDrawing(ribs_mm=truth, origin_mm=centred_origin(truth, 0.0))]))
    out = run('--camera-info', tmp_path / 'camera.yaml', '--plane-distance-m', 0.5,
              tmp_path / 'a.png')
    assert out.returncode == 0, out.stderr
    record = json.loads(out.stdout.strip())
    assert record['rmse_to_model_mm'] is None and record['missing'] == []


def test_bad_arguments_exit_2_with_one_line(tmp_path):
    (tmp_path / 'camera.yaml').write_text('image_width: 640\nimage_height: 480\n')
    out = run('--camera-info', tmp_path / 'camera.yaml', '--plane-distance-m', 0.5, 'x.png')
    assert out.returncode == 2 and 'camera_matrix' in out.stderr
    cam = Camera()
    (tmp_path / 'camera.yaml').write_text(cam.camera_info_yaml())
    out = run('--camera-info', tmp_path / 'camera.yaml', '--plane-distance-m', 0.5,
              '--threading', 'R1 R9', '--cable-length-mm', 100, 'x.png')
    assert out.returncode == 2 and 'measure:' in out.stderr
