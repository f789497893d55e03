"""A top-down camera renderer for the vision tests, written apart from the measurement code.

Forward model only: every marker is a 3-D disc (or a tag's square cells) on the world
plane z = 0, its outline projected by ``cv2.projectPoints`` with the lens distortion, and
filled with 8x8 supersampling for each pixel's coverage. The measurement goes the other
way (thresholds, moments, ``cv2.undistortPoints``); nothing here is imported from
softsnap_vision, so a mistake in one is not repeated in the other.

World frame: z up, the camera ``height_m`` above the origin looking straight down, image
x along world +x, image y along world -y (seen from above, not mirrored).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

PINK_BGR = (160, 64, 255)
ORANGE_BGR = (0, 128, 255)
SUPERSAMPLE = 8


@dataclass
class Camera:
    width: int = 640
    height: int = 480
    focal_px: float = 1000.0
    height_m: float = 0.5          # 0.5 mm per pixel at the plane
    distortion: tuple = (-0.22, 0.09, 0.0012, -0.0008, -0.01)
    cx: float | None = None
    cy: float | None = None

    @property
    def K(self) -> np.ndarray:
        cx = (self.width - 1) / 2 + 3.7 if self.cx is None else self.cx
        cy = (self.height - 1) / 2 - 2.9 if self.cy is None else self.cy
        return np.array([[self.focal_px, 0, cx], [0, self.focal_px * 1.002, cy], [0, 0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        return np.array(self.distortion, dtype=float)

    def camera_info_yaml(self) -> str:
        k = self.K.ravel().tolist()
        p = [k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0]
        return (f'image_width: {self.width}\nimage_height: {self.height}\ncamera_name: test_cam\n'
                f'camera_matrix:\n  rows: 3\n  cols: 3\n  data: {k}\n'
                f'distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n'
                f'  data: {list(map(float, self.distortion))}\n'
                f'rectification_matrix:\n  rows: 3\n  cols: 3\n  data: {np.eye(3).ravel().tolist()}\n'
                f'projection_matrix:\n  rows: 3\n  cols: 4\n  data: {p}\n')

    def project(self, world_mm: np.ndarray) -> np.ndarray:
        """World plane points (N, 2) mm -> pixels (N, 2), distortion included."""
        pts = np.column_stack([np.asarray(world_mm, float).reshape(-1, 2) / 1000.0,
                               np.zeros(len(np.asarray(world_mm).reshape(-1, 2)))])
        rot = np.diag([1.0, -1.0, -1.0])            # camera looks down, y flipped
        rvec, _ = cv2.Rodrigues(rot)
        tvec = -rot @ np.array([0.0, 0.0, self.height_m])
        px, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, self.K, self.D)
        return px.reshape(-1, 2)


def module_to_world(points_mm, origin_mm, yaw_rad) -> np.ndarray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    p = np.asarray(points_mm, float).reshape(-1, 2)
    return np.column_stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]]) + origin_mm


def centred_origin(ribs_mm, yaw_rad, base_distance_mm=30.0, at=(0.0, 0.0)) -> tuple:
    """Origin that puts the module's bounding box (ribs and base marker) centred on ``at``."""
    pts = np.vstack([np.asarray(ribs_mm, float), [[-base_distance_mm - 10.0, 0.0]]])
    w = module_to_world(pts, np.zeros(2), yaw_rad)
    mid = 0.5 * (w.min(axis=0) + w.max(axis=0))
    return (at[0] - mid[0], at[1] - mid[1])


def table_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A wood-like table: low-saturation grain, blotches and fine noise (BGR float)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    grain = np.sin(0.21 * x + 6.0 * np.sin(0.013 * y) + 2.0 * np.sin(0.031 * x + 0.02 * y))
    blotch = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 9)
    blotch /= max(float(np.abs(blotch).max()), 1e-6)
    fine = rng.normal(0, 1, (h, w)).astype(np.float32)
    lum = 150 + 22 * grain + 25 * blotch + 6 * fine
    base = np.stack([lum * 0.86, lum * 0.93, lum * 1.0], axis=-1)  # a grey-beige, S ~ 0.15
    return base


def _coverage(polygons_px: list[np.ndarray], shape) -> tuple[np.ndarray, int, int] | None:
    """Per-pixel coverage (float 0-1) of filled polygons, on their bounding box."""
    allp = np.vstack(polygons_px)
    h, w = shape
    x0 = max(int(math.floor(allp[:, 0].min())) - 2, 0)
    y0 = max(int(math.floor(allp[:, 1].min())) - 2, 0)
    x1 = min(int(math.ceil(allp[:, 0].max())) + 3, w)
    y1 = min(int(math.ceil(allp[:, 1].max())) + 3, h)
    if x1 <= x0 or y1 <= y0:
        return None
    S = SUPERSAMPLE
    canvas = np.zeros(((y1 - y0) * S, (x1 - x0) * S), np.uint8)
    shift = 8
    polys = []
    for poly in polygons_px:
        # pixel centre u (integer) covers [u - 0.5, u + 0.5): sub-sample centres at
        # (u - x0 + 0.5) * S - 0.5
        sub = (poly - np.array([x0, y0]) + 0.5) * S - 0.5
        polys.append(np.round(sub * (1 << shift)).astype(np.int32))
    cv2.fillPoly(canvas, polys, 255, lineType=cv2.LINE_8, shift=shift)
    cov = canvas.reshape(y1 - y0, S, x1 - x0, S).mean(axis=(1, 3)) / 255.0
    return cov, x0, y0


def _blend(image: np.ndarray, cov_info, color_bgr) -> None:
    if cov_info is None:
        return
    cov, x0, y0 = cov_info
    region = image[y0:y0 + cov.shape[0], x0:x0 + cov.shape[1]]
    region[:] = region * (1 - cov[..., None]) + np.array(color_bgr, float) * cov[..., None]


def disc_outline(center_mm, diameter_mm, n=128) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([center_mm[0] + 0.5 * diameter_mm * np.cos(t),
                            center_mm[1] + 0.5 * diameter_mm * np.sin(t)])


@dataclass
class ModuleDrawing:
    """One module on the table: true rib centres in its own frame and its pose."""

    ribs_mm: np.ndarray                  # (12, 2) module frame
    origin_mm: tuple = (0.0, 0.0)
    yaw_rad: float = 0.0
    base_marker: bool = True
    base_distance_mm: float = 30.0
    tag_id: int | None = None
    tag_size_mm: float = 20.0
    tag_distance_mm: float = 35.0
    hidden: tuple = ()                    # ribs not drawn at all
    rib_color_bgr: tuple = PINK_BGR
    base_color_bgr: tuple = ORANGE_BGR
    diameter_mm: float = 6.0

    def world(self, pts) -> np.ndarray:
        return module_to_world(pts, np.asarray(self.origin_mm, float), self.yaw_rad)


@dataclass
class Occluder:
    """A grey rectangle (world mm, axis-aligned) drawn over whatever lies under it."""
    x0: float
    y0: float
    x1: float
    y1: float
    color_bgr: tuple = (70, 72, 75)


def _tag_cells(dictionary, tag_id: int, size_mm: float):
    """(white quiet-zone square, black cell squares) in the tag's frame (mm, y up)."""
    bits = cv2.aruco.generateImageMarker(dictionary, tag_id, 6, borderBits=1)  # 6x6 cells
    cell = size_mm / 6.0
    half = size_mm / 2.0
    quiet = half + cell
    white = np.array([[-quiet, -quiet], [quiet, -quiet], [quiet, quiet], [-quiet, quiet]])
    blacks = []
    for r in range(6):
        for c in range(6):
            if bits[r, c] < 128:
                x0 = -half + c * cell
                y_top = half - r * cell   # image row 0 is the tag's top (+y)
                blacks.append(np.array([[x0, y_top - cell], [x0 + cell, y_top - cell],
                                        [x0 + cell, y_top], [x0, y_top]]))
    return white, blacks


def _subdivide(square: np.ndarray, n: int = 6) -> np.ndarray:
    out = []
    for i in range(4):
        a, b = square[i], square[(i + 1) % 4]
        for t in np.linspace(0, 1, n, endpoint=False):
            out.append(a + (b - a) * t)
    return np.array(out)


def render(camera: Camera, modules: list[ModuleDrawing], *, seed: int = 0, noise_sigma: float = 3.0,
           lighting: bool = True, texture: bool = True, occluders=(), tag_dictionary=None) -> np.ndarray:
    """BGR uint8 image of the modules on the table."""
    rng = np.random.default_rng(seed)
    h, w = camera.height, camera.width
    image = table_texture(h, w, rng) if texture else np.full((h, w, 3), 150.0)
    for m in modules:
        for i, p in enumerate(m.ribs_mm):
            if i in m.hidden:
                continue
            outline = camera.project(m.world(disc_outline(p, m.diameter_mm)))
            _blend(image, _coverage([outline], (h, w)), m.rib_color_bgr)
        if m.base_marker:
            outline = camera.project(m.world(disc_outline((-m.base_distance_mm, 0.0), m.diameter_mm)))
            _blend(image, _coverage([outline], (h, w)), m.base_color_bgr)
        if m.tag_id is not None:
            white, blacks = _tag_cells(tag_dictionary, m.tag_id, m.tag_size_mm)
            shift = np.array([-m.tag_distance_mm, 0.0])
            _blend(image, _coverage([camera.project(m.world(_subdivide(white) + shift))], (h, w)),
                   (235, 235, 235))
            # all black cells in one fill: adjacent cells share edges without a seam
            _blend(image, _coverage([camera.project(m.world(_subdivide(sq) + shift))
                                     for sq in blacks], (h, w)), (25, 25, 25))
    for occ in occluders:
        rect = np.array([[occ.x0, occ.y0], [occ.x1, occ.y0], [occ.x1, occ.y1], [occ.x0, occ.y1]])
        _blend(image, _coverage([camera.project(_subdivide(rect, 20))], (h, w)), occ.color_bgr)
    if lighting:
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        # light from one side, falling to 55 %, and a vignette
        gain = 0.55 + 0.55 * (x / w) ** 0.8
        gain *= 1.0 - 0.25 * (((x - w / 2) / w) ** 2 + ((y - h / 2) / h) ** 2)
        gain = np.minimum(gain, 1.1)
        image *= gain[..., None]
    image += rng.normal(0, noise_sigma, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)
