"""Small frame and vector helpers of the MJCF builder (quaternions, rotation matrices,
validated vectors); split from :mod:`softsnap_model.physics.mjcf` to keep one file per
concept under 800 lines. No ``mujoco`` import.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['rotation_from_xyzw', 'wxyz_from_matrix', 'finite_vector', 'unit_quaternion']


def _vector(name, value, n) -> tuple:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be {n} numbers, got {value!r}') from None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValueError(f'{name} must be {n} finite numbers, got {value!r}')
    return tuple(float(v) for v in arr)


def _unit_quaternion(name, value) -> tuple:
    q = np.array(_vector(name, value, 4))
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-6:
        raise ValueError(f'{name} must be a unit quaternion (w, x, y, z), got {value!r} '
                         f'(norm {norm:.6g})')
    return tuple(float(v) for v in q / norm)


def _rot(xyzw) -> np.ndarray:
    x, y, z, w = xyzw
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _mat_to_wxyz(r: np.ndarray) -> tuple:
    # Shepperd's method: the largest diagonal term keeps the square root well conditioned.
    tr = np.trace(r)
    if tr > 0:
        sq = math.sqrt(tr + 1.0) * 2
        q = (0.25 * sq, (r[2, 1] - r[1, 2]) / sq, (r[0, 2] - r[2, 0]) / sq,
             (r[1, 0] - r[0, 1]) / sq)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        sq = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = ((r[2, 1] - r[1, 2]) / sq, 0.25 * sq, (r[0, 1] + r[1, 0]) / sq,
             (r[0, 2] + r[2, 0]) / sq)
    elif r[1, 1] > r[2, 2]:
        sq = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = ((r[0, 2] - r[2, 0]) / sq, (r[0, 1] + r[1, 0]) / sq, 0.25 * sq,
             (r[1, 2] + r[2, 1]) / sq)
    else:
        sq = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = ((r[1, 0] - r[0, 1]) / sq, (r[0, 2] + r[2, 0]) / sq, (r[1, 2] + r[2, 1]) / sq,
             0.25 * sq)
    q = np.array(q)
    q /= np.linalg.norm(q)
    return tuple(float(v) for v in (q if q[0] >= 0 else -q))


rotation_from_xyzw = _rot
wxyz_from_matrix = _mat_to_wxyz
finite_vector = _vector
unit_quaternion = _unit_quaternion


def _flat(rot: np.ndarray) -> bool:
    """Ribs (module y) within 30 deg of horizontal for this orientation."""
    return abs(rot[2, 1]) < 0.5
