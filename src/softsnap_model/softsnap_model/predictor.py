"""Live shape prediction for a whole robot: the model node's logic, free of ROS.

A :class:`RobotPredictor` holds, per module of a scene and per source ("commanded": the
length the gait asked for; "predicted": the length the driver measured), the latest cable
length and the last solved shape. Lengths arrive at any time through :meth:`submit`;
:meth:`tick` solves what changed and returns the new shapes. It skips work the robot does
not need, and counts what it skipped:

- a length within ``length_tol_mm`` of the last solved one is not solved again;
- modules with the same threading, stiffness and length in one tick share one solve (a
  snake of five identical modules given the same command costs one solve), across both
  sources;
- all problems of one tick are solved together in one vectorised call of a
  :class:`~softsnap_model.forward.PreparedBatch` holding the tables of the scene's
  threadings, stacked once (the batch's per-item cost is a small fraction of a single
  solve's, but a call has a fixed cost of about four single solves); fewer than
  :data:`BATCH_MIN_PROBLEMS` problems are solved one by one, warm-started from each
  module's previous shape. Both give the certified shape; they agree to rounding (a few
  ulp), and which one a tick uses depends only on how many distinct problems it has, so
  the same sequence of ticks always gives the same shapes;
- a tick with nothing pending costs a dictionary look-up: only slots with a new length
  are visited;
- rib centres are handed on only when the caller asks for them (someone subscribes), so
  the node builds point messages only for subscribers.

Units: millimetres and radians inside (the solver core's units); the node converts to SI.
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, Mapping

import numpy as np

from . import geometry
from .forward import PreparedBatch, reachable_range, solve_forward
from .scene import Scene, compose_base_pose, quaternion_to_matrix

__all__ = ['BATCH_MIN_PROBLEMS', 'SOURCES', 'ModulePrediction', 'PredictorCounters',
           'RobotPredictor']

#: The two shapes kept per module: from the commanded and from the measured cable length.
SOURCES = ('commanded', 'predicted')

#: Distinct problems of one tick from which they are solved in one batch call rather
#: than one by one: the crossover measured for 12-rib modules (a batch call of 1-4 rows
#: cost 340-390 us, one by one 100-330 us; 6 rows: 430 against 610 us).
BATCH_MIN_PROBLEMS = 5

#: Default length change (mm) below which a module is not solved again (0.1 µm: far below
#: an encoder count, so no visible shape change is ever skipped).
DEFAULT_LENGTH_TOL_MM = 1e-4


@dataclasses.dataclass(frozen=True)
class ModulePrediction:
    """Solved shape of one module for one source.

    Attributes
    ----------
    module, source : str
        Module name and "commanded" or "predicted".
    cable_length_mm : float
        Length the shape was solved for, mm.
    angles : ndarray, shape (n_segments,)
        Bending angles, rad.
    rib_centers_mm : ndarray, shape (n_ribs, 2), or None
        Rib centres in the module base frame, mm; None when not requested.
    tension : float
        Lagrange multiplier of the length constraint per unit stiffness, rad^2/mm.
    energy : float
        Bending energy ``sum k_i a_i^2``, rad^2.
    converged : bool
    residual : float
        Solver residual (max of constraint and stationarity residuals).
    solve_time_s : float
        Wall time of the solve, s; 0 when the shape was shared from another module's solve.
    stamp_ns : int
        Stamp of the length message the shape was solved from, ns.
    """

    module: str
    source: str
    cable_length_mm: float
    angles: np.ndarray
    rib_centers_mm: np.ndarray | None
    tension: float
    energy: float
    converged: bool
    residual: float
    solve_time_s: float
    stamp_ns: int


def _new_prediction(module, source, cable_length_mm, angles, rib_centers_mm, tension, energy,
                    converged, residual, solve_time_s, stamp_ns) -> ModulePrediction:
    """A :class:`ModulePrediction` from the tick's own checked values, at a third of the
    cost of the frozen dataclass's ``__init__`` (which sets each field through
    ``object.__setattr__``): a tick of a 50-module robot makes 100 of them. The instance
    is the same frozen dataclass (equal fields, setting one still raises)."""
    shape = _object_new(ModulePrediction)
    shape.__dict__.update(
        module=module, source=source, cable_length_mm=cable_length_mm, angles=angles,
        rib_centers_mm=rib_centers_mm, tension=tension, energy=energy, converged=converged,
        residual=residual, solve_time_s=solve_time_s, stamp_ns=stamp_ns)
    return shape


_object_new = object.__new__


@dataclasses.dataclass
class PredictorCounters:
    """Work done and skipped since the predictor was created (counts, seconds)."""

    solves: int = 0
    skipped_unchanged: int = 0
    skipped_duplicate: int = 0
    skipped_rib_points: int = 0
    refused: int = 0
    solve_time_s: float = 0.0


@dataclasses.dataclass
class _Slot:
    """Latest requested length and last solved shape of one (module, source)."""

    pending_mm: float | None = None
    pending_stamp_ns: int = 0
    shape: ModulePrediction | None = None


class RobotPredictor:
    """Predicts every module's shape of a scene from its cable lengths.

    Parameters
    ----------
    scene : Scene
        Modules (threadings, base poses) and the skeleton.
    length_tol_mm : float
        Length change below which a module is not solved again, mm.
    solver : callable, optional
        ``solver(skeleton, threading_mm, cable_length_mm, initial=None)`` returning a result
        with ``angles``, ``rib_centers``, ``tension``, ``energy``, ``converged`` and
        ``residual``; the forward solver by default.
    skip : bool
        Skip unneeded work (unchanged lengths, duplicate problems, unrequested rib
        centres). False solves every length received, separately, with rib centres: the
        reference the benchmark compares against.
    batch : bool
        Solve the problems of one tick in one batch call (:class:`PreparedBatch`; only
        with the default solver and ``skip``); False solves them one by one (the
        reference).
    """

    def __init__(self, scene: Scene, length_tol_mm: float = DEFAULT_LENGTH_TOL_MM,
                 solver: Callable = solve_forward, skip: bool = True, batch: bool = True):
        if not (math.isfinite(length_tol_mm) and length_tol_mm >= 0.0):
            raise ValueError(f'length_tol_mm must be finite and >= 0, got {length_tol_mm!r}')
        self.scene = scene
        self.skeleton = scene.skeleton
        self.length_tol_mm = float(length_tol_mm)
        self._solver = solver
        self.skip = bool(skip)
        # A custom solver (tests, other models) is called one problem at a time.
        self.batch = bool(batch) and self.skip and solver is solve_forward
        self.counters = PredictorCounters()
        #: (module, source, reason) of lengths the solver refused at tick time; the caller
        #: reports and clears them.
        self.errors: list[tuple[str, str, str]] = []
        self._index = {m.name: i for i, m in enumerate(scene.modules)}
        self._threading = {m.name: np.asarray(m.threading_mm, dtype=float) for m in scene.modules}
        # Modules with equal threadings share solves: key them by their offsets. Equal
        # keys are one object, so a batch converts each distinct threading once.
        interned: dict[tuple, tuple] = {}
        self._threading_key = {name: interned.setdefault(tuple(t.tolist()), tuple(t.tolist()))
                               for name, t in self._threading.items()}
        ranges = {}
        for key in set(self._threading_key.values()):
            ranges[key] = reachable_range(self.skeleton, np.asarray(key))
        self.reachable_mm = {name: ranges[self._threading_key[name]] for name in self._index}
        # The scene's threadings stacked once for the batch solves of every tick.
        self._batch_solver = (PreparedBatch(self.skeleton, list(ranges)) if self.batch
                              else None)
        self._slots = {(name, source): _Slot() for name in self._index for source in SOURCES}
        # Per source, the slots in scene order (shapes() every prediction); and the base
        # poses, fixed unless a module is chained to another (base_poses() as often).
        self._source_slots = {source: [self._slots[(m.name, source)] for m in scene.modules]
                              for source in SOURCES}
        self._fixed_poses = (None if any(m.parent is not None for m in scene.modules) else
                             [(m.base_position_m, m.base_orientation_xyzw)
                              for m in scene.modules])
        # Slots holding a length not solved yet, in arrival order: an idle tick visits none.
        self._pending: dict[tuple[str, str], _Slot] = {}

    # ------------------------------------------------------------------ input
    def submit(self, source: str, module: str, cable_length_mm: float, stamp_ns: int = 0) -> None:
        """Queue a new cable length for one module; solved at the next :meth:`tick`.

        Raises
        ------
        ValueError
            Unknown source or module, a non-finite length, or a length the threading
            cannot reach (the message names the reachable range). The last valid length
            and shape are kept.
        """
        try:
            if source not in SOURCES:
                raise ValueError(f'unknown source {source!r}; expected one of {SOURCES}')
            if module not in self._index:
                raise ValueError(f'unknown module {module!r}; scene {self.scene.name!r} has '
                                 f'{", ".join(self._index)}')
            length = float(cable_length_mm)
            if not math.isfinite(length):
                raise ValueError(f'cable length of {module!r} must be finite, got {length!r}')
            low, _straight = self.reachable_mm[module]
            if length < low:
                raise ValueError(f'cable length {length:.6g} mm of {module!r} is below the '
                                 f'reachable minimum {low:.6g} mm (reachable range '
                                 f'[{low:.6g}, {_straight:.6g}] mm; longer means slack)')
        except ValueError:
            self.counters.refused += 1
            raise
        slot = self._slots[(module, source)]
        solved = slot.shape.cable_length_mm if slot.shape is not None else None
        if self.skip and solved is not None and abs(length - solved) <= self.length_tol_mm:
            self.counters.skipped_unchanged += 1
            slot.pending_mm = None
            self._pending.pop((module, source), None)
            return
        slot.pending_mm = length
        slot.pending_stamp_ns = int(stamp_ns)
        self._pending[(module, source)] = slot

    # ------------------------------------------------------------------ solving
    def tick(self, rib_centers: bool | Mapping[str, bool] = False) -> dict[str, list[ModulePrediction]]:
        """Solve all pending lengths; return the new shapes per source (scene order).

        Parameters
        ----------
        rib_centers : bool or mapping source -> bool
            Whether the new shapes carry rib centres (per source if a mapping).
        """
        updated: dict[str, list[ModulePrediction]] = {source: [] for source in SOURCES}
        if not self._pending:
            return updated
        want = rib_centers if isinstance(rib_centers, Mapping) else dict.fromkeys(SOURCES, rib_centers)
        if not self.skip:
            want = dict.fromkeys(SOURCES, True)
        pending, self._pending = self._pending, {}
        # Group identical problems (threading, length) across modules and sources.
        groups: dict[tuple, list[tuple[str, str, _Slot]]] = {}
        threading_key = self._threading_key
        for (name, source), slot in pending.items():
            key = (threading_key[name], slot.pending_mm)
            if not self.skip:
                key += (name, source)  # every module and source solved on its own
            groups.setdefault(key, []).append((name, source, slot))
        counters = self.counters
        for key, members, result, elapsed in self._solve_groups(groups):
            if result is None:  # refused: keep the last valid shapes, report why
                for name, source, slot in members:
                    slot.pending_mm = None
                    self.errors.append((name, source, elapsed))
                counters.refused += len(members)
                continue
            length = key[1]
            counters.solves += 1
            counters.solve_time_s += elapsed
            counters.skipped_duplicate += len(members) - 1
            angles, centers, tension, energy, converged, residual = result
            for name, source, slot in members:
                points = want.get(source, False)
                if not points:
                    counters.skipped_rib_points += 1
                slot.shape = shape = _new_prediction(
                    name, source, length, angles, centers if points else None,
                    tension, energy, converged, residual, elapsed, slot.pending_stamp_ns)
                elapsed = 0.0   # the solve's time goes with its first shape only
                slot.pending_mm = None
                updated[source].append(shape)
        for source in SOURCES:
            if len(updated[source]) > 1:
                updated[source].sort(key=self._scene_place)
        return updated

    def _scene_place(self, shape: ModulePrediction) -> int:
        return self._index[shape.module]

    def _solve_groups(self, groups: dict[tuple, list[tuple[str, str, _Slot]]]):
        """Yield (key, members, fields or None, solve time s or the refusal) per group.

        fields = (angles, rib centres, tension, energy, converged, residual). Several
        groups go through one batch solve, whose time is shared out evenly; the batch
        refuses bad groups one by one (with the single solve's reason), so a bad length
        never holds up the others.
        """
        if self.batch and len(groups) >= BATCH_MIN_PROBLEMS:
            keys = list(groups)
            lengths = np.fromiter((key[1] for key in keys), dtype=float, count=len(keys))
            # Offsets as the (interned) tuples the solver was prepared with: one
            # dictionary look-up per row.
            threadings = [key[0] for key in keys]
            start = time.perf_counter()
            try:
                batch = self._batch_solver.solve(threadings, lengths)
            except ValueError:   # a malformed call only (bad rows are refused in it):
                batch = None     # the one-by-one path below still answers every group
            if batch is not None:
                each = (time.perf_counter() - start) / len(keys)
                # One conversion per array, not per item: Python floats and bools.
                tension, energy = batch.tension.tolist(), batch.energy.tolist()
                converged, residual = batch.converged.tolist(), batch.residual.tolist()
                for i, key in enumerate(keys):
                    if batch.refused[i]:
                        yield key, groups[key], None, batch.refused[i]
                    else:
                        yield key, groups[key], (batch.angles[i], batch.rib_centers[i],
                                                 tension[i], energy[i], converged[i],
                                                 residual[i]), each
                return
        for key, members in groups.items():
            first = members[0][2]
            initial = first.shape.angles if first.shape is not None else None
            start = time.perf_counter()
            try:
                result = self._solver(self.skeleton, self._threading[members[0][0]], key[1],
                                      initial=initial)
            except ValueError as error:
                # e.g. a length inside a snap-through the solver refuses
                yield key, members, None, str(error)
                continue
            elapsed = time.perf_counter() - start
            yield key, members, (np.array(result.angles, dtype=float),
                                 np.asarray(result.rib_centers, dtype=float),
                                 float(result.tension), float(result.energy),
                                 bool(result.converged), float(result.residual)), elapsed

    # ------------------------------------------------------------------ queries
    @property
    def has_pending(self) -> bool:
        """True if some length waits for the next :meth:`tick`."""
        return bool(self._pending)

    def shapes(self, source: str) -> list[ModulePrediction | None]:
        """Last solved shape per module in scene order (None before the first length)."""
        return [slot.shape for slot in self._source_slots[source]]

    def base_poses(self, source: str) -> list[tuple[tuple[float, float, float],
                                                     tuple[float, float, float, float]]]:
        """Base pose (position m, quaternion xyzw) of every module in the robot frame.

        Chained modules (a snake) sit on their parent's tip rib, so their pose follows the
        parent's current shape of the same source; others use the scene's fixed pose.
        """
        if self._fixed_poses is not None:
            return list(self._fixed_poses)
        poses: dict[str, tuple] = {}

        def pose_of(module):
            # Scenes may list a child before its parent (the snake lists head first).
            if module.name not in poses:
                if module.parent is None:
                    poses[module.name] = (module.base_position_m, module.base_orientation_xyzw)
                else:
                    parent = self.scene.module(module.parent)
                    shape = self._slots[(parent.name, source)].shape
                    angles = (shape.angles if shape is not None
                              else np.zeros(self.skeleton.n_segments))
                    tip = self._tip_pose(pose_of(parent), angles)
                    poses[module.name] = compose_base_pose(tip[0], tip[1], module)
            return poses[module.name]

        return [pose_of(m) for m in self.scene.modules]

    def _tip_pose(self, base_pose, angles):
        """Robot-frame pose of the last rib of a module with the given base pose, angles."""
        position, orientation = base_pose
        tip_xy_mm = geometry.rib_centers(angles, self.skeleton.spacing_mm)[-1]
        heading = float(np.sum(angles))
        rot = np.array(quaternion_to_matrix(tuple(orientation)))
        tip = np.asarray(position) + rot @ np.array([tip_xy_mm[0], tip_xy_mm[1], 0.0]) * 1e-3
        c, s = math.cos(heading / 2.0), math.sin(heading / 2.0)
        return tuple(tip.tolist()), _quat_multiply(tuple(orientation), (0.0, 0.0, s, c))


def _quat_multiply(q1, q2):
    """Hamilton product of two xyzw quaternions (q1 then q2 in the body frame)."""
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)
