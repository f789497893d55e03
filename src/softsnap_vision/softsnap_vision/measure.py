"""``python -m softsnap_vision.measure``: the paper's camera measurement of a module, offline.

    python -m softsnap_vision.measure --camera-info CAMERA.yaml --plane-distance-m H \\
        [--threading "R1 R1 ..." --cable-length-mm L] [--markers MARKERS.yaml] [--json] IMAGE...

One JSON object per image (a list with ``--json``; otherwise one line of text each)::

    {"image": path, "ribs_mm": [[x, y] or null, ... one per rib], "missing": [rib indices],
     "rmse_to_model_mm": float or null, "error": null or "message"}

Exit status 0 when every image was measured, 1 when any image had an error (the others
are still measured and printed), 2 for bad arguments (camera_info, markers, threading).
"""
from __future__ import annotations

import argparse
import json
import sys

import cv2
import numpy as np

from softsnap_model import Skeleton

from .camera_info import CameraInfoError, load_camera_info
from .marker_config import MarkerConfigError, load_marker_config
from .measurement import MeasurementError, measure_image, model_rib_centers_mm

__all__ = ['main', 'measure_files', 'build_parser']


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='python -m softsnap_vision.measure',
                                description='Rib centres of a SoftSnap module from top-down images '
                                            "(the paper's colour-marker measurement).")
    p.add_argument('--camera-info', required=True, help='camera_info YAML (camera_calibration_parsers)')
    p.add_argument('--plane-distance-m', type=float, required=True,
                   help='distance from the camera centre to the marker plane along the optical axis (m)')
    p.add_argument('--threading', help='holes rib 0 first, e.g. "R1 R1 R2 ..." (with --cable-length-mm)')
    p.add_argument('--cable-length-mm', type=float, help='cable length at the images (mm)')
    p.add_argument('--markers', help='marker colours and sizes (YAML; default: the paper\'s)')
    p.add_argument('--json', action='store_true', help='print one JSON list')
    p.add_argument('images', nargs='+', metavar='IMAGE')
    return p


def _record(path: str, measurement=None, error: str | None = None) -> dict:
    if measurement is None:
        return {'image': path, 'ribs_mm': None, 'missing': None, 'rmse_to_model_mm': None,
                'error': error}
    ribs = [None if not v else [round(float(x), 4), round(float(y), 4)]
            for (x, y), v in zip(measurement.ribs_mm, measurement.visible)]
    out = {'image': path, 'ribs_mm': ribs, 'missing': list(measurement.missing),
           'rmse_to_model_mm': (None if measurement.rmse_to_model_mm is None
                                else round(measurement.rmse_to_model_mm, 4)),
           'error': None}
    if measurement.fit is not None:
        out['fit_residual_mm'] = round(measurement.fit.residual_mm, 4)
    if measurement.note:
        out['note'] = measurement.note
    return out


def measure_files(paths, camera, plane_distance_m, config, skeleton, model_mm=None) -> list[dict]:
    """One record per image path (see the module docstring); errors never stop the others."""
    records = []
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            records.append(_record(str(path), error=f'cannot read image {path}'))
            continue
        try:
            m = measure_image(image, camera, plane_distance_m, config, skeleton, model_mm)
        except MeasurementError as exc:
            records.append(_record(str(path), error=str(exc)))
            continue
        records.append(_record(str(path), m))
    return records


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    skeleton = Skeleton()
    try:
        camera = load_camera_info(args.camera_info)
        config = load_marker_config(args.markers)
        if not (args.plane_distance_m > 0 and np.isfinite(args.plane_distance_m)):
            raise ValueError(f'--plane-distance-m must be > 0, got {args.plane_distance_m}')
        model_mm = None
        if (args.threading is None) != (args.cable_length_mm is None):
            raise ValueError('--threading and --cable-length-mm go together')
        if args.threading is not None:
            model_mm = model_rib_centers_mm(skeleton, args.threading.replace(',', ' ').split(),
                                            args.cable_length_mm)
    except (CameraInfoError, MarkerConfigError, ValueError) as exc:
        print(f'measure: {exc}', file=sys.stderr)
        return 2
    records = measure_files(args.images, camera, args.plane_distance_m, config, skeleton, model_mm)
    if args.json:
        print(json.dumps(records, indent=1))
    else:
        for r in records:
            print(json.dumps(r))
    return 1 if any(r['error'] for r in records) else 0


if __name__ == '__main__':
    sys.exit(main())
