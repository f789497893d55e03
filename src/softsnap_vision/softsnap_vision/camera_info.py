"""Camera intrinsics and distortion as ROS ``camera_info`` holds them, and back-projection
of image points onto the marker plane (numpy + OpenCV, no rclpy).

File format: the YAML that ``camera_calibration_parsers`` writes (``image_width``,
``image_height``, ``camera_name``, ``camera_matrix``, ``distortion_model``,
``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``; matrices as
``{rows, cols, data}``). Distortion models: ``plumb_bob`` (k1 k2 p1 p2 k3) and
``rational_polynomial`` (k1 k2 p1 p2 k3 k4 k5 k6), both OpenCV's own model.

Frames. Image points are pixels (u right, v down; pixel centres at integer coordinates,
OpenCV's convention). The camera optical frame is z forward, x right, y down (REP 103).
For a camera looking straight down at a plane at distance ``H`` along its optical axis, a
plane point has optical-frame coordinates ``(x_n H, y_n H, H)`` with ``(x_n, y_n)`` the
undistorted normalised image point. Seen from above, the plane's right-handed frame has
x to the right of the image and y up the image: ``(x_n H, -y_n H)``, so that
counter-clockwise angles seen from above are positive, as in the model.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from softsnap_ros.units import MM_PER_M

__all__ = ['CameraInfo', 'CameraInfoError', 'load_camera_info', 'save_camera_info',
           'pixels_to_plane_mm', 'DISTORTION_COEFFICIENTS']

#: Distortion models we undistort, and how many coefficients each has.
DISTORTION_COEFFICIENTS = {'plumb_bob': 5, 'rational_polynomial': 8}


class CameraInfoError(ValueError):
    """A camera_info file or message is missing, malformed or inconsistent."""


@dataclass(frozen=True, eq=False)   # arrays inside: identity equality
class CameraInfo:
    """Pinhole intrinsics and lens distortion of one camera.

    Attributes
    ----------
    width, height : int
        Image size (px) the calibration is for.
    camera_matrix : ndarray, shape (3, 3)
        ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (px).
    distortion_model : str
        ``plumb_bob`` or ``rational_polynomial``.
    distortion : ndarray, shape (5,) or (8,)
        OpenCV distortion coefficients (k1 k2 p1 p2 k3 [k4 k5 k6]).
    name : str
        ``camera_name`` of the file.
    """

    width: int
    height: int
    camera_matrix: np.ndarray
    distortion_model: str = 'plumb_bob'
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(5))
    name: str = 'camera'

    def __post_init__(self):
        k = np.asarray(self.camera_matrix, dtype=float)
        if k.shape != (3, 3):
            raise CameraInfoError(f'camera_matrix must be 3x3, got shape {k.shape}')
        if not np.isfinite(k).all() or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise CameraInfoError(f'camera_matrix must be finite with fx, fy > 0, got {k.tolist()}')
        if self.distortion_model not in DISTORTION_COEFFICIENTS:
            raise CameraInfoError(f'distortion_model must be one of '
                                  f'{", ".join(DISTORTION_COEFFICIENTS)}, got {self.distortion_model!r}')
        d = np.asarray(self.distortion, dtype=float).ravel()
        if d.size == 0:
            d = np.zeros(DISTORTION_COEFFICIENTS[self.distortion_model])
        if d.size != DISTORTION_COEFFICIENTS[self.distortion_model] or not np.isfinite(d).all():
            raise CameraInfoError(
                f'{self.distortion_model} needs {DISTORTION_COEFFICIENTS[self.distortion_model]} '
                f'finite distortion coefficients, got {d.tolist()}')
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraInfoError(f'image size must be > 0, got {self.width}x{self.height}')
        k.setflags(write=False)
        d.setflags(write=False)
        object.__setattr__(self, 'camera_matrix', k)
        object.__setattr__(self, 'distortion', d)
        object.__setattr__(self, 'width', int(self.width))
        object.__setattr__(self, 'height', int(self.height))

    @property
    def focal_px(self) -> float:
        """Mean focal length (px)."""
        return 0.5 * (self.camera_matrix[0, 0] + self.camera_matrix[1, 1])

    @classmethod
    def from_msg(cls, msg) -> 'CameraInfo':
        """From a sensor_msgs/CameraInfo message (any object with its fields)."""
        model = msg.distortion_model or 'plumb_bob'
        return cls(width=msg.width, height=msg.height,
                   camera_matrix=np.asarray(msg.k, dtype=float).reshape(3, 3),
                   distortion_model=model, distortion=np.asarray(msg.d, dtype=float),
                   name=getattr(msg.header, 'frame_id', '') or 'camera')

    def to_dict(self) -> dict:
        """The camera_calibration_parsers YAML layout (P = K, no rectification)."""
        k = self.camera_matrix
        p = np.zeros((3, 4))
        p[:, :3] = k
        return {
            'image_width': self.width,
            'image_height': self.height,
            'camera_name': self.name,
            'camera_matrix': {'rows': 3, 'cols': 3, 'data': [float(v) for v in k.ravel()]},
            'distortion_model': self.distortion_model,
            'distortion_coefficients': {'rows': 1, 'cols': int(self.distortion.size),
                                        'data': [float(v) for v in self.distortion]},
            'rectification_matrix': {'rows': 3, 'cols': 3,
                                     'data': [float(v) for v in np.eye(3).ravel()]},
            'projection_matrix': {'rows': 3, 'cols': 4, 'data': [float(v) for v in p.ravel()]},
        }


def _matrix(data: dict, key: str, rows: int, cols: int | None, path) -> np.ndarray:
    entry = data.get(key)
    if not isinstance(entry, dict) or 'data' not in entry:
        raise CameraInfoError(f'{path}: {key} must be a mapping with rows, cols and data')
    values = np.asarray(entry['data'], dtype=float).ravel()
    if cols is None:
        return values
    if values.size != rows * cols:
        raise CameraInfoError(f'{path}: {key} needs {rows * cols} values, got {values.size}')
    return values.reshape(rows, cols)


def load_camera_info(path: str | os.PathLike) -> CameraInfo:
    """Read a camera_info YAML (camera_calibration_parsers layout); CameraInfoError if bad."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise CameraInfoError(f'{path}: cannot read: {exc}') from None
    except yaml.YAMLError as exc:
        raise CameraInfoError(f'{path}: not valid YAML: {exc}') from None
    if not isinstance(data, dict):
        raise CameraInfoError(f'{path}: expected a mapping at the top level')
    for key in ('image_width', 'image_height', 'camera_matrix'):
        if key not in data:
            raise CameraInfoError(f'{path}: missing key {key!r}')
    try:
        return CameraInfo(
            width=int(data['image_width']), height=int(data['image_height']),
            camera_matrix=_matrix(data, 'camera_matrix', 3, 3, path),
            distortion_model=str(data.get('distortion_model', 'plumb_bob')),
            distortion=(_matrix(data, 'distortion_coefficients', 1, None, path)
                        if 'distortion_coefficients' in data else np.zeros(0)),
            name=str(data.get('camera_name', 'camera')))
    except (TypeError, ValueError) as exc:
        if isinstance(exc, CameraInfoError):
            raise CameraInfoError(f'{path}: {exc}') from None
        raise CameraInfoError(f'{path}: {exc}') from None


def save_camera_info(camera: CameraInfo, path: str | os.PathLike) -> None:
    """Write ``camera`` as a camera_info YAML that load_camera_info (and ROS) read back."""
    Path(path).write_text(yaml.safe_dump(camera.to_dict(), sort_keys=False))


def pixels_to_plane_mm(pixels, camera: CameraInfo, plane_distance_m: float) -> np.ndarray:
    """Pixels (N, 2) -> plane points (N, 2) in mm, seen from above (x right, y up the image).

    Distortion is removed first (cv2.undistortPoints to normalised coordinates), then the
    ray is cut with the plane at ``plane_distance_m`` along the optical axis.
    """
    if not (math.isfinite(plane_distance_m) and plane_distance_m > 0):
        raise ValueError(f'plane_distance_m must be finite and > 0, got {plane_distance_m!r}')
    pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    normalised = cv2.undistortPoints(pts, camera.camera_matrix, camera.distortion).reshape(-1, 2)
    h_mm = plane_distance_m * MM_PER_M
    return np.column_stack([normalised[:, 0] * h_mm, -normalised[:, 1] * h_mm])
