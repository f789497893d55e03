"""``RobotRecorder``: a robot's shapes, lengths and plots, batched per entity, and the rate
limiter that keeps a recording small."""
from __future__ import annotations

import math
import time
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np
import pyarrow as pa
import rerun as rr

from softsnap_ros.units import MM_PER_M

from .log_entities import (_ArrowBatch, _SCALARS_DESCRIPTOR, _strips_column, log_base_poses,
                           log_connector, log_legend, log_robot_pose, log_scalar, log_scene_setup,
                           log_series_styles, log_shape_styles)
from .paths import plot_path, shape_path
from .shapes import (RIB_HALF_LENGTH_MM, RIB_SPACING_MM, RibFrames, _as_vector, cable_points_m,
                     rib_centres_mm, rib_segments_m)
from .stream import set_stamp, time_column
from .style import RGB, color_name, module_colors


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
        half = RIB_HALF_LENGTH_MM / MM_PER_M
        offset = np.stack((-half * sin_t, half * cos_t, np.zeros_like(t)), axis=-1)
        ribs = np.stack((c + offset, c - offset), axis=2)  # (rows, n, 2, 3)
        parts = [('spine', c[:, None]), ('ribs', ribs)]
        if threading is not None:
            d = threading / MM_PER_M
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
            planar = rib_centres_mm(angles, self.spacing_mm) / MM_PER_M
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
                      float(np.linalg.norm(tip) * MM_PER_M))
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
        self._row(plot_path('cable_length_mm', module, kind), 'scalar', stamp_ns,
                  length_m * MM_PER_M)
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
