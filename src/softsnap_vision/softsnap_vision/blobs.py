"""Round colour markers in an image: colour thresholding, contours, image moments.

The paper's pipeline with three guards a researcher's photos need:

- Thresholds in HSV (hue window, minimum saturation and value): uneven lighting scales a
  marker's brightness but hardly its hue and saturation.
- A blob is a marker only if its outline, back-projected onto the marker plane, has the
  printed marker's area and is round: specks of noise, texture and a marker partly hidden
  behind something are refused (reported as not seen, never guessed).
- The centre is the moment centroid of a soft membership (each pixel's fraction of marker
  colour against the local background), not of the binary mask: the edge pixels' partial
  coverage carries the sub-pixel position (about 0.02 px instead of 0.1 px for a 12 px
  disc), which matters because the frame's x-axis is drawn through two markers 30 mm apart.

No rclpy; numpy and OpenCV only.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .camera_info import CameraInfo, pixels_to_plane_mm
from .marker_config import MarkerConfig, MarkerSpec

__all__ = ['Blob', 'hsv_mask', 'find_blobs', 'downscaled_hsv', 'coarse_scale', 'MIN_AREA_RATIO',
           'MAX_AREA_RATIO', 'MIN_FILL']

#: A blob's area on the plane over the printed marker's area must lie in this range.
MIN_AREA_RATIO = 0.8
MAX_AREA_RATIO = 1.3
#: A blob's area over its minimum enclosing circle's (on the plane): 1 for a disc, about
#: 0.6 for a half disc; below this the marker is taken as partly hidden.
MIN_FILL = 0.72
#: Smallest marker diameter (px) the half-size first search still finds reliably.
COARSE_MIN_DIAMETER_PX = 5.0
#: Pixels around the mask that the soft centroid may draw on (px).
_SOFT_MARGIN_PX = 1
#: Ring outside the mask where the local background colour is taken (px).
_RING_INNER_PX, _RING_OUTER_PX = 2, 4


@dataclass(frozen=True)
class Blob:
    """One accepted marker: centre in pixels and on the plane, and its size check."""

    center_px: tuple[float, float]
    center_mm: tuple[float, float]     # on the plane, seen from above (camera_info module)
    area_ratio: float                  # plane area / printed area
    fill: float                        # area / enclosing circle area


def hsv_mask(hsv: np.ndarray, spec: MarkerSpec, config: MarkerConfig) -> np.ndarray:
    """uint8 mask (255 = marker colour) of an HSV image (OpenCV ranges: H 0-180, S, V 0-255)."""
    hue = spec.hue_deg / 2.0                   # OpenCV hue is degrees / 2
    tol = config.hue_tolerance_deg / 2.0
    s_min = int(round(config.min_saturation * 255))
    v_min = int(round(config.min_value * 255))
    lo, hi = hue - tol, hue + tol
    if lo < 0 or hi >= 180:                    # the window wraps around red
        lo %= 180
        hi %= 180
        a = cv2.inRange(hsv, (0, s_min, v_min), (int(np.floor(hi)), 255, 255))
        b = cv2.inRange(hsv, (int(np.ceil(lo)), s_min, v_min), (180, 255, 255))
        return cv2.bitwise_or(a, b)
    return cv2.inRange(hsv, (int(np.ceil(lo)), s_min, v_min), (int(np.floor(hi)), 255, 255))


def _soft_centroid(image: np.ndarray, mask: np.ndarray, x0: int, y0: int) -> tuple[float, float]:
    """Centroid (px, full-image coordinates) of the marker fraction of each pixel.

    ``image`` and ``mask`` are the blob's region (float32 BGR and uint8); ``x0, y0`` its
    corner. Each pixel is modelled as a mix of the marker colour (median inside the
    eroded mask) and the local background (median of a ring around the mask).
    """
    kernel = np.ones((3, 3), np.uint8)
    inner = cv2.erode(mask, kernel)
    if not inner.any():
        inner = mask
    grow = cv2.dilate(mask, kernel, iterations=_SOFT_MARGIN_PX)
    ring = cv2.dilate(mask, kernel, iterations=_RING_OUTER_PX) & ~cv2.dilate(
        mask, kernel, iterations=_RING_INNER_PX)
    marker = np.array(cv2.mean(image, inner)[:3], np.float32)
    if ring.any():
        background = np.array(cv2.mean(image, ring)[:3], np.float32)
    else:
        background = np.zeros(3, np.float32)
    contrast = marker - background
    norm = float(contrast @ contrast)
    ys, xs = np.nonzero(grow)
    if norm < 1e-6:
        weights = (mask[ys, xs] > 0).astype(np.float64)
    else:
        weights = np.clip((image[ys, xs] - background) @ contrast / norm, 0.0, 1.0)
    total = weights.sum()
    if total <= 0:
        ys, xs = np.nonzero(mask)
        weights = np.ones(xs.size)
        total = float(xs.size)
    return (float(x0 + (weights * xs).sum() / total), float(y0 + (weights * ys).sum() / total))


def coarse_scale(spec: MarkerSpec, camera: CameraInfo, plane_distance_m: float) -> float:
    """Image scale for the first search: half size while a marker stays >= 10 px across."""
    diameter_px = spec.diameter_mm * camera.focal_px / (plane_distance_m * 1000.0)
    return 0.5 if diameter_px >= 2 * COARSE_MIN_DIAMETER_PX else 1.0


def downscaled_hsv(image_bgr: np.ndarray, scale: float) -> np.ndarray:
    """HSV of the image at ``scale`` (area-averaged), for the first search of every kind."""
    small = image_bgr if scale == 1.0 else cv2.resize(image_bgr, None, fx=scale, fy=scale,
                                                      interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2HSV)


def find_blobs(image_bgr: np.ndarray, hsv_coarse: np.ndarray, scale: float, spec: MarkerSpec,
               config: MarkerConfig, camera: CameraInfo, plane_distance_m: float
               ) -> tuple[list[Blob], int]:
    """Markers of one kind in an image: (accepted blobs, number of refused candidates).

    Candidates are found in ``hsv_coarse`` (the image at ``scale``, see
    :func:`downscaled_hsv`: a quarter of the pixels to threshold), then each is measured
    on the full image around it. A candidate is refused when its plane area or roundness
    says it is not a whole marker (see the module docstring): a partly hidden marker is
    not seen.
    """
    coarse = hsv_mask(hsv_coarse, spec, config)
    contours, _ = cv2.findContours(coarse, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    px_per_mm = camera.focal_px / (plane_distance_m * 1000.0)
    expected_px = spec.area_mm2 * px_per_mm ** 2
    h, w = image_bgr.shape[:2]
    blobs: list[Blob] = []
    refused = 0
    margin = _RING_OUTER_PX + 2
    for small in contours:
        area_small = cv2.contourArea(small) / (scale * scale)
        if area_small < 0.15 * expected_px or area_small > 5.0 * expected_px:
            if area_small >= 0.1 * expected_px and area_small <= 5.0 * expected_px:
                refused += 1
            continue
        x, y, bw, bh = cv2.boundingRect(small)
        x0, y0 = max(int(x / scale) - margin, 0), max(int(y / scale) - margin, 0)
        x1 = min(int((x + bw) / scale) + margin + 1, w)
        y1 = min(int((y + bh) / scale) + margin + 1, h)
        region = image_bgr[y0:y1, x0:x1]
        mask = hsv_mask(cv2.cvtColor(region, cv2.COLOR_BGR2HSV), spec, config)
        found, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not found:
            refused += 1
            continue
        contour = max(found, key=cv2.contourArea)
        blob = _measure(region, mask, contour, x0, y0, spec, camera, plane_distance_m, px_per_mm)
        if blob is None:
            refused += 1
        else:
            blobs.append(blob)
    return blobs, refused


def _measure(region, mask, contour, x0, y0, spec, camera, plane_distance_m, px_per_mm):
    """The whole-marker check and the soft centroid of one contour in a region; None if refused."""
    area_px = cv2.contourArea(contour)
    if area_px <= 0:
        return None
    outline = pixels_to_plane_mm(contour.reshape(-1, 2).astype(np.float64) + (x0, y0), camera,
                                 plane_distance_m).astype(np.float32)
    region_mask = np.zeros_like(mask)
    cv2.drawContours(region_mask, [contour], -1, 255, cv2.FILLED)
    region_mask &= mask
    # The pixel contour runs through the centres of the edge pixels: half a pixel inside
    # the true edge. Count the mask's pixels instead, scaled to the plane.
    count = float(np.count_nonzero(region_mask))
    area_mm2 = count * cv2.contourArea(outline) / area_px
    (_, _), radius = cv2.minEnclosingCircle(outline)
    circle = np.pi * (radius + 0.5 / px_per_mm) ** 2
    fill = area_mm2 / circle if circle > 0 else 0.0
    ratio = area_mm2 / spec.area_mm2
    if not (MIN_AREA_RATIO <= ratio <= MAX_AREA_RATIO and fill >= MIN_FILL):
        return None
    center = _soft_centroid(region.astype(np.float32), region_mask, x0, y0)
    center_mm = pixels_to_plane_mm([center], camera, plane_distance_m)[0]
    return Blob(center_px=center, center_mm=(float(center_mm[0]), float(center_mm[1])),
                area_ratio=float(ratio), fill=float(fill))
