"""Camera intrinsics and distortion from checkerboard images, written as a camera_info YAML.

    python -m softsnap_vision.calibrate_camera --cols 9 --rows 6 --square-mm 20 \\
        --output camera.yaml [--camera-name NAME] [--rational] IMAGE...

``--cols`` and ``--rows`` count the board's inner corners. Each image's corners are found
with ``cv2.findChessboardCornersSB`` (sub-pixel, robust to blur and uneven light); images
where the whole board is not found are listed and skipped. ``cv2.calibrateCamera`` fits
K and the plumb_bob distortion (k1 k2 p1 p2 k3; ``--rational`` for 8 coefficients).
The file is what ``camera_calibration_parsers`` writes (P = K, R = I), read by
``python -m softsnap_vision.measure --camera-info`` and publishable as camera_info.
Take 10-20 views that tilt the board and cover the corners of the image: distortion is
largest there. Exit status 0, 1 when fewer than ``MIN_VIEWS`` views were usable, 2 for bad
arguments.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import cv2
import numpy as np

from .camera_info import CameraInfo, save_camera_info

__all__ = ['CalibrationResult', 'calibrate_checkerboard', 'find_board', 'main', 'MIN_VIEWS']

#: Fewest usable views for a calibration (5-coefficient distortion, 4 intrinsics).
MIN_VIEWS = 4


@dataclass(frozen=True)
class CalibrationResult:
    """Result of :func:`calibrate_checkerboard`."""

    camera: CameraInfo
    rms_px: float                        # reprojection error over every corner (px)
    used: tuple[int, ...]                # image indices the board was found in
    skipped: tuple[int, ...]             # image indices without the whole board


def find_board(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """Inner corners (cols*rows, 2) px of a checkerboard, row by row; None if not all found."""
    found, corners = cv2.findChessboardCornersSB(
        gray, (cols, rows), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    if not found:
        return None
    return corners.reshape(-1, 2).astype(np.float64)


def calibrate_checkerboard(images, cols: int, rows: int, square_mm: float,
                           camera_name: str = 'camera', rational: bool = False
                           ) -> CalibrationResult:
    """Calibrate from BGR or grey images of one checkerboard (see the module docstring)."""
    if cols < 3 or rows < 3:
        raise ValueError(f'the board needs at least 3x3 inner corners, got {cols}x{rows}')
    if not square_mm > 0:
        raise ValueError(f'square_mm must be > 0, got {square_mm!r}')
    grid = np.zeros((rows * cols, 3), np.float32)
    grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * (square_mm / 1000.0)
    object_points, image_points, used, skipped = [], [], [], []
    size = None
    for i, image in enumerate(images):
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if size is None:
            size = gray.shape[::-1]
        elif gray.shape[::-1] != size:
            raise ValueError(f'image {i} is {gray.shape[1]}x{gray.shape[0]} px, the first '
                             f'is {size[0]}x{size[1]}')
        corners = find_board(gray, cols, rows)
        if corners is None:
            skipped.append(i)
            continue
        object_points.append(grid)
        image_points.append(corners.astype(np.float32).reshape(-1, 1, 2))
        used.append(i)
    if len(used) < MIN_VIEWS:
        raise ValueError(f'the board was found in {len(used)} image(s), at least {MIN_VIEWS} '
                         'are needed')
    flags = cv2.CALIB_RATIONAL_MODEL if rational else 0
    rms, k, d, _, _ = cv2.calibrateCamera(object_points, image_points, size, None, None,
                                          flags=flags)
    model = 'rational_polynomial' if rational else 'plumb_bob'
    n = 8 if rational else 5
    camera = CameraInfo(width=size[0], height=size[1], camera_matrix=k, distortion_model=model,
                        distortion=np.asarray(d, float).ravel()[:n], name=camera_name)
    return CalibrationResult(camera=camera, rms_px=float(rms), used=tuple(used),
                             skipped=tuple(skipped))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m softsnap_vision.calibrate_camera',
                                description='camera_info YAML from checkerboard images')
    p.add_argument('--cols', type=int, required=True, help='inner corners along a row')
    p.add_argument('--rows', type=int, required=True, help='inner corners along a column')
    p.add_argument('--square-mm', type=float, required=True, help='square edge (mm)')
    p.add_argument('--output', required=True, help='camera_info YAML to write')
    p.add_argument('--camera-name', default='camera')
    p.add_argument('--rational', action='store_true', help='8-coefficient rational model')
    p.add_argument('images', nargs='+')
    args = p.parse_args(argv)
    images = []
    for path in args.images:
        image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if image is None:
            print(f'calibrate_camera: cannot read {path}', file=sys.stderr)
            return 2
        images.append(image)
    try:
        result = calibrate_checkerboard(images, args.cols, args.rows, args.square_mm,
                                        args.camera_name, args.rational)
    except ValueError as exc:
        print(f'calibrate_camera: {exc}', file=sys.stderr)
        return 1
    save_camera_info(result.camera, args.output)
    for i in result.skipped:
        print(f'skipped {args.images[i]}: board not found', file=sys.stderr)
    k = result.camera.camera_matrix
    print(f'{len(result.used)} views, reprojection RMS {result.rms_px:.3f} px; fx {k[0, 0]:.2f} '
          f'fy {k[1, 1]:.2f} cx {k[0, 2]:.2f} cy {k[1, 2]:.2f}; wrote {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
