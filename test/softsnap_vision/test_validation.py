"""Batch validation: a folder of rendered images and a manifest give the paper's RMSE table,
a PNG plot and a rerun recording with the same numbers."""
from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import yaml

from render import Camera, ModuleDrawing, centred_origin, render
from softsnap_model import Skeleton, solve_forward

SK = Skeleton()
TRUE_SK = Skeleton(stiffness=[1.3] * 4 + [1.0] * 4 + [0.8] * 3)
THREADINGS = {'yellow': 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3',
              'w': 'R3 R3 R3 R3 L2 L3 L2 R3 R3 R3 R3 R3'}
STEPS_MM = (10.0, 25.0, 40.0)


def test_manifest_to_table_plot_and_recording(tmp_path, read_rrd):
    cam = Camera()
    (tmp_path / 'camera.yaml').write_text(cam.camera_info_yaml())
    rows, truth = [], {}
    for label, holes in THREADINGS.items():
        for i, c in enumerate(STEPS_MM):
            length = SK.straight_length_mm(holes.split()) - c
            ribs = solve_forward(TRUE_SK, holes.split(), length).rib_centers
            model = solve_forward(SK, holes.split(), length).rib_centers
            truth[(label, c)] = float(np.sqrt(np.mean(np.sum((ribs - model) ** 2, axis=1))))
            name = f'{label}_{i}.png'
            cv2.imwrite(str(tmp_path / name), render(
                cam, [ModuleDrawing(ribs_mm=ribs, origin_mm=centred_origin(ribs, 0.1), yaw_rad=0.1)],
                seed=100 + i))
            rows.append({'image': name, 'threading': holes, 'cable_length_mm': round(length, 6),
                         'label': label})
    rows.append({'image': 'missing.png', 'threading': THREADINGS['w'], 'cable_length_mm': 190.0,
                 'label': 'broken'})
    (tmp_path / 'manifest.yaml').write_text(yaml.safe_dump(rows))
    out = subprocess.run([sys.executable, '-m', 'softsnap_vision.validation', '--camera-info',
                          str(tmp_path / 'camera.yaml'), '--plane-distance-m', str(cam.height_m),
                          '--manifest', str(tmp_path / 'manifest.yaml'), '--output',
                          str(tmp_path / 'out')], capture_output=True, text=True, timeout=600)
    assert out.returncode == 1, out.stderr          # the missing image, the others measured
    assert 'missing.png' in out.stderr
    table = (tmp_path / 'out' / 'table.md').read_text().splitlines()
    assert table[0] == '| threading | 10 mm | 25 mm | 40 mm |'
    for line in table[2:]:
        label, *cells = [c.strip() for c in line.strip('|').split('|')]
        for c, cell in zip(STEPS_MM, cells):
            assert abs(float(cell) - truth[(label, c)]) <= 0.2 + 0.005, (label, c, cell)
    assert max(truth.values()) > 1.0      # the table shows something: the truth differs
    png = cv2.imread(str(tmp_path / 'out' / 'rmse.png'))
    assert png is not None and png.shape[0] > 200 and png.std() > 5
    rec = read_rrd(tmp_path / 'out' / 'validation.rrd')
    for label in THREADINGS:
        values = rec.scalars(f'validation/{label}/rmse_mm')
        assert len(values) == 3
        for c, v in zip(STEPS_MM, values):
            assert abs(v - truth[(label, c)]) <= 0.2
        assert rec.scalars(f'validation/{label}/contraction_mm') == list(STEPS_MM)
        assert len(rec.values(f'validation/{label}/model', 'Points2D:positions')) == 3


def test_csv_manifest_and_bad_rows(tmp_path):
    from softsnap_vision.validation import ManifestError, load_manifest
    (tmp_path / 'm.csv').write_text('image,threading,cable_length_mm\na.png,R3 R3 R3 R3 R3 R3 '
                                    'R3 R3 R3 R3 R3 R3,180\n')
    rows = load_manifest(tmp_path / 'm.csv')
    assert rows[0].holes == ('R3',) * 12 and rows[0].cable_length_mm == 180.0
    assert rows[0].image == tmp_path / 'a.png'
    (tmp_path / 'bad.csv').write_text('image,threading,cable_length_mm\na.png,R3,abc\n')
    try:
        load_manifest(tmp_path / 'bad.csv')
    except ManifestError as exc:
        assert 'row 1' in str(exc) and 'abc' in str(exc)
    else:
        raise AssertionError('bad length accepted')
