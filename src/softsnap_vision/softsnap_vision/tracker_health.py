"""The marker tracker's DiagnosticStatus messages: one for the camera input, one per module.

No rclpy (diagnostic_msgs only). Levels (docs/vision.md, Diagnostics):

camera ``softsnap/<robot>/marker_tracker/camera``:
- STALE: no camera_info yet, or no image for ``stale_after_s``;
- WARN: images refused since the last report (encoding, size, data), or tracking failed;
- OK otherwise.

module ``softsnap/<robot>/<module>/camera``:
- STALE: the module's tag not seen for ``stale_after_s`` (or never);
- WARN: seen, but its frame could not be set up, or fewer than ``MIN_VISIBLE_RIBS`` ribs;
- OK otherwise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticStatus

from softsnap_ros.diagnostics import key_values

__all__ = ['CameraCounters', 'ModuleCounters', 'camera_status', 'module_status',
           'MIN_VISIBLE_RIBS', 'status_name']

#: Fewer seen ribs than this in the last frame is a WARN (the shape is poorly measured).
MIN_VISIBLE_RIBS = 8


def status_name(namespace: str, *parts: str) -> str:
    robot = namespace.strip('/')
    return '/'.join(p for p in ('softsnap', robot, *parts) if p)


@dataclass
class CameraCounters:
    """What the node counted about its input (monotonic times in s)."""

    frames: int = 0
    frames_tracked: int = 0
    refused: int = 0
    failures: int = 0
    last_problem: str = ''
    last_image_at: float = -math.inf
    camera_info: bool = False
    processing_s: float = 0.0        # sum over frames_tracked
    rib_markers_found: int = 0       # in the last frame
    tags_found: int = 0              # in the last frame
    unknown_tags: tuple = ()


@dataclass
class ModuleCounters:
    tracked_frames: int = 0
    last_seen_at: float = -math.inf
    visible_ribs: int = 0
    rmse_to_model_m: float = math.nan
    residual_m: float = math.nan
    error: str = ''
    extra: dict = field(default_factory=dict)


def camera_status(name: str, now: CameraCounters, before: CameraCounters | None, now_s: float,
                  period_s: float, stale_after_s: float) -> DiagnosticStatus:
    status = DiagnosticStatus(name=name, hardware_id='camera')
    frames = now.frames - (before.frames if before else 0)
    tracked = now.frames_tracked - (before.frames_tracked if before else 0)
    refused = now.refused - (before.refused if before else 0)
    failures = now.failures - (before.failures if before else 0)
    age = now_s - now.last_image_at
    problems = []
    if not now.camera_info:
        status.level = DiagnosticStatus.STALE
        problems.append('no camera_info yet')
    elif age > stale_after_s:
        status.level = DiagnosticStatus.STALE
        problems.append('no image yet' if now.frames == 0 else f'no image for {age:.1f} s')
    else:
        status.level = DiagnosticStatus.OK
    if refused or failures:
        if status.level == DiagnosticStatus.OK:
            status.level = DiagnosticStatus.WARN
        problems.append(f'{refused + failures} image(s) not tracked since the last report: '
                        f'{now.last_problem}')
    status.message = '; '.join(problems) if problems else 'ok'
    status.values = key_values({
        'frame rate (Hz)': float(frames / period_s) if period_s > 0 else 0.0,
        'tracked frame rate (Hz)': float(tracked / period_s) if period_s > 0 else 0.0,
        'frames (count)': now.frames,
        'frames tracked (count)': now.frames_tracked,
        'images refused (count)': now.refused,
        'tracking failures (count)': now.failures,
        'mean processing time (ms)': (float(1e3 * now.processing_s / now.frames_tracked)
                                      if now.frames_tracked else 0.0),
        'rib markers found (count)': now.rib_markers_found,
        'tags found (count)': now.tags_found,
        'unknown tags': ' '.join(map(str, now.unknown_tags)) or 'none',
        'image age (s)': float(age) if math.isfinite(age) else 'never',
        'last problem': now.last_problem or 'none',
    })
    return status


def module_status(name: str, module: str, c: ModuleCounters, now_s: float,
                  stale_after_s: float) -> DiagnosticStatus:
    status = DiagnosticStatus(name=name, hardware_id=module)
    age = now_s - c.last_seen_at
    if age > stale_after_s:
        status.level = DiagnosticStatus.STALE
        status.message = ('tag never seen' if not math.isfinite(age)
                          else f'tag not seen for {age:.1f} s')
    elif c.error:
        status.level = DiagnosticStatus.WARN
        status.message = c.error
    elif c.visible_ribs < MIN_VISIBLE_RIBS:
        status.level = DiagnosticStatus.WARN
        status.message = f'only {c.visible_ribs} ribs seen (fewer than {MIN_VISIBLE_RIBS})'
    else:
        status.level = DiagnosticStatus.OK
        status.message = 'ok'
    status.values = key_values({
        'tracked frames (count)': c.tracked_frames,
        'visible ribs (count)': c.visible_ribs,
        'rmse to model (m)': float(c.rmse_to_model_m),
        'fit residual (m)': float(c.residual_m),
        'last seen (s ago)': float(age) if math.isfinite(age) else 'never',
    })
    return status
