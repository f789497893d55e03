"""Logging one thing to a recording: scene setup, styles, legend, poses, shapes, scalars,
and the Arrow columns the batched logger sends."""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
import pyarrow as pa
import rerun as rr

from .paths import LEGEND_ROOT, ROBOT_ROOT, module_path, plot_path, shape_path
from .shapes import RibFrames, cable_points_m, rib_segments_m
from .style import (CABLE_RADIUS_M, CONNECTOR_COLOR, NAMED_COLORS, RGB, RIB_RADIUS_M, ROLE_WIDTH,
                    SERIES_WIDTH, SPINE_RADIUS_M, legend_markdown, role_color, shade)


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
