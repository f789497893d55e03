"""Standard ROS messages of the model node: markers, joint states and diagnostics.

Pure functions (numpy and message types, no rclpy) so that they are unit-tested without a
graph; :class:`softsnap_model.model_node.ModelNode` calls them from its timers.

Frames (REP 103): one frame per robot, named after the scene (the ``frame_id`` of
``RobotShape``). There is no tf tree on this stack, so every marker is expressed in that
frame: a module's marker carries the module's base pose as its ``pose`` and its points in
the module base frame (rib 0 at the origin, spine along +x, bending in the x-y plane), in
metres. A viewer whose Fixed Frame is the robot's name then draws the assembled robot.

Marker namespaces are ``<module>/<source>/<part>`` with part ``spine`` (LINE_STRIP through
the rib centres), ``ribs`` (LINE_LIST, one segment per rib) and ``cable`` (LINE_STRIP
through the threaded holes); ids are fixed per (module, source, part) (see
:func:`marker_id`), so each message replaces the previous one in the viewer.

Joint names are ``<module>/segment_<i>`` with i = 0 .. n_segments - 1: segment i bends
between rib i and rib i + 1, the index of ``ModuleShape.angles``.

Examples
--------
>>> import numpy as np
>>> parts = module_parts_m(np.zeros(2), [0.0, 1.0, 2.0], spacing_mm=18.0, rib_length_mm=25.0)
>>> parts.spine.tolist()
[[0.0, 0.0, 0.0], [0.018, 0.0, 0.0], [0.036, 0.0, 0.0]]
>>> joint_names('yellow', 2)
['yellow/segment_0', 'yellow/segment_1']
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Point, Pose
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker

from softsnap_ros.diagnostics import key_values

from . import geometry
from softsnap_ros.units import MM_PER_M, sec_nanosec

__all__ = ['SOURCE_COLORS', 'PARTS', 'LINE_WIDTH_M', 'ModuleParts', 'ModelHealth',
           'module_parts_m', 'module_markers', 'prediction_markers', 'robot_shape_markers', 'marker_id', 'joint_names', 'joint_states',
           'model_status', 'pose_msg', 'stamp_msg', 'MODEL_SLOW_SOLVE_FRACTION']


#: Colour (r, g, b, a in 0-1) of each source's spine and ribs; the cable is a darker shade.
SOURCE_COLORS: Mapping[str, tuple[float, float, float, float]] = {
    'commanded': (0.20, 0.50, 1.00, 1.0),   # blue: what the gait asked for
    'predicted': (1.00, 0.55, 0.10, 1.0),   # orange: the model from the measured length
    'simulated': (0.20, 0.80, 0.30, 1.0),   # green: the physics simulation
}
#: Brightness factor of the cable relative to its source's colour.
CABLE_SHADE = 0.6
#: Drawn parts of a module, in id order.
PARTS = ('spine', 'ribs', 'cable')
#: Line width of each part (m): Marker.scale.x of LINE_STRIP and LINE_LIST markers.
LINE_WIDTH_M = {'spine': 0.002, 'ribs': 0.0015, 'cable': 0.0008}
#: Source order in marker ids (any other source gets the next index).
_SOURCE_INDEX = {'commanded': 0, 'predicted': 1, 'simulated': 2}
#: Mean solve time above this fraction of the prediction period: the model node falls
#: behind the lengths it receives (WARN).
MODEL_SLOW_SOLVE_FRACTION = 0.5


@dataclass(frozen=True)
class ModuleParts:
    """Drawn geometry of one module shape in its base frame, in metres.

    spine: (n_ribs, 3) rib centres; ribs: (n_ribs, 2, 3) end points of each rib;
    cable: (n_ribs, 3) threaded holes, or None without a threading.
    """

    spine: np.ndarray
    ribs: np.ndarray
    cable: np.ndarray | None


def module_parts_m(angles_rad, threading_mm, *, spacing_mm: float, rib_length_mm: float,
                   rib_centers_mm=None) -> ModuleParts:
    """Spine, ribs and cable of one module (metres, module base frame).

    Parameters
    ----------
    angles_rad : array_like, shape (n_segments,)
        Bending angles (rad).
    threading_mm : array_like, shape (n_segments + 1,), or None
        Hole offset per rib (mm, positive to the right, -y); None draws no cable.
    spacing_mm, rib_length_mm : float
        Spine arc length between ribs and rib length (mm).
    rib_centers_mm : array_like, shape (n_segments + 1, 2 or 3), optional
        The solver's own rib centres (mm); used as given when present, so that the
        markers show exactly the points the model published.

    Raises
    ------
    ValueError
        Angles, threading or rib centres of inconsistent lengths, or non-finite values.
    """
    angles = np.asarray(angles_rad, dtype=float).reshape(-1)
    if not np.all(np.isfinite(angles)):
        raise ValueError(f'angles must be finite, got {angles.tolist()}')
    n_ribs = angles.size + 1
    centers, theta = geometry._rib_frames(angles, spacing_mm)
    if rib_centers_mm is not None:
        given = np.asarray(rib_centers_mm, dtype=float)
        if given.ndim != 2 or given.shape[0] != n_ribs or given.shape[1] not in (2, 3):
            raise ValueError(f'expected {n_ribs} rib centres of 2 or 3 coordinates for '
                             f'{angles.size} angles, got shape {given.shape}')
        centers = given[:, :2]
    spine = np.zeros((n_ribs, 3))
    spine[:, :2] = centers / MM_PER_M
    # Each rib runs across the spine: direction (-sin t, cos t), half its length each side.
    across = np.zeros((n_ribs, 3))
    across[:, 0], across[:, 1] = -np.sin(theta), np.cos(theta)
    half = 0.5 * rib_length_mm / MM_PER_M
    ribs = np.stack((spine + half * across, spine - half * across), axis=1)
    cable = None
    if threading_mm is not None:
        d = np.asarray(threading_mm, dtype=float).reshape(-1)
        if d.size != n_ribs:
            raise ValueError(f'expected {n_ribs} hole offsets (one per rib), got {d.size}')
        cable = spine - (d / MM_PER_M)[:, None] * across   # +d is the right side, -across
    return ModuleParts(spine=spine, ribs=ribs, cable=cable)


def marker_id(module_index: int, source: str, part: str) -> int:
    """Fixed marker id of one part: unique in a robot's MarkerArray, stable across messages."""
    source_index = _SOURCE_INDEX.get(source, len(_SOURCE_INDEX))
    return (module_index * 8 + source_index) * len(PARTS) + PARTS.index(part)


def stamp_msg(stamp_ns: int) -> Time:
    """builtin_interfaces/Time of a stamp in ns."""
    sec, nanosec = sec_nanosec(stamp_ns)
    return Time(sec=sec, nanosec=nanosec)


def _points(array: np.ndarray) -> list[Point]:
    return [Point(x=x, y=y, z=z) for x, y, z in array.reshape(-1, 3).tolist()]


def _color(source: str, factor: float = 1.0) -> ColorRGBA:
    r, g, b, a = SOURCE_COLORS.get(source, (0.7, 0.7, 0.7, 1.0))
    return ColorRGBA(r=r * factor, g=g * factor, b=b * factor, a=a)


def module_markers(parts: ModuleParts, *, frame_id: str, stamp: Time, module: str,
                   module_index: int, source: str, base_pose: Pose,
                   reuse: Sequence[Marker] = ()) -> list[Marker]:
    """LINE_STRIP spine, LINE_LIST ribs and LINE_STRIP cable of one module shape.

    The points stay in the module base frame; ``base_pose`` (the module base pose in
    ``frame_id``, metres) is each marker's pose, so the viewer places them on the robot.

    ``reuse``: markers this function returned before for the same module and source,
    already published (publishing serialises them): they are updated in place instead
    of building new ones, which saves about a third of the cost (a Marker holds ~20
    nested messages). Pass nothing when the old markers may still be read elsewhere.
    """
    old = {marker.ns: marker for marker in reuse}
    markers = []
    for part in PARTS:
        points = getattr(parts, part)
        if points is None:
            continue
        ns = f'{module}/{source}/{part}'
        marker = old.get(ns)
        if marker is None:
            marker = Marker()
            marker.ns = ns
            marker.id = marker_id(module_index, source, part)
            marker.type = Marker.LINE_LIST if part == 'ribs' else Marker.LINE_STRIP
            marker.action = Marker.ADD
            marker.scale.x = LINE_WIDTH_M[part]
            marker.color = _color(source, CABLE_SHADE if part == 'cable' else 1.0)
        marker.header.frame_id = frame_id
        marker.header.stamp = stamp
        marker.pose = base_pose
        marker.points = _points(points)
        markers.append(marker)
    return markers


def prediction_markers(shape, *, module_index: int, threading_mm, base_pose_m,
                       frame_id: str, spacing_mm: float, rib_length_mm: float,
                       reuse: Sequence[Marker] = ()) -> list[Marker]:
    """Markers of one :class:`~softsnap_model.predictor.ModulePrediction`.

    Its own rib centres when it has them (else from its angles), the cable through
    ``threading_mm``, at ``base_pose_m`` = (position m, quaternion xyzw) in ``frame_id``,
    stamped with the stamp of the length it was solved from. ``reuse``: see
    :func:`module_markers`.
    """
    parts = module_parts_m(shape.angles, threading_mm, spacing_mm=spacing_mm,
                           rib_length_mm=rib_length_mm, rib_centers_mm=shape.rib_centers_mm)
    return module_markers(parts, frame_id=frame_id, stamp=stamp_msg(shape.stamp_ns),
                          module=shape.module, module_index=module_index, source=shape.source,
                          base_pose=pose_msg(*base_pose_m), reuse=reuse)


def robot_shape_markers(msg, *, default_frame_id: str, module_names: Sequence[str],
                        threadings_mm: Mapping[str, Sequence[float]], spacing_mm: float,
                        rib_length_mm: float) -> tuple[list[Marker], list[str]]:
    """Markers of a ``softsnap_interfaces/RobotShape`` (a physics simulation's shapes).

    Each module's rib centres (m, module base frame; computed from its angles when
    empty) are drawn at its base pose, in the message's ``header.frame_id`` (else
    ``default_frame_id``). Modules of the scene (``module_names``) keep their ids; others
    get ids after them. The cable is drawn for modules with a known threading.

    Returns the markers and the problems found (a module that cannot be drawn is
    skipped, with the reason); never raises for a bad message.
    """
    if len(msg.base_poses) != len(msg.modules):
        return [], [f'RobotShape has {len(msg.modules)} modules but {len(msg.base_poses)} '
                    'base poses: not drawn']
    markers, problems = [], []
    frame_id = msg.header.frame_id or default_frame_id
    names = list(module_names)
    for i, (shape, pose) in enumerate(zip(msg.modules, msg.base_poses)):
        index = names.index(shape.module) if shape.module in names else len(names) + i
        centers = ([(p.x * MM_PER_M, p.y * MM_PER_M, p.z * MM_PER_M) for p in shape.rib_centers]
                   or None)
        try:
            parts = module_parts_m(shape.angles, threadings_mm.get(shape.module),
                                   spacing_mm=spacing_mm, rib_length_mm=rib_length_mm,
                                   rib_centers_mm=centers)
        except ValueError as error:
            problems.append(f'shape of {shape.module!r} not drawn: {error}')
            continue
        stamp = shape.header.stamp if (shape.header.stamp.sec or shape.header.stamp.nanosec) \
            else msg.header.stamp
        markers += module_markers(parts, frame_id=frame_id, stamp=stamp, module=shape.module,
                                  module_index=index, source=shape.source or 'simulated',
                                  base_pose=pose)
    return markers, problems


def pose_msg(position_m: Sequence[float], orientation_xyzw: Sequence[float]) -> Pose:
    """geometry_msgs/Pose from a position (m) and an xyzw quaternion."""
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position_m)
    (pose.orientation.x, pose.orientation.y, pose.orientation.z,
     pose.orientation.w) = (float(v) for v in orientation_xyzw)
    return pose


def joint_names(module: str, n_segments: int) -> list[str]:
    """``<module>/segment_<i>``, i = 0 .. n_segments - 1 (segment i: rib i to rib i + 1)."""
    return [f'{module}/segment_{i}' for i in range(n_segments)]


def joint_states(shapes: Iterable) -> list[JointState]:
    """JointState messages of new shapes, one per length stamp.

    ``shapes`` are objects with ``module``, ``angles`` (rad) and ``stamp_ns`` (the stamp
    of the length they were solved from), e.g.
    :class:`softsnap_model.predictor.ModulePrediction`. Shapes solved from lengths with
    the same stamp (a gait commands all modules at once) share one message; each
    message's ``header.stamp`` is that stamp, so a joint's position is never stamped
    with another length's time. Positions in rad; velocity and effort are left empty
    (unknown), as sensor_msgs/JointState allows.
    """
    by_stamp: dict[int, JointState] = {}
    for shape in shapes:
        msg = by_stamp.get(shape.stamp_ns)
        if msg is None:
            msg = by_stamp[shape.stamp_ns] = JointState()
            msg.header.stamp = stamp_msg(shape.stamp_ns)
        angles = np.asarray(shape.angles, dtype=float).tolist()
        msg.name.extend(joint_names(shape.module, len(angles)))
        msg.position.extend(angles)
    return [by_stamp[stamp] for stamp in sorted(by_stamp)]


@dataclass(frozen=True)
class ModelHealth:
    """Model-node counters at one diagnostics report (counts since start; time in s)."""

    solves: int
    skipped_unchanged: int
    skipped_duplicate: int
    skipped_rib_points: int
    refused: int
    service_calls: int
    service_failures: int
    mean_solve_time_s: float
    marker_arrays_published: int
    joint_states_published: int


def model_status(name: str, now: ModelHealth, before: ModelHealth | None,
                 prediction_period_s: float) -> DiagnosticStatus:
    """DiagnosticStatus of the model node from its counters now and at the last report.

    Levels (docs/diagnostics.md):

    - WARN: lengths refused since the last report (NaN, infinite, unknown module,
      unreachable or a length the solver refused); service calls failed since the last
      report; the mean solve time of the period above ``MODEL_SLOW_SOLVE_FRACTION`` of
      the prediction period (the node falls behind).
    - OK otherwise.
    """
    problems = []
    refused = now.refused - (before.refused if before else 0)
    if refused > 0:
        problems.append(f'{refused} length(s) refused since the last report')
    failures = now.service_failures - (before.service_failures if before else 0)
    if failures > 0:
        problems.append(f'{failures} service call(s) failed since the last report')
    if now.mean_solve_time_s > MODEL_SLOW_SOLVE_FRACTION * prediction_period_s:
        problems.append(f'mean solve time {now.mean_solve_time_s * 1e3:.3g} ms is above '
                        f'{MODEL_SLOW_SOLVE_FRACTION:g} of the prediction period '
                        f'{prediction_period_s * 1e3:.3g} ms')
    status = DiagnosticStatus(name=name, hardware_id='')
    status.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
    status.message = '; '.join(problems) if problems else 'ok'
    status.values = key_values({
        'solves': now.solves,
        'skipped unchanged': now.skipped_unchanged,
        'skipped duplicate': now.skipped_duplicate,
        'skipped rib points': now.skipped_rib_points,
        'refused': now.refused,
        'service calls': now.service_calls,
        'service failures': now.service_failures,
        'mean solve time (s)': float(now.mean_solve_time_s),
        'marker arrays published': now.marker_arrays_published,
        'joint states published': now.joint_states_published,
    })
    return status

