"""Calibrate the model from what the camera saw: measured shapes + measured cable lengths.

    python -m softsnap_vision.calibrate_model --camera-info CAMERA.yaml --plane-distance-m H \\
        --manifest MANIFEST.csv|.yaml [--fit stiffness,friction,length_offset] [--markers M]
    python -m softsnap_vision.calibrate_model --bag BAG --scene brittle_star [--fit ...]

The manifest is validation's (image, threading, cable_length_mm), where
``cable_length_mm`` is the length the encoder reported, and may add ``direction`` (pull
or release, how the length was reached). Every image is measured (the paper's
measurement, :mod:`.measurement`); each measured shape becomes a
:class:`softsnap_model.calibration.Observation` (missing ribs NaN) and
:func:`softsnap_model.calibration.calibrate` fits the chosen parameters (stiffness
ratios, friction, encoder scale and offset). Prints the result as JSON (``to_dict``);
images that could not be measured are listed on stderr and left out.

From a bag (``--bag``, :func:`observations_from_bag`) or live,
:func:`observation_from_shape_message` turns a MeasuredShape (the marker_tracker's, with
its measured cable length) into the same Observation.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import yaml

from softsnap_model import Skeleton
from softsnap_model.calibration import DEFAULT_FIT, PARAMETERS, Observation, calibrate

from .camera_info import CameraInfoError, load_camera_info
from .marker_config import MarkerConfigError, load_marker_config
from .measure import measure_files
from .validation import ManifestError, load_manifest
from softsnap_ros.units import MM_PER_M

__all__ = ['observation_from_measurement', 'observation_from_shape_message',
           'observations_from_manifest', 'observations_from_bag', 'main']



def observation_from_measurement(holes, ribs_mm, cable_length_mm: float,
                                 direction: str = 'pull') -> Observation:
    """An Observation from measured rib centres (mm, base frame; None or NaN = missing)."""
    pts = np.array([[np.nan, np.nan] if p is None else p for p in ribs_mm], dtype=float)
    return Observation(tuple(holes), float(cable_length_mm), pts, direction)


def observation_from_shape_message(msg, holes, direction: str = 'pull') -> Observation | None:
    """An Observation from a MeasuredShape (m); None without a measured cable length."""
    if not math.isfinite(msg.cable_length) or msg.cable_length <= 0:
        return None
    pts = np.array([[p.x, p.y] for p in msg.rib_centers], dtype=float) * MM_PER_M
    pts[~np.asarray(msg.visible, dtype=bool)] = np.nan
    return Observation(tuple(holes), msg.cable_length * MM_PER_M, pts, direction)


def observations_from_bag(path, scene, topic_suffix: str = '/shape/measured',
                          length_tol_mm: float = 0.01) -> list[Observation]:
    """Observations from the MeasuredShape messages of a rosbag2 bag (MCAP or sqlite3).

    Every topic ending in ``topic_suffix`` is read; the module (the message's ``module``)
    gives the threading from ``scene``. The direction is inferred per module from its
    cable length: ``release`` after the length grew, ``pull`` after it shrank (and at
    first). Frames at the same length and direction (within ``length_tol_mm``) are one
    observation, the last frame of the run: a camera sees a still module many times.
    Uses rosbags (pinned) and rclpy's deserialisation (no ROS graph).
    """
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from softsnap_interfaces.msg import MeasuredShape

    with Reader(Path(path)) as reader:
        connections = [c for c in reader.connections if c.topic.endswith(topic_suffix)
                       and c.msgtype == 'softsnap_interfaces/msg/MeasuredShape']
        messages = [deserialize_message(bytes(data), MeasuredShape)
                    for _, _, data in reader.messages(connections=connections)]
    kept: dict[str, list] = {}
    state: dict[str, tuple[float, str]] = {}
    for msg in messages:
        if msg.module not in scene.module_names or not math.isfinite(msg.cable_length):
            continue
        length = msg.cable_length * MM_PER_M
        previous, direction = state.get(msg.module, (None, 'pull'))
        if previous is not None and abs(length - previous) > length_tol_mm:
            direction = 'release' if length > previous else 'pull'
        holes = scene.module(msg.module).holes
        obs = observation_from_shape_message(msg, holes, direction)
        runs = kept.setdefault(msg.module, [])
        if previous is not None and abs(length - previous) <= length_tol_mm and runs \
                and runs[-1].direction == direction:
            runs[-1] = obs          # the same still shape again: keep the latest frame
        else:
            runs.append(obs)
        state[msg.module] = (length, direction)
    return [o for runs in kept.values() for o in runs]


def _directions(path) -> list[str]:
    """Per manifest row, its optional direction (default pull)."""
    path = Path(path)
    if path.suffix.lower() in ('.yaml', '.yml'):
        entries = yaml.safe_load(path.read_text())
    else:
        entries = list(csv.DictReader(path.read_text().splitlines()))
    return [str(e.get('direction') or 'pull') for e in entries]


def observations_from_manifest(manifest, camera, plane_distance_m, config,
                               skeleton: Skeleton = Skeleton()):
    """(observations, [(image, error)]) from a manifest's images."""
    rows = load_manifest(manifest)
    directions = _directions(manifest)
    observations, failed = [], []
    for row, direction in zip(rows, directions):
        record = measure_files([row.image], camera, plane_distance_m, config, skeleton)[0]
        if record['error']:
            failed.append((row.image, record['error']))
            continue
        observations.append(observation_from_measurement(row.holes, record['ribs_mm'],
                                                         row.cable_length_mm, direction))
    return observations, failed


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m softsnap_vision.calibrate_model',
                                description='fit the model to shapes measured by the camera')
    p.add_argument('--camera-info', help='with --manifest')
    p.add_argument('--plane-distance-m', type=float, help='with --manifest')
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument('--manifest', help='images with threading and encoder cable length')
    source.add_argument('--bag', help="a bag of the marker_tracker's MeasuredShape messages")
    p.add_argument('--scene', default='brittle_star', help='with --bag: threadings by module')
    p.add_argument('--markers')
    p.add_argument('--fit', default=','.join(DEFAULT_FIT),
                   help=f'parameters to fit, comma-separated, from {", ".join(PARAMETERS)}')
    args = p.parse_args(argv)
    try:
        fit = tuple(f for f in args.fit.split(',') if f)
        if args.bag:
            from softsnap_model.scene import load_scene
            scene = load_scene(args.scene)
            skeleton = scene.skeleton
            observations = observations_from_bag(args.bag, scene)
        else:
            if args.camera_info is None or args.plane_distance_m is None:
                raise ValueError('--manifest needs --camera-info and --plane-distance-m')
            skeleton = Skeleton()
            camera = load_camera_info(args.camera_info)
            config = load_marker_config(args.markers)
            observations, failed = observations_from_manifest(args.manifest, camera,
                                                              args.plane_distance_m, config)
            for image, error in failed:
                print(f'{image}: {error} (left out)', file=sys.stderr)
        result = calibrate(skeleton, observations, fit=fit)
    except (CameraInfoError, MarkerConfigError, ManifestError, ValueError, OSError) as exc:
        print(f'calibrate_model: {exc}', file=sys.stderr)
        return 2
    print(json.dumps(result.to_dict(), indent=1))
    return 0 if result.converged else 1


if __name__ == '__main__':
    sys.exit(main())
