"""Rerun recordings of SoftSnap shapes: entity paths, blueprint, logging functions, writers.

This module has no ROS dependency. The ROS node ``softsnap_gaits.rerun_logger`` adapts
messages to :class:`RobotRecorder` calls; the command line (``python -m
softsnap_model.recording``) writes recordings of one module's workspace sweep or of a
comparison of threadings without ROS.

Frames and units (REP 103)
--------------------------
* The 3D scene is in metres. ``robot`` is the robot (connector) frame, x forward, y left,
  z up. ``robot/<module>`` carries the module base pose (a ``Transform3D`` from
  ``RobotShape.base_poses``, logged when it changes); below it everything is in the
  module base frame: rib 0 at the origin, spine along +x, bending in the x-y plane
  (positive angles counter-clockwise about +z).
* Plots carry their unit in the entity name (``tip_error_mm``, ``solve_time_ms``, ...).
* One timeline, ``ros_time``, a timestamp taken from the message header stamps. The
  no-ROS writers use a sequence timeline ``step`` instead.

With a physics simulation (``sim_robot``) the robot moves: ``robot`` carries the pose
of the robot base in the world (a ``Transform3D``, :func:`log_robot_pose`) and the 3D
view's origin is the world (``build_blueprint(world_view=True)``); the simulated shapes
(source ``simulated``) hang under the same module frames as the commanded and
predicted ones.

Entity tree (``<source>`` is ``commanded``, ``predicted`` or ``simulated``)::

    robot                                   view coordinates (static)
    robot/connector                         module base positions, labelled (static)
    robot/<module>                          base pose, Transform3D (logged on change)
    robot/<module>/<source>/spine           spine through the rib centres, LineStrips3D
    robot/<module>/<source>/ribs            one 25 mm strip per rib, LineStrips3D
    robot/<module>/<source>/cable           cable through its holes (needs a threading)
    plots/cable_length_mm/<module>/commanded|measured
    plots/tip_error_mm/<module>             commanded versus predicted tip distance
    plots/solve_time_ms/<module>/<source>
    plots/battery_v/<module>

Plots are grouped by quantity first because a blueprint view selects a subtree
(``plots/tip_error_mm/**``); rerun's path filters have no wildcard for one level.
"""
from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence
from urllib.parse import quote

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from . import geometry
from .rrd_check import require_recording
from .skeleton import Skeleton

APPLICATION_ID = 'softsnap'
TIMELINE = 'ros_time'
STEP_TIMELINE = 'step'
ROBOT_ROOT = 'robot'
PLOTS_ROOT = 'plots'
SOURCES = ('commanded', 'predicted', 'simulated')

# Drawing defaults of the authors' module, in millimetres (from the one Skeleton definition).
RIB_SPACING_MM = Skeleton().spacing_mm
RIB_HALF_LENGTH_MM = Skeleton().rib_length_mm / 2.0

# Colour is identity, style is role. Each module keeps one hue everywhere (3D shapes and
# every plot): its scene colour (the paper's module colours), else its name when that
# is a colour, else the next free colour of MODULE_PALETTE. What a line is (commanded,
# predicted, measured) is shown by saturation and width, never by hue: the commanded
# shape (the target) is a thin muted "ghost" of the module's colour, the predicted shape
# (from the measured length: where the module is) is bold in its full colour. So a
# module called "blue" is blue and nothing else is.
NAMED_COLORS = {
    'blue': (40, 110, 240), 'orange': (245, 130, 20), 'green': (40, 175, 70),
    'red': (225, 45, 45), 'purple': (160, 85, 230), 'yellow': (235, 200, 0),
    'cyan': (0, 190, 210), 'magenta': (225, 60, 190), 'brown': (160, 100, 50),
    'grey': (150, 150, 150),
}
MODULE_PALETTE = ('blue', 'orange', 'green', 'red', 'purple', 'yellow', 'cyan', 'magenta',
                  'brown', 'grey')
#: Share of the module colour kept in a commanded (target) line; the rest is a middle
#: grey, so the target reads as a muted ghost of the bold predicted shape on the light
#: and on the dark viewer theme alike.
COMMANDED_BRIGHTNESS = 0.55
GHOST_BASE = (128, 128, 128)
#: Role styles: width factor of each role's lines (1 = bold). Plots use the same rule:
#: a commanded series is dim and thin, a measured or predicted series full and thick.
ROLE_WIDTH = {'commanded': 0.45, 'predicted': 1.0, 'measured': 1.0, 'simulated': 0.7}
ROLE_DESCRIPTION = {'commanded': 'thin, muted: the commanded shape or length (the target)',
                    'predicted': 'bold, full colour: the shape predicted from the measured '
                                 'length (where the module is)',
                    'measured': 'bold, full colour: the measured length',
                    'simulated': 'medium, dark shade: the shape simulated in MuJoCo '
                                 '(gravity, contact, dynamics)'}
#: Share of the module colour kept in a simulated line (a darker shade of it).
SIMULATED_SHADE = 0.6
CONNECTOR_COLOR = (110, 110, 110)
# Line radii in metres of the bold (predicted) role.
SPINE_RADIUS_M = 0.0022
RIB_RADIUS_M = 0.0009
CABLE_RADIUS_M = 0.0005
#: Series line widths in UI points of the bold role (plots).
SERIES_WIDTH = 2.5

MM = 1e-3  # metres per millimetre


# --- entity paths -----------------------------------------------------------------------

def module_path(module: str) -> str:
    """Entity carrying the base pose of ``module``: ``robot/<module>``."""
    _check_name(module)
    return f'{ROBOT_ROOT}/{module}'


@functools.lru_cache(maxsize=4096)  # called for every row: the paths are few
def shape_path(module: str, source: str, part: str) -> str:
    """Entity of one drawn part (spine, ribs, cable) of a module's shape."""
    if source not in SOURCES:
        raise ValueError(f'source must be one of {SOURCES}, got {source!r}')
    return f'{module_path(module)}/{source}/{part}'


@functools.lru_cache(maxsize=4096)
def plot_path(quantity: str, module: str, *series: str) -> str:
    """Entity of a time series: ``plots/<quantity>/<module>[/<series>]``.

    For example ``plot_path('cable_length_mm', 'red', 'measured')``.
    """
    _check_name(module)
    return '/'.join((PLOTS_ROOT, quantity, module, *series))


def _check_name(module: str) -> None:
    if not module or '/' in module or module.strip() != module:
        raise ValueError(f'module name must be a non-empty word without "/", got {module!r}')


# --- colours and styles -----------------------------------------------------------------

RGB = tuple[int, int, int]


def module_colors(modules: Iterable[tuple[str, str]]) -> dict[str, RGB]:
    """Display colour of each module from (name, scene colour) pairs, in order.

    The scene colour wins if it is a known colour name (NAMED_COLORS), then the module's
    name if it is one; other modules take the next palette colour no module uses yet.

    >>> module_colors([('head', ''), ('body2', ''), ('blue', '')])
    {'head': (245, 130, 20), 'body2': (40, 175, 70), 'blue': (40, 110, 240)}
    """
    pairs = list(modules)
    chosen: dict[str, str | None] = {}
    for name, color in pairs:
        for candidate in (str(color or '').strip().lower(), name.lower()):
            if candidate in NAMED_COLORS:
                chosen[name] = candidate
                break
        else:
            chosen[name] = None
    used = {c for c in chosen.values() if c}
    free = [c for c in MODULE_PALETTE if c not in used] or list(MODULE_PALETTE)
    k = 0
    for name in chosen:
        if chosen[name] is None:
            chosen[name] = free[k % len(free)]
            k += 1
    return {name: NAMED_COLORS[c] for name, c in chosen.items()}


def color_name(rgb: RGB) -> str:
    """Name of a NAMED_COLORS colour (for legends); '' for any other."""
    return next((n for n, c in NAMED_COLORS.items() if c == tuple(rgb)), '')


def role_color(rgb: RGB, role: str) -> RGB:
    """The colour a role draws a module in: full colour, or a muted ghost for commanded."""
    if role not in ROLE_WIDTH:
        raise ValueError(f'role must be one of {tuple(ROLE_WIDTH)}, got {role!r}')
    if role == 'simulated':
        return shade(rgb, SIMULATED_SHADE)
    if role != 'commanded':
        return tuple(int(c) for c in rgb)
    a = COMMANDED_BRIGHTNESS
    return tuple(int(round(a * c + (1.0 - a) * g)) for c, g in zip(rgb, GHOST_BASE))


def shade(rgb: RGB, factor: float) -> RGB:
    """A darker shade (factor < 1) of a colour, for the cable inside the skeleton."""
    return tuple(int(round(c * factor)) for c in rgb)


def robot_bounds_m(points_m: Iterable[Sequence[float]]) -> tuple[tuple[float, float, float], float]:
    """(centre, radius) in metres of a set of points: what the default camera frames."""
    pts = np.asarray([[float(v) for v in p] for p in points_m], dtype=float).reshape(-1, 3)
    if pts.size == 0:
        raise ValueError('robot_bounds_m needs at least one point, got none')
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    radius = float(np.linalg.norm(pts - centre, axis=1).max())
    return tuple(float(c) for c in centre), max(radius, 0.05)


def scene_style(scene) -> tuple[dict[str, RGB], tuple[tuple[float, float, float], float]]:
    """Module colours and robot bounds of a softsnap_model Scene (all modules straight)."""
    from .scene import straight_tip_pose
    colors = module_colors((m.name, m.color) for m in scene.modules)
    points = [m.base_position_m for m in scene.modules]
    points += [straight_tip_pose(m, scene.skeleton)[0] for m in scene.modules]
    return colors, robot_bounds_m(points)


# --- blueprint --------------------------------------------------------------------------

#: The default camera looks down on the robot from this far above the centre of its
#: bounds, in bound radii (the 3D view is about as wide as tall; 55 degree field of view),
#: tilted this far from the vertical so the orbit keeps z up.
CAMERA_HEIGHT_RADII = 2.1
CAMERA_TILT_RAD = math.radians(12.0)
LEGEND_ROOT = 'legend'


def top_down_eye(bounds: tuple[Sequence[float], float]) -> rrb.EyeControls3D:
    """Orbital camera above the centre of `bounds` (centre m, radius m), looking down."""
    centre, radius = bounds
    height = CAMERA_HEIGHT_RADII * radius
    position = (centre[0], centre[1] - height * math.tan(CAMERA_TILT_RAD), centre[2] + height)
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position,
                             look_target=tuple(centre), eye_up=(0.0, 0.0, 1.0))


def build_blueprint(colors: Mapping[str, RGB] | None = None,
                    bounds: tuple[Sequence[float], float] | None = None,
                    world_view: bool = False) -> rrb.Blueprint:
    """The layout: the robot in 3D and the legend on the left, the time series on the right.

    One plot per quantity; each takes a quantity subtree, so one blueprint fits every robot
    and module count. The plots draw no legend of their own (with ten series it would
    cover the data): the legend view names every module's colour and every role's style,
    and hovering a line names its series. With `bounds` (centre m, radius m: see
    `scene_style`) the 3D view starts looking down on the whole robot. With `world_view`
    the 3D view's origin is the world (the recording root) rather than the robot, so a
    robot whose ``robot`` transform moves (:func:`log_robot_pose`) is seen moving.
    """
    def plot(title: str, quantity: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=title, origin=f'{PLOTS_ROOT}/{quantity}',
                                  plot_legend=rrb.PlotLegend(visible=False))

    plots = rrb.Vertical(
        plot('Cable length (mm): commanded thin, measured bold', 'cable_length_mm'),
        plot('Tip error, commanded vs predicted (mm)', 'tip_error_mm'),
        plot('Solver time (ms): commanded thin, predicted bold', 'solve_time_ms'),
        plot('Battery (V)', 'battery_v'),
    )
    # The world view adds only what differs, so other recordings keep their view as is.
    world = {'origin': '/', 'contents': f'{ROBOT_ROOT}/**'} if world_view else {'origin': ROBOT_ROOT}
    scene = rrb.Spatial3DView(
        name='Robot from above: commanded thin and muted, predicted bold',
        eye_controls=None if bounds is None else top_down_eye(bounds), **world)
    legend = rrb.TextDocumentView(name='Legend', origin=LEGEND_ROOT)
    left = rrb.Vertical(scene, legend, row_shares=[4, 1])
    return rrb.Blueprint(rrb.Horizontal(left, plots, column_shares=[3, 2]),
                         collapse_panels=True)


def build_sweep_blueprint() -> rrb.Blueprint:
    """Layout of the no-ROS recordings: shapes in 3D, the swept quantities below."""
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Spatial3DView(name='Shapes', origin=ROBOT_ROOT),
            rrb.Horizontal(
                rrb.TimeSeriesView(name='Contraction (mm)', origin=f'{PLOTS_ROOT}/contraction_mm'),
                rrb.TimeSeriesView(name='Tip angle (deg)', origin=f'{PLOTS_ROOT}/tip_angle_deg'),
            ),
            row_shares=[3, 1],
        ),
        collapse_panels=True,
    )


# --- recording streams ------------------------------------------------------------------

def open_recording(output: str | Path | None = None, viewer_url: str | None = None, *,
                   serve_grpc_port: int | None = None, serve_bind_ip: str = '127.0.0.1',
                   blueprint: rrb.Blueprint | None = None,
                   application_id: str = APPLICATION_ID,
                   recording_id: str | None = None) -> rr.RecordingStream:
    """A recording stream writing to any of: a file, a running viewer, a hosted server.

    Parameters
    ----------
    output:
        .rrd file; its parent directories are created.
    viewer_url:
        rerun gRPC address of a running viewer, e.g. ``rerun+http://127.0.0.1:9876/proxy``.
    serve_grpc_port, serve_bind_ip:
        Host a gRPC server on this port that viewers (native, or the web viewer started
        with :func:`serve_web_viewer`) connect to. It keeps up to 1 GiB for late viewers.

    At least one sink must be given. Close the stream with :func:`close_recording` so the
    file gets its footer.
    """
    sinks = []
    if output is not None:
        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(output)))
    if viewer_url:
        sinks.append(rr.GrpcSink(viewer_url))
    if serve_grpc_port:
        sinks.append(rr.GrpcServerSink(bind_ip=serve_bind_ip, port=int(serve_grpc_port)))
    if not sinks:
        raise ValueError('open_recording needs an output file, a viewer_url or a '
                         'serve_grpc_port')
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    rec.set_sinks(*sinks, default_blueprint=blueprint)
    return rec


def serve_web_viewer(web_port: int, grpc_port: int, host: str = '127.0.0.1') -> str:
    """Serve rerun's bundled web viewer (offline) pointed at a gRPC server; returns its url."""
    grpc_url = f'rerun+http://{host}:{int(grpc_port)}/proxy'
    rr.serve_web_viewer(web_port=int(web_port), open_browser=False, connect_to=grpc_url)
    return f'http://{host}:{int(web_port)}/?url={quote(grpc_url, safe="")}'


def close_recording(rec: rr.RecordingStream, timeout_s: float = 10.0) -> None:
    """Flush everything logged so far and close the sinks (the file gets its footer)."""
    rec.flush(timeout_sec=timeout_s)
    rec.disconnect()


def set_stamp(rec: rr.RecordingStream, stamp_ns: int, sim_time: bool = False) -> None:
    """Set the ``ros_time`` timeline for this thread: a timestamp (nanoseconds since the
    epoch), or with `sim_time` a duration (nanoseconds of simulated time, shown as
    seconds from the simulation's start rather than as a date in January 1970)."""
    if sim_time:
        rec.set_time(TIMELINE, duration=np.timedelta64(int(stamp_ns), 'ns'))
    else:
        rec.set_time(TIMELINE, timestamp=np.datetime64(int(stamp_ns), 'ns'))


def time_column(stamps_ns, sim_time: bool = False) -> rr.TimeColumn:
    """The ``ros_time`` column of `stamps_ns`, as `set_stamp` sets it."""
    if sim_time:
        return rr.TimeColumn(TIMELINE, duration=np.array(stamps_ns, dtype='timedelta64[ns]'))
    return rr.TimeColumn(TIMELINE, timestamp=np.array(stamps_ns, dtype='datetime64[ns]'))


# --- geometry helpers (module base frame) -----------------------------------------------

@dataclass(frozen=True)
class RibFrames:
    """Rib centres (n, 3) in metres and spine headings (n,) in radians, rib 0 first."""

    centres_m: np.ndarray
    headings_rad: np.ndarray


def _as_vector(values, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f'{name} must be a flat sequence, got shape {arr.shape}')
    if not np.isfinite(arr).all():
        raise ValueError(f'{name} must be finite, got {arr.tolist()}')
    return arr


def rib_centres_mm(angles_rad: Sequence[float], spacing_mm: float = RIB_SPACING_MM
                   ) -> np.ndarray:
    """Rib centres (n + 1, 2) in mm of a module with bending angles ``angles_rad`` (n)."""
    return np.asarray(geometry.rib_centers(_as_vector(angles_rad, 'angles_rad'), spacing_mm),
                      dtype=float)


def rib_frames(angles_rad: Sequence[float], rib_centres_m: np.ndarray | None = None,
               spacing_mm: float = RIB_SPACING_MM) -> RibFrames:
    """Rib frames from a message's angles, using its rib centres (m) when it has them."""
    angles = _as_vector(angles_rad, 'angles_rad')
    headings = np.concatenate(([0.0], np.cumsum(angles)))
    if rib_centres_m is not None and len(rib_centres_m):
        centres = np.asarray(rib_centres_m, dtype=float).reshape(-1, 3)
        if len(centres) != len(headings):
            raise ValueError(f'expected {len(headings)} rib centres for {len(angles)} angles, '
                             f'got {len(centres)}')
    else:
        planar = rib_centres_mm(angles, spacing_mm) * MM
        centres = np.column_stack((planar, np.zeros(len(planar))))
    return RibFrames(centres, headings)


def rib_segments_m(frames: RibFrames) -> np.ndarray:
    """End points (n, 2, 3) of each rib: centre -/+ 12.5 mm along (-sin t, cos t)."""
    t = frames.headings_rad
    half = RIB_HALF_LENGTH_MM * MM * np.column_stack((-np.sin(t), np.cos(t), np.zeros_like(t)))
    return np.stack((frames.centres_m + half, frames.centres_m - half), axis=1)


def cable_points_m(frames: RibFrames, threading_mm: Sequence[float]) -> np.ndarray:
    """Cable holes (n, 3): hole offset d (mm, + = right) on rib k is P_k + d (sin t, -cos t).

    The cable is taut, so it runs straight from hole to hole and the polyline through the
    holes is the cable path.
    """
    d = _as_vector(threading_mm, 'threading_mm') * MM
    t = frames.headings_rad
    if len(d) != len(t):
        raise ValueError(f'expected {len(t)} hole offsets (one per rib), got {len(d)}')
    return frames.centres_m + np.column_stack((d * np.sin(t), -d * np.cos(t), np.zeros_like(t)))


def tip_error_mm(commanded: RibFrames, predicted: RibFrames) -> float:
    """Distance between the last rib centres of two shapes of one module, in mm."""
    return float(np.linalg.norm(commanded.centres_m[-1] - predicted.centres_m[-1]) / MM)


# --- logging functions (one per data source) --------------------------------------------

def log_scene_setup(rec: rr.RecordingStream) -> None:
    """Static view coordinates of the robot frame (REP 103: x forward, y left, z up)."""
    rec.log(ROBOT_ROOT, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)


def log_series_styles(rec: rr.RecordingStream, module: str, color: RGB) -> None:
    """Static names, colours and widths of a module's time series.

    The module's colour on every series; the role by brightness and width (commanded
    dim and thin, measured/predicted full and bold).
    """
    for quantity, series in (('cable_length_mm', 'commanded'), ('cable_length_mm', 'measured'),
                             ('solve_time_ms', 'commanded'), ('solve_time_ms', 'predicted')):
        rec.log(plot_path(quantity, module, series),
                rr.SeriesLines(names=[f'{module} {series}'], colors=[role_color(color, series)],
                               widths=[SERIES_WIDTH * ROLE_WIDTH[series]]), static=True)
    for quantity in ('tip_error_mm', 'battery_v'):
        rec.log(plot_path(quantity, module),
                rr.SeriesLines(names=[module], colors=[color], widths=[SERIES_WIDTH]),
                static=True)


def legend_markdown(colors: Mapping[str, RGB]) -> str:
    """The legend's text: which colour is which module, which style is which role, and
    the series of every plot (the plots draw no legend of their own)."""
    modules = ', '.join(f'**{name}** {color_name(rgb) or "rgb" + str(tuple(rgb))}'
                        if color_name(rgb) != name else f'**{name}**'
                        for name, rgb in colors.items())
    return (f'**Colour = module** (named at its base in 3D): {modules}.  \n'
            '**Style = role:** thin, muted = commanded (the target); bold, full colour = '
            'predicted from the measured length (3D, solver time) or measured (cable length).'
            f'  \n**Plots** (hover a line for its name): cable length, commanded and measured '
            f'of each module ({2 * len(colors)} lines); tip error ({len(colors)}); solver '
            f'time, commanded and predicted ({2 * len(colors)}); battery ({len(colors)}).')


def log_legend(rec: rr.RecordingStream, colors: Mapping[str, RGB]) -> None:
    """Static legend text (markdown) for the legend view; see `legend_markdown`."""
    if colors:
        rec.log(LEGEND_ROOT, rr.TextDocument(legend_markdown(colors),
                                             media_type=rr.MediaType.MARKDOWN), static=True)


def log_base_poses(rec: rr.RecordingStream,
                   poses: Mapping[str, tuple[Sequence[float], Sequence[float]]], *,
                   static: bool = False) -> None:
    """Module base transforms: ``poses`` maps module name to (translation_m xyz,
    quaternion xyzw) of the module base frame in the robot frame.

    Temporal by default, so chains whose bases move with their parents replay correctly
    (static data would shadow every later pose).
    """
    for module, (translation, quaternion) in poses.items():
        rec.log(module_path(module),
                rr.Transform3D(translation=[float(v) for v in translation],
                               quaternion=rr.Quaternion(xyzw=[float(v) for v in quaternion])),
                static=static)


def log_robot_pose(rec: rr.RecordingStream, translation: Sequence[float],
                   quaternion_xyzw: Sequence[float]) -> None:
    """Pose of the robot frame in the world (translation m, quaternion xyzw), temporal."""
    rec.log(ROBOT_ROOT, rr.Transform3D(translation=[float(v) for v in translation],
                                       quaternion=rr.Quaternion(xyzw=[float(v) for v in quaternion_xyzw])))


def log_connector(rec: rr.RecordingStream, positions_m: Mapping[str, Sequence[float]],
                  colors: Mapping[str, RGB] | None = None) -> None:
    """Static markers where the modules attach to the connector, labelled by module and
    drawn in the module's colour (grey without colours)."""
    if positions_m:
        colors = colors or {}
        rec.log(f'{ROBOT_ROOT}/connector',
                rr.Points3D([[float(v) for v in p] for p in positions_m.values()],
                            radii=0.004, labels=list(positions_m),
                            colors=[colors.get(m, CONNECTOR_COLOR) for m in positions_m]),
                static=True)


def shape_colors(color: RGB, source: str) -> dict[str, RGB]:
    """Colours of the spine, ribs and cable of a module's `source` shape.

    Spine and ribs in the role's colour (`role_color`), the cable a darker shade of it.
    """
    base = role_color(color, source)
    return {'spine': base, 'ribs': base, 'cable': shade(base, 0.6)}


def log_shape_styles(rec: rr.RecordingStream, module: str, source: str,
                     cable: bool = True, color: RGB = NAMED_COLORS['blue']) -> None:
    """Static colours and radii of a shape's strips, logged once per module and source.

    The module's colour, styled by role (see `shape_colors`, `ROLE_WIDTH`). Per-frame logs
    then carry the points only (about half the bytes and time per frame).
    """
    colors = shape_colors(color, source)
    width = ROLE_WIDTH[source]
    parts = [('spine', SPINE_RADIUS_M), ('ribs', RIB_RADIUS_M)]
    if cable:
        parts.append(('cable', CABLE_RADIUS_M))
    for part, radius in parts:
        rec.log(shape_path(module, source, part),
                rr.LineStrips3D.from_fields(colors=[colors[part]], radii=[radius * width]),
                static=True)


def log_module_shape(rec: rr.RecordingStream, module: str, source: str, frames: RibFrames,
                     threading_mm: Sequence[float] | None = None) -> None:
    """Spine, ribs and (given a threading) cable of one shape, at the current time.

    Colours and radii come from :func:`log_shape_styles`.
    """
    rec.log(shape_path(module, source, 'spine'),
            rr.LineStrips3D.from_fields(strips=[frames.centres_m]))
    rec.log(shape_path(module, source, 'ribs'),
            rr.LineStrips3D.from_fields(strips=rib_segments_m(frames)))
    if threading_mm is not None:
        rec.log(shape_path(module, source, 'cable'),
                rr.LineStrips3D.from_fields(strips=[cable_points_m(frames, threading_mm)]))


def log_scalar(rec: rr.RecordingStream, path: str, value: float) -> None:
    """One sample of a time series; NaN (for example no target yet) is skipped."""
    if math.isfinite(value):
        rec.log(path, rr.Scalars(float(value)))


# --- the recorder the ROS node drives ---------------------------------------------------

class _ArrowBatch:
    """A component batch (rerun's ComponentBatchLike) over a ready arrow array."""

    def __init__(self, array):
        self._array = array

    def as_arrow_array(self):
        return self._array


def _strips_column(strips: np.ndarray) -> rr.ComponentColumn:
    """The LineStrips3D:strips column of ``strips`` (rows, k, m, 3), k strips of m points a
    row, built as arrow arrays in a few numpy calls: what ``LineStrips3D.columns(...)
    .partition(...)`` builds, which walks the strips one by one in Python (about two thirds
    of a flush's CPU)."""
    rows, k, m = strips.shape[:3]
    points = pa.array(np.ascontiguousarray(strips, dtype=np.float32).reshape(-1))
    points = pa.FixedSizeListArray.from_arrays(points, type=_STRIP_TYPE.value_type)
    lines = pa.ListArray.from_arrays(pa.array(np.arange(0, rows * k * m + 1, m, dtype=np.int32)),
                                     points, type=_STRIP_TYPE)
    return rr.ComponentColumn(_STRIPS_DESCRIPTOR, _ArrowBatch(lines),
                              offsets=np.arange(0, rows * k + 1, k, dtype=np.int32))


# The columns' descriptors and the strips' arrow type, as rerun's own archetypes build them.
_SCALARS_DESCRIPTOR = next(iter(rr.Scalars.columns(scalars=np.zeros(1)))).descriptor
_STRIPS_DESCRIPTOR, _STRIP_TYPE = (lambda column: (
    column.descriptor, column.component_batch.as_arrow_array().type))(
    next(iter(rr.LineStrips3D.columns(strips=np.zeros((1, 2, 3))))))


class RateLimiter:
    """At most ``rate_hz`` events per key, measured on the events' own time stamps.

    ``rate_hz = 0`` lets everything through. Stamps going backwards (a replayed bag, a
    restarted clock) reset the key.
    """

    def __init__(self, rate_hz: float):
        if not (rate_hz >= 0.0 and math.isfinite(rate_hz)):
            raise ValueError(f'rate_hz must be finite and >= 0, got {rate_hz!r}')
        self.period_ns = int(1e9 / rate_hz) if rate_hz > 0 else 0
        self._last: dict[object, int] = {}

    def allow(self, key: object, stamp_ns: int) -> bool:
        last = self._last.get(key)
        if last is not None and last <= stamp_ns < last + self.period_ns:
            return False
        self._last[key] = stamp_ns
        return True


class RobotRecorder:
    """Logs a robot's shapes, cable lengths and module states to one recording stream.

    Parameters
    ----------
    rec:
        The recording stream (see :func:`open_recording`).
    modules:
        Names of the modules to log (the scene's); ``None`` logs every module seen.
    threadings_mm:
        Hole offsets per rib (mm) by module name, for drawing the cable; optional.
    rate_hz:
        Largest logging rate per module and data source (0: log everything).
    spacing_mm:
        Spine arc length between ribs, used when a message carries no rib centres.
    colors:
        Display colour (RGB) by module name (see `module_colors`, `scene_style`); modules
        without one take the next free palette colour when first seen.
    flush_period_s:
        0 logs every row at once (``rec.log``). Above 0, rows wait in per-entity buffers
        and go out as columns (one ``send_columns`` per entity) at most this long after
        the first of them, in seconds: a ``rec.log`` of a line strip costs about 1 ms of
        Python on the development machine, a row of a column batch about 10 µs. The
        recording holds the same rows, stamps and values either way; call :meth:`flush`
        (or :meth:`flush_if_due` from a timer) so the rows reach the sinks.
    skip_unchanged:
        A shape equal to the one last logged for its module and source (same angles and
        rib centres: the model node re-sends unchanged modules in every RobotShape) is
        not logged again, and counted in ``unchanged``; the viewer keeps showing the
        latest shape, so the picture is the same.
    clock:
        Monotonic clock (s) deciding when buffers are due.
    sim_time:
        The stamps are simulated time (a node on ``use_sim_time``): the timeline is a
        duration in seconds from the simulation's start, not a date (`set_stamp`).
    """

    def __init__(self, rec: rr.RecordingStream, *, modules: Iterable[str] | None = None,
                 threadings_mm: Mapping[str, Sequence[float]] | None = None,
                 rate_hz: float = 30.0, spacing_mm: float = RIB_SPACING_MM,
                 colors: Mapping[str, RGB] | None = None, flush_period_s: float = 0.0,
                 skip_unchanged: bool = False, clock: Callable[[], float] = time.monotonic,
                 sim_time: bool = False):
        if not (math.isfinite(flush_period_s) and flush_period_s >= 0.0):
            raise ValueError(f'flush_period_s must be finite and >= 0, got {flush_period_s!r}')
        self.rec = rec
        self.colors: dict[str, RGB] = dict(colors or {})
        self.modules = None if modules is None else frozenset(modules)
        self.threadings_mm = {m: np.asarray(t, dtype=float)
                              for m, t in (threadings_mm or {}).items()}
        self.spacing_mm = spacing_mm
        self.limiter = RateLimiter(rate_hz)
        self.flush_period_s = float(flush_period_s)
        self.skip_unchanged = bool(skip_unchanged)
        self.sim_time = bool(sim_time)
        self.logged = 0
        self.dropped = 0
        self.unchanged = 0
        self._clock = clock
        self._poses: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {}
        # (module, source) -> (rib count, last rib centre (m)) of the latest shape, logged
        # or not: the other source's tip error is measured against it.
        self._latest_tip: dict[tuple[str, str], tuple[int, np.ndarray]] = {}
        self._last_input: dict[tuple[str, str], tuple] = {}  # (angles, centres) last logged
        self._styled: set[object] = set()
        # entity path -> ('scalar' | 'strips', stamps ns, values), oldest row first.
        self._buffers: dict[str, tuple[str, list[int], list]] = {}
        # (module, source) -> (stamps ns, rib centres (n, 3) m, angles (n - 1,) rad) of
        # buffered shapes: their strips are computed at flush, for all rows at once.
        self._shape_buffers: dict[tuple[str, str], tuple[list[int], list, list]] = {}
        self._first_buffered = math.inf  # clock time of the oldest buffered row
        log_scene_setup(rec)
        if self.colors:
            log_legend(rec, self.colors)

    def color(self, module: str) -> RGB:
        """The module's display colour; a new module takes the next free palette colour
        (and the legend is redrawn with it)."""
        if module not in self.colors:
            pairs = [(m, color_name(c)) for m, c in self.colors.items()] + [(module, '')]
            self.colors[module] = module_colors(pairs)[module]
            log_legend(self.rec, self.colors)
        return self.colors[module]

    def wants(self, module: str) -> bool:
        """True if ``module`` belongs to the logged set."""
        return self.modules is None or module in self.modules

    def _admit(self, module: str, stream: str, stamp_ns: int) -> bool:
        if not self.wants(module):
            return False
        if not self.limiter.allow((module, stream), stamp_ns):
            self.dropped += 1
            return False
        if module not in self._styled:
            self._styled.add(module)
            log_series_styles(self.rec, module, self.color(module))
        self.logged += 1
        if not self.flush_period_s:
            set_stamp(self.rec, stamp_ns, self.sim_time)
        return True

    # --- rows: logged at once, or buffered and sent as columns ----------------------------

    def _row(self, path: str, kind: str, stamp_ns: int, value) -> None:
        """One temporal row; ``value`` a float (scalar) or an (k, m, 3) array of k strips."""
        if not self.flush_period_s:
            if kind == 'scalar':
                log_scalar(self.rec, path, value)
            else:
                self.rec.log(path, rr.LineStrips3D.from_fields(strips=value))
            return
        if kind == 'scalar' and not math.isfinite(value):
            return  # as log_scalar: no sample for NaN (no target yet)
        buffer = self._buffers.get(path)
        if buffer is None:
            buffer = self._buffers[path] = (kind, [], [])
            if self._first_buffered == math.inf:
                self._first_buffered = self._clock()
        buffer[1].append(stamp_ns)
        buffer[2].append(value)

    def flush_if_due(self) -> None:
        """:meth:`flush` if the oldest buffered row waited ``flush_period_s`` or longer."""
        if self._clock() - self._first_buffered >= self.flush_period_s:
            self.flush()

    def flush(self) -> None:
        """Send every buffered row: one ``send_columns`` per entity, rows in arrival order."""
        shapes, self._shape_buffers = self._shape_buffers, {}
        for (module, source), (stamps, centres, angles) in shapes.items():
            for part, strips in self._shape_strips(module, centres, angles):
                self._buffers[shape_path(module, source, part)] = ('strips', stamps, strips)
        buffers, self._buffers = self._buffers, {}
        self._first_buffered = math.inf
        for path, (kind, stamps, values) in buffers.items():
            index = [time_column(stamps, self.sim_time)]
            if kind == 'scalar':
                columns = [rr.ComponentColumn(  # as Scalars.columns(...) builds it, minus its
                    _SCALARS_DESCRIPTOR,        # per-call archetype machinery
                    _ArrowBatch(pa.array(np.array(values, dtype=np.float64))))]
            elif isinstance(values, np.ndarray):  # (rows, k, m, 3): k strips of m points a row
                columns = [_strips_column(values)]
            else:
                counts = [len(v) for v in values]
                if len({v.shape[1:] for v in values}) == 1:
                    strips = np.concatenate(values)  # (sum k, m, 3): one array, fast
                else:  # strips of different lengths (a module's rib count changed)
                    strips = [strip for v in values for strip in v]
                columns = rr.LineStrips3D.columns(strips=strips).partition(counts)
            self.rec.send_columns(path, indexes=index, columns=columns)

    def _shape_strips(self, module: str, centres: list[np.ndarray], angles: list[np.ndarray]
                      ) -> list[tuple[str, np.ndarray | list[np.ndarray]]]:
        """(part, strips) of buffered shapes, strips (rows, k, m, 3) or one (k, m, 3) array
        per row: the values of `rib_segments_m` and `cable_points_m` row by row, computed
        for all rows with one numpy call per step (a row at a time took ~10 calls a shape)."""
        threading = self.threadings_mm.get(module)
        if len({len(c) for c in centres}) > 1:  # the module's rib count changed: row by row
            frames = [RibFrames(c, np.concatenate(([0.0], np.cumsum(a))))
                      for c, a in zip(centres, angles)]
            parts = [('spine', [f.centres_m[None] for f in frames]),
                     ('ribs', [rib_segments_m(f) for f in frames])]
            if threading is not None:
                parts.append(('cable', [cable_points_m(f, threading)[None] for f in frames]))
            return parts
        c = np.stack(centres)  # (rows, n, 3)
        t = np.zeros(c.shape[:2])
        np.cumsum(np.stack(angles), axis=1, out=t[:, 1:])  # spine headings, rad
        sin_t, cos_t = np.sin(t), np.cos(t)
        half = RIB_HALF_LENGTH_MM * MM
        offset = np.stack((-half * sin_t, half * cos_t, np.zeros_like(t)), axis=-1)
        ribs = np.stack((c + offset, c - offset), axis=2)  # (rows, n, 2, 3)
        parts = [('spine', c[:, None]), ('ribs', ribs)]
        if threading is not None:
            d = threading * MM
            cable = c + np.stack((d * sin_t, -d * cos_t, np.zeros_like(t)), axis=-1)
            parts.append(('cable', cable[:, None]))
        return parts

    # --- data sources ---------------------------------------------------------------------

    def base_poses(self, stamp_ns: int,
                   poses: Mapping[str, tuple[Sequence[float], Sequence[float]]]) -> None:
        """Module base poses (translation m, quaternion xyzw) in the robot frame.

        A module's transform is logged when it first appears and whenever it changes; the
        connector markers (static) come from the first poses seen.
        """
        changed = {}
        for module, (p, q) in poses.items():
            pose = (tuple(map(float, p)), tuple(map(float, q)))
            if self.wants(module) and self._poses.get(module) != pose:
                changed[module] = pose
        if not changed:
            return
        if not self._poses:
            log_connector(self.rec, {m: p for m, (p, _) in changed.items()},
                          {m: self.color(m) for m in changed})
        self._poses.update(changed)
        set_stamp(self.rec, stamp_ns, self.sim_time)
        log_base_poses(self.rec, changed)

    def shape(self, stamp_ns: int, module: str, source: str, angles_rad: Sequence[float],
              rib_centres_m: np.ndarray | None = None, solve_time_s: float | None = None
              ) -> bool:
        """One shape of one module; returns False if skipped (other module, rate limit,
        or unchanged with ``skip_unchanged``)."""
        if not self.wants(module):
            return False
        key = (module, source)
        angles = _as_vector(angles_rad, 'angles_rad')
        centres = (None if rib_centres_m is None or not len(rib_centres_m) else
                   np.asarray(rib_centres_m, dtype=float).reshape(-1, 3))
        if self.skip_unchanged:
            given = (angles.tobytes(), None if centres is None else centres.tobytes())
            if self._last_input.get(key) == given:
                self.unchanged += 1
                return False
        if centres is None:
            planar = rib_centres_mm(angles, self.spacing_mm) * MM
            centres = np.column_stack((planar, np.zeros(len(planar))))
        elif len(centres) != len(angles) + 1:
            raise ValueError(f'expected {len(angles) + 1} rib centres for {len(angles)} '
                             f'angles, got {len(centres)}')
        threading = self.threadings_mm.get(module)
        if threading is not None and len(threading) != len(centres):
            raise ValueError(f'{module}: expected {len(centres)} hole offsets (one per rib), '
                             f'got {len(threading)}')
        self._latest_tip[key] = (len(centres), centres[-1])
        if not self._admit(module, source, stamp_ns):
            return False
        if self.skip_unchanged:
            self._last_input[key] = given
        if key not in self._styled:
            self._styled.add(key)
            log_shape_styles(self.rec, module, source, module in self.threadings_mm,
                             self.color(module))
        if self.flush_period_s:  # strips computed at flush, for all buffered rows at once
            buffer = self._shape_buffers.get(key)
            if buffer is None:
                buffer = self._shape_buffers[key] = ([], [], [])
                if self._first_buffered == math.inf:
                    self._first_buffered = self._clock()
            buffer[0].append(stamp_ns)
            buffer[1].append(centres)
            buffer[2].append(angles)
        else:
            frames = RibFrames(centres, np.concatenate(([0.0], np.cumsum(angles))))
            self._row(shape_path(module, source, 'spine'), 'strips', stamp_ns,
                      frames.centres_m[None])
            self._row(shape_path(module, source, 'ribs'), 'strips', stamp_ns,
                      rib_segments_m(frames))
            if threading is not None:
                self._row(shape_path(module, source, 'cable'), 'strips', stamp_ns,
                          cable_points_m(frames, threading)[None])
        if solve_time_s is not None:
            self._row(plot_path('solve_time_ms', module, source), 'scalar', stamp_ns,
                      solve_time_s * 1e3)
        # The tip error plot compares the model's two shapes (the latest of the other one,
        # logged or not); a simulated one has no partner.
        other = (None if source == 'simulated' else
                 self._latest_tip.get((module, 'predicted' if source == 'commanded'
                                       else 'commanded')))
        if other is not None and other[0] == len(centres):
            tip = centres[-1] - other[1] if source == 'commanded' else other[1] - centres[-1]
            self._row(plot_path('tip_error_mm', module), 'scalar', stamp_ns,
                      float(np.linalg.norm(tip) / MM))
        if self.flush_period_s:
            self.flush_if_due()
        return True

    def robot_pose(self, stamp_ns: int, translation: Sequence[float],
                   quaternion_xyzw: Sequence[float]) -> bool:
        """The robot base in the world (simulated robots), rate-limited like a shape."""
        if not self.limiter.allow(('robot', 'pose'), stamp_ns):
            self.dropped += 1
            return False
        self.logged += 1
        set_stamp(self.rec, stamp_ns, self.sim_time)
        log_robot_pose(self.rec, translation, quaternion_xyzw)
        return True

    def cable_length(self, stamp_ns: int, module: str, kind: str, length_m: float) -> bool:
        """A commanded or measured cable length (m), plotted in mm."""
        if kind not in ('commanded', 'measured'):
            raise ValueError(f'kind must be "commanded" or "measured", got {kind!r}')
        if not self._admit(module, f'cable_length/{kind}', stamp_ns):
            return False
        self._row(plot_path('cable_length_mm', module, kind), 'scalar', stamp_ns, length_m / MM)
        if self.flush_period_s:
            self.flush_if_due()
        return True

    def module_state(self, stamp_ns: int, module: str, battery_v: float) -> bool:
        """A driver state report (battery voltage, V)."""
        if not self._admit(module, 'state', stamp_ns):
            return False
        self._row(plot_path('battery_v', module), 'scalar', stamp_ns, float(battery_v))
        if self.flush_period_s:
            self.flush_if_due()
        return True


# --- no-ROS writers ---------------------------------------------------------------------

Solve = Callable[[Sequence[float], Sequence[float]], np.ndarray]
"""``solve(threading_mm, contractions_mm) -> angles_rad`` of shape (len(contractions), n)."""


def forward_sweep_angles(threading_mm: Sequence[float], contractions_mm: Sequence[float]
                         ) -> np.ndarray:
    """Angles (rad) of the solver core's quasi-static sweep, authors' skeleton."""
    from softsnap_model.forward import sweep

    return np.asarray(sweep(Skeleton(), list(threading_mm), list(contractions_mm)).angles)


def _write_shapes(path: str | Path, shapes: Mapping[str, Sequence[Sequence[float]]],
                  threadings_mm: Mapping[str, Sequence[float]],
                  contractions_mm: Sequence[float], spacing_mm: float,
                  row_spacing_m: float) -> Path:
    """Log pre-solved shapes: ``shapes[name][i]`` are the angles at ``contractions_mm[i]``."""
    path = Path(path)
    rec = open_recording(path, blueprint=build_sweep_blueprint())
    try:
        log_scene_setup(rec)
        poses = {name: ((0.0, -row_spacing_m * i, 0.0), (0.0, 0.0, 0.0, 1.0))
                 for i, name in enumerate(shapes)}
        log_base_poses(rec, poses, static=True)
        colors = module_colors((name, '') for name in shapes)
        log_connector(rec, {name: p for name, (p, _) in poses.items()}, colors)
        for name in shapes:
            log_shape_styles(rec, name, 'predicted', name in threadings_mm, colors[name])
        tips: dict[str, list[np.ndarray]] = {name: [] for name in shapes}
        for step, contraction in enumerate(contractions_mm):
            rec.set_time(STEP_TIMELINE, sequence=step)
            for name, series in shapes.items():
                frames = rib_frames(series[step], None, spacing_mm)
                log_module_shape(rec, name, 'predicted', frames, threadings_mm.get(name))
                tips[name].append(frames.centres_m[-1])
                log_scalar(rec, plot_path('contraction_mm', name), contraction)
                log_scalar(rec, plot_path('tip_angle_deg', name),
                           math.degrees(frames.headings_rad[-1]))
        for name, points in tips.items():
            # The workspace: where the tip goes over the whole sweep.
            rec.log(f'{module_path(name)}/workspace/tip_path',
                    rr.LineStrips3D([np.asarray(points)], radii=SPINE_RADIUS_M / 4,
                                    colors=[shade(colors[name], 0.6)]), static=True)
    finally:
        close_recording(rec)
    return path


def record_sweep(path: str | Path, threading_mm: Sequence[float],
                 contractions_mm: Sequence[float], *, solve: Solve | None = None,
                 module: str = 'module', spacing_mm: float = RIB_SPACING_MM) -> Path:
    """Write a recording of one module's shapes over a sweep of cable contractions.

    Step ``i`` of the ``step`` timeline shows the shape at ``contractions_mm[i]`` (mm of
    cable pulled in); the tip path over the whole sweep is logged static. ``solve``
    defaults to the solver core's forward sweep (:func:`forward_sweep_angles`).

    Examples
    --------
    >>> record_sweep('sweep.rrd', parse_threading('R3x12'), [0.0, 20.0, 40.0])  # doctest: +SKIP
    """
    angles = (solve or forward_sweep_angles)(threading_mm, contractions_mm)
    return _write_shapes(path, {module: angles}, {module: threading_mm}, contractions_mm,
                         spacing_mm, row_spacing_m=0.0)


def record_threadings(path: str | Path, threadings_mm: Mapping[str, Sequence[float]],
                      contractions_mm: Sequence[float], *, solve: Solve | None = None,
                      spacing_mm: float = RIB_SPACING_MM, row_spacing_m: float = 0.25
                      ) -> Path:
    """Write a recording comparing threadings side by side over the same contractions.

    Each threading is drawn as a module named by its key, placed ``row_spacing_m`` apart
    along -y, all stepping through ``contractions_mm`` together.
    """
    solve = solve or forward_sweep_angles
    shapes = {name: solve(t, contractions_mm) for name, t in threadings_mm.items()}
    return _write_shapes(path, shapes, threadings_mm, contractions_mm, spacing_mm,
                         row_spacing_m)


# --- command line -----------------------------------------------------------------------

def parse_threading(text: str, skeleton: Skeleton | None = None) -> list[float]:
    """Hole offsets (mm) from names: ``"R1 R1 R2 ..."``, ``"R3x6 L3x6"`` or ``"R3x12"``."""
    from softsnap_model.cli import parse_threading as parse_words

    return (skeleton or Skeleton()).threading_mm(parse_words(text)).tolist()


def add_record_arguments(parser: argparse.ArgumentParser):
    """Arguments of the ``record`` command (for a ``softsnap-model record`` subcommand).

    Returns the subparsers object so callers can add more commands beside these.
    """
    sub = parser.add_subparsers(dest='what', required=True)
    sweep = sub.add_parser('sweep', help="one module's shapes over a range of contractions")
    sweep.add_argument('--threading', required=True, help='e.g. "R3x12" or "R1 R1 ... R3"')
    compare = sub.add_parser('threadings', help='several threadings side by side')
    compare.add_argument('--threading', action='append', required=True, metavar='NAME=HOLES',
                         help='repeat per threading, e.g. --threading s="R3x6 L3x6"')
    for p in (sweep, compare):
        p.add_argument('--max-contraction-mm', type=float, default=40.0,
                       help='largest cable contraction of the sweep (mm, default 40)')
        p.add_argument('--steps', type=int, default=41, help='number of contractions (41)')
        p.add_argument('--out', required=True, help='.rrd file to write')
    return sub


def run_record(args: argparse.Namespace) -> Path:
    """Carry out a parsed ``record`` command; returns the path written."""
    if args.steps < 1 or not args.max_contraction_mm >= 0.0:
        raise ValueError(f'need steps >= 1 and max contraction >= 0 mm, got {args.steps} '
                         f'and {args.max_contraction_mm}')
    contractions = np.linspace(0.0, args.max_contraction_mm, args.steps).tolist()
    if args.what == 'sweep':
        path = record_sweep(args.out, parse_threading(args.threading), contractions)
    else:
        named = {}
        for item in args.threading:
            name, sep, holes = item.partition('=')
            if not sep:
                raise ValueError(f'expected NAME=HOLES, got {item!r}')
            named[name.strip()] = parse_threading(holes)
        path = record_threadings(args.out, named, contractions)
    return path


def add_cli(subparsers):
    """Register ``softsnap-model record {sweep,threadings}`` (see :mod:`softsnap_model.cli`)."""
    parser = subparsers.add_parser(
        'record', help='write a rerun recording without ROS (a sweep, or threadings compared)')
    add_record_arguments(parser)
    parser.set_defaults(handler=_cli_handler)


def _cli_handler(args: argparse.Namespace, skeleton) -> dict:
    if skeleton != Skeleton():
        raise ValueError('record draws the authors\' module only; --skeleton is not supported')
    return {'recording': str(run_record(args).resolve()), 'steps': args.steps}


def serve_recording(path: str | Path, *, web_port: int = 9090, grpc_port: int = 9876,
                    online: bool = False) -> tuple[str, rr.RecordingStream]:
    """Serve an .rrd file to rerun's bundled web viewer; returns (url, stream).

    The viewer's files come from the installed rerun-sdk; a browser opening the url gets
    the recording over gRPC from this process. Keep the returned stream (and the process)
    alive while the page is open. Unless `online`, nothing leaves this machine: no
    analytics, no web fonts, no examples list (:mod:`softsnap_model.viewer_offline`).
    """
    path = Path(path)
    require_recording(path)   # not a recording: a ValueError; cut short or damaged: a warning
    if not online:
        from . import viewer_offline
        viewer_offline.disable_analytics()   # before rerun's native side starts its sinks
    rec = rr.RecordingStream(f'{APPLICATION_ID}_view')
    rec.serve_grpc(grpc_port=grpc_port)
    rec.log_file_from_path(path)
    if online:
        return serve_web_viewer(web_port, grpc_port), rec
    grpc_url = f'rerun+http://127.0.0.1:{int(grpc_port)}/proxy'
    return viewer_offline.serve_offline(web_port, grpc_url), rec


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m softsnap_model.recording {sweep,threadings,view} ...``."""
    parser = argparse.ArgumentParser(prog='python -m softsnap_model.recording',
                                     description='Write or view rerun recordings without ROS.')
    sub = add_record_arguments(parser)
    view = sub.add_parser('view', help="serve an .rrd to rerun's web viewer (offline)")
    view.add_argument('file', help='.rrd recording')
    view.add_argument('--web-port', type=int, default=9090)
    view.add_argument('--grpc-port', type=int, default=9876)
    view.add_argument('--online', action='store_true',
                      help="rerun's defaults: its analytics, web fonts and examples list "
                           '(default: offline, nothing leaves this machine)')
    args = parser.parse_args(argv)
    try:
        if args.what != 'view':
            print(f'wrote {run_record(args)}')
            return 0
        url, _stream = serve_recording(args.file, web_port=args.web_port,
                                       grpc_port=args.grpc_port, online=args.online)
        print(f'open {url}  (Ctrl-C to stop)', flush=True)
        try:
            # Short sleeps: a Ctrl-C the kernel hands to one of rerun's threads only sets
            # Python's flag, and a long sleep of the main thread would not see it for an
            # hour (a test saw `view` ignore SIGINT that way).
            while True:
                time.sleep(0.2)
        except KeyboardInterrupt:
            return 0
    except (ValueError, RuntimeError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
