"""The camera in the rerun recording: images, the tracker's detections and the model's
prediction projected onto them (rerun_logger's ``camera`` parameter).

Entities (under ``camera/image``, a 2D view added to the recording's layout):

- ``camera/image``: the camera's pinhole (``image_from_camera`` = camera_info's K, the
  resolution) and the frames as JPEG (``EncodedImage``), at most ``rate_hz`` per second
  of stamps (a 1280x960 rgb8 frame is 3.7 MB; JPEG at quality 85 ~0.1 MB);
- ``camera/image/measured/<module>``: the marker tracker's rib centres
  (``<module>/shape/measured``, visible ribs only), as points;
- ``camera/image/predicted/<module>``: the model's predicted rib centres
  (``model/shape/predicted``), as a line through the ribs.

Both are in their module's base frame; they are drawn where the simulator puts that
frame (the base poses of ``model/shape/simulated``, world) seen through the camera
(``camera/pose``, world; K): so the picture shows the detections on the markers and how
far the model's prediction is from the simulated robot. Without a simulator (a real
camera) nothing gives the module's pose in the image, and only the frames are logged.

No rclpy here: rerun_logger hands over the messages.
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from softsnap_model import recording
from softsnap_ros.units import stamp_ns

IMAGE_PATH = 'camera/image'
#: Default largest rate of logged frames, per second of stamps.
DEFAULT_RATE_HZ = 5.0
JPEG_QUALITY = 85


def _rotation_xyzw(q) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def camera_blueprint(blueprint: rrb.Blueprint) -> rrb.Blueprint:
    """`blueprint` with the camera's 2D view beside it."""
    view = rrb.Spatial2DView(name='Camera: tracker (points), model (lines)', origin=IMAGE_PATH)
    return rrb.Blueprint(rrb.Horizontal(blueprint.root_container, view, column_shares=[3, 2]),
                         collapse_panels=True)


class CameraRecorder:
    """Logs frames and projected shapes to `rec` (one thread: the logger's executor)."""

    def __init__(self, rec: rr.RecordingStream, spacing_mm: float,
                 rate_hz: float = DEFAULT_RATE_HZ, sim_time: bool = False):
        self.rec = rec
        # The logger's kind of ros_time (a duration on simulated time): one timeline
        # with two types makes rerun refuse the file's closing chunks.
        self.sim_time = bool(sim_time)
        self.spacing_mm = float(spacing_mm)
        self.limiter = recording.RateLimiter(rate_hz)
        self.k: np.ndarray | None = None
        self.camera_position: np.ndarray | None = None
        self.camera_rotation: np.ndarray | None = None   # optical frame in the world
        self.base_poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.predicted: dict[str, np.ndarray] = {}       # module -> (n, 3) m, base frame
        self.measured: dict[str, np.ndarray] = {}        # module -> (k, 3) m, base frame
        self.frames = 0
        self._pinhole = None

    # -- inputs ---------------------------------------------------------------------------
    def camera_info(self, msg) -> None:
        k = np.asarray(msg.k, dtype=float).reshape(3, 3)
        key = (tuple(k.ravel()), msg.width, msg.height)
        if key != self._pinhole:
            self._pinhole = key
            self.k = k
            self.rec.log(IMAGE_PATH, rr.Pinhole(image_from_camera=k,
                                                resolution=[msg.width, msg.height]), static=True)

    def camera_pose(self, msg) -> None:
        p, q = msg.pose.position, msg.pose.orientation
        self.camera_position = np.array([p.x, p.y, p.z])
        self.camera_rotation = _rotation_xyzw((q.x, q.y, q.z, q.w))

    def simulated(self, shape) -> None:
        """A decoded RobotShape from sim_robot: its base poses are world poses."""
        if len(shape.base_poses) == len(shape.modules):
            for module, pose in zip(shape.modules, shape.base_poses):
                self.base_poses[module.module] = (np.array(pose[:3]), _rotation_xyzw(pose[3:]))

    def predicted_shape(self, shape) -> None:
        """A decoded RobotShape from the model: rib centres (or angles) per module."""
        for module in shape.modules:
            if len(module.rib_centers):
                self.predicted[module.module] = np.array(module.rib_centers, dtype=float)
            elif len(module.angles):
                mm = recording.rib_centres_mm(module.angles, self.spacing_mm)
                self.predicted[module.module] = np.column_stack(
                    [np.asarray(mm, dtype=float)[:, :2] * 1e-3, np.zeros(len(mm))])

    def measured_shape(self, msg) -> None:
        visible = np.array(msg.visible, dtype=bool)
        points = np.array([[p.x, p.y, p.z] for p in msg.rib_centers], dtype=float).reshape(-1, 3)
        if len(points) == len(visible):
            points = points[visible]
        self.measured[msg.module] = np.nan_to_num(points, nan=0.0)

    # -- projection and logging -----------------------------------------------------------
    def _project(self, module: str, points_base_m: np.ndarray) -> np.ndarray | None:
        pose = self.base_poses.get(module)
        if pose is None or self.k is None or self.camera_position is None or not len(points_base_m):
            return None
        position, rotation = pose
        world = points_base_m @ rotation.T + position
        optical = (world - self.camera_position) @ self.camera_rotation
        uv = optical[:, :2] / optical[:, 2:3]
        return uv @ self.k[:2, :2].T + self.k[:2, 2]

    def image(self, msg) -> bool:
        """Log a frame (rgb8 or bgr8) and the shapes over it; False when rate-limited."""
        stamp = stamp_ns(msg.header.stamp)
        if msg.encoding not in ('rgb8', 'bgr8') or not self.limiter.allow(IMAGE_PATH, stamp):
            return False
        import cv2
        pixels = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width, 3)
        bgr = pixels[:, :, ::-1] if msg.encoding == 'rgb8' else pixels
        ok, jpeg = cv2.imencode('.jpg', np.ascontiguousarray(bgr),
                                [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise ValueError('the frame could not be JPEG-encoded')
        recording.set_stamp(self.rec, stamp, self.sim_time)
        self.rec.log(IMAGE_PATH, rr.EncodedImage(contents=jpeg.tobytes(), media_type='image/jpeg'))
        for module, points in self.measured.items():
            uv = self._project(module, points)
            if uv is not None:
                self.rec.log(f'{IMAGE_PATH}/measured/{module}',
                             rr.Points2D(uv, radii=3.0, colors=[[0, 255, 255]]))
        for module, points in self.predicted.items():
            uv = self._project(module, points)
            if uv is not None:
                self.rec.log(f'{IMAGE_PATH}/predicted/{module}',
                             rr.LineStrips2D([uv], radii=1.0, colors=[[255, 255, 0]]))
        self.frames += 1
        return True


def attach_camera(node, scene, rate_hz: float = DEFAULT_RATE_HZ) -> CameraRecorder:
    """A CameraRecorder on rerun_logger `node`'s recording, its subscriptions on the node's
    inbox (drained with the rest), and the layout with the camera view."""
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image
    from softsnap_interfaces.msg import MeasuredShape
    spacing = scene.skeleton.spacing_mm if scene is not None else recording.RIB_SPACING_MM
    camera = CameraRecorder(node.rec, spacing, rate_hz,
                            sim_time=bool(node.get_parameter('use_sim_time').value))
    colors, bounds = recording.scene_style(scene) if scene is not None else (None, None)
    node.rec.send_blueprint(camera_blueprint(recording.build_blueprint(
        colors, bounds, node.get_parameter('world_view').value)))
    # Frames are 3.7 MB: keep two, the newest; the pose is latched by sim_robot.
    frames = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                        reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node._subscribe(Image, 'camera/image_raw', camera.image, qos=frames)
    node._subscribe(CameraInfo, 'camera/camera_info', camera.camera_info)
    node._subscribe(PoseStamped, 'camera/pose', camera.camera_pose, qos=latched)
    for module in getattr(scene, 'modules', ()):
        node._subscribe(MeasuredShape, f'{module.name}/shape/measured', camera.measured_shape)
    return camera
