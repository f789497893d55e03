"""Recordings without ROS: one module's workspace sweep and a comparison of threadings."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
import rerun as rr

from ..skeleton import Skeleton
from .log_entities import (log_base_poses, log_connector, log_module_shape, log_scalar,
                           log_scene_setup, log_shape_styles)
from .paths import STEP_TIMELINE, module_path, plot_path
from .shapes import RIB_SPACING_MM, rib_frames
from .stream import close_recording, open_recording
from .style import SPINE_RADIUS_M, build_sweep_blueprint, module_colors, shade

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


def parse_threading(text: str, skeleton: Skeleton | None = None) -> list[float]:
    """Hole offsets (mm) from names: ``"R1 R1 R2 ..."``, ``"R3x6 L3x6"`` or ``"R3x12"``."""
    from softsnap_model.cli import parse_threading as parse_words

    return (skeleton or Skeleton()).threading_mm(parse_words(text)).tolist()
