"""Every module of a scene in one image, told apart by an ArUco tag on each case.

The paper's measurement with the orange dot replaced by one tag per module (the scene's
``markers: {tag_id: N}``): the tag's centre plays the orange marker's part (the x-axis
runs from it through rib 0), and its id says which module the rib markers belong to.
The tag's own x-axis only narrows where rib 0 may be (within 25 degrees), since a 20 mm
edge gives a less exact direction than the 35 mm from the tag centre to rib 0.

Each module's ribs are ordered by the same walk as :mod:`.measurement`; a rib marker
that two modules' walks both claim is missing in both (never given to one by a guess).

Speed: the tag detector runs on the image at ``tag_scale`` (half size by default: about
3 ms instead of 25-200 ms at 1280x960) and the corners are refined on the full image.
No rclpy.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from softsnap_model import Skeleton

from .blobs import coarse_scale, downscaled_hsv, find_blobs
from .camera_info import CameraInfo, pixels_to_plane_mm
from .chain import FrameError
from .marker_config import MarkerConfig
from .measurement import ShapeFit, fit_shape, measure_points

__all__ = ['MarkerTracker', 'TrackedModule', 'TrackResult', 'TagTarget']


@dataclass(frozen=True)
class TagTarget:
    """A module the tracker looks for: its name and the id of the tag on its case."""

    name: str
    tag_id: int


@dataclass(frozen=True)
class TrackedModule:
    """One module in one image (``error`` set when its frame could not be set up)."""

    name: str
    ribs_mm: np.ndarray            # (n_ribs, 2), NaN where not seen
    visible: np.ndarray            # (n_ribs,) bool
    fit: ShapeFit | None
    tag_px: tuple[float, float]
    ribs_px: np.ndarray            # (n_ribs, 2) px, NaN where not seen
    note: str = ''
    error: str | None = None


@dataclass(frozen=True)
class TrackResult:
    """Result of :meth:`MarkerTracker.track` for one image."""

    modules: dict                  # name -> TrackedModule, for the modules whose tag was seen
    rib_markers_found: int
    rib_markers_refused: int
    tags_found: int
    unknown_tags: tuple[int, ...]  # ids seen that no module has


def _centre(corners: np.ndarray) -> np.ndarray:
    """Intersection of a quadrilateral's diagonals (the projected centre of a square)."""
    p0, p1, p2, p3 = corners
    d1, d2 = p2 - p0, p3 - p1
    m = np.array([[d1[0], -d2[0]], [d1[1], -d2[1]]])
    if abs(np.linalg.det(m)) < 1e-9:
        return corners.mean(axis=0)
    t = np.linalg.solve(m, p1 - p0)[0]
    return p0 + t * d1


def _ink_offset_mm(dictionary, tag_id: int, size_mm: float) -> np.ndarray:
    """Centroid (mm, tag frame: x right, y up the printed tag) of a tag's black cells."""
    bits = cv2.aruco.generateImageMarker(dictionary, tag_id, 6, borderBits=1)
    rows, cols = np.nonzero(bits < 128)
    cell = size_mm / 6.0
    return np.array([(-size_mm / 2 + (cols + 0.5) * cell).mean(),
                     (size_mm / 2 - (rows + 0.5) * cell).mean()])


class MarkerTracker:
    """Finds the modules' tags and rib markers in images from one calibrated camera.

    Build once (the detector is reused per frame); :meth:`track` is the per-frame call.
    """

    def __init__(self, camera: CameraInfo, plane_distance_m: float, targets: list[TagTarget],
                 config: MarkerConfig = MarkerConfig(), skeleton: Skeleton = Skeleton(),
                 tag_scale: float = 0.5, fit: bool = True):
        if not 0.2 <= tag_scale <= 1.0:
            raise ValueError(f'tag_scale must be in [0.2, 1], got {tag_scale!r}')
        ids = [t.tag_id for t in targets]
        if len(set(ids)) != len(ids):
            raise ValueError(f'tag ids must be distinct, got {ids}')
        self.camera = camera
        self.plane_distance_m = float(plane_distance_m)
        self.config = config
        self.skeleton = skeleton
        self.tag_scale = float(tag_scale)
        self.fit = fit
        self.targets = {t.tag_id: t.name for t in targets}
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, config.tag.dictionary))
        params = cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)
        self._subpix = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        self._ink = {t.tag_id: _ink_offset_mm(dictionary, t.tag_id, config.tag.size_mm)
                     for t in targets}

    def _tags(self, image_bgr: np.ndarray):
        """[(id, corners px (4, 2) refined on the full image)] of the tags seen."""
        gray = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
        s = self.tag_scale
        small = gray if s == 1.0 else cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        corners, ids, _ = self._detector.detectMarkers(small)
        if ids is None:
            return []
        out = []
        for c, i in zip(corners, ids.ravel()):
            # a small-image pixel centre u covers full-image [u/s - 0.5/s, ...): centre (u+0.5)/s-0.5
            full = ((c.reshape(4, 2).astype(np.float64) + 0.5) / s - 0.5).astype(np.float32)
            refined = cv2.cornerSubPix(gray, full.reshape(-1, 1, 2).copy(), (4, 4), (-1, -1),
                                       self._subpix)
            out.append((int(i), refined.reshape(4, 2).astype(np.float64)))
        return out

    def _tag_centre_mm(self, gray: np.ndarray, tag_id: int, corners_px: np.ndarray,
                       axis: np.ndarray) -> np.ndarray | None:
        """The tag's centre on the plane (mm) from the soft centroid of its black cells.

        Refined corners are good to 0.1-0.2 px; the ink's centroid, like a colour
        marker's, to a few hundredths, and the x-axis is drawn through this point. The
        ink centroid sits at a known offset from the centre (the tag's bit pattern),
        turned by the tag's axis from its corners (whose error hardly matters over a
        few millimetres). None when the tag's surroundings are not usable.
        """
        h, w = gray.shape
        x0 = max(int(np.floor(corners_px[:, 0].min())) - 6, 0)
        y0 = max(int(np.floor(corners_px[:, 1].min())) - 6, 0)
        x1 = min(int(np.ceil(corners_px[:, 0].max())) + 7, w)
        y1 = min(int(np.ceil(corners_px[:, 1].max())) + 7, h)
        region = gray[y0:y1, x0:x1].astype(np.float32)
        quad = np.zeros(region.shape, np.uint8)
        cv2.fillPoly(quad, [np.round((corners_px - (x0, y0)) * 16).astype(np.int32)], 255,
                     lineType=cv2.LINE_8, shift=4)
        kernel = np.ones((3, 3), np.uint8)
        inside = cv2.dilate(quad, kernel, iterations=2)
        ring = cv2.dilate(quad, kernel, iterations=4) & ~cv2.dilate(quad, kernel, iterations=3)
        core = cv2.erode(quad, kernel, iterations=1)
        if not ring.any() or not core.any():
            return None
        # The white level as a plane over the region (uneven light would otherwise pull
        # the centroid toward the darker side), the black level a fixed fraction of it.
        ry, rx = np.nonzero(ring)
        design = np.column_stack([np.ones(rx.size), rx, ry]).astype(np.float64)
        plane_fit = np.linalg.lstsq(design, region[ry, rx].astype(np.float64), rcond=None)[0]
        ys, xs = np.nonzero(inside)
        white = plane_fit[0] + plane_fit[1] * xs + plane_fit[2] * ys
        cy, cx = np.nonzero(core)
        core_white = plane_fit[0] + plane_fit[1] * cx + plane_fit[2] * cy
        ratio = float(np.percentile(region[cy, cx] / np.maximum(core_white, 1.0), 5))
        black = white * ratio
        if np.min(white - black) < 20.0:
            return None
        weight = np.clip((white - region[ys, xs]) / (white - black), 0.0, 1.0)
        plane = pixels_to_plane_mm(np.column_stack([xs + x0, ys + y0]).astype(np.float64),
                                   self.camera, self.plane_distance_m)
        ink = (plane * weight[:, None]).sum(axis=0) / max(weight.sum(), 1e-9)
        ox, oy = self._ink[tag_id]
        return ink - ox * axis - oy * np.array([-axis[1], axis[0]])

    def track(self, image_bgr: np.ndarray) -> TrackResult:
        """Rib centres of every module whose tag is seen (see the module docstring)."""
        h, w = image_bgr.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height) or image_bgr.ndim != 3:
            raise ValueError(f'image is {w}x{h} px but the camera_info is for '
                             f'{self.camera.width}x{self.camera.height}')
        scale = coarse_scale(self.config.rib_marker, self.camera, self.plane_distance_m)
        blobs, refused = find_blobs(image_bgr, downscaled_hsv(image_bgr, scale), scale,
                                    self.config.rib_marker, self.config, self.camera,
                                    self.plane_distance_m)
        points = np.array([b.center_mm for b in blobs]).reshape(-1, 2)
        tags = self._tags(image_bgr)
        gray = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY) if tags else None
        unknown = tuple(sorted({i for i, _ in tags if i not in self.targets}))
        seen = [(i, c) for i, c in tags if i in self.targets]
        # a tag id seen twice cannot say which module is which: both refused
        counts = {}
        for i, _ in seen:
            counts[i] = counts.get(i, 0) + 1
        walks = {}
        claims: dict[int, list[str]] = {}
        n = self.skeleton.n_ribs
        for tag_id, corners_px in seen:
            name = self.targets[tag_id]
            centre_px = _centre(corners_px)
            plane = pixels_to_plane_mm(np.vstack([corners_px, centre_px]), self.camera,
                                       self.plane_distance_m)
            # ArUco corner order: top-left, top-right, bottom-right, bottom-left of the tag
            axis = (plane[1] - plane[0]) + (plane[2] - plane[3])
            axis /= max(float(np.hypot(*axis)), 1e-9)
            anchor = self._tag_centre_mm(gray, tag_id, corners_px, axis)
            if anchor is None:
                anchor = plane[4]
            empty = np.full((n, 2), np.nan)
            if counts[tag_id] > 1:
                walks[name] = TrackedModule(name, empty, np.zeros(n, bool), None, tuple(centre_px),
                                            empty, error=f'tag {tag_id} seen {counts[tag_id]} times')
                continue
            try:
                ribs_mm, visible, note, _, order = measure_points(
                    anchor, points, self.skeleton, self.config,
                    self.config.tag.distance_to_first_rib_mm, axis_hint=axis)
            except FrameError as exc:
                walks[name] = TrackedModule(name, empty, np.zeros(n, bool), None, tuple(centre_px),
                                            empty, error=str(exc))
                continue
            for j in order.point_index:
                if j is not None:
                    claims.setdefault(j, []).append(name)
            walks[name] = (ribs_mm, visible, note, order, tuple(centre_px))
        contested = {j for j, names in claims.items() if len(names) > 1}
        modules = {}
        for name, walk in walks.items():
            if isinstance(walk, TrackedModule):
                modules[name] = walk
                continue
            ribs_mm, visible, note, order, centre_px = walk
            ribs_px = np.full((n, 2), np.nan)
            for rib, j in enumerate(order.point_index):
                if j is None:
                    continue
                if j in contested:
                    visible[rib] = False
                    ribs_mm[rib] = np.nan
                    note = (note + '; ' if note else '') + f'rib {rib} claimed by two modules'
                else:
                    ribs_px[rib] = blobs[j].center_px
            modules[name] = TrackedModule(
                name, ribs_mm, visible,
                fit_shape(ribs_mm, visible, self.skeleton.spacing_mm) if self.fit else None,
                centre_px, ribs_px, note)
        return TrackResult(modules=modules, rib_markers_found=len(blobs),
                           rib_markers_refused=refused, tags_found=len(tags), unknown_tags=unknown)
