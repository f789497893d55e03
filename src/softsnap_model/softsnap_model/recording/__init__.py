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

Where each part lives: :mod:`.paths` (entity paths, timelines), :mod:`.style` (colours,
widths, legend, blueprints), :mod:`.stream` (open, serve, stamp, close), :mod:`.shapes`
(rib frames and cable in metres), :mod:`.log_entities` (one logging call per thing),
:mod:`.recorder` (:class:`RobotRecorder`, :class:`RateLimiter`), :mod:`.sweeps` (the
no-ROS writers) and :mod:`.cli` (the command line).
"""
from __future__ import annotations

from .cli import add_cli, add_record_arguments, main, run_record, serve_recording
from .log_entities import (log_base_poses, log_connector, log_legend, log_module_shape,
                           log_robot_pose, log_scalar, log_scene_setup, log_series_styles,
                           log_shape_styles, shape_colors)
from .paths import (APPLICATION_ID, LEGEND_ROOT, PLOTS_ROOT, ROBOT_ROOT, SOURCES, STEP_TIMELINE,
                    TIMELINE, module_path, plot_path, shape_path)
from .recorder import RateLimiter, RobotRecorder
from .shapes import (RIB_HALF_LENGTH_MM, RIB_SPACING_MM, RibFrames, cable_points_m, rib_centres_mm,
                     rib_frames, rib_segments_m, tip_error_mm)
from .stream import close_recording, open_recording, serve_web_viewer, set_stamp, time_column
from .style import (CABLE_RADIUS_M, CAMERA_HEIGHT_RADII, CAMERA_TILT_RAD, COMMANDED_BRIGHTNESS,
                    CONNECTOR_COLOR, GHOST_BASE, MODULE_PALETTE, NAMED_COLORS, RGB, RIB_RADIUS_M,
                    ROLE_DESCRIPTION, ROLE_WIDTH, SERIES_WIDTH, SIMULATED_SHADE, SPINE_RADIUS_M,
                    build_blueprint, build_sweep_blueprint, color_name, legend_markdown,
                    module_colors, robot_bounds_m, role_color, scene_style, shade, top_down_eye)
from .sweeps import Solve, forward_sweep_angles, parse_threading, record_sweep, record_threadings

__all__ = [
    'APPLICATION_ID',
    'CABLE_RADIUS_M',
    'CAMERA_HEIGHT_RADII',
    'CAMERA_TILT_RAD',
    'COMMANDED_BRIGHTNESS',
    'CONNECTOR_COLOR',
    'GHOST_BASE',
    'LEGEND_ROOT',
    'MODULE_PALETTE',
    'NAMED_COLORS',
    'PLOTS_ROOT',
    'RGB',
    'RIB_HALF_LENGTH_MM',
    'RIB_RADIUS_M',
    'RIB_SPACING_MM',
    'ROBOT_ROOT',
    'ROLE_DESCRIPTION',
    'ROLE_WIDTH',
    'RateLimiter',
    'RibFrames',
    'RobotRecorder',
    'SERIES_WIDTH',
    'SIMULATED_SHADE',
    'SOURCES',
    'SPINE_RADIUS_M',
    'STEP_TIMELINE',
    'Solve',
    'TIMELINE',
    'add_cli',
    'add_record_arguments',
    'build_blueprint',
    'build_sweep_blueprint',
    'cable_points_m',
    'close_recording',
    'color_name',
    'forward_sweep_angles',
    'legend_markdown',
    'log_base_poses',
    'log_connector',
    'log_legend',
    'log_module_shape',
    'log_robot_pose',
    'log_scalar',
    'log_scene_setup',
    'log_series_styles',
    'log_shape_styles',
    'main',
    'module_colors',
    'module_path',
    'open_recording',
    'parse_threading',
    'plot_path',
    'record_sweep',
    'record_threadings',
    'rib_centres_mm',
    'rib_frames',
    'rib_segments_m',
    'robot_bounds_m',
    'role_color',
    'run_record',
    'scene_style',
    'serve_recording',
    'serve_web_viewer',
    'set_stamp',
    'shade',
    'shape_colors',
    'shape_path',
    'time_column',
    'tip_error_mm',
    'top_down_eye',
]
