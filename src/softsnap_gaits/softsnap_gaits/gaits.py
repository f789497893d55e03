"""Gait library: each module's commanded cable contraction as a function of time.

Pure numpy, no ROS. A gait spec is a mapping read from a scene file's ``gaits`` section
(see docs/gaits.md); `make_gait(spec, scene)` validates it against the scene and returns
a frozen `Gait` whose `contraction_mm(t_s)` gives the contraction of every module (mm,
0 = straight, cable pulled in by that much) and `cable_length_mm(t_s)` the commanded
cable length (straight length minus contraction).

Two shapes cover the paper's robots:

* pulse gaits (``pulse``, ``alternating``, ``wave``): each module is contracted for a
  fraction ``duty`` of every period, starting at its own phase; every edge is a cosine
  ramp lasting ``rise_time_s`` (continuous velocity, so a motor can follow);
* keyframe gaits (``keyframes``, ``grasp``): contraction keyframes per module joined by
  cosine ease curves (zero velocity at each keyframe), looping or played once.

Every gait is checked at construction: each module's peak contraction must stay within
its reachable contraction (the solver's `reachable_range`) and within the scene's
``max_contraction_mm`` (the paper shows 0-80 mm), and each module's peak commanded cable
speed within `WINCH_SPEED_MARGIN` of its winch's speed (the scene's ``winch_speed_mm_s``),
so that the winch can follow and the module reaches every shape the gait asks for. A gait
too fast for its winches is refused, or slowed down with ``time_scale: auto`` (every
duration multiplied by the smallest factor that makes it followable).

Examples
--------
>>> from softsnap_model.scene import load_scene
>>> scene = load_scene('brittle_star')
>>> gait = make_gait('walk', scene)
>>> gait.period_s, gait.module_names[:2]
(3.0, ('yellow', 'blue'))
>>> gait.contraction_mm(1.0).round(1).tolist()   # blue and orange step first
[0.0, 30.0, 0.0, 0.0, 30.0]
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from softsnap_model.forward import reachable_range

__all__ = [
    'Gait', 'GaitError', 'GAIT_TYPES', 'make_gait', 'reachable_contraction_mm',
    'pulse_shape', 'ease_keyframes', 'DEFAULT_RISE_TIME_S', 'LIMIT_TOL_MM',
    'WINCH_SPEED_MARGIN', 'MAX_TIME_SCALE',
]

#: Rise (and fall) time of pulse edges when a spec gives none (s).
DEFAULT_RISE_TIME_S = 0.05
#: A peak contraction may exceed its limit by this much (mm) before a gait is refused:
#: absorbs rounding in the files and the solver's own tolerance.
LIMIT_TOL_MM = 1e-6
#: Fraction of a winch's stated speed (scene ``winch_speed_mm_s``) a gait may command at
#: its fastest. The rest is the winch's reserve to catch up: the motor model's load and
#: battery vary (the firmware runs the motor from the battery within 60 counts of its
#: target), and commands reach the module 10-100 ms late over Wi-Fi and ROS, so a winch
#: driven at its full speed would lag for the whole edge and arrive late at every shape.
WINCH_SPEED_MARGIN = 0.75
#: Largest time scale a gait accepts (an explicit one or the one ``auto`` finds).
MAX_TIME_SCALE = 100.0
#: Relative tolerance on the speed check: a gait tuned to exactly the limit passes.
SPEED_TOL = 1e-9
#: Shortest period a gait accepts (s); also the lower bound of the node's overrides.
MIN_PERIOD_S = 0.05
#: Longest period a gait accepts (s).
MAX_PERIOD_S = 3600.0


class GaitError(ValueError):
    """A gait spec is invalid for its scene; the message names the gait, key and rule."""


# --------------------------------------------------------------------- pure shapes

def pulse_shape(u, duty: float, rise: float) -> np.ndarray:
    """Smoothed rectangular pulse of height 1 over one period, vectorised.

    Parameters
    ----------
    u : array_like
        Time since the pulse's onset as a fraction of the period, any real (wrapped to
        [0, 1)).
    duty : float
        Fraction of the period from the start of the rise to the start of the fall,
        0 < duty < 1.
    rise : float
        Duration of each edge as a fraction of the period, 0 <= rise <= min(duty, 1 - duty).
        Edges are half cosines: the value and its time derivative are continuous.

    Returns
    -------
    ndarray
        Values in [0, 1]: rising on [0, rise), 1 on [rise, duty), falling on
        [duty, duty + rise), 0 after.

    Examples
    --------
    >>> pulse_shape([0.0, 0.05, 0.3, 0.55, 0.8], duty=0.5, rise=0.1).round(3).tolist()
    [0.0, 0.5, 1.0, 0.5, 0.0]
    """
    u = np.mod(np.asarray(u, dtype=float), 1.0)
    out = np.where(u < duty, 1.0, 0.0)
    if rise > 0.0:
        up = u < rise
        out = np.where(up, 0.5 - 0.5 * np.cos(np.pi * u / rise), out)
        down = (u >= duty) & (u < duty + rise)
        out = np.where(down, 0.5 + 0.5 * np.cos(np.pi * (u - duty) / rise), out)
    return out


def ease_keyframes(t, times, values, *, period: float | None = None) -> np.ndarray:
    """Cosine-eased interpolation through keyframes, vectorised.

    Between keyframes (t0, v0) and (t1, v1) the value is
    ``v0 + (v1 - v0) * (1 - cos(pi * s)) / 2`` with ``s = (t - t0) / (t1 - t0)``: it
    passes through every keyframe with zero slope. Before the first keyframe the first
    value holds, after the last the last value holds. With `period`, t is wrapped into
    [0, period) and the curve returns from the last keyframe to the first value at t =
    period (a loop).

    Examples
    --------
    >>> ease_keyframes([0.0, 0.5, 1.0, 2.0], [0.0, 1.0], [0.0, 10.0]).round(9).tolist()
    [0.0, 5.0, 10.0, 10.0]
    """
    t = np.asarray(t, dtype=float)
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    if period is not None:
        t = np.mod(t, period)
        if times[-1] < period:
            times = np.append(times, period)
            values = np.append(values, values[0])
    if times.size == 1:
        return np.full(t.shape, values[0])
    k = np.clip(np.searchsorted(times, t, side='right') - 1, 0, times.size - 2)
    t0, t1 = times[k], times[k + 1]
    v0, v1 = values[k], values[k + 1]
    s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return v0 + (v1 - v0) * (0.5 - 0.5 * np.cos(np.pi * s))


# ------------------------------------------------------------------------- the gait

@dataclass(frozen=True, eq=False)
class Gait:
    """A validated gait for one scene.

    Attributes
    ----------
    name, type : str
        Gait name in the scene and its type (a key of `GAIT_TYPES`).
    period_s : float
        Cycle length (s); for a gait played once (``loop`` false), its duration.
    loop : bool
        True: periodic. False: played once, then every module holds its last value.
    module_names : tuple of str
        Scene modules in scene order; arrays below and `contraction_mm` follow it.
    straight_length_mm : ndarray
        Straight cable length per module (mm).
    peak_contraction_mm : ndarray
        Largest contraction the gait commands per module (mm).
    limit_contraction_mm : ndarray
        Largest contraction allowed per module (mm): the smaller of the solver's
        reachable contraction and the scene's ``max_contraction_mm``.
    peak_speed_mm_s : ndarray
        Largest commanded cable speed per module (mm/s), exact for the cosine edges;
        inf for steps without ramps.
    speed_limit_mm_s : ndarray
        Largest cable speed allowed per module (mm/s): `WINCH_SPEED_MARGIN` times the
        scene's ``winch_speed_mm_s``; ``peak_speed_mm_s`` never exceeds it.
    time_scale : float
        Factor every duration of the spec was multiplied by (1: as written; above 1:
        slowed down, by ``time_scale: auto`` or an explicit scale).
    reachable_checked : bool
        True if the limits include the solver's reachable contraction (False only when
        the solver is not installed; a RuntimeWarning is issued then).
    params : Mapping
        The effective parameters after defaults and overrides (read-only).
    """

    name: str
    type: str
    period_s: float
    loop: bool
    module_names: tuple[str, ...]
    straight_length_mm: np.ndarray
    peak_contraction_mm: np.ndarray
    limit_contraction_mm: np.ndarray
    peak_speed_mm_s: np.ndarray
    reachable_checked: bool
    params: Mapping[str, Any]
    speed_limit_mm_s: np.ndarray
    time_scale: float
    _profile: Callable[[np.ndarray], np.ndarray] = field(repr=False)

    @property
    def amplitude_mm(self) -> float:
        """Largest contraction over all modules (mm): what an amplitude override sets."""
        return float(self.peak_contraction_mm.max(initial=0.0))

    @property
    def duration_s(self) -> float:
        """Duration (s): inf for a looping gait, `period_s` otherwise."""
        return math.inf if self.loop else self.period_s

    def contraction_mm(self, t_s) -> np.ndarray:
        """Commanded contraction (mm, >= 0) of every module at time(s) `t_s` (s from start).

        A scalar time gives shape (n_modules,), an array of shape (k,) gives (k, n_modules).
        Negative times are treated as 0 (the gait's start value).
        """
        t = np.asarray(t_s, dtype=float)
        if not np.all(np.isfinite(t)):
            raise ValueError(f'gait {self.name!r}: time must be finite, got {t_s!r}')
        flat = np.maximum(np.atleast_1d(t).ravel(), 0.0)
        if not self.loop:
            flat = np.minimum(flat, self.period_s)
        out = np.clip(self._profile(flat), 0.0, None)
        return out[0] if t.ndim == 0 else out.reshape(t.shape + (len(self.module_names),))

    def cable_length_mm(self, t_s) -> np.ndarray:
        """Commanded cable length (mm) = straight length - contraction, same shapes."""
        return self.straight_length_mm - self.contraction_mm(t_s)

    def phase(self, t_s: float) -> tuple[float, int]:
        """(phase in [0, 1], completed cycles) at time `t_s` (s) since the start.

        A gait played once reports phase t / duration, and (1.0, 1) once finished.
        """
        t = max(float(t_s), 0.0)
        if not self.loop:
            return (1.0, 1) if t >= self.period_s else (t / self.period_s, 0)
        cycles = math.floor(t / self.period_s)
        return (t / self.period_s - cycles, int(cycles))

    def finished(self, t_s: float) -> bool:
        """True once a gait played once has reached its end (never for a loop)."""
        return (not self.loop) and t_s >= self.period_s

    def sample(self, rate_hz: float):
        """Times (s) over one period at `rate_hz`, and the contractions there (k, n)."""
        t = np.arange(0.0, self.period_s, 1.0 / rate_hz)
        return t, self.contraction_mm(t)

    def index(self, module_name: str) -> int:
        return self.module_names.index(module_name)


# -------------------------------------------------------------------- spec readers

class _Spec:
    """Typed access to one gait spec; errors name the gait and the key."""

    def __init__(self, name: str, spec: Mapping, scene, source: str):
        self.name = name
        self.spec = spec
        self.scene = scene
        self.source = source
        self.used = {'type'}

    def fail(self, key: str, expected: str, value: Any = None, show: bool = True):
        got = f', got {value!r}' if show else ''
        where = f'gaits.{self.name}.{key}' if key else f'gaits.{self.name}'
        raise GaitError(f'{self.source}: {where}: expected {expected}{got}')

    def get(self, key, default=None):
        self.used.add(key)
        return self.spec.get(key, default)

    def number(self, key, default=None, *, low=None, high=None, low_open=False, value=None):
        v = self.get(key, default) if value is None else value
        if v is None:
            self.fail(key, 'a number (required)', show=False)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(key, 'a finite number', v)
        v = float(v)
        if low is not None and (v < low or (low_open and v == low)):
            rng = f'{">" if low_open else ">="} {low:g}' + (f' and <= {high:g}' if high is not None else '')
            self.fail(key, f'a number {rng}', v)
        if high is not None and v > high:
            self.fail(key, f'a number <= {high:g}' + (f' and >= {low:g}' if low is not None else ''), v)
        return v

    def boolean(self, key, default):
        v = self.get(key, default)
        if not isinstance(v, bool):
            self.fail(key, 'true or false', v)
        return v

    def module(self, key, value):
        if value not in self.scene.module_names:
            self.fail(key, f'a module of scene {self.scene.name!r} '
                      f'({", ".join(self.scene.module_names)})', value)
        return value

    def module_list(self, key, value):
        if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
            self.fail(key, 'a non-empty list of module names', value)
        return [self.module(f'{key}[{i}]', m) for i, m in enumerate(value)]

    def amplitudes(self, key, default=None) -> dict[str, float]:
        """``amplitude_mm``: one number for all modules, or a mapping module -> mm."""
        v = self.get(key, default)
        if isinstance(v, Mapping):
            return {self.module(f'{key}.{m}', m): self.number(f'{key}.{m}', value=a, low=0.0)
                    for m, a in v.items()}
        a = self.number(key, value=v, low=0.0)
        return {m: a for m in self.scene.module_names}

    def finish(self):
        unknown = sorted(set(self.spec) - self.used)
        if unknown:
            self.fail(unknown[0], f'one of the known keys of a {self.spec["type"]!r} gait '
                      f'({", ".join(sorted(self.used))})', unknown[0])


def _pulse_gait(s: _Spec, phases: dict[str, float], duty_default: float | None = None):
    """Shared builder of the pulse family: per-module phase, common duty and rise."""
    period = s.number('period_s', low=MIN_PERIOD_S, high=MAX_PERIOD_S)
    duty = s.number('duty', duty_default, low=0.0, high=1.0, low_open=True)
    if duty >= 1.0:
        s.fail('duty', 'a fraction below 1 (a module contracted all the time is no gait)', duty)
    rise_s = s.number('rise_time_s', DEFAULT_RISE_TIME_S, low=0.0)
    limit_s = min(duty, 1.0 - duty) * period
    if rise_s > limit_s + 1e-12:
        s.fail('rise_time_s', f'at most min(duty, 1 - duty) * period_s = {limit_s:g} s '
               'so that both edges fit in the cycle', rise_s)
    amplitude = s.amplitudes('amplitude_mm')
    names = s.scene.module_names
    phase = np.array([phases.get(m, 0.0) for m in names])
    amp = np.array([amplitude[m] if m in phases else 0.0 for m in names])
    rise = rise_s / period

    def profile(t):
        u = t[:, None] / period - phase[None, :]
        # Before its first onset (phase * period after the start) a module rests: the gait
        # starts from the straight robot instead of jumping into pulses begun "earlier".
        return np.where(u < 0.0, 0.0, amp[None, :] * pulse_shape(u, duty, rise))

    # Peak speed of a half-cosine edge of height a over r seconds: a * pi / (2 r), exactly.
    speed = amp * math.pi / (2.0 * rise_s) if rise_s > 0 else np.where(amp > 0, np.inf, 0.0)
    edges = [f'{a:g} mm pulse edges ({rise_s:g} s cosine ramps, rise_time_s)' for a in amp]
    params = {'period_s': period, 'duty': duty, 'rise_time_s': rise_s,
              'amplitude_mm': {m: float(a) for m, a in zip(names, amp)},
              'phase': {m: float(p) for m, p in zip(names, phase) if m in phases}}
    return period, True, profile, amp, speed, params, edges


def _build_pulse(s: _Spec):
    """``pulse``: explicit phase (fraction of the period) per module."""
    raw = s.get('phases')
    if not isinstance(raw, Mapping) or not raw:
        s.fail('phases', 'a mapping module -> phase (fraction of the period, 0 to 1)', raw)
    phases = {s.module(f'phases.{m}', m): s.number(f'phases.{m}', value=p, low=0.0, high=1.0)
              for m, p in raw.items()}
    return _pulse_gait(s, phases)


def _build_alternating(s: _Spec):
    """``alternating``: groups take turns; group k starts at k / len(groups) of the period."""
    groups = s.get('groups')
    if not isinstance(groups, (list, tuple)) or not groups:
        s.fail('groups', 'a non-empty list of module groups (lists of names)', groups)
    phases: dict[str, float] = {}
    for k, group in enumerate(groups):
        for i, m in enumerate(s.module_list(f'groups[{k}]', group)):
            if m in phases:
                s.fail(f'groups[{k}][{i}]', 'each module in at most one group', m)
            phases[m] = k / len(groups)
    return _pulse_gait(s, phases, duty_default=1.0 / len(groups) if len(groups) > 1 else 0.5)


def _build_wave(s: _Spec):
    """``wave``: modules in `order` start one after another, `lag` of the period apart."""
    order = s.module_list('order', s.get('order'))
    if len(set(order)) != len(order):
        s.fail('order', 'each module at most once', list(order))
    lag_max = 1.0 / len(order) if len(order) > 1 else 1.0
    lag = s.number('lag', lag_max, low=0.0, high=lag_max)
    return _pulse_gait(s, {m: k * lag for k, m in enumerate(order)})


def _keyframe_gait(s: _Spec, frames: dict[str, tuple[np.ndarray, np.ndarray]],
                   period: float, loop: bool, params: dict):
    names = s.scene.module_names
    zero = (np.array([0.0]), np.array([0.0]))
    tables = [frames.get(m, zero) for m in names]

    def profile(t):
        return np.stack([ease_keyframes(t, ts, vs, period=period if loop else None)
                         for ts, vs in tables], axis=-1)

    peak = np.array([vs.max() for _, vs in tables])
    speed, edges = [], []
    for ts, vs in tables:
        if loop and ts[-1] < period:
            ts, vs = np.append(ts, period), np.append(vs, vs[0])
        dt, dv = np.diff(ts), np.abs(np.diff(vs))
        # Peak speed of a cosine ease of height dv over dt seconds: dv * pi / (2 dt), exactly.
        seg = dv * math.pi / (2.0 * dt)
        speed.append(float(seg.max(initial=0.0)))
        k = int(np.argmax(seg)) if seg.size else 0
        edges.append(f'keyframes [{ts[k]:g} s, {vs[k]:g} mm] -> [{ts[k + 1]:g} s, '
                     f'{vs[k + 1]:g} mm]' if seg.size else 'no motion')
    return period, loop, profile, peak, np.array(speed), params, edges


def _build_keyframes(s: _Spec):
    """``keyframes``: per-module [[time_s, contraction_mm], ...] lists."""
    period = s.number('period_s', low=MIN_PERIOD_S, high=MAX_PERIOD_S)
    loop = s.boolean('loop', True)
    raw = s.get('keyframes')
    if not isinstance(raw, Mapping) or not raw:
        s.fail('keyframes', 'a mapping module -> list of [time_s, contraction_mm]', raw)
    frames = {}
    for m, rows in raw.items():
        key = f'keyframes.{m}'
        s.module(key, m)
        if isinstance(rows, str) or not isinstance(rows, (list, tuple)) or not rows:
            s.fail(key, 'a non-empty list of [time_s, contraction_mm] pairs', rows)
        ts, vs = [], []
        for i, row in enumerate(rows):
            if isinstance(row, str) or not isinstance(row, (list, tuple)) or len(row) != 2:
                s.fail(f'{key}[{i}]', 'a pair [time_s, contraction_mm]', row)
            t = s.number(f'{key}[{i}][0]', value=row[0], low=0.0, high=period)
            if ts and t <= ts[-1]:
                s.fail(f'{key}[{i}][0]', f'a time after the previous keyframe ({ts[-1]:g} s)', t)
            ts.append(t)
            vs.append(s.number(f'{key}[{i}][1]', value=row[1], low=0.0))
        if ts[0] != 0.0 or vs[0] != 0.0:
            s.fail(f'{key}[0]', 'the first keyframe at [0, 0] (gaits start from the straight '
                   'module)', list(rows[0]))
        frames[m] = (np.array(ts), np.array(vs))
    scale = s.number('amplitude_scale', 1.0, low=0.0)
    frames = {m: (ts, vs * scale) for m, (ts, vs) in frames.items()}
    params = {'period_s': period, 'loop': loop,
              'keyframes': {m: [[float(t), float(v)] for t, v in zip(ts, vs)]
                            for m, (ts, vs) in frames.items()}}
    return _keyframe_gait(s, frames, period, loop, params)


def _build_grasp(s: _Spec):
    """``grasp``: all modules close, hold, open and rest together."""
    close = s.number('close_s', low=0.0, low_open=True)
    hold = s.number('hold_s', 0.0, low=0.0)
    open_ = s.number('open_s', low=0.0, low_open=True)
    rest = s.number('rest_s', 0.0, low=0.0)
    loop = s.boolean('loop', True)
    amplitude = s.amplitudes('amplitude_mm')
    period = close + hold + open_ + rest
    if period < MIN_PERIOD_S:
        s.fail('close_s', f'phases lasting at least {MIN_PERIOD_S} s in total', period)
    knots = [0.0, close] + ([close + hold] if hold > 0 else []) + [close + hold + open_]
    frames = {}
    for m in s.scene.module_names:
        a = amplitude[m]
        vals = [0.0, a] + ([a] if hold > 0 else []) + [0.0]
        frames[m] = (np.array(knots), np.array(vals))
    params = {'period_s': period, 'loop': loop, 'close_s': close, 'hold_s': hold,
              'open_s': open_, 'rest_s': rest, 'amplitude_mm': dict(amplitude)}
    return _keyframe_gait(s, frames, period, loop, params)


#: Gait type name -> builder. Each builder reads its keys from the spec (see docs/gaits.md).
GAIT_TYPES: Mapping[str, Callable] = MappingProxyType({
    'pulse': _build_pulse,
    'alternating': _build_alternating,
    'wave': _build_wave,
    'keyframes': _build_keyframes,
    'grasp': _build_grasp,
})


# ------------------------------------------------------------------ reachability

def reachable_contraction_mm(skeleton, threading_mm) -> float:
    """Largest contraction (mm) the solver can reach for a threading on `skeleton`.

    ``straight_length_mm - min_length_mm`` from `softsnap_model.forward.reachable_range`
    (which caches each threading's path itself).
    """
    min_length, straight_length = reachable_range(skeleton, tuple(threading_mm))
    return float(straight_length) - float(min_length)


# --------------------------------------------------------------------- entry point

def make_gait(spec, scene, *, name: str | None = None, period_s: float | None = None,
              amplitude_mm: float | None = None, check_reachable: bool = True,
              time_scale: float | str | None = None) -> Gait:
    """Build and check a gait for `scene`.

    Parameters
    ----------
    spec : str or Mapping
        A gait name of the scene (``'walk'``) or a gait spec mapping with a ``type``.
    scene : softsnap_model.scene.Scene
    name : str, optional
        Name for a spec given as a mapping (default ``'custom'``).
    period_s : float, optional
        Override of the period (s). Pulse gaits keep their rise time in seconds;
        keyframe gaits are stretched in time.
    amplitude_mm : float, optional
        Override of the largest contraction (mm); every module's contraction is scaled
        by the same factor, so the gait's shape is kept.
    check_reachable : bool
        Check peaks against the solver's reachable contraction (True by default; the
        scene's ``max_contraction_mm`` is always checked).
    time_scale : float or 'auto', optional
        Multiply every duration of the gait (period, rise times, keyframe times, grasp
        phases; after a `period_s` override) by this factor, > 0. ``'auto'``: the
        smallest factor >= 1 that brings every module's peak cable speed within
        `WINCH_SPEED_MARGIN` of its winch speed (1 if the gait is slow enough already).
        None (default): the spec's own ``time_scale`` key, else 1.

    Raises
    ------
    GaitError (a ValueError)
        Unknown gait name or type (the message lists the known ones), invalid spec,
        override out of range, a contraction beyond a module's limit, or a cable speed
        beyond what a module's winch can follow (the message gives the speed needed, the
        winch's, the module and the edge, and the time scale that would fix it).

    Examples
    --------
    >>> from softsnap_model.scene import load_scene
    >>> scene = load_scene('brittle_star')
    >>> fast = {'type': 'alternating', 'period_s': 1.0, 'groups': [['blue'], ['red']],
    ...         'amplitude_mm': 40.0, 'rise_time_s': 0.1}
    >>> make_gait(fast, scene)                                    # doctest: +ELLIPSIS
    Traceback (most recent call last):
    softsnap_gaits.gaits.GaitError: ... module 'blue' needs 628.3 mm/s of cable on its 40 mm pulse edges ...
    >>> gait = make_gait(fast, scene, time_scale='auto')
    >>> round(gait.time_scale, 3), round(float(gait.peak_speed_mm_s.max()), 2)
    (9.067, 69.3)
    """
    source = f'scene {scene.name!r} ({scene.path})'
    if isinstance(spec, str):
        if spec not in scene.gaits:
            raise GaitError(f'{source}: unknown gait {spec!r}; known gaits: '
                            f'{", ".join(scene.gaits)}')
        name, spec = spec, scene.gaits[spec]
    name = name or 'custom'
    if not isinstance(spec, Mapping):
        raise GaitError(f'{source}: gaits.{name}: expected a mapping with a type, got {spec!r}')
    spec = dict(spec)
    gait_type = spec.get('type')
    if gait_type not in GAIT_TYPES:
        raise GaitError(f'{source}: gaits.{name}.type: unknown gait type {gait_type!r}; known '
                        f'types: {", ".join(GAIT_TYPES)}')
    spec_scale = spec.pop('time_scale', None)
    if time_scale is None:
        time_scale, scale_key = (1.0 if spec_scale is None else spec_scale), f'gaits.{name}.time_scale'
    else:
        scale_key = f'gaits.{name}: time scale override'
    auto = isinstance(time_scale, str) and time_scale.strip().lower() == 'auto'
    if not auto and (isinstance(time_scale, bool) or not isinstance(time_scale, (int, float))
                     or not 1.0 / MAX_TIME_SCALE <= time_scale <= MAX_TIME_SCALE):
        raise GaitError(f'{source}: {scale_key}: expected auto or a number from '
                        f'{1.0 / MAX_TIME_SCALE:g} to {MAX_TIME_SCALE:g}, got {time_scale!r}')
    if period_s is not None:
        if isinstance(period_s, bool) or not MIN_PERIOD_S <= float(period_s) <= MAX_PERIOD_S:
            raise GaitError(f'{source}: gaits.{name}: period override must be from '
                            f'{MIN_PERIOD_S} to {MAX_PERIOD_S} s, got {period_s!r}')
        spec = _with_period(spec, float(period_s))
    if amplitude_mm is not None:
        amplitude_mm = float(amplitude_mm)
        if not math.isfinite(amplitude_mm) or amplitude_mm < 0.0:
            raise GaitError(f'{source}: gaits.{name}: amplitude override must be >= 0 mm, '
                            f'got {amplitude_mm!r}')

    winch = np.array([m.winch_speed_mm_s for m in scene.modules], dtype=float)
    speed_limit = WINCH_SPEED_MARGIN * winch
    built = _build(spec, name, scene, source, amplitude_mm)
    scale = 1.0 if auto else float(time_scale)
    if auto:
        ratio = built[4] / speed_limit
        if np.any(np.isinf(ratio)):
            i = int(np.argmax(np.isinf(ratio)))
            raise GaitError(f'{source}: gaits.{name}: module {scene.modules[i].name!r} steps '
                            f'without a ramp on its {built[6][i]}: no time scale makes a step '
                            'followable; give it a ramp (rise_time_s > 0)')
        scale = max(1.0, float(ratio.max(initial=0.0)) * (1.0 + 1e-12))
        if scale > MAX_TIME_SCALE:
            raise GaitError(f'{source}: gaits.{name}: time_scale auto would slow the gait '
                            f'{scale:.3g} times, beyond {MAX_TIME_SCALE:g}; lower its amplitude')
    if scale != 1.0:
        scaled = _with_time_scale(spec, scale)
        _check_period(scaled, name, source)
        built = _build(scaled, name, scene, source, amplitude_mm)
    period, loop, profile, peak, speed, params, edges = built
    params = dict(params, time_scale=scale)

    limits = []
    for i, m in enumerate(scene.modules):
        limit, why = m.max_contraction_mm, "the scene's max_contraction_mm"
        if check_reachable:
            reach = reachable_contraction_mm(scene.skeleton, m.threading_mm)
            if reach < limit:
                limit, why = reach, "the solver's reachable contraction for its threading"
        limits.append(limit)
        if peak[i] > limit + LIMIT_TOL_MM:
            raise GaitError(f'{source}: gaits.{name}: module {m.name!r} would contract '
                            f'{peak[i]:.3f} mm, beyond {why} ({limit:.3f} mm)')
    for i, m in enumerate(scene.modules):
        if speed[i] > speed_limit[i] * (1.0 + SPEED_TOL):
            need = speed[i] / speed_limit[i] * scale
            fix = (f'slow it down at least {need:.3g} times (time_scale: auto does this)'
                   if math.isfinite(need) else 'give it a ramp (rise_time_s > 0)')
            raise GaitError(f'{source}: gaits.{name}: module {m.name!r} needs '
                            f'{speed[i]:.1f} mm/s of cable on its {edges[i]}, beyond '
                            f'{speed_limit[i]:.1f} mm/s ({WINCH_SPEED_MARGIN:.0%} of its '
                            f'winch speed {winch[i]:g} mm/s, winch_speed_mm_s): the winch '
                            f'could not follow; {fix}, or lower the amplitude')
    return Gait(name=name, type=gait_type, period_s=period, loop=loop,
                module_names=scene.module_names,
                straight_length_mm=_frozen(np.array([m.straight_length_mm for m in scene.modules])),
                peak_contraction_mm=_frozen(peak), limit_contraction_mm=_frozen(np.array(limits)),
                peak_speed_mm_s=_frozen(np.asarray(speed, dtype=float)),
                reachable_checked=check_reachable,
                params=MappingProxyType(params), speed_limit_mm_s=_frozen(speed_limit),
                time_scale=scale, _profile=profile)


def _build(spec: dict, name: str, scene, source: str, amplitude_mm: float | None):
    """Run the type's builder and the amplitude override: (period, loop, profile, peak,
    speed, params, edges)."""
    s = _Spec(name, spec, scene, source)
    period, loop, profile, peak, speed, params, edges = GAIT_TYPES[spec['type']](s)
    s.finish()
    if amplitude_mm is not None:
        top = float(peak.max(initial=0.0))
        factor = amplitude_mm / top if top > 0 else 0.0
        base_profile = profile
        profile = lambda t, f=factor, p=base_profile: f * p(t)  # noqa: E731
        peak, speed = peak * factor, speed * factor
        params = dict(params, amplitude_scale=factor)
        edges = [f'{e} scaled by {factor:.3g} (amplitude override)' for e in edges]
    return period, loop, profile, peak, speed, params, edges


def _check_period(spec: dict, name: str, source: str) -> None:
    """A time-scaled period must still be within [MIN_PERIOD_S, MAX_PERIOD_S]."""
    p = spec.get('period_s')
    if isinstance(p, (int, float)) and not isinstance(p, bool) and not MIN_PERIOD_S <= p <= MAX_PERIOD_S:
        raise GaitError(f'{source}: gaits.{name}: time-scaled period {p:g} s is outside '
                        f'{MIN_PERIOD_S} to {MAX_PERIOD_S} s')


def _with_time_scale(spec: dict, factor: float) -> dict:
    """Spec with every duration multiplied by `factor` (the curve's shape is kept)."""
    t = spec.get('type')
    if t == 'grasp':
        keys = ('close_s', 'hold_s', 'open_s', 'rest_s')
        return dict(spec, **{k: spec[k] * factor for k in keys
                             if isinstance(spec.get(k), (int, float)) and not isinstance(spec[k], bool)})
    period = spec.get('period_s')
    if not isinstance(period, (int, float)) or isinstance(period, bool):
        return spec          # invalid: the builder refuses it with the reason
    if t == 'keyframes':
        return _with_period(spec, period * factor)
    rise = spec.get('rise_time_s', DEFAULT_RISE_TIME_S)
    out = dict(spec, period_s=period * factor)
    if isinstance(rise, (int, float)) and not isinstance(rise, bool):
        out['rise_time_s'] = rise * factor
    return out


def _with_period(spec: dict, period_s: float) -> dict:
    """Spec with a new period: keyframe times stretched, grasp phases scaled."""
    t = spec.get('type')
    if t == 'grasp':
        keys = ('close_s', 'hold_s', 'open_s', 'rest_s')
        old = sum(float(spec.get(k, 0.0) or 0.0) for k in keys)
        f = period_s / old if old > 0 else 1.0
        return dict(spec, **{k: float(spec[k]) * f for k in keys if k in spec})
    if t == 'keyframes':
        old = spec.get('period_s')
        if isinstance(old, (int, float)) and not isinstance(old, bool) and old > 0:
            f = period_s / float(old)
            frames = spec.get('keyframes')
            if isinstance(frames, Mapping):
                frames = {m: [[r[0] * f, r[1]] if isinstance(r, (list, tuple)) and len(r) == 2
                               and isinstance(r[0], (int, float)) else r for r in rows]
                          if isinstance(rows, (list, tuple)) else rows
                          for m, rows in frames.items()}
                return dict(spec, period_s=period_s, keyframes=frames)
    return dict(spec, period_s=period_s)


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a
