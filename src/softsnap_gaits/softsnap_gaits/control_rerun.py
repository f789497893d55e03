"""Rerun entities of the shape controller (no rclpy): target, measured and predicted shape
per module, and the error over time.

Entities (module base frame, metres; the ``ros_time`` timeline of softsnap_model.recording):

    control/<module>/target          Points3D, the target points
    control/<module>/measured        LineStrips3D, the measured rib centres
    control/<module>/predicted       LineStrips3D, the model's shape at the command
    control/<module>/error_mm        Scalars, the target's error (mm)
    control/<module>/command_mm      Scalars, the commanded cable length (mm)
    control/<module>/correction_mm   Scalars, command minus feedforward (mm)

One thread at a time (the node calls it under its lock or from one callback): rerun's
current time is per thread, so every log sets it first.
"""
from __future__ import annotations

import math
import threading

import numpy as np
import rerun as rr

from softsnap_model.recording import close_recording, open_recording, set_stamp

#: Shapes are logged at most this often per module (s of the stamps): a 20 Hz controller
#: would otherwise write 20 strips a second per module for no visible gain.
SHAPE_PERIOD_S = 0.1


def _xyz(points_m) -> np.ndarray:
    pts = np.asarray(points_m, dtype=float)[:, :2]
    return np.column_stack([pts, np.zeros(len(pts))])


class ControlRecorder:
    """Writes the controller's entities to a .rrd file."""

    def __init__(self, path: str, robot: str):
        self.rec = open_recording(path, application_id=f'softsnap_control_{robot}')
        self._last_shape = {}
        self._lock = threading.Lock()

    def _due(self, key, time_s) -> bool:
        last = self._last_shape.get(key)
        if last is not None and time_s - last < SHAPE_PERIOD_S:
            return False
        self._last_shape[key] = time_s
        return True

    def measured(self, module: str, time_s: float, ribs_m) -> None:
        with self._lock:
            if not self._due((module, 'measured'), time_s):
                return
            set_stamp(self.rec, int(time_s * 1e9))
            self.rec.log(f'control/{module}/measured', rr.LineStrips3D([_xyz(ribs_m)]))

    def step(self, module: str, time_s: float, target_m, step, predicted_m) -> None:
        with self._lock:
            set_stamp(self.rec, int(time_s * 1e9))
            for name, value in (('error_mm', step.error_m), ('command_mm', step.command_m),
                                ('correction_mm', step.correction_m)):
                if value is not None and math.isfinite(value):
                    self.rec.log(f'control/{module}/{name}', rr.Scalars(value * 1e3))
            if self._due((module, 'shapes'), time_s):
                self.rec.log(f'control/{module}/target', rr.Points3D(_xyz(target_m)))
                self.rec.log(f'control/{module}/predicted',
                             rr.LineStrips3D([_xyz(predicted_m)]))

    def close(self) -> None:
        with self._lock:
            close_recording(self.rec)
