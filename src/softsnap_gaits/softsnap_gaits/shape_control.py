"""Closed-loop shape control of one SoftSnap module (plain numpy/scipy, no rclpy).

A module has one cable, so its cable length is its only input: the shapes it can take
form a one-parameter family. A target (rib centres, or a tip position, in the module
base frame) is reached in the least-squares sense:

- **Feedforward**: the model's inverse for the target, the cable length whose predicted
  shape is closest to it (:meth:`ShapeModel.closest_length`: a coarse sweep of the
  reachable range, then a bounded Brent search). A target whose closest predicted shape
  is farther than ``ControllerConfig.max_model_miss_m`` is refused with that distance.
- **Feedback**: each new measurement gives the error ``e = target - measured`` over the
  visible points; the model's sensitivity ``J = d(points)/d(cable length)`` at the current
  command turns it into a length correction ``(J . e) / (J . J)`` (Gauss-Newton on the
  one input), integrated with gain ``integral_gain_per_s`` per second of measurement
  time. With the model's sensitivity off by a factor ``r`` the loop still converges for
  ``0 < r < 2 / (gain dt)``: a wrong model changes the speed, not the end point.
- **Bounds**: the command stays inside the reachable range (the solver's, cut by the
  scene's ``max_contraction_mm``) and moves at most ``max_speed_m_s`` (a fraction of the
  winch speed) per second. Anti-windup by back-calculation: the integrator is reset to
  what was actually commanded, so a saturated command never stores correction it cannot
  apply.
- **Staleness**: a measurement older than ``stale_after_s`` (or none yet) holds the last
  command and reports ``STALE``; nothing is integrated from it.
- **Tolerance and timeout**: the target is ``REACHED`` once its error stays within the
  tolerance for ``settle_window_s`` of measurement time; ``TIMED_OUT`` after its timeout
  (the last command is held, integration stops).

Units: metres (m) and seconds (s) at this interface; the model works in millimetres
inside (softsnap_model's convention). Times are whatever clock the caller uses (the
node's ROS clock), consistently.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from softsnap_model.forward import InfeasibleLengthError, reachable_range, solve_forward
from softsnap_model.loads import Loads, solve_loaded

#: Target kinds.
TARGET_RIBS, TARGET_TIP = 'ribs', 'tip'
#: Controller states (strings, so they go into messages and logs as they are).
IDLE, CONVERGING, REACHED, STALE, TIMED_OUT = ('idle', 'converging', 'reached', 'stale',
                                              'timed_out')
#: Largest tolerance (m) and timeout (s) a target may ask for.
MAX_TOLERANCE_M, MAX_TIMEOUT_S = 0.05, 600.0
#: Margin (m) kept from the shortest reachable length: there the tension grows without
#: bound (every segment at rib contact).
RANGE_MARGIN_M = 0.0005
#: Finite-difference step (m) of the model's sensitivity.
SENSITIVITY_STEP_M = 0.0002
#: The sensitivity is recomputed when the command moved farther than this (m).
SENSITIVITY_REUSE_M = 0.001
#: Sweep points of the feedforward's coarse search over the reachable range.
FEEDFORWARD_SWEEP = 33


class TargetError(ValueError):
    """A target refused: the message says why (NaN, wrong size, unreachable, ...)."""


@dataclass(frozen=True)
class ShapeTarget:
    """A validated target of one module.

    Attributes
    ----------
    kind : str
        ``'ribs'`` (every rib centre) or ``'tip'`` (the last rib's centre).
    points_m : ndarray (k, 2)
        Target points in the module base frame (m): k = n_ribs for ``'ribs'``, 1 for
        ``'tip'``.
    tolerance_m : float
        Error (m) within which the target counts as reached: the tip distance for
        ``'tip'``, the RMS over the ribs for ``'ribs'``.
    timeout_s : float
        Time (s) after which an unreached target stops being pursued.
    name : str
        A label (a named shape, or empty).
    """

    kind: str
    points_m: np.ndarray
    tolerance_m: float
    timeout_s: float
    name: str = ''


def make_target(kind: str, points_m, n_ribs: int, *, tolerance_m: float = 0.001,
                timeout_s: float = 10.0, name: str = '') -> ShapeTarget:
    """Validate a target; raise :class:`TargetError` with the reason otherwise.

    ``points_m`` holds (x, y) or (x, y, z) rows in metres; z is ignored (the module bends
    in its x-y plane). For ``'tip'`` one row; for ``'ribs'`` one row per rib.
    """
    if kind not in (TARGET_RIBS, TARGET_TIP):
        raise TargetError(f"target kind must be 'ribs' or 'tip', got {kind!r}")
    try:
        pts = np.asarray(points_m, dtype=float)
    except (TypeError, ValueError):
        raise TargetError(f'target points must be numbers (m), got {points_m!r}') from None
    if pts.ndim == 1:
        pts = pts[None, :]
    expected = n_ribs if kind == TARGET_RIBS else 1
    if pts.ndim != 2 or pts.shape[0] != expected or pts.shape[1] not in (2, 3):
        raise TargetError(f'a {kind!r} target needs {expected} point(s) of 2 or 3 '
                          f'coordinates (m), got shape {pts.shape}')
    if not np.all(np.isfinite(pts)):
        raise TargetError('target points must be finite (m): NaN or inf refused')
    if not (isinstance(tolerance_m, (int, float)) and math.isfinite(tolerance_m)
            and 0.0 < tolerance_m <= MAX_TOLERANCE_M):
        raise TargetError(f'tolerance must be in (0, {MAX_TOLERANCE_M}] m, got '
                          f'{tolerance_m!r}')
    if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s)
            and 0.0 < timeout_s <= MAX_TIMEOUT_S):
        raise TargetError(f'timeout must be in (0, {MAX_TIMEOUT_S:g}] s, got {timeout_s!r}')
    return ShapeTarget(kind, pts[:, :2].copy(), float(tolerance_m), float(timeout_s), name)


class ShapeModel:
    """The quasi-static model of one module as a function cable length (m) -> rib centres.

    Parameters
    ----------
    skeleton : softsnap_model.Skeleton
    threading : sequence of str or float
        One hole per rib, rib 0 first.
    loads : softsnap_model.loads.Loads, optional
        Gravity (in the module frame), bending stiffness and a point load the model
        assumes; None for the unloaded model (:func:`solve_forward`).
    max_contraction_m : float, optional
        User limit on the contraction (m) (the scene's ``max_contraction_mm``).
    """

    def __init__(self, skeleton, threading, loads: Loads | None = None,
                 max_contraction_m: float | None = None):
        self.skeleton = skeleton
        self.threading = tuple(threading)
        self.loads = loads if loads is not None and not loads.is_zero else None
        lo_mm, hi_mm = reachable_range(skeleton, self.threading)
        low = lo_mm * 1e-3 + RANGE_MARGIN_M
        if max_contraction_m is not None:
            low = max(low, hi_mm * 1e-3 - float(max_contraction_m))
        #: Commandable cable lengths (m): (shortest, straight).
        self.range_m = (low, hi_mm * 1e-3)
        self.n_ribs = len(self.threading)
        self._grid = None          # (lengths, ribs) of the feedforward sweep, built once
        self._sens_at = None       # (length, sensitivity) last computed

    def rib_centers_m(self, cable_length_m: float) -> np.ndarray:
        """Predicted rib centres (n_ribs, 2) in m for a cable length in m."""
        length_mm = float(cable_length_m) * 1e3
        try:
            if self.loads is None:
                res = solve_forward(self.skeleton, self.threading, length_mm)
            else:
                res = solve_loaded(self.skeleton, self.threading, length_mm, self.loads)
        except InfeasibleLengthError:
            res = solve_forward(self.skeleton, self.threading, self.range_m[0] * 1e3)
        return np.asarray(res.rib_centers, dtype=float) * 1e-3

    def sensitivity(self, cable_length_m: float) -> np.ndarray:
        """d(rib centres)/d(cable length), (n_ribs, 2), dimensionless (m/m); central
        differences inside the range, one-sided at its ends. Reused while the length
        stays within SENSITIVITY_REUSE_M of where it was computed (a loaded solve costs
        ~30 ms; the sensitivity changes slowly along the range)."""
        if self._sens_at is not None and abs(self._sens_at[0] - cable_length_m) \
                <= SENSITIVITY_REUSE_M:
            return self._sens_at[1]
        value = self._sensitivity(cable_length_m)
        self._sens_at = (float(cable_length_m), value)
        return value

    def _sensitivity(self, cable_length_m: float) -> np.ndarray:
        lo, hi = self.range_m
        a = max(lo, cable_length_m - SENSITIVITY_STEP_M)
        b = min(hi, cable_length_m + SENSITIVITY_STEP_M)
        if b - a < 1e-9:
            return np.zeros((self.n_ribs, 2))
        return (self.rib_centers_m(b) - self.rib_centers_m(a)) / (b - a)

    def closest_length(self, target: ShapeTarget) -> tuple[float, float]:
        """(cable length m, error m) of the predicted shape closest to `target`."""
        if self._grid is None:
            grid = np.linspace(*self.range_m, FEEDFORWARD_SWEEP)
            self._grid = (grid, [self.rib_centers_m(x) for x in grid])
        grid, shapes = self._grid
        costs = np.array([target_error_m(target, ribs) for ribs in shapes])
        i = int(np.argmin(costs))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        best = minimize_scalar(lambda x: target_error_m(target, self.rib_centers_m(x)),
                               bounds=(a, b), method='bounded',
                               options={'xatol': 1e-6})
        if best.fun <= costs[i]:
            return float(best.x), float(best.fun)
        return float(grid[i]), float(costs[i])


def _selected(target: ShapeTarget, ribs_m: np.ndarray) -> np.ndarray:
    return ribs_m[-1:, :2] if target.kind == TARGET_TIP else ribs_m[:, :2]


def target_error_m(target: ShapeTarget, ribs_m: np.ndarray, visible=None) -> float:
    """Error (m) of a shape against a target: tip distance, or rib RMS over the visible
    ribs. NaN when no selected point is visible."""
    pts = _selected(target, np.asarray(ribs_m, dtype=float))
    diff = target.points_m - pts
    mask = np.all(np.isfinite(diff), axis=1)
    if visible is not None:
        vis = np.asarray(visible, dtype=bool)
        mask &= (vis[-1:] if target.kind == TARGET_TIP else vis)
    if not np.any(mask):
        return math.nan
    return float(np.sqrt(np.mean(np.sum(diff[mask] ** 2, axis=1))))


@dataclass(frozen=True)
class ControllerConfig:
    """Gains and limits of a :class:`ShapeController` (SI units)."""

    #: Integral gain on the Gauss-Newton length correction (1/s of measurement time).
    integral_gain_per_s: float = 4.0
    #: Largest rate of change of the command (m/s): a fraction of the winch speed.
    max_speed_m_s: float = 0.069
    #: A measurement older than this (s) is stale: the command is held.
    stale_after_s: float = 0.5
    #: Time (s) the error must stay within the tolerance to count as reached.
    settle_window_s: float = 0.3
    #: A target whose closest predicted shape is farther (m) is refused as unreachable.
    max_model_miss_m: float = 0.05
    #: Largest correction (m) feedback may add to the feedforward length.
    max_correction_m: float = 0.02

    def __post_init__(self):
        for name in ('integral_gain_per_s', 'max_speed_m_s', 'stale_after_s',
                     'settle_window_s', 'max_model_miss_m', 'max_correction_m'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')


@dataclass(frozen=True)
class Feedforward:
    """The model's answer for a target: length (m), predicted ribs (m), predicted error (m)."""

    cable_length_m: float
    predicted_ribs_m: np.ndarray
    model_error_m: float


@dataclass(frozen=True)
class ControlStep:
    """What one :meth:`ShapeController.step` decided.

    ``command_m`` is None before the first target. ``error_m`` (m): the target's error
    measure on the latest measurement (NaN if none); ``tip_error_m`` the tip distance.
    ``correction_m``: command minus feedforward (m), the model's error as feedback saw it.
    ``saturated``: the range or speed bound cut the command this step.
    """

    command_m: float | None
    state: str
    error_m: float
    tip_error_m: float
    correction_m: float
    saturated: bool
    reason: str
    elapsed_s: float
    measurement_age_s: float


@dataclass(frozen=True)
class CorrectionRecord:
    """The steady correction of a reached target, for calibration to refit the model
    from: the model said ``feedforward_m``, the robot needed ``command_m`` (m)."""

    target_kind: str
    target_name: str
    target_points_m: tuple
    feedforward_m: float
    command_m: float
    correction_m: float
    error_m: float
    measured_ribs_m: tuple
    time_s: float


@dataclass
class _Measurement:
    ribs_m: np.ndarray
    visible: np.ndarray
    stamp_s: float


class ShapeController:
    """Closed-loop controller of one module's shape (see the module docstring).

    Use: :meth:`set_target`, then :meth:`observe` for every measurement and
    :meth:`step` at the control rate; each step returns the command to send.
    """

    def __init__(self, model: ShapeModel, config: ControllerConfig | None = None):
        self.model = model
        self.config = config or ControllerConfig()
        self.target: ShapeTarget | None = None
        self.feedforward: Feedforward | None = None
        self.command_m: float | None = None
        self._integral_m = 0.0
        self._started_s = 0.0
        self._last_step_s: float | None = None
        self._measurement: _Measurement | None = None
        self._used_stamp_s = -math.inf
        self._within_since_s: float | None = None
        self._state = IDLE
        self._error_m = math.nan
        self._tip_error_m = math.nan
        #: Steady corrections of reached targets, oldest first.
        self.corrections: list[CorrectionRecord] = []
        self._recorded = False
        self._ramping = False
        self._timeout_reason = ''

    @property
    def state(self) -> str:
        return self._state

    def plan(self, target: ShapeTarget) -> Feedforward:
        """The feedforward for `target` without changing anything (the model's search,
        ~0.1-1 s: callers may run it outside their lock and pass it to set_target)."""
        length, miss = self.model.closest_length(target)
        return Feedforward(length, self.model.rib_centers_m(length), miss)

    def set_target(self, target: ShapeTarget, now_s: float,
                   feedforward: Feedforward | None = None) -> Feedforward:
        """Aim at `target` from now on; raise :class:`TargetError` if it is unreachable
        by the model (the previous target, if any, stays). `feedforward`: from
        :meth:`plan`, to skip the search here."""
        if target.points_m.shape[0] not in (1, self.model.n_ribs):
            raise TargetError(f'target has {target.points_m.shape[0]} points; the module '
                              f'has {self.model.n_ribs} ribs')
        length, miss = self.model.closest_length(target) if feedforward is None else (
            feedforward.cable_length_m, feedforward.model_error_m)
        if not math.isfinite(miss) or miss > self.config.max_model_miss_m:
            raise TargetError(
                f'unreachable: the closest shape the model predicts is {miss * 1e3:.1f} mm '
                f'from the target (at cable length {length * 1e3:.1f} mm); one cable gives '
                f'a one-parameter family of shapes, and a target more than '
                f'{self.config.max_model_miss_m * 1e3:g} mm off it is refused')
        self.target = target
        self.feedforward = feedforward or Feedforward(length, self.model.rib_centers_m(length),
                                                      miss)
        self._integral_m = 0.0
        self._started_s = now_s
        self._within_since_s = None
        self._state = CONVERGING
        self._recorded = False
        # Only measurements taken after the new target count (older ones saw old commands).
        self._used_stamp_s = max(self._used_stamp_s, now_s)
        return self.feedforward

    def predicted_ribs_m(self) -> np.ndarray | None:
        """The model's shape at the current command (m): the feedforward shape moved by
        the sensitivity times the correction (first order; no solve per step)."""
        if self.feedforward is None or self.command_m is None:
            return None
        delta = self.command_m - self.feedforward.cable_length_m
        return self.feedforward.predicted_ribs_m + self.model.sensitivity(self.command_m) * delta

    def clear_target(self) -> None:
        """Stop controlling: no more commands until the next target."""
        self.target = None
        self.feedforward = None
        self._state = IDLE

    def observe(self, ribs_m, stamp_s: float, visible=None) -> None:
        """Store a measurement: rib centres (n_ribs, 2 or 3) m, module frame, taken at
        `stamp_s`. NaN rows count as not visible."""
        ribs = np.asarray(ribs_m, dtype=float)
        if ribs.ndim != 2 or ribs.shape[0] != self.model.n_ribs or ribs.shape[1] < 2:
            raise ValueError(f'measurement needs {self.model.n_ribs} rib centres, got '
                             f'shape {ribs.shape}')
        vis = np.all(np.isfinite(ribs[:, :2]), axis=1)
        if visible is not None and len(visible) == ribs.shape[0]:
            vis &= np.asarray(visible, dtype=bool)
        if self._measurement is not None and stamp_s < self._measurement.stamp_s:
            return   # out of order: keep the newer one
        self._measurement = _Measurement(ribs[:, :2].copy(), vis, float(stamp_s))

    def step(self, now_s: float) -> ControlStep:
        """One control period: integrate a new measurement, bound and return the command."""
        dt = 0.0 if self._last_step_s is None else max(0.0, now_s - self._last_step_s)
        self._last_step_s = now_s
        meas = self._measurement
        age = math.inf if meas is None else now_s - meas.stamp_s
        if self.target is None:
            return self._result(False, 'no target', now_s, age)
        cfg = self.config
        elapsed = now_s - self._started_s
        if self._state == TIMED_OUT:
            return self._result(False, self._timeout_reason, now_s, age)
        fresh = meas is not None and age <= cfg.stale_after_s \
            and meas.stamp_s >= self._started_s
        if fresh and meas.stamp_s > self._used_stamp_s:
            mdt = min(meas.stamp_s - self._used_stamp_s, cfg.stale_after_s)
            self._used_stamp_s = meas.stamp_s
            self._error_m = target_error_m(self.target, meas.ribs_m, meas.visible)
            self._tip_error_m = (float(np.linalg.norm(meas.ribs_m[-1] - self._tip_target()))
                                 if meas.visible[-1] else math.nan)
            if self.command_m is not None and not self._ramping \
                    and math.isfinite(self._error_m):
                self._integrate(meas, mdt)
            self._track_settling(meas.stamp_s)
        reason = ''
        if not fresh and self.command_m is not None:
            # Stale or missing: hold what was last commanded, integrate nothing.
            if self._state != STALE:
                self._state = STALE
            reason = ('no measurement since the target was set' if meas is None
                      or meas.stamp_s < self._started_s else
                      f'measurement {age:.2f} s old (stale after {cfg.stale_after_s:g} s)')
            reason += '; holding the last command'
            saturated = False
        else:
            if not fresh:
                reason = 'no measurement yet: open loop at the feedforward'
            ff = self.feedforward.cable_length_m
            lo, hi = self.model.range_m
            wanted = ff + self._integral_m
            in_range = min(max(wanted, lo), hi)
            # Anti-windup (back-calculation): the integrator keeps only what the range allows.
            self._integral_m = in_range - ff
            command = in_range
            if self.command_m is not None:
                limit = cfg.max_speed_m_s * dt
                command = min(max(in_range, self.command_m - limit), self.command_m + limit)
            # While the winch is still catching up with the command the measured error says
            # nothing about the model: no integration until it has.
            self._ramping = abs(command - in_range) > 1e-9
            saturated = self._ramping or abs(in_range - wanted) > 1e-9
            self.command_m = command
            if self._state == STALE and fresh:
                self._state = CONVERGING
        if self._state != REACHED and elapsed > self.target.timeout_s:
            stale = f' ({reason})' if self._state == STALE else '; holding the last command'
            self._state = TIMED_OUT
            self._timeout_reason = reason = (f'timed out after {self.target.timeout_s:g} s at '
                                             f'error {self._error_m * 1e3:.2f} mm{stale}')
        return self._result(saturated, reason, now_s, age)

    def _tip_target(self) -> np.ndarray:
        if self.target.kind == TARGET_TIP:
            return self.target.points_m[0]
        return self.target.points_m[-1]

    def _integrate(self, meas: _Measurement, dt_s: float) -> None:
        sens = _selected(self.target, self.model.sensitivity(self.command_m))
        got = _selected(self.target, meas.ribs_m)
        vis = meas.visible[-1:] if self.target.kind == TARGET_TIP else meas.visible
        err = (self.target.points_m - got)[vis]
        jac = sens[vis]
        denom = float(np.sum(jac * jac))
        if denom < 1e-12:
            return
        correction = float(np.sum(jac * err)) / denom
        gain = min(1.0, self.config.integral_gain_per_s * dt_s)
        limit = self.config.max_correction_m
        self._integral_m = min(max(self._integral_m + gain * correction, -limit), limit)

    def _track_settling(self, stamp_s: float) -> None:
        if not (math.isfinite(self._error_m) and self._error_m <= self.target.tolerance_m):
            self._within_since_s = None
            if self._state == REACHED:
                self._state = CONVERGING
            return
        if self._within_since_s is None:
            self._within_since_s = stamp_s
        if stamp_s - self._within_since_s >= self.config.settle_window_s \
                and self._state != REACHED:
            self._state = REACHED
            if not self._recorded:
                self._recorded = True
                self.corrections.append(CorrectionRecord(
                    self.target.kind, self.target.name,
                    tuple(map(tuple, self.target.points_m.tolist())),
                    self.feedforward.cable_length_m, float(self.command_m),
                    float(self.command_m - self.feedforward.cable_length_m), self._error_m,
                    tuple(map(tuple, self._measurement.ribs_m.tolist())), stamp_s))

    def _result(self, saturated: bool, reason: str, now_s: float, age: float) -> ControlStep:
        ff = self.feedforward.cable_length_m if self.feedforward else math.nan
        correction = (self.command_m - ff) if (self.command_m is not None
                                               and self.feedforward) else math.nan
        return ControlStep(self.command_m if self.target is not None else None, self._state,
                           self._error_m, self._tip_error_m, correction, saturated, reason,
                           now_s - self._started_s, age)


#: Gravity in the robot frame (m/s^2): the scenes' robot frames have z up.
GRAVITY_ROBOT_MPS2 = (0.0, 0.0, -9.81)


def gravity_in_module_frame(module) -> tuple:
    """Gravity (m/s^2) in a scene module's base frame, for a robot standing level."""
    from softsnap_model.scene import quaternion_to_matrix
    rot = np.array(quaternion_to_matrix(module.base_orientation_xyzw))
    return tuple(float(x) for x in rot.T @ np.array(GRAVITY_ROBOT_MPS2))


def module_model(scene, module_name: str, *, gravity: bool = True,
                 bending_stiffness_nmm: float | None = None,
                 tip_load_n: tuple = (0.0, 0.0, 0.0)) -> ShapeModel:
    """The controller's model of a scene module: the quasi-static model under gravity (in
    the module's frame from the scene's pose), a bending stiffness and a tip load."""
    module = scene.module(module_name)
    kwargs = {}
    if bending_stiffness_nmm is not None:
        kwargs['bending_stiffness_nmm'] = bending_stiffness_nmm
    loads = Loads(gravity_mps2=gravity_in_module_frame(module) if gravity else (0, 0, 0),
                  load_n=tip_load_n, **kwargs)
    return ShapeModel(scene.skeleton, module.holes, loads,
                      max_contraction_m=module.max_contraction_mm * 1e-3)


def named_shape_m(scene, model: ShapeModel, name: str) -> np.ndarray:
    """Rib centres (n_ribs, 2) m of a named shape: ``'straight'``, or a gait of the scene
    (its contraction at the gait's amplitude), as the model predicts it."""
    lo, hi = model.range_m
    if name == 'straight':
        return model.rib_centers_m(hi)
    spec = scene.gaits.get(name)
    if spec is None:
        raise TargetError(f'no named shape {name!r}: use straight or a gait of the scene '
                          f'({", ".join(scene.gaits)})')
    amplitude = spec.get('amplitude_mm')
    if not isinstance(amplitude, (int, float)):
        raise TargetError(f'gait {name!r} has no single amplitude_mm to make a shape of')
    return model.rib_centers_m(max(lo, hi - float(amplitude) * 1e-3))
