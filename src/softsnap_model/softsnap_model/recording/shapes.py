"""Module shapes in the 3D scene: rib frames, rib strips and the cable path, in metres."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from softsnap_ros.units import MM_PER_M

from .. import geometry
from ..skeleton import Skeleton

# Drawing defaults of the authors' module, in millimetres (from the one Skeleton definition).
RIB_SPACING_MM = Skeleton().spacing_mm

RIB_HALF_LENGTH_MM = Skeleton().rib_length_mm / 2.0



@dataclass(frozen=True)
class RibFrames:
    """Rib centres (n, 3) in metres and spine headings (n,) in radians, rib 0 first."""

    centres_m: np.ndarray
    headings_rad: np.ndarray


def _as_vector(values, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f'{name} must be a flat sequence, got shape {arr.shape}')
    if not np.isfinite(arr).all():
        raise ValueError(f'{name} must be finite, got {arr.tolist()}')
    return arr


def rib_centres_mm(angles_rad: Sequence[float], spacing_mm: float = RIB_SPACING_MM
                   ) -> np.ndarray:
    """Rib centres (n + 1, 2) in mm of a module with bending angles ``angles_rad`` (n)."""
    return np.asarray(geometry.rib_centers(_as_vector(angles_rad, 'angles_rad'), spacing_mm),
                      dtype=float)


def rib_frames(angles_rad: Sequence[float], rib_centres_m: np.ndarray | None = None,
               spacing_mm: float = RIB_SPACING_MM) -> RibFrames:
    """Rib frames from a message's angles, using its rib centres (m) when it has them."""
    angles = _as_vector(angles_rad, 'angles_rad')
    headings = np.concatenate(([0.0], np.cumsum(angles)))
    if rib_centres_m is not None and len(rib_centres_m):
        centres = np.asarray(rib_centres_m, dtype=float).reshape(-1, 3)
        if len(centres) != len(headings):
            raise ValueError(f'expected {len(headings)} rib centres for {len(angles)} angles, '
                             f'got {len(centres)}')
    else:
        planar = rib_centres_mm(angles, spacing_mm) / MM_PER_M
        centres = np.column_stack((planar, np.zeros(len(planar))))
    return RibFrames(centres, headings)


def rib_segments_m(frames: RibFrames) -> np.ndarray:
    """End points (n, 2, 3) of each rib: centre -/+ 12.5 mm along (-sin t, cos t)."""
    t = frames.headings_rad
    half_m = RIB_HALF_LENGTH_MM / MM_PER_M
    half = half_m * np.column_stack((-np.sin(t), np.cos(t), np.zeros_like(t)))
    return np.stack((frames.centres_m + half, frames.centres_m - half), axis=1)


def cable_points_m(frames: RibFrames, threading_mm: Sequence[float]) -> np.ndarray:
    """Cable holes (n, 3): hole offset d (mm, + = right) on rib k is P_k + d (sin t, -cos t).

    The cable is taut, so it runs straight from hole to hole and the polyline through the
    holes is the cable path.
    """
    d = _as_vector(threading_mm, 'threading_mm') / MM_PER_M
    t = frames.headings_rad
    if len(d) != len(t):
        raise ValueError(f'expected {len(t)} hole offsets (one per rib), got {len(d)}')
    return frames.centres_m + np.column_stack((d * np.sin(t), -d * np.cos(t), np.zeros_like(t)))


def tip_error_mm(commanded: RibFrames, predicted: RibFrames) -> float:
    """Distance between the last rib centres of two shapes of one module, in mm."""
    return float(np.linalg.norm(commanded.centres_m[-1] - predicted.centres_m[-1]) * MM_PER_M)
