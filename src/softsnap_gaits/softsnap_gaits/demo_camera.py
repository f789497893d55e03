"""The demo's ``--camera`` (with ``--physics``): sim_robot's camera and the marker tracker.

:func:`with_camera` turns the camera on in the graph's ``sim_robot`` (ArUco tags on the
cases, so the tracker tells the modules apart; the ground truth sampled at the camera's
rate, so every frame has a ground truth of the same instant; the camera 0.82 m above the
ground, so the tracker is given its distance to the markers of a robot lying on the
ground) and adds softsnap_vision's ``marker_tracker`` on its images. :class:`CameraObserver` (on the demo's observer node)
counts the frames (``camera/camera_info``, one per image, without taking the images) and
pairs every measured shape (``<module>/shape/measured``) with the ground truth of its
stamp (``<module>/shape/ground_truth``); :meth:`CameraObserver.summary` gives the
summary's ``camera`` entry::

    camera: {frames, fps, wall_fps, modules: {name: {tracked_frames, tracked_fraction,
             rib_error_mm_mean, rib_error_mm_max, unmatched}}}

``fps`` is frames per simulated second of the run window (the camera runs on simulated
time), ``wall_fps`` per wall second; a module's rib error is the distance between each
visible measured rib centre and the simulator's, in the module base frame (x, y), mm,
over every tracked frame. ``unmatched``: measured shapes whose stamp has no ground truth.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from softsnap_ros.units import stamp_ns

#: Camera rate of the demo, Hz of simulated time (issue 33's default).
DEMO_CAMERA_RATE_HZ = 15.0
#: The ground truth every camera frame: the same ticks (softsnap_driver.sim_observation).
_TRUTH_PER_FRAME = 1
#: The demo's camera height above the ground, m (what sim_robot fits for the brittle
#: star: 0.70 mm/px at 1280x960), given so the tracker knows its distance to the markers.
DEMO_CAMERA_HEIGHT_M = 0.82
#: The markers' plane above the ground for a robot lying on it, m: the 9 mm skeleton's top
#: face and the disc's 0.1 mm gap (softsnap_driver.sim_camera).
MARKER_PLANE_Z_M = 0.0091


def with_camera(specs: list, scene, camera_rate_hz: float = DEMO_CAMERA_RATE_HZ) -> list:
    """`specs` (robot_graph with physics) with sim_robot's camera on and the marker tracker.

    Raises ValueError when the graph has no sim_robot (``--camera`` needs ``--physics``).
    """
    from .graph import NodeSpec
    out = []
    sim = None
    for spec in specs:
        if spec.executable == 'sim_robot':
            spec = dataclasses.replace(spec, parameters={
                **spec.parameters, 'camera': True, 'camera_tags': True,
                'camera_rate_hz': float(camera_rate_hz),
                'camera_height_m': DEMO_CAMERA_HEIGHT_M,
                'ground_truth_rate_hz': float(camera_rate_hz) * _TRUTH_PER_FRAME})
            sim = spec
        elif spec.executable == 'rerun_logger':   # frames, detections, projected prediction
            spec = dataclasses.replace(spec, parameters={**spec.parameters, 'camera': True})
        elif spec.name == 'bag_recorder' and '--exclude' in spec.arguments:
            # Not the frames (3.7 MB each, 55 MB/s at 15 Hz): a reader that slow starves
            # the tracker's best-effort subscription of whole frames. camera_info, the
            # ground truth and the measured shapes are recorded.
            args = list(spec.arguments)
            at = args.index('--exclude') + 1
            args[at] = f'({args[at]})|(/camera/image_raw$)'
            spec = dataclasses.replace(spec, arguments=tuple(args))
        out.append(spec)
    if sim is None:
        raise ValueError('--camera renders the physics simulation: it needs --physics')
    tracker = NodeSpec('softsnap_vision', 'marker_tracker', 'marker_tracker', sim.namespace,
                       {'scene': sim.parameters['scene'], 'use_sim_time': True,
                        'plane_distance': DEMO_CAMERA_HEIGHT_M - MARKER_PLANE_Z_M,
                        # 20 mm tags are 28 px here: at half size two of the five are lost.
                        'tag_scale': 1.0, 'reliable_images': True},
                       # Its standard image_raw / camera_info names onto sim_robot's camera
                       # (rcl takes several --ros-args blocks).
                       arguments=('--ros-args', '-r', 'image_raw:=camera/image_raw',
                                  '-r', 'camera_info:=camera/camera_info'))
    # After sim_robot and before the gait: tracking from the robot's first frames.
    index = out.index(sim) + 1
    return out[:index] + [tracker] + out[index:]


def _stamp_ns(msg) -> int:
    return stamp_ns(msg.header.stamp)


def _points_mm(msg) -> np.ndarray:
    return np.array([[p.x, p.y] for p in msg.rib_centers], dtype=float).reshape(-1, 2) * 1e3


@dataclasses.dataclass
class _ModuleTrack:
    truth: dict = dataclasses.field(default_factory=dict)      # stamp ns -> (12, 2) mm
    measured: list = dataclasses.field(default_factory=list)   # (stamp ns, (12, 2) mm, visible)


class CameraObserver:
    """Frames and measured/true shapes seen by the demo's observer node (see module doc)."""

    def __init__(self, node, scene):
        from sensor_msgs.msg import CameraInfo
        from softsnap_interfaces.msg import MeasuredShape
        self.frame_stamps_ns: list[int] = []
        self.frame_wall_s: list[float] = []
        self.modules = {m.name: _ModuleTrack() for m in scene.modules}
        node.create_subscription(CameraInfo, 'camera/camera_info', self._frame, 100)
        for name, track in self.modules.items():
            node.create_subscription(MeasuredShape, f'{name}/shape/ground_truth',
                                     lambda msg, t=track: self._truth(t, msg), 200)
            node.create_subscription(MeasuredShape, f'{name}/shape/measured',
                                     lambda msg, t=track: self._measured(t, msg), 200)

    def _frame(self, msg) -> None:
        self.frame_stamps_ns.append(_stamp_ns(msg))
        self.frame_wall_s.append(time.monotonic())

    @staticmethod
    def _truth(track: _ModuleTrack, msg) -> None:
        track.truth[_stamp_ns(msg)] = _points_mm(msg)

    @staticmethod
    def _measured(track: _ModuleTrack, msg) -> None:
        track.measured.append((_stamp_ns(msg), _points_mm(msg), np.array(msg.visible, bool)))

    def ready(self) -> bool:
        """Frames arrive and the tracker measured every module at least once."""
        return bool(self.frame_stamps_ns) and all(t.measured for t in self.modules.values())

    def missing(self) -> list[str]:
        """What has not arrived yet (for the demo's start-up report)."""
        out = [] if self.frame_stamps_ns else ['camera/camera_info']
        return out + [f'{n}/shape/measured' for n, t in self.modules.items() if not t.measured]

    def _truth_behind(self, end_ns: int) -> bool:
        for track in self.modules.values():
            measured = [t for t, _p, _v in track.measured if t <= end_ns]
            if measured and max(track.truth, default=-1) < max(measured):
                return True
        return False

    def wait_for_truth(self, spin_for, end_ns: int, timeout_s: float = 20.0) -> None:
        """Spin (``spin_for(seconds)``) until every module's ground truth reaches its last
        measured shape up to `end_ns`, or `timeout_s` wall seconds pass: sim_robot's
        publishing thread ran seconds behind the tracker on the loaded machine, and the
        run's last frames had no truth yet when the gait stopped."""
        deadline = time.monotonic() + timeout_s
        while self._truth_behind(end_ns) and time.monotonic() < deadline:
            spin_for(0.1)

    def summary(self, window_ns) -> dict:
        """The summary's ``camera`` entry for the run window (stamps, ns)."""
        inside = [i for i, t in enumerate(self.frame_stamps_ns) if window_ns[0] <= t <= window_ns[1]]
        frames = len(inside)
        sim_s = (window_ns[1] - window_ns[0]) * 1e-9
        wall = [self.frame_wall_s[i] for i in inside]
        out = {'frames': frames,
               'fps': frames / sim_s if sim_s > 0 else None,
               'wall_fps': ((frames - 1) / (wall[-1] - wall[0])
                            if frames > 1 and wall[-1] > wall[0] else None),
               'modules': {}}
        for name, track in self.modules.items():
            errors, tracked, unmatched = [], 0, 0
            for stamp, points, visible in track.measured:
                if not window_ns[0] <= stamp <= window_ns[1] or not visible.any():
                    continue
                truth = track.truth.get(stamp)
                if truth is None or len(truth) != len(points):
                    unmatched += 1
                    continue
                tracked += 1
                errors.extend(np.linalg.norm(points[visible] - truth[visible], axis=1).tolist())
            out['modules'][name] = {
                'tracked_frames': tracked,
                'tracked_fraction': tracked / frames if frames else None,
                'rib_error_mm_mean': float(np.mean(errors)) if errors else None,
                'rib_error_mm_max': float(np.max(errors)) if errors else None,
                'unmatched': unmatched}
        return out


def print_camera(c: dict) -> None:
    """The camera lines of the demo's table."""
    fps = 'n/a' if c['fps'] is None else f"{c['fps']:.1f}"
    wall = 'n/a' if c['wall_fps'] is None else f"{c['wall_fps']:.1f}"
    print(f"camera: {c['frames']} frames, {fps} per simulated s ({wall} per wall s); "
          'tracked frames and rib error vs the simulator (mean/max mm):')
    for name, m in c['modules'].items():
        fraction = m['tracked_fraction']
        error = ('-' if m['rib_error_mm_mean'] is None
                 else f"{m['rib_error_mm_mean']:.2f}/{m['rib_error_mm_max']:.2f}")
        share = '-' if fraction is None or math.isnan(fraction) else f'{100 * fraction:.0f} %'
        print(f"  {name}: {m['tracked_frames']} ({share}), {error}")
