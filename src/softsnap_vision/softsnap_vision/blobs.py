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

__all__ = ['Blob', 'hsv_mask', 'find_blobs', 'MIN_AREA_RATIO', 'MAX_AREA_RATIO', 'MIN_FILL']

#: A blob's area on the plane over the printed marker's area must lie in this range.
MIN_AREA_RATIO = 0.8
MAX_AREA_RATIO = 1.3
#: A blob's area over its minimum enclosing circle's (on the plane): 1 for a disc, about
#: 0.6 for a half disc; below this the marker is taken as partly hidden.
MIN_FILL = 0.72
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
    marker = np.median(image[inner > 0], axis=0)
    if ring.any():
        background = np.median(image[ring > 0], axis=0)
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


def find_blobs(image_bgr: np.ndarray, hsv: np.ndarray, spec: MarkerSpec, config: MarkerConfig,
               camera: CameraInfo, plane_distance_m: float) -> tuple[list[Blob], int]:
    """Markers of one kind in an image: (accepted blobs, number of refused candidates).

    A candidate is refused when its plane area or roundness says it is not a whole
    marker (see the module docstring): a partly hidden marker is not seen.
    """
    mask = hsv_mask(hsv, spec, config)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    # Expected area in pixels from the focal length alone (no distortion): a loose
    # pre-filter before the exact check on the plane.
    px_per_mm = camera.focal_px / (plane_distance_m * 1000.0)
    expected_px = spec.area_mm2 * px_per_mm ** 2
    h, w = mask.shape
    blobs: list[Blob] = []
    refused = 0
    for contour in contours:
        area_px = cv2.contourArea(contour)
        if area_px < 0.25 * expected_px or area_px > 4.0 * expected_px:
            if area_px >= 0.1 * expected_px:
                refused += 1
            continue
        outline = pixels_to_plane_mm(contour.reshape(-1, 2).astype(np.float64), camera,
                                     plane_distance_m).astype(np.float32)
        # The pixel contour runs through the centres of the edge pixels: half a pixel
        # inside the true edge. Count the mask's pixels instead, scaled to the plane.
        count = float(np.count_nonzero(
            mask[max(contour[:, 0, 1].min(), 0):contour[:, 0, 1].max() + 1,
                 max(contour[:, 0, 0].min(), 0):contour[:, 0, 0].max() + 1]))
        plane_area = cv2.contourArea(outline)
        scale = plane_area / area_px if area_px > 0 else 0.0
        area_mm2 = count * scale
        (_, _), radius = cv2.minEnclosingCircle(outline)
        circle = np.pi * (radius + 0.5 / px_per_mm) ** 2
        fill = area_mm2 / circle if circle > 0 else 0.0
        ratio = area_mm2 / spec.area_mm2
        if not (MIN_AREA_RATIO <= ratio <= MAX_AREA_RATIO and fill >= MIN_FILL):
            refused += 1
            continue
        x, y, bw, bh = cv2.boundingRect(contour)
        m = _RING_OUTER_PX + 1
        x0, y0 = max(x - m, 0), max(y - m, 0)
        x1, y1 = min(x + bw + m, w), min(y + bh + m, h)
        region_mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.drawContours(region_mask, [contour - np.array([x0, y0])], -1, 255, cv2.FILLED)
        region_mask &= mask[y0:y1, x0:x1]
        center = _soft_centroid(image_bgr[y0:y1, x0:x1].astype(np.float32), region_mask, x0, y0)
        center_mm = pixels_to_plane_mm([center], camera, plane_distance_m)[0]
        blobs.append(Blob(center_px=center, center_mm=(float(center_mm[0]), float(center_mm[1])),
                          area_ratio=float(ratio), fill=float(fill)))
    return blobs, refused
