"""The paper's measurement of one module in one top-down image (numpy/OpenCV/scipy core).

:func:`measure_image` finds the rib and base markers (:mod:`.blobs`), sets up the module
base frame and orders the ribs (:mod:`.chain`), and returns a :class:`ShapeMeasurement`:
rib centres in the base frame (mm, NaN where not seen), the fit residual of a module
shape through them, and, given the threading and cable length, the RMSE to the model's
forward solve. :func:`rmse_to_model_mm` and :func:`fit_shape` are shared with the marker
tracker.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from softsnap_model import Skeleton, solve_forward
from softsnap_model.geometry import rib_centers

from .blobs import coarse_scale, downscaled_hsv, find_blobs
from .camera_info import CameraInfo
from .chain import FrameError, base_frame, order_ribs
from .marker_config import MarkerConfig

__all__ = ['ShapeMeasurement', 'MeasurementError', 'measure_image', 'measure_points',
           'fit_shape', 'rmse_to_model_mm', 'model_rib_centers_mm', 'ShapeFit']


#: How far (mm) rib 0 may lie from the layout's distance to the base marker (the base is
#: rigid: this covers a marker glued a little off and the measurement's error, and stays
#: well below the 18 mm to rib 1, which would otherwise be taken as rib 0).
FIRST_RIB_TOLERANCE_MM = 2.5


#: Shape fit: finite-difference step (rad), convergence on the angle update (rad), cap.
_FIT_STEP_RAD = 1e-6
_FIT_TOL_RAD = 1e-9
_FIT_MAX_ITER = 20


class MeasurementError(ValueError):
    """An image cannot be measured (unreadable, no base marker, frame undefined)."""


@dataclass(frozen=True)
class ShapeFit:
    """Module shape (bending angles) fitted through the measured rib centres."""

    angles_rad: np.ndarray     # (n_segments,)
    residual_mm: float         # RMS distance of the measured ribs from the fitted shape


@dataclass(frozen=True)
class ShapeMeasurement:
    """One module measured in one image.

    Attributes
    ----------
    ribs_mm : ndarray, shape (n_ribs, 2)
        Rib centres in the module base frame (mm); NaN rows for ribs not seen.
    visible : ndarray of bool, shape (n_ribs,)
    missing : tuple of int
        Ribs not seen (hidden, partly hidden, ambiguous).
    fit : ShapeFit or None
        Shape through the seen ribs (None with fewer than 2 of them).
    rmse_to_model_mm : float or None
        RMS distance of the seen ribs from the model's shape at the given cable length.
    note : str
        Why the walk along the spine stopped early ('' if it reached the last rib).
    markers_found : int
        Whole rib markers seen in the image (all modules).
    markers_refused : int
        Candidates refused as not whole markers (partly hidden, wrong size).
    """

    ribs_mm: np.ndarray
    visible: np.ndarray
    missing: tuple[int, ...]
    fit: ShapeFit | None = None
    rmse_to_model_mm: float | None = None
    note: str = ''
    markers_found: int = 0
    markers_refused: int = 0
    anchor_px: tuple[float, float] | None = None
    ribs_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def model_rib_centers_mm(skeleton: Skeleton, threading, cable_length_mm: float) -> np.ndarray:
    """The model's rib centres (mm, base frame) at a cable length (forward solve)."""
    result = solve_forward(skeleton, threading, cable_length_mm)
    if not result.converged:
        raise ValueError(f'model did not converge at {cable_length_mm:g} mm: {result.message}')
    return np.asarray(result.rib_centers, dtype=float)


def rmse_to_model_mm(ribs_mm: np.ndarray, visible: np.ndarray, model_mm: np.ndarray) -> float | None:
    """RMS distance (mm) of the seen ribs from the model's; None when none was seen."""
    if not visible.any():
        return None
    d = ribs_mm[visible] - model_mm[visible]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def fit_shape(ribs_mm: np.ndarray, visible: np.ndarray, spacing_mm: float) -> ShapeFit | None:
    """Bending angles whose rib centres best match the seen ones (least squares).

    The frame is the measured one (rib 0 at the origin, x along rib 0's tangent), so the
    residual also shows a wrong plane distance (scale) or a mislabelled marker.
    """
    n = ribs_mm.shape[0]
    if visible.sum() < 2:
        return None
    # Start from the chord directions between seen neighbours (t_k + a_k / 2).
    start = np.zeros(n - 1)
    heading = 0.0
    for k in range(n - 1):
        if visible[k] and visible[k + 1]:
            d = ribs_mm[k + 1] - ribs_mm[k]
            chord = math.atan2(d[1], d[0])
            start[k] = 2.0 * (((chord - heading) + math.pi) % (2 * math.pi) - math.pi)
        heading += start[k]
    # Angles past the last seen rib are not observable: fit only those before it.
    last = int(np.flatnonzero(visible).max())
    free = max(last, 1)

    angles = np.concatenate([start[:free], np.zeros(n - 1 - free)])
    steps = np.eye(n - 1)[:free] * _FIT_STEP_RAD
    r = None
    for _ in range(_FIT_MAX_ITER):
        # Gauss-Newton with a forward-difference Jacobian: every perturbed shape in one
        # vectorised rib_centers call (~0.1 ms per iteration instead of scipy's ~6 ms).
        batch = rib_centers(np.vstack([angles, angles + steps]), spacing_mm)[:, visible]
        r = (batch[0] - ribs_mm[visible]).ravel()
        jac = ((batch[1:] - batch[0]).reshape(free, -1) / _FIT_STEP_RAD).T
        delta = np.linalg.lstsq(jac, -r, rcond=None)[0]
        angles[:free] += delta
        if np.abs(delta).max() < _FIT_TOL_RAD:
            break
    r = (rib_centers(angles, spacing_mm)[visible] - ribs_mm[visible])
    angles[free:] = np.nan
    return ShapeFit(angles_rad=angles, residual_mm=float(np.sqrt(np.mean(np.sum(r * r, axis=1)))))


def measure_points(anchor_mm, rib_points_mm: np.ndarray, skeleton: Skeleton, config: MarkerConfig,
                   anchor_distance_mm: float, axis_hint=None, used=()) -> tuple:
    """Base frame and rib order from plane points: (ribs_mm, visible, note, frame, order)."""
    tol0 = FIRST_RIB_TOLERANCE_MM
    frame = base_frame(anchor_mm, rib_points_mm, anchor_distance_mm, tol0, axis_hint=axis_hint)
    base_pts = frame.to_base(rib_points_mm)
    order = order_ribs(base_pts, frame.first_rib_index, skeleton.n_ribs, skeleton.spacing_mm,
                       skeleton.contact_angle_rad, math.radians(config.max_segment_angle_deg),
                       config.max_gap, config.distance_tolerance_mm, used=used)
    ribs = np.full((skeleton.n_ribs, 2), np.nan)
    visible = np.zeros(skeleton.n_ribs, dtype=bool)
    for rib, j in enumerate(order.point_index):
        if j is not None:
            ribs[rib] = base_pts[j]
            visible[rib] = True
    return ribs, visible, order.stopped, frame, order


def measure_image(image_bgr: np.ndarray, camera: CameraInfo, plane_distance_m: float,
                  config: MarkerConfig = MarkerConfig(), skeleton: Skeleton = Skeleton(),
                  model_mm: np.ndarray | None = None, fit: bool = True) -> ShapeMeasurement:
    """Measure one module (rib markers + one base marker) in a BGR image.

    ``model_mm`` (the model's rib centres, e.g. from :func:`model_rib_centers_mm`) gives
    ``rmse_to_model_mm``. Raises MeasurementError for an image that cannot be measured.
    """
    if image_bgr is None or image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
        raise MeasurementError('not a 3-channel colour image')
    h, w = image_bgr.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise MeasurementError(f'image is {w}x{h} px but the camera_info is for '
                               f'{camera.width}x{camera.height}')
    scale = min(coarse_scale(config.rib_marker, camera, plane_distance_m),
                coarse_scale(config.base_marker, camera, plane_distance_m))
    hsv = downscaled_hsv(image_bgr, scale)
    ribs, rib_refused = find_blobs(image_bgr, hsv, scale, config.rib_marker, config, camera,
                                   plane_distance_m)
    bases, _ = find_blobs(image_bgr, hsv, scale, config.base_marker, config, camera,
                          plane_distance_m)
    if not bases:
        raise MeasurementError('no base (orange) marker seen: the module frame is undefined')
    if len(bases) > 1:
        raise MeasurementError(f'{len(bases)} base (orange) markers seen, expected one')
    points = np.array([b.center_mm for b in ribs]).reshape(-1, 2)
    try:
        ribs_mm, visible, note, _, order = measure_points(
            bases[0].center_mm, points, skeleton, config,
            config.base_marker.distance_to_first_rib_mm)
    except FrameError as exc:
        raise MeasurementError(str(exc)) from None
    ribs_px = np.full((skeleton.n_ribs, 2), np.nan)
    for rib, j in enumerate(order.point_index):
        if j is not None:
            ribs_px[rib] = ribs[j].center_px
    return ShapeMeasurement(
        ribs_mm=ribs_mm, visible=visible, missing=tuple(int(i) for i in np.flatnonzero(~visible)),
        fit=fit_shape(ribs_mm, visible, skeleton.spacing_mm) if fit else None,
        rmse_to_model_mm=(rmse_to_model_mm(ribs_mm, visible, model_mm)
                          if model_mm is not None else None),
        note=note, markers_found=len(ribs), markers_refused=rib_refused,
        anchor_px=bases[0].center_px, ribs_px=ribs_px)
