"""Camera calibration on checkerboards rendered with known intrinsics and distortion."""
from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from render import _blend, _coverage, _subdivide
from softsnap_vision.calibrate_camera import calibrate_checkerboard
from softsnap_vision.camera_info import load_camera_info

W, H = 800, 600
K_TRUE = np.array([[820.0, 0, 405.5], [0, 818.0, 297.2], [0, 0, 1]])
D_TRUE = np.array([-0.24, 0.11, 0.0009, -0.0006, -0.02])
COLS, ROWS, SQUARE_MM = 8, 6, 25.0


def render_board(rvec, tvec, seed) -> np.ndarray:
    """A checkerboard (COLS x ROWS inner corners) seen from a pose, by forward projection."""
    rng = np.random.default_rng(seed)
    img = np.full((H, W, 3), 90.0) + rng.normal(0, 8, (H, W, 1))

    def project(points_mm):
        pts = np.column_stack([np.asarray(points_mm) / 1000.0, np.zeros(len(points_mm))])
        px, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, K_TRUE, D_TRUE)
        return px.reshape(-1, 2)

    s = SQUARE_MM
    # white board with a margin of one square, then the black squares
    x0, y0, x1, y1 = -0.8 * s, -0.8 * s, (COLS + 1.8) * s, (ROWS + 1.8) * s
    rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    _blend(img, _coverage([project(_subdivide(rect, 40))], (H, W)), (235, 235, 235))
    for r in range(ROWS + 1):          # (ROWS + 1) x (COLS + 1) squares: the inner
        for c in range(COLS + 1):      # corners are the ROWS x COLS asked for
            if (r + c) % 2 == 0:
                sq = np.array([[c * s, r * s], [(c + 1) * s, r * s], [(c + 1) * s, (r + 1) * s],
                               [c * s, (r + 1) * s]])
                _blend(img, _coverage([project(_subdivide(sq, 8))], (H, W)), (20, 20, 20))
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def views(n=18):
    rng = np.random.default_rng(7)
    out = []
    centre = np.array([(COLS + 1) * SQUARE_MM / 2000.0, (ROWS + 1) * SQUARE_MM / 2000.0, 0.0])
    for i in range(n):
        angles = rng.uniform(-0.45, 0.45, 3) * np.array([1, 1, 0.5])
        rot, _ = cv2.Rodrigues(angles)
        distance = rng.uniform(0.45, 0.6)
        # board centre at an offset from the axis so the views cover the image's corners
        offset = np.array([rng.uniform(-0.11, 0.11), rng.uniform(-0.08, 0.08), distance])
        tvec = offset - rot @ centre
        out.append(render_board(cv2.Rodrigues(rot)[0], tvec, seed=i))
    return out


@pytest.fixture(scope='module')
def board_images():
    return views()


def test_calibration_recovers_the_rendered_camera(board_images):
    result = calibrate_checkerboard(board_images, COLS, ROWS, SQUARE_MM)
    assert len(result.used) >= 10
    assert result.rms_px < 0.2
    k = result.camera.camera_matrix
    for (i, j), tol in (((0, 0), 0.005), ((1, 1), 0.005)):
        assert abs(k[i, j] / K_TRUE[i, j] - 1) < tol, (k, K_TRUE)
    assert abs(k[0, 2] - K_TRUE[0, 2]) < 3.0 and abs(k[1, 2] - K_TRUE[1, 2]) < 3.0
    # Distortion coefficients trade off against each other: compare what they do. Every
    # pixel of a grid, undistorted with the estimate and re-projected with the truth.
    # Over the part of the image the boards covered (a calibration says nothing beyond).
    from softsnap_vision.calibrate_camera import find_board
    seen = np.vstack([find_board(cv2.cvtColor(board_images[i], cv2.COLOR_BGR2GRAY), COLS, ROWS)
                      for i in result.used]).astype(np.float32)
    hull = cv2.convexHull(seen)
    u, v = np.meshgrid(np.linspace(0, W - 1, 40), np.linspace(0, H - 1, 30))
    grid = np.column_stack([u.ravel(), v.ravel()])
    inside = np.array([cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0
                       for x, y in grid])
    assert inside.mean() > 0.4     # the views cover the middle of the image and more
    px = grid[inside].reshape(-1, 1, 2)
    rays = cv2.undistortPoints(px, k, result.camera.distortion).reshape(-1, 2)
    back, _ = cv2.projectPoints(np.column_stack([rays, np.ones(len(rays))]).reshape(-1, 1, 3),
                                np.zeros(3), np.zeros(3), K_TRUE, D_TRUE)
    err = np.hypot(*(back.reshape(-1, 2) - px.reshape(-1, 2)).T)
    # ~0.4 px is nearly uniform over the image: the principal point's error (~0.5 px),
    # which a top-down measurement does not see (the origin and axis are markers).
    assert err.max() < 1.0 and np.median(err) < 0.6, (err.max(), np.median(err))
    spread = err - np.median(err)
    assert np.abs(spread).max() < 0.4


def test_cli_writes_a_camera_info_yaml_that_loads(tmp_path, board_images):
    paths = []
    for i, img in enumerate(board_images[:8]):
        paths.append(tmp_path / f'board{i}.png')
        cv2.imwrite(str(paths[-1]), img)
    blank = tmp_path / 'blank.png'
    cv2.imwrite(str(blank), np.full((H, W), 128, np.uint8))
    out = subprocess.run([sys.executable, '-m', 'softsnap_vision.calibrate_camera', '--cols',
                          str(COLS), '--rows', str(ROWS), '--square-mm', str(SQUARE_MM),
                          '--output', str(tmp_path / 'cam.yaml'), *map(str, paths), str(blank)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert 'skipped' in out.stderr and 'blank.png' in out.stderr
    camera = load_camera_info(tmp_path / 'cam.yaml')
    assert (camera.width, camera.height) == (W, H)
    assert abs(camera.camera_matrix[0, 0] / K_TRUE[0, 0] - 1) < 0.01


def test_too_few_views_is_an_error():
    with pytest.raises(ValueError, match='at least'):
        calibrate_checkerboard([np.full((H, W), 128, np.uint8)] * 3, COLS, ROWS, SQUARE_MM)
