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
            empty = np.full((n, 2), np.nan)
            if counts[tag_id] > 1:
                walks[name] = TrackedModule(name, empty, np.zeros(n, bool), None, tuple(centre_px),
                                            empty, error=f'tag {tag_id} seen {counts[tag_id]} times')
                continue
            try:
                ribs_mm, visible, note, _, order = measure_points(
                    plane[4], points, self.skeleton, self.config,
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
