"""A camera of sim_robot's MuJoCo scene with the paper's markers: the core.

No rclpy here (:mod:`softsnap_driver.sim_camera_publisher` publishes the frames).

What the camera sees
--------------------
MuJoCo's own OpenGL renderer (offscreen: ``MUJOCO_GL=egl``, or ``osmesa``) draws the
robot from a free camera straight above it, looking down (``-z``), with image right along
world ``+x`` and image up along world ``+y`` (``CameraSettings.view = 'down'``, the
default); or, with ``view = 'module'``, from the marked side of the first module (its
``+z``, the bending axis: the paper's camera, perpendicular to the bending plane, which
for a hanging gripper finger looks sideways), image up as close to world ``+z`` as the
view allows. The markers are drawn as thin discs on the
top faces (``+z`` of the module frame) of the skeleton, as stickers glued on a printed
skeleton would be:

- one **pink** disc (FACTS.md: sRGB about (255, 64, 160), 6 mm across) at each rib
  centre, the intersection of the rib and the middle rod (the rib body's origin);
- one **orange** disc (about (255, 128, 0), 6 mm) on the module's axis behind rib 0, on
  the motor case (:attr:`MarkerLayout.base_marker_offset_m` behind the rib centre);
- or, for a module given one, an ArUco tag (the marker tracker's module identity,
  softsnap_vision's ``tag``) on the case instead of the orange disc (:class:`MarkerLayout`).

The skeleton itself is drawn in a neutral grey (:attr:`MarkerLayout.skeleton_rgb`), as
the paper's validation skeleton: the scenes colour modules yellow, blue, green, red and
orange, and an orange module beside an orange marker is no measurement. Tendons and
hole sites are hidden (a real cable is a 0.23 mm line). The lights are set so that a
face looking at the camera shows its colour unchanged (ambient 0.4 + 0.6 of diffuse light
along the view: a sun straight down from above, the headlight for a face view; no
specular highlights, no shadows): the markers have their nominal sRGB in the
image, and the colour thresholds of :mod:`softsnap_vision` see what they would see
under even lighting.

Geometry (what :class:`PinholeCamera` states and ``camera_info`` publishes): MuJoCo's
``fovy`` is the vertical field of view of the whole image, pixels are square, the
principal point is the image centre. In OpenCV's (and ROS's) pixel convention, whose
pixel ``(0, 0)`` is centred on coordinate 0, that is
``fy = fx = (height / 2) / tan(fovy / 2)``, ``cx = (width - 1) / 2``,
``cy = (height - 1) / 2``, no distortion. The camera's optical frame (REP 103: x right,
y down, z forward) is world ``(+x, -y, -z)`` for the top-down view
(:attr:`SimCameraView.optical_in_world` in general); its origin is at
:attr:`SimCameraView.position_m`.

Threads: :class:`SimCamera` owns its own copy of the model and its own ``MjData`` (the
simulation changes its model's tendon limits as winches turn), and is used by one thread
only, which also owns the OpenGL context: the simulation thread only copies ``qpos``
(:func:`capture_frame_state`).
"""
from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass, field

import numpy as np

#: Default camera rate, Hz of simulated time (issue 33).
DEFAULT_CAMERA_RATE_HZ = 15.0
#: Default image size, px: the marker tracker's benchmark size (issue 33).
DEFAULT_WIDTH_PX = 1280
DEFAULT_HEIGHT_PX = 960
#: Default vertical field of view, degrees (MuJoCo's default camera).
DEFAULT_FOVY_DEG = 45.0
#: Free space around the robot's start footprint when the camera height is fitted, m
#: (the brittle star walks ~40 mm per 10 s: a walk stays in view).
DEFAULT_VIEW_MARGIN_M = 0.08
#: FACTS.md's marker colours (sRGB 0-255) and size.
PINK_RGB = (255, 64, 160)
ORANGE_RGB = (255, 128, 0)
MARKER_DIAMETER_M = 0.006
#: Thickness of a drawn marker disc, m, and its gap above the face (no z-fighting).
_DISC_THICKNESS_M = 0.0002
_DISC_GAP_M = 0.0001
#: The skeleton's half thickness, m (the top faces of ribs and motor case):
#: softsnap_model.physics.parameters.SKELETON_THICKNESS_MM / 2.
_TOP_FACE_M = 0.0045
#: Where the camera looks from (CameraSettings.view): above the robot, or the first
#: module's marked side.
VIEWS = ('down', 'module')
#: Backends MuJoCo renders with offscreen on Linux without a display.
OFFSCREEN_BACKENDS = ('egl', 'osmesa')


#: Niceness added to the camera's thread (and so to the rasteriser threads Mesa's llvmpipe
#: starts from it): the physics comes first (benchmarks/sim_camera_bench.py).
CAMERA_THREAD_NICE = 10


def lower_thread_priority(niceness: int = CAMERA_THREAD_NICE) -> bool:
    """Lower the calling thread's CPU priority by `niceness` (Linux: per thread); threads
    it starts afterwards inherit it. False where the system does not allow it."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + niceness)
        return True
    except (AttributeError, OSError):
        return False


class CameraError(RuntimeError):
    """The simulated camera cannot work here (one line: what failed and what to do)."""


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of an undistorted pinhole camera, px (OpenCV/ROS pixel convention)."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    @classmethod
    def from_fovy(cls, width_px: int, height_px: int, fovy_deg: float) -> 'PinholeCamera':
        """MuJoCo's camera: square pixels, vertical field of view `fovy_deg` (degrees)."""
        f = 0.5 * height_px / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(width_px, height_px, f, f, 0.5 * (width_px - 1), 0.5 * (height_px - 1))

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px],
                         [0.0, 0.0, 1.0]])

    def project(self, points_optical_m: np.ndarray) -> np.ndarray:
        """Pixel coordinates (n, 2) of points (n, 3) in the optical frame, m."""
        p = np.asarray(points_optical_m, dtype=float).reshape(-1, 3)
        return np.stack([self.fx_px * p[:, 0] / p[:, 2] + self.cx_px,
                         self.fy_px * p[:, 1] / p[:, 2] + self.cy_px], axis=1)


#: Rotation of the optical frame in the world (columns: its x, y, z axes).
OPTICAL_IN_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class SimCameraView:
    """Where the camera is: its optical centre in the world (m), its orientation (the
    optical frame's axes in the world, as the columns of a rotation) and its intrinsics.
    ``azimuth_deg``/``elevation_deg`` are MuJoCo's free-camera angles of that
    orientation."""

    position_m: tuple[float, float, float]
    intrinsics: PinholeCamera
    fovy_deg: float
    optical_in_world: tuple = tuple(map(tuple, OPTICAL_IN_WORLD))
    azimuth_deg: float = 90.0
    elevation_deg: float = -90.0

    @property
    def rotation(self) -> np.ndarray:
        """The optical frame's axes in the world (3x3, columns x, y, z)."""
        return np.array(self.optical_in_world, dtype=float)

    @property
    def forward(self) -> np.ndarray:
        """The viewing direction (optical z) in the world, unit."""
        return self.rotation[:, 2]

    def world_to_optical(self, points_world_m: np.ndarray) -> np.ndarray:
        """Points (n, 3) in the world, m, to the optical frame, m."""
        p = np.asarray(points_world_m, dtype=float).reshape(-1, 3) - np.asarray(self.position_m)
        return p @ self.rotation

    def orientation_wxyz(self) -> tuple[float, float, float, float]:
        """The optical frame's orientation in the world as a unit quaternion (w, x, y, z)."""
        r = self.rotation
        w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
        x = math.copysign(math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0,
                          r[2, 1] - r[1, 2])
        y = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0,
                          r[0, 2] - r[2, 0])
        z = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0,
                          r[1, 0] - r[0, 1])
        return (w, x, y, z)

    def project_world(self, points_world_m: np.ndarray) -> np.ndarray:
        """Pixel coordinates (n, 2) of world points (n, 3), m."""
        return self.intrinsics.project(self.world_to_optical(points_world_m))


@dataclass(frozen=True)
class MarkerLayout:
    """The markers drawn on every module (colours sRGB 0-255, sizes m).

    Defaults are softsnap_vision's (``config/markers.yaml``): 6 mm discs, the orange one
    30 mm behind rib 0; a module given a tag in ``tags`` (module name -> ArUco id of
    ``tag_dictionary``) carries a ``tag_size_m`` tag (black square edge) centred
    ``tag_distance_m`` behind rib 0 on its axis, **instead of** the orange disc, the tag's
    top edge towards the module's +y (its cells in the module frame, x along the axis).
    """

    rib_rgb: tuple[int, int, int] = PINK_RGB
    rib_diameter_m: float = MARKER_DIAMETER_M
    base_rgb: tuple[int, int, int] = ORANGE_RGB
    base_diameter_m: float = MARKER_DIAMETER_M
    #: Distance of the orange marker behind rib 0's centre along the module axis, m.
    base_marker_offset_m: float = 0.030
    skeleton_rgb: tuple[int, int, int] = (200, 200, 200)
    tags: dict = field(default_factory=dict)
    tag_dictionary: str = 'DICT_4X4_50'
    tag_size_m: float = 0.020
    tag_distance_m: float = 0.035


#: A tag's colours (sRGB): black cells on a white square one cell wider each way.
_TAG_BLACK = (25, 25, 25)
_TAG_WHITE = (235, 235, 235)


def tag_cells(dictionary: str, tag_id: int, size_m: float) -> tuple[tuple, list]:
    """An ArUco tag as squares in its own frame (x right, y up = the tag's top), m.

    Returns (white quiet-zone square (centre (x, y), half edge), black cells [(centre,
    half edge), ...]); OpenCV's marker image gives the bits.
    """
    import cv2
    try:
        table = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    except AttributeError:
        raise ValueError(f'unknown ArUco dictionary {dictionary!r}') from None
    bits = cv2.aruco.generateImageMarker(table, int(tag_id), 6, borderBits=1)   # 6x6 cells
    cell = size_m / 6.0
    half = size_m / 2.0
    blacks = []
    for row in range(6):
        for col in range(6):
            if bits[row, col] < 128:
                # Image row 0 is the tag's top edge (+y).
                blacks.append(((-half + (col + 0.5) * cell, half - (row + 0.5) * cell), 0.5 * cell))
    return ((0.0, 0.0), half + cell), blacks


@dataclass(frozen=True)
class CameraSettings:
    """The camera's options (see :data:`CAMERA_OPTIONS`).

    ``height_m`` 0 fits the robot's start footprint (plus ``margin_m``) in the image;
    ``center_x_m``/``center_y_m`` NaN put the camera over the footprint's centre.
    ``view`` is where it looks from (:data:`VIEWS`); ``'module'`` fits the first module's
    start shape plus ``margin_m`` (``height_m`` and the centre do not apply).
    """

    width_px: int = DEFAULT_WIDTH_PX
    height_px: int = DEFAULT_HEIGHT_PX
    fovy_deg: float = DEFAULT_FOVY_DEG
    height_m: float = 0.0
    center_x_m: float = math.nan
    center_y_m: float = math.nan
    margin_m: float = DEFAULT_VIEW_MARGIN_M
    view: str = 'down'

    def __post_init__(self):
        if self.view not in VIEWS:
            raise ValueError(f'camera view must be one of {VIEWS}, got {self.view!r}')
        if not (16 <= self.width_px <= 4096 and 16 <= self.height_px <= 4096):
            raise ValueError(f'camera image size must be 16-4096 px each way, got '
                             f'{self.width_px}x{self.height_px}')
        if not (math.isfinite(self.fovy_deg) and 1.0 <= self.fovy_deg <= 150.0):
            raise ValueError(f'camera_fovy_deg must be in [1, 150] degrees, got {self.fovy_deg!r}')
        if not (math.isfinite(self.height_m) and 0.0 <= self.height_m <= 20.0):
            raise ValueError(f'camera_height_m must be in [0, 20] m (0: fit the robot), '
                             f'got {self.height_m!r}')
        if not (math.isfinite(self.margin_m) and 0.0 <= self.margin_m <= 5.0):
            raise ValueError(f'camera margin must be in [0, 5] m, got {self.margin_m!r}')


def fit_view(settings: CameraSettings, footprint_xy_m: np.ndarray,
             marker_plane_z_m: float) -> SimCameraView:
    """The camera over a robot whose points' world (x, y) are `footprint_xy_m` (n, 2), m.

    Without a height, the camera is raised until the footprint plus the margin fills the
    image at the marker plane (world z `marker_plane_z_m`, m) without cutting it.
    """
    xy = np.asarray(footprint_xy_m, dtype=float).reshape(-1, 2)
    low, high = xy.min(axis=0), xy.max(axis=0)
    centre = 0.5 * (low + high)
    x = settings.center_x_m if math.isfinite(settings.center_x_m) else float(centre[0])
    y = settings.center_y_m if math.isfinite(settings.center_y_m) else float(centre[1])
    intrinsics = PinholeCamera.from_fovy(settings.width_px, settings.height_px, settings.fovy_deg)
    height = settings.height_m
    if height <= 0.0:
        # Half extents about the camera's centre, plus the margin; the distance at which
        # each fits its half of the image (tan of the half angle each way).
        half_x = max(abs(high[0] - x), abs(low[0] - x)) + settings.margin_m
        half_y = max(abs(high[1] - y), abs(low[1] - y)) + settings.margin_m
        tan_y = math.tan(math.radians(settings.fovy_deg) / 2.0)
        tan_x = tan_y * settings.width_px / settings.height_px
        height = marker_plane_z_m + max(half_x / tan_x, half_y / tan_y)
    return SimCameraView(position_m=(x, y, float(height)), intrinsics=intrinsics,
                         fovy_deg=settings.fovy_deg)


#: Below this |cos| between the viewing direction and the vertical, a face view is taken
#: as a top-down one (MuJoCo's free camera rolls with its azimuth when looking straight
#: down or up).
_VERTICAL_COS = 0.999


def fit_face_view(settings: CameraSettings, points_world_m: np.ndarray,
                  face_normal_world: np.ndarray) -> SimCameraView:
    """The camera looking at a face (unit normal `face_normal_world`, towards the camera)
    on which `points_world_m` (n, 3) lie: its optical axis along the normal's opposite,
    image up as close to world +z as that allows, at the distance at which the points
    plus ``settings.margin_m`` fill the image without being cut."""
    points = np.asarray(points_world_m, dtype=float).reshape(-1, 3)
    normal = np.asarray(face_normal_world, dtype=float)
    forward = -normal / np.linalg.norm(normal)
    if abs(forward[2]) > _VERTICAL_COS:
        raise ValueError('the face looks straight up or down: use the top-down view')
    elevation = math.asin(float(forward[2]))
    azimuth = math.atan2(float(forward[1]), float(forward[0]))
    # MuJoCo's free camera: up is the forward direction tilted by +90 degrees of elevation.
    up = np.array([-math.sin(elevation) * math.cos(azimuth),
                   -math.sin(elevation) * math.sin(azimuth), math.cos(elevation)])
    right = np.cross(forward, up)
    rotation = np.column_stack([right, -up, forward])
    centre_plane = points @ rotation
    low, high = centre_plane.min(axis=0), centre_plane.max(axis=0)
    mid = 0.5 * (low + high)
    centre = rotation @ np.array([mid[0], mid[1], float(centre_plane[:, 2].mean())])
    half_x = 0.5 * (high[0] - low[0]) + settings.margin_m
    half_y = 0.5 * (high[1] - low[1]) + settings.margin_m
    tan_y = math.tan(math.radians(settings.fovy_deg) / 2.0)
    tan_x = tan_y * settings.width_px / settings.height_px
    distance = max(half_x / tan_x, half_y / tan_y)
    intrinsics = PinholeCamera.from_fovy(settings.width_px, settings.height_px, settings.fovy_deg)
    return SimCameraView(position_m=tuple(float(v) for v in centre - distance * forward),
                         intrinsics=intrinsics, fovy_deg=settings.fovy_deg,
                         optical_in_world=tuple(map(tuple, rotation)),
                         azimuth_deg=math.degrees(azimuth), elevation_deg=math.degrees(elevation))


@dataclass(frozen=True)
class FrameState:
    """What a frame is rendered from: the physics' time (s) and ``qpos`` at that instant."""

    time_s: float
    qpos: np.ndarray


def capture_frame_state(simulation) -> FrameState:
    """Copy the simulation's state for a frame (the simulation thread; ~1 us)."""
    return FrameState(time_s=float(simulation.time_s), qpos=simulation.data.qpos.copy())


def offscreen_backend() -> str:
    """The MuJoCo GL backend in use, after choosing EGL where nothing was chosen.

    MuJoCo reads ``MUJOCO_GL`` once, when it is first imported: call this before
    anything imports mujoco (the node does, before building the simulation). Raises
    CameraError when mujoco was imported with a backend that needs a display.
    """
    import sys
    os.environ.setdefault('MUJOCO_GL', 'egl')
    # Mesa's llvmpipe rasterises in the rendering thread itself, not in threads of its own
    # spread over every core: ~20 ms of one thread's CPU per 1280x960 frame, niced with
    # it (lower_thread_priority), and no hand-offs between threads on a busy machine.
    os.environ.setdefault('LP_NUM_THREADS', '0')
    backend = os.environ['MUJOCO_GL'].lower().strip()
    if 'mujoco' in sys.modules:
        from mujoco.rendering.classic import gl_context
        backend = getattr(gl_context, '_MUJOCO_GL', backend)
    if backend not in OFFSCREEN_BACKENDS:
        raise CameraError(f'the camera renders offscreen with MUJOCO_GL=egl or osmesa; '
                          f'mujoco was loaded with MUJOCO_GL={backend!r}')
    return backend


class SimCamera:
    """Renders frames of a :class:`~softsnap_model.physics.simulation.RobotSimulation`.

    Build it in the thread that renders (the OpenGL context is that thread's). Raises
    CameraError with the reason when nothing can be rendered here.
    """

    def __init__(self, simulation, settings: CameraSettings = CameraSettings(),
                 markers: MarkerLayout = MarkerLayout()):
        backend = offscreen_backend()
        import copy

        import mujoco
        self._mujoco = mujoco
        self.settings = settings
        self.markers = markers
        model = copy.deepcopy(simulation.model)   # the physics changes its own as it runs
        self.model = model
        self.data = mujoco.MjData(model)
        self._bodies = {}
        body = mujoco.mjtObj.mjOBJ_BODY
        for module in simulation.layout.modules:
            ids = np.array([mujoco.mj_name2id(model, body, b) for b in module.rib_bodies])
            self._bodies[module.name] = ids
        self.module_names = tuple(self._bodies)
        unknown = sorted(set(markers.tags) - set(self.module_names))
        if unknown:
            raise ValueError(f'tags for modules not in the scene: {unknown}')
        self._tags = {name: tag_cells(markers.tag_dictionary, tag_id, markers.tag_size_m)
                      for name, tag_id in markers.tags.items()}
        self._style(model)
        self.data.qpos[:] = simulation.data.qpos
        self._kinematics()
        if settings.view == 'module':
            first = self._bodies[self.module_names[0]]
            points = np.concatenate([self.marker_positions_world()[self.module_names[0]]['ribs'],
                                     self._base_points_world()[:1]])
            normal = self.data.xmat[first[0]].reshape(3, 3)[:, 2]
            self.view = fit_face_view(settings, points, normal)
        else:
            footprint = np.concatenate([self.data.xpos[ids][:, :2]
                                        for ids in self._bodies.values()])
            # Include the cases behind rib 0 (the orange markers) in the fitted view.
            footprint = np.concatenate([footprint, self._base_points_world()[:, :2]])
            self.view = fit_view(settings, footprint, self.marker_plane_z_m())
        model.vis.global_.fovy = settings.fovy_deg
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), settings.width_px)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), settings.height_px)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        # The free camera sits at lookat - distance * forward: look at the ground (top
        # down) or the face centre (a face view) along the view's forward direction.
        position = np.asarray(self.view.position_m)
        distance = position[2] if settings.view == 'down' else 1.0
        self.camera.lookat[:] = position + distance * self.view.forward
        self.camera.distance = distance
        self.camera.elevation = self.view.elevation_deg
        self.camera.azimuth = self.view.azimuth_deg
        self.option = mujoco.MjvOption()
        self.option.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0
        self.option.sitegroup[:] = 0
        try:
            self.renderer = mujoco.Renderer(model, settings.height_px, settings.width_px)
        except Exception as exc:  # noqa: BLE001 - any GL failure is the same refusal
            raise CameraError(f'cannot render offscreen with MUJOCO_GL={backend} '
                              f'({type(exc).__name__}: {exc}); install libegl1, libegl-mesa0 '
                              'and libgl1-mesa-dri (scripts/bootstrap.sh does) or set '
                              'MUJOCO_GL=osmesa with libosmesa6') from None
        self.frames = 0

    def _style(self, model) -> None:
        """Lights, colours and quality for a plain measurement picture (see module doc)."""
        mujoco = self._mujoco
        model.vis.quality.shadowsize = 0      # no shadow map (llvmpipe: 10x the cost)
        model.vis.quality.offsamples = 0      # no multisampling: crisp marker edges
        # Coarser tessellation: half the CPU of a frame (18 -> 10 ms at 1280x960 with
        # llvmpipe). Discs stay 16-gons (centroid exact, area within 2.6 % of a circle);
        # nothing round but the markers is in view from above.
        model.vis.quality.numslices = 16
        model.vis.quality.numstacks = 2
        model.vis.quality.numquads = 1
        # The diffuse light comes from the camera's direction: the scene's sun (straight
        # down) for the top-down view, the headlight (along the view) for a face view.
        face_view = self.settings.view != 'down'
        model.vis.headlight.ambient[:] = 0.4
        model.vis.headlight.diffuse[:] = 0.6 if face_view else 0.0
        model.vis.headlight.specular[:] = 0.0
        model.light_ambient[:] = 0.0
        model.light_diffuse[:] = 0.0 if face_view else 0.6
        model.light_specular[:] = 0.0
        model.light_castshadow[:] = 0
        model.geom_matid[:] = -1
        grey = np.array([*self.markers.skeleton_rgb, 255]) / 255.0
        robot_bodies = set()
        for ids in self._bodies.values():
            robot_bodies.update(int(b) for b in ids)
        # Every geom of a module (ribs, rods, motor case, mount) in the skeleton's grey;
        # the rods a shade darker so the spine shows.
        for g in range(model.ngeom):
            if self._in_module(model, int(model.geom_bodyid[g]), robot_bodies):
                rgba = grey.copy()
                if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX and model.geom_rgba[g, 3] < 1:
                    rgba[:3] *= 0.6
                model.geom_rgba[g] = rgba

    def _in_module(self, model, body: int, rib_bodies: set) -> bool:
        # A module's geoms hang below its base body (rib 0): walk up the tree.
        while body > 0:
            if body in rib_bodies:
                return True
            body = int(model.body_parentid[body])
        return False

    def marker_distance_m(self) -> float:
        """Distance of the marker discs' faces from the camera along its axis now, m (mean
        over the ribs): the marker tracker's ``plane_distance``."""
        ribs = np.concatenate([m['ribs'] for m in self.marker_positions_world().values()])
        return float(np.mean(self.view.world_to_optical(ribs)[:, 2]))

    def marker_plane_z_m(self) -> float:
        """World z of the marker discs' faces now, m (mean over the ribs)."""
        z = [self._top_points(ids, np.zeros((len(ids), 2)))[:, 2] for ids in self._bodies.values()]
        return float(np.mean(np.concatenate(z)))

    def _kinematics(self) -> None:
        mujoco = self._mujoco
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def _top_points(self, bodies: np.ndarray, offsets_xy: np.ndarray) -> np.ndarray:
        """World points on the top faces of `bodies` at body-frame (x, y) `offsets_xy`."""
        d = self.data
        local = np.concatenate([offsets_xy, np.full((len(bodies), 1),
                                                    _TOP_FACE_M + _DISC_GAP_M)], axis=1)
        rot = d.xmat[bodies].reshape(-1, 3, 3)
        return d.xpos[bodies] + np.einsum('nij,nj->ni', rot, local)

    def _base_points_world(self) -> np.ndarray:
        """The orange disc's centre (or the tag's) of every module, world, m."""
        bases = np.array([ids[0] for ids in self._bodies.values()])
        offsets = np.array([[-(self.markers.tag_distance_m if name in self.markers.tags
                               else self.markers.base_marker_offset_m), 0.0]
                            for name in self._bodies])
        return self._top_points(bases, offsets)

    def marker_positions_world(self) -> dict[str, dict[str, np.ndarray]]:
        """Centres of the drawn markers now, m, world: per module ``ribs`` (n_ribs, 3) and
        ``base`` (3,): the orange disc's centre, or the tag's for a module with a tag."""
        out = {}
        bases = self._base_points_world()
        for i, (name, ids) in enumerate(self._bodies.items()):
            out[name] = {'ribs': self._top_points(ids, np.zeros((len(ids), 2))),
                         'base': bases[i]}
        return out

    def _add_square(self, scene, centre, rot, half_m, rgb, lift_m=0.0) -> None:
        self._add_geom(scene, self._mujoco.mjtGeom.mjGEOM_BOX,
                       np.array([half_m, half_m, 0.5 * _DISC_THICKNESS_M]),
                       centre + lift_m * rot.reshape(3, 3)[:, 2], rot, rgb)

    def _add_geom(self, scene, kind, size, centre, rot, rgb) -> None:
        if scene.ngeom >= scene.maxgeom:
            return
        geom = scene.geoms[scene.ngeom]
        self._mujoco.mjv_initGeom(geom, kind, size, centre, rot.reshape(9),
                                  np.array([*rgb, 255], dtype=float) / 255.0)
        geom.specular = 0.0
        geom.shininess = 0.0
        scene.ngeom += 1

    def _add_disc(self, scene, centre, rot, diameter_m, rgb) -> None:
        self._add_geom(scene, self._mujoco.mjtGeom.mjGEOM_CYLINDER,
                       np.array([0.5 * diameter_m, 0.5 * _DISC_THICKNESS_M, 0.0]), centre, rot, rgb)

    def _add_tag(self, scene, name, base_body) -> None:
        (white_xy, white_half), blacks = self._tags[name]
        d = self.data
        rot = d.xmat[base_body]
        r = rot.reshape(3, 3)
        origin = d.xpos[base_body] + r @ np.array([-self.markers.tag_distance_m, 0.0,
                                                   _TOP_FACE_M + _DISC_GAP_M])
        self._add_square(scene, origin + r @ np.array([*white_xy, 0.0]), rot, white_half,
                         _TAG_WHITE)
        for (x, y), half in blacks:
            self._add_square(scene, origin + r @ np.array([x, y, 0.0]), rot, half, _TAG_BLACK,
                             lift_m=_DISC_THICKNESS_M)

    def render(self, state: FrameState) -> np.ndarray:
        """The image (height, width, 3) uint8 RGB, row 0 at the top, of `state`."""
        self.data.qpos[:] = state.qpos
        self.data.time = state.time_s
        self._kinematics()
        self.renderer.update_scene(self.data, self.camera, self.option)
        scene = self.renderer.scene
        mujoco = self._mujoco
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        markers = self.marker_positions_world()
        rot = self.data.xmat
        m = self.markers
        for name, ids in self._bodies.items():
            where = markers[name]
            for body, centre in zip(ids, where['ribs']):
                self._add_disc(scene, centre, rot[body], m.rib_diameter_m, m.rib_rgb)
            if name in self._tags:
                self._add_tag(scene, name, ids[0])
            else:
                self._add_disc(scene, where['base'], rot[ids[0]], m.base_diameter_m, m.base_rgb)
        image = self.renderer.render()
        self.frames += 1
        return image

    def close(self) -> None:
        renderer = getattr(self, 'renderer', None)
        if renderer is not None:
            renderer.close()
            self.renderer = None
