"""marker_tracker: rib centres of every module in view of a calibrated top-down camera.

``ros2 run softsnap_vision marker_tracker --ros-args -p scene:=brittle_star
-p plane_distance:=0.5 -r image_raw:=camera/image_raw -r camera_info:=camera/camera_info``

Subscribes (in the node's namespace, remappable):

- ``image_raw`` (sensor_msgs/Image: bgr8, rgb8, bgra8 or rgba8) and ``camera_info``
  (sensor_msgs/CameraInfo: K and plumb_bob / rational_polynomial distortion), sensor-data
  QoS (the newest frame only; matches reliable and best-effort cameras);
- ``<module>/cable_length/measured`` (CableLength, m) for the model's prediction.

Publishes per module whose tag is in view ``<module>/shape/measured``
(softsnap_interfaces/MeasuredShape, source ``camera``, frame ``<robot>/<module>``, rib
centres in m in the module base frame, NaN and visible=false where not seen, fit
residual and RMSE to the model at the last measured cable length, m), and every
``diagnostics_period`` on ``/diagnostics`` the camera's and each module's status
(:mod:`.tracker_health`). A bad image (encoding, size, data) or one before any
camera_info is counted, warned about (throttled) and skipped: never a crash.

The node only translates messages; the work is :class:`softsnap_vision.tracker.MarkerTracker`.
"""
from __future__ import annotations

import math
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo as CameraInfoMsg
from sensor_msgs.msg import Image

from softsnap_ros.node import SoftSnapNode
from softsnap_ros.spinning import run_node_main
from softsnap_interfaces.msg import CableLength, MeasuredShape
from softsnap_model import solve_forward
from softsnap_model.scene import load_scene

from .camera_info import CameraInfo, CameraInfoError
from .image_message import ImageMessageError, image_to_bgr
from .marker_config import load_marker_config
from .measurement import rmse_to_model_mm
from .tracker import MarkerTracker, TagTarget
from .tracker_health import CameraCounters, ModuleCounters, camera_status, module_status, status_name
from softsnap_ros.units import MM_PER_M

#: Cable lengths closer than this (mm) share one model prediction.
PREDICTION_LENGTH_TOL_MM = 1e-3


class MarkerTrackerNode(SoftSnapNode):
    """Thin shell around :class:`MarkerTracker` (see the module docstring)."""

    def __init__(self):
        super().__init__('marker_tracker')
        self.declare_parameter('scene', 'brittle_star', ParameterDescriptor(
            description='Robot scene (name or YAML path): the modules and their tag ids '
                        '(markers: {tag_id: N}; a module without one has its index)',
            read_only=True))
        self.declare_parameter('markers', '', ParameterDescriptor(
            description="Marker colours, sizes and tag layout (YAML); '' = the paper's "
                        'defaults (docs/vision.md)', read_only=True))
        self.declare_parameter('plane_distance', 0.5, ParameterDescriptor(
            description='Distance from the camera centre to the marker plane along the '
                        'optical axis (m)', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=0.05, to_value=20.0)]))
        self.declare_parameter('tag_scale', 0.5, ParameterDescriptor(
            description='Image scale the tag detector runs at (corners are refined on the '
                        'full image); 1 for small tags far away', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=0.2, to_value=1.0)]))
        self.declare_parameter('diagnostics_period', 1.0, ParameterDescriptor(
            description='Period of /diagnostics (s)',
            floating_point_range=[FloatingPointRange(from_value=0.05, to_value=60.0)],
            read_only=True))
        self.declare_parameter('stale_after', 2.0, ParameterDescriptor(
            description='No image (or no tag of a module) for this long: STALE (s)',
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=600.0)],
            read_only=True))
        self.declare_parameter('warn_period', 5.0, ParameterDescriptor(
            description='Shortest time between two warnings of the same kind (s)',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=600.0)],
            read_only=True))
        self.scene = load_scene(self.get_parameter('scene').value)
        markers = self.get_parameter('markers').value
        self.config = load_marker_config(markers or None)
        self.plane_distance_m = float(self.get_parameter('plane_distance').value)
        self.tag_scale = float(self.get_parameter('tag_scale').value)
        self.period_s = float(self.get_parameter('diagnostics_period').value)
        self.stale_after_s = float(self.get_parameter('stale_after').value)
        self.warn_period_s = float(self.get_parameter('warn_period').value)
        self.targets = [TagTarget(m.name, m.tag_id if m.tag_id is not None else m.index)
                        for m in self.scene.modules]
        self.camera: CameraInfo | None = None
        self.tracker: MarkerTracker | None = None
        self.counters = CameraCounters()
        self._reported: CameraCounters | None = None
        self.module_counters = {m.name: ModuleCounters() for m in self.scene.modules}
        self.lengths_m = {m.name: math.nan for m in self.scene.modules}
        self._predictions: dict[str, tuple[float, np.ndarray | None]] = {}
        self._warned_at: dict[str, float] = {}

        # reliable_images (issue 33, the physics demo's camera): a 1280x960 rgb8 frame is
        # 3.7 MB, ~57 UDP fragments; best effort on a loaded machine lost all but 2 of
        # ~60 frames in the demo (any lost fragment loses the frame). Reliable with depth 1
        # still keeps only the newest frame.
        self.declare_parameter('reliable_images', False, ParameterDescriptor(
            description='subscribe to image_raw reliable (depth 1) instead of sensor-data '
                        'best effort (large frames over a loaded machine)', read_only=True))
        image_qos = (QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
                     if self.get_parameter('reliable_images').value else qos_profile_sensor_data)
        self.create_subscription(Image, 'image_raw', self.image_callback, image_qos)
        self.create_subscription(CameraInfoMsg, 'camera_info', self.camera_info_callback,
                                 qos_profile_sensor_data)
        qos = QoSProfile(depth=10)
        self.shape_publishers = {}
        for m in self.scene.modules:
            self.create_subscription(CableLength, f'{m.name}/cable_length/measured',
                                     lambda msg, name=m.name: self.length_callback(name, msg), 10)
            self.shape_publishers[m.name] = self.create_publisher(
                MeasuredShape, f'{m.name}/shape/measured', qos)
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', qos)
        self._reported_at = time.monotonic()
        self.create_timer(self.period_s, self.diagnostics_callback)

    # ------------------------------------------------------------------ callbacks
    def _warn(self, kind: str, text: str) -> None:
        """A warning at most every warn_period per kind; the last problem is kept."""
        self.counters.last_problem = text
        now = time.monotonic()
        if now - self._warned_at.get(kind, -math.inf) >= self.warn_period_s:
            self._warned_at[kind] = now
            self.get_logger().warning(text)

    def length_callback(self, module: str, msg: CableLength) -> None:
        self.lengths_m[module] = float(msg.cable_length)

    def camera_info_callback(self, msg: CameraInfoMsg) -> None:
        try:
            camera = CameraInfo.from_msg(msg)
        except CameraInfoError as exc:
            self._warn('camera_info', f'camera_info refused: {exc}')
            return
        if (self.camera is not None and camera.width == self.camera.width
                and camera.height == self.camera.height
                and np.array_equal(camera.camera_matrix, self.camera.camera_matrix)
                and np.array_equal(camera.distortion, self.camera.distortion)):
            return
        self.camera = camera
        self.tracker = MarkerTracker(camera, self.plane_distance_m, self.targets, self.config,
                                     self.scene.skeleton, tag_scale=self.tag_scale)
        self.counters.camera_info = True
        self.get_logger().info(f'camera_info: {camera.width}x{camera.height} px, '
                               f'f = {camera.focal_px:.1f} px, {camera.distortion_model}')

    def image_callback(self, msg: Image) -> None:
        c = self.counters
        c.frames += 1
        c.last_image_at = time.monotonic()
        if self.tracker is None:
            c.refused += 1
            self._warn('no_camera_info', 'image skipped: no camera_info yet')
            return
        try:
            image = image_to_bgr(msg, (self.camera.width, self.camera.height))
        except ImageMessageError as exc:
            c.refused += 1
            self._warn('image', f'image refused: {exc}')
            return
        start = time.perf_counter()
        try:
            result = self.tracker.track(image)
        except Exception as exc:   # a bug must not kill the node: counted and reported
            c.failures += 1
            self._warn('track', f'tracking failed: {exc!r}')
            return
        c.processing_s += time.perf_counter() - start
        c.frames_tracked += 1
        c.rib_markers_found = result.rib_markers_found
        c.tags_found = result.tags_found
        c.unknown_tags = result.unknown_tags
        now = time.monotonic()
        for name, tracked in result.modules.items():
            self._publish(msg, name, tracked, now)

    def _model_mm(self, name: str, length_m: float):
        """The model's rib centres (mm) at a cable length, cached per module; None if none."""
        if not math.isfinite(length_m):
            return None
        length_mm = length_m * MM_PER_M
        cached = self._predictions.get(name)
        if cached is not None and abs(cached[0] - length_mm) <= PREDICTION_LENGTH_TOL_MM:
            return cached[1]
        module = self.scene.module(name)
        try:
            result = solve_forward(self.scene.skeleton, module.threading_mm, length_mm)
            ribs = np.asarray(result.rib_centers) if result.converged else None
        except ValueError:   # outside the reachable range: no prediction
            ribs = None
        self._predictions[name] = (length_mm, ribs)
        return ribs

    def _publish(self, image_msg: Image, name: str, tracked, now: float) -> None:
        counters = self.module_counters[name]
        counters.last_seen_at = now
        counters.error = tracked.error or ''
        out = MeasuredShape()
        out.header.stamp = image_msg.header.stamp
        out.header.frame_id = f'{self.scene.name}/{name}'
        out.module = name
        out.source = 'camera'
        length_m = self.lengths_m[name]
        out.cable_length = length_m
        visible = tracked.visible
        ribs_m = tracked.ribs_mm / MM_PER_M
        out.rib_centers = [Point(x=float(x), y=float(y), z=0.0) for x, y in ribs_m]
        out.visible = [bool(v) for v in visible]
        out.residual = (tracked.fit.residual_mm / MM_PER_M if tracked.fit is not None
                        else math.nan)
        model = self._model_mm(name, length_m)
        rmse = rmse_to_model_mm(tracked.ribs_mm, visible, model) if model is not None else None
        out.rmse_to_model = rmse / MM_PER_M if rmse is not None else math.nan
        counters.visible_ribs = int(visible.sum())
        counters.residual_m = out.residual
        counters.rmse_to_model_m = out.rmse_to_model
        if tracked.error is None:
            counters.tracked_frames += 1
        self.shape_publishers[name].publish(out)

    def diagnostics_callback(self) -> None:
        now = time.monotonic()
        period = now - self._reported_at
        ns = self.get_namespace()
        statuses = [camera_status(status_name(ns, 'marker_tracker', 'camera'), self.counters,
                                  self._reported, now, period, self.stale_after_s)]
        for name, counters in self.module_counters.items():
            statuses.append(module_status(status_name(ns, name, 'camera'), name, counters, now,
                                          self.stale_after_s))
        msg = DiagnosticArray(status=statuses)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_publisher.publish(msg)
        self._reported = CameraCounters(**vars(self.counters))
        self._reported_at = now


def main(args=None) -> int:
    # One thread: a frame is tracked in a few ms; the sensor-data QoS keeps only the
    # newest frame, so a slow frame drops the ones behind it instead of queueing them.
    return run_node_main(args, 'marker_tracker', MarkerTrackerNode, fast_exit=True)


if __name__ == '__main__':
    raise SystemExit(main())
