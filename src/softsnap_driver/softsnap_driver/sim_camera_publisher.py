"""sim_robot's simulated camera on ROS: ``camera/image_raw`` and ``camera/camera_info``.

The rendering core is :mod:`softsnap_driver.sim_camera`; this module gives it a thread
and publishers. With ``camera:=true`` the sim_robot node
(:mod:`softsnap_driver.sim_robot_node`) publishes, in its namespace:

- ``camera/image_raw`` (sensor_msgs/Image, ``rgb8``, row 0 at the top), every
  ``camera_rate_hz`` of simulated time (default 15 Hz), stamped with the simulation time
  of the instant it shows;
- ``camera/camera_info`` (sensor_msgs/CameraInfo) with each image, same stamp: the
  intrinsics MuJoCo renders with (``fovy`` and the resolution; plumb_bob, no
  distortion);
- ``camera/pose`` (geometry_msgs/PoseStamped, frame ``world``, latched): the optical
  frame (x right, y down, z forward, REP 103) in the world, m.

The frame's state is copied in the simulation thread on a ``/clock`` tick (``qpos``,
microseconds); rendering and publishing happen in the camera's own thread, which owns the
OpenGL context. When the renderer is still busy with the last frame at the next tick, the
new one is dropped (counted, and a throttled warning says so): the physics never waits
for the camera.
"""
from __future__ import annotations

import array
import math
import queue
import threading

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from softsnap_driver.sim_camera import (DEFAULT_CAMERA_RATE_HZ, DEFAULT_FOVY_DEG,
                                        DEFAULT_HEIGHT_PX, DEFAULT_WIDTH_PX, CameraError,
                                        CameraSettings, MarkerLayout, SimCamera,
                                        capture_frame_state, lower_thread_priority)
from softsnap_driver.sim_observation import TickSchedule
from softsnap_ros.units import NS_PER_S, sec_nanosec

#: The node's camera options: name: (type, default, help), as sim_robot.OPTIONS.
CAMERA_OPTIONS = {
    'camera': (bool, False, 'render a top-down camera of the scene with the markers and '
                            'publish camera/image_raw and camera/camera_info'),
    'camera_rate_hz': (float, DEFAULT_CAMERA_RATE_HZ,
                       'camera frames this often, Hz of simulated time (at most clock_rate_hz)'),
    'camera_width_px': (int, DEFAULT_WIDTH_PX, 'image width, px'),
    'camera_height_px': (int, DEFAULT_HEIGHT_PX, 'image height, px'),
    'camera_fovy_deg': (float, DEFAULT_FOVY_DEG, 'vertical field of view, degrees'),
    'camera_height_m': (float, 0.0, 'camera height above the ground, m (0: fit the robot '
                                    'with a margin)'),
    'camera_tags': (bool, False, "one ArUco tag per module (DICT_4X4_50; the scene's "
                                 "tag_id of the module, else its index in the scene) on the "
                                 'case instead of the orange marker: the marker tracker tells '
                                 'modules apart by it'),
    'camera_view': (str, 'down', "where the camera looks from: 'down' (above the robot) or "
                                 "'module' (the first module's marked side, perpendicular to "
                                 "its bending plane: a hanging finger's face)"),
    'camera_x_m': (float, math.nan, 'camera x in the world, m (NaN: over the robot)'),
    'camera_y_m': (float, math.nan, 'camera y in the world, m (NaN: over the robot)'),
}
#: Ranges of the camera's numeric options (inclusive), for the parameter descriptors.
CAMERA_RANGES = {
    'camera_rate_hz': (0.1, 1000.0),
    'camera_width_px': (16, 4096),
    'camera_height_px': (16, 4096),
    'camera_fovy_deg': (1.0, 150.0),
    'camera_height_m': (0.0, 20.0),
}
#: Image and camera_info QoS: reliable (a reliable publisher matches reliable and
#: best-effort subscribers alike), the newest two frames only.
IMAGE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
POSE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: How long start-up waits for the first frame (an OpenGL context on a loaded machine), s.
READY_TIMEOUT_S = 120.0


def camera_settings(opts) -> CameraSettings:
    """The camera's settings from the node's options (ValueError naming a bad one)."""
    return CameraSettings(width_px=int(opts.camera_width_px),
                          height_px=int(opts.camera_height_px),
                          fovy_deg=float(opts.camera_fovy_deg),
                          height_m=float(opts.camera_height_m),
                          center_x_m=float(opts.camera_x_m), center_y_m=float(opts.camera_y_m),
                          view=str(getattr(opts, 'camera_view', 'down')))


def marker_layout(opts, scene) -> MarkerLayout:
    """The markers for the node's options: tags per module with ``camera_tags``."""
    if not opts.camera_tags:
        return MarkerLayout()
    tags = {}
    for index, module in enumerate(scene.modules):
        tag_id = getattr(module, 'tag_id', None)
        tags[module.name] = int(index if tag_id is None else tag_id)
    return MarkerLayout(tags=tags)


def _sim_time_ns(time_s: float) -> int:
    return round(time_s * NS_PER_S)


def _stamp(stamp_ns: int) -> Time:
    sec, nanosec = sec_nanosec(stamp_ns)
    return Time(sec=sec, nanosec=nanosec)


class CameraPublisher:
    """The camera's thread and publishers on `node` (start-up raises CameraError if it
    cannot render: the first frame is rendered before this returns)."""

    def __init__(self, node, simulation, settings: CameraSettings, markers: MarkerLayout,
                 rate_hz: float, frame_id: str, capture_stamp_ns=None):
        # capture_stamp_ns() -> the stamp of a frame (ns), read when its state is copied;
        # default: the simulation time itself (sim_robot's /clock).
        self._capture_stamp_ns = capture_stamp_ns
        self.node = node
        self.simulation = simulation
        self.frame_id = frame_id
        self.schedule = TickSchedule(rate_hz)
        self.image_publisher = node.create_publisher(Image, 'camera/image_raw', IMAGE_QOS)
        self.info_publisher = node.create_publisher(CameraInfo, 'camera/camera_info', IMAGE_QOS)
        self.pose_publisher = node.create_publisher(PoseStamped, 'camera/pose', POSE_QOS)
        self.published = 0
        self.dropped = 0
        self._queue: queue.Queue = queue.Queue(maxsize=1)
        self._ready = threading.Event()
        self._error: str | None = None
        self._stopping = False
        self.camera: SimCamera | None = None
        self._settings, self._markers = settings, markers
        self._thread = threading.Thread(target=self._run, name='sim_robot.camera', daemon=True)
        self._thread.start()
        if not self._ready.wait(READY_TIMEOUT_S):
            self.stop()
            raise CameraError(f'camera: no frame rendered within {READY_TIMEOUT_S:g} s')
        if self._error is not None:
            self._thread.join(5.0)
            raise CameraError(f'camera: {self._error}')
        self._info = self._camera_info()
        self._publish_pose()

    # -- the simulation thread ---------------------------------------------------------
    def on_tick(self, time_s: float) -> None:
        """On each /clock tick (the simulation thread): copy the state if a frame is due."""
        if not self.schedule.due(time_s):
            return
        try:
            state = capture_frame_state(self.simulation)
            stamp_ns = (self._capture_stamp_ns() if self._capture_stamp_ns is not None
                        else _sim_time_ns(state.time_s))   # the instant shown
            self._queue.put_nowait((state, stamp_ns))
        except queue.Full:
            self.dropped += 1
            self.node.get_logger().warning(
                f'camera: the renderer falls behind the {self.schedule.rate_hz:g} Hz camera '
                f'rate: {self.dropped} frames dropped so far', throttle_duration_sec=10.0)

    # -- the camera thread --------------------------------------------------------------
    def _run(self) -> None:
        # Physics first: this thread and the rasteriser threads it starts run niced.
        lower_thread_priority()
        try:
            self.camera = SimCamera(self.simulation, self._settings, self._markers)
            self._first_image = self.camera.render(capture_frame_state(self.simulation))
            #: The marker plane's distance from the camera at the start, m.
            self.marker_distance_m = self.camera.marker_distance_m()
        except Exception as exc:  # noqa: BLE001 - the refusal says why, in one line
            self._error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._ready.set()
            return
        self._ready.set()
        while True:
            item = self._queue.get()
            if item is None:
                break
            state, stamp_ns = item
            try:
                image = self.camera.render(state)
                self._publish(image, stamp_ns)
            except Exception as exc:  # noqa: BLE001 - reported; the next frame is tried
                if self.node.context.ok():
                    self.node.get_logger().error(f'camera frame at t = {state.time_s:.3f} s '
                                                 f'not published: {exc!r}',
                                                 throttle_duration_sec=5.0)
        self.camera.close()

    def _camera_info(self) -> CameraInfo:
        k = self.camera.view.intrinsics
        info = CameraInfo()
        info.header.frame_id = self.frame_id
        info.width, info.height = k.width_px, k.height_px
        info.distortion_model = 'plumb_bob'
        info.d = [0.0] * 5
        info.k = [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.p = [k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0]
        return info

    def _publish_pose(self) -> None:
        pose = PoseStamped()
        pose.header.frame_id = 'world'
        pose.header.stamp = _stamp(_sim_time_ns(float(self.simulation.time_s)))
        x, y, z = self.camera.view.position_m
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = x, y, z
        o = pose.pose.orientation
        o.w, o.x, o.y, o.z = self.camera.view.orientation_wxyz()
        self.pose_publisher.publish(pose)

    def _publish(self, image, stamp_ns: int) -> None:
        stamp = _stamp(stamp_ns)
        msg = Image()
        msg.header.stamp = stamp
        msg.header.frame_id = self.frame_id
        msg.height, msg.width = int(image.shape[0]), int(image.shape[1])
        msg.encoding = 'rgb8'
        msg.is_bigendian = 0
        msg.step = msg.width * 3
        data = array.array('B')
        data.frombytes(image.tobytes())   # array('B'): the message takes it without a copy per byte
        msg.data = data
        self._info.header.stamp = stamp
        self.image_publisher.publish(msg)
        self.info_publisher.publish(self._info)
        self.published += 1

    def describe(self) -> str:
        """One line: size, rate, where the camera is and the scale at the marker plane."""
        view = self.camera.view
        distance = self.marker_distance_m
        k = view.intrinsics
        x, y, z = view.position_m
        where = (f'{z:.3f} m above the ground over ({x:.3f}, {y:.3f}) m'
                 if self._settings.view == 'down' else
                 f"at ({x:.3f}, {y:.3f}, {z:.3f}) m facing the first module's markers")
        return (f'camera: {k.width_px}x{k.height_px} px at {self.schedule.rate_hz:g} Hz, '
                f'{where}; marker plane {distance:.4f} m from the camera '
                f'({1000.0 * distance / k.fx_px:.3f} mm/px)')

    def stop(self) -> None:
        """End the camera thread (after the frame it renders)."""
        while self._thread.is_alive():
            try:
                self._queue.put(None, timeout=0.1)
                break
            except queue.Full:
                try:
                    self._queue.get_nowait()
                except queue.Empty:
                    pass
        self._thread.join(10.0)
