"""Inverse design: the globally best threading and cable length for a desired module shape.

Problem. A skeleton has ``n`` ribs and ``m`` holes per rib; a threading picks one hole per
rib and the cable length sets the shape through the quasi-static model (minimum bending
energy ``sum_i k_i a_i^2`` at the given total cable length). Given target bending angles
``t`` (one per segment, rad), find the threading ``T`` and cable length ``L`` whose
forward-solved angles ``a(T, L)`` minimise ``||a(T, L) - t||_2`` over every threading of
the hole set and every cable length.

Structure used. The cable tension ``lam`` (the Lagrange multiplier of the length
constraint) is shared by all segments, and at a fixed tension each segment's equilibrium
angle depends only on its own two holes and stiffness:
``a_i = forward.segment_angle_at_tension(lam, d_i, d_{i+1}, s, k_i)``. Hence designs are
parametrised by ``(T, lam)`` instead of ``(T, L)``; at fixed ``lam`` the best threading is
a min-sum dynamic programme over the rib chain (``O(n m^2)``), and the cable length of a
design is ``sum_i L(a_i)``, which decreases monotonically with the tension.

Globality over the tension. Along each branch of the per-segment equilibrium, ``|a|``
grows monotonically with the tension (stationarity ``2 k a = -lam L'(a)`` and stability
give ``da/dlam`` the sign of ``a``). So on a tension interval ``[lo, hi]`` every angle lies
between its values at the two ends (or, should its side change inside the interval,
within ``[-max|a|, max|a|]``). The distance of the target to these angle intervals gives
a lower bound of the cost of every threading on the interval; a k-best dynamic programme
over these lower bounds bounds the k-th best cost on the interval. Branch and bound over
the tension then splits every interval whose bound could still beat the incumbent, and
each threading the bounds point at is refined by a 1-D search over the tension. On exit
no threading of the allowed hole set, at any cable length, has an error below the
returned one minus ``GLOBAL_TOL_RAD`` (``lower_bound`` reports the certified bound).

The forward solver is the truth: every returned design is re-solved with
``forward.solve_forward`` at its cable length and the reported angles, points and errors
are those of that solve.

Bounded work. A design can be stopped from outside: ``should_stop`` (a callable, e.g.
``threading.Event().is_set``) and ``time_limit_s`` are checked between the steps of the
search (each step of the dynamic programme, each tension node, each refinement round and
each forward solve), so a stopped design ends within one step (milliseconds to tens of
milliseconds at the node's alternative cap) by raising :class:`DesignCancelled` or
:class:`DesignTimedOut`. ``progress(fraction, stage)`` reports how far the design got.
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, Mapping

import numpy as np

from . import forward, geometry
from .inverse_dp import kbest_chain

__all__ = [
    'DesignResult',
    'DesignStopped',
    'DesignCancelled',
    'DesignTimedOut',
    'DesignSensitivity',
    'design_threading',
    'design_sensitivity',
    'fit_angles_to_points',
    'GLOBAL_TOL_RAD',
    'result_to_dict',
    'add_cli',
]

#: Optimality tolerance of the branch and bound: no design has an angle error (L2, rad)
#: below the returned error minus this.
GLOBAL_TOL_RAD = 1e-6
#: Largest difference (rad) accepted between the tension-table angles of a design and
#: the forward solve at its cable length before the design is flagged as off-branch.
BRANCH_AGREEMENT_TOL_RAD = 1e-6
#: Tension grid (per unit stiffness): geometric from MIN to MAX, plus zero (slack cable).
INITIAL_TENSION_NODES = 64
MIN_TENSION = 1e-4
MAX_TENSION = 1e3  # grid top when no hole pair saturates (custom hole sets)
#: Branch and bound stops after this many rounds of interval splitting (the certified
#: lower bound is reported either way).
MAX_BB_ROUNDS = 40
#: ... or once more intervals than this remain open.
MAX_BB_INTERVALS = 4096
#: Distance (mm) the first target point may lie from the base rib centre (the origin).
ORIGIN_TOL_MM = 1e-6
#: Tolerance sensitivity (:func:`design_sensitivity`): Monte Carlo samples per design,
#: the default seed (the same noise draws for every design, so rankings compare like with
#: like), and how many designs of the exact search are re-ranked under tolerance.
ROBUST_SAMPLES = 128
ROBUST_SEED = 0
ROBUST_CANDIDATES = 12
#: Cable-length residual (mm) of the perturbed-module solves of the sensitivity.
_ROBUST_LENGTH_TOL_MM = 1e-9


@dataclasses.dataclass(frozen=True)
class DesignSensitivity:
    """Angle error of a design when the printed module deviates from it (seeded MC).

    Each sample moves every hole by an independent normal offset of standard deviation
    ``hole_tolerance_mm`` (along the rib) and the cable length by one of standard
    deviation ``length_tolerance_mm``, and forward-solves the perturbed module
    (:func:`design_sensitivity`). Errors are L2 norms of ``angles - target``, rad.

    Attributes
    ----------
    hole_tolerance_mm, length_tolerance_mm : float
        Standard deviations of the hole-offset and cable-length noise, mm.
    n_samples : int
        Monte Carlo samples.
    seed : int
        Seed of ``numpy.random.default_rng`` for the noise draws.
    median_error, p90_error, mean_error, max_error : float
        Median, 90th percentile, mean and largest error over the samples, rad.
    nominal_error : float
        Error of the design as designed (no noise), rad.
    n_at_limit : int
        Samples whose cable length is at or below the perturbed module's reachable
        range: the shape with every segment at its branch end (rib contact) is used.
    quantile, quantile_error : float
        The quantile the designs were ranked by (0.5: the median) and its error, rad.
    """

    hole_tolerance_mm: float
    length_tolerance_mm: float
    n_samples: int
    seed: int
    median_error: float
    p90_error: float
    mean_error: float
    max_error: float
    nominal_error: float
    n_at_limit: int = 0
    quantile: float = 0.5
    quantile_error: float = math.nan


class DesignStopped(ValueError):
    """A design stopped before it finished (base of the two reasons below).

    Attributes
    ----------
    stage : str
        Step of the design that was running (see :data:`DESIGN_STAGES`).
    fraction : float
        Progress reached, 0 to 1.
    elapsed_s : float
        Wall time from the start of the design to the stop, s.
    """

    def __init__(self, message, stage, fraction, elapsed_s):
        super().__init__(message)
        self.stage = stage
        self.fraction = fraction
        self.elapsed_s = elapsed_s


class DesignCancelled(DesignStopped):
    """``should_stop()`` returned true: the caller cancelled the design."""


class DesignTimedOut(DesignStopped):
    """The design ran past ``time_limit_s`` (attribute ``time_limit_s``, s)."""

    def __init__(self, message, stage, fraction, elapsed_s, time_limit_s):
        super().__init__(message, stage, fraction, elapsed_s)
        self.time_limit_s = time_limit_s


#: Stages reported to ``progress`` in order (``fraction`` never decreases).
DESIGN_STAGES = ('fit target', 'tension tables', 'branch and bound', 'polish', 'verify', 'done')


class _Monitor:
    """Cancel and time-limit checks and progress reports of one design."""

    def __init__(self, should_stop, time_limit_s, progress, started):
        self.should_stop = should_stop
        self.time_limit_s = time_limit_s
        self.deadline = None if time_limit_s is None else started + time_limit_s
        self.progress = progress
        self.started = started
        self.fraction = 0.0
        self.stage = DESIGN_STAGES[0]

    def check(self):
        """Raise DesignCancelled / DesignTimedOut when the design must stop now."""
        if self.should_stop is not None and self.should_stop():
            elapsed = time.perf_counter() - self.started
            raise DesignCancelled(
                f'design cancelled after {elapsed:.3g} s during {self.stage} '
                f'({100 * self.fraction:.0f} % done)', self.stage, self.fraction, elapsed)
        if self.deadline is not None and (now := time.perf_counter()) > self.deadline:
            elapsed = now - self.started
            raise DesignTimedOut(
                f'design exceeded its time limit of {self.time_limit_s:g} s (stopped after '
                f'{elapsed:.3g} s during {self.stage}, {100 * self.fraction:.0f} % done)',
                self.stage, self.fraction, elapsed, self.time_limit_s)

    def report(self, fraction, stage):
        """Record progress (kept monotone), tell the caller, then check for a stop."""
        self.fraction = min(max(float(fraction), self.fraction), 1.0)
        self.stage = stage
        if self.progress is not None:
            self.progress(self.fraction, stage)
        self.check()


def _no_check():
    pass


@dataclasses.dataclass(frozen=True)
class DesignResult:
    """One inverse design and, for the best one, its ranked alternatives.

    Attributes
    ----------
    threading : ndarray, shape (n_ribs,)
        Hole offset per rib, rib 0 first, in mm (positive: right side, -y).
    holes : tuple of str
        Hole name per rib.
    cable_length : float
        Cable length inside the module that produces the shape, in mm.
    angles : ndarray, shape (n_segments,)
        Forward-solved bending angle per segment, rad.
    rib_centers : ndarray, shape (n_ribs, 2)
        Forward-solved rib centres in the module base frame, mm.
    error : float
        L2 norm of ``angles - target_angles``, rad.
    position_error : float
        Largest distance between a rib centre of the design and that of the target
        shape, mm.
    alternatives : tuple of DesignResult
        Next best distinct threadings, best first (empty on the alternatives themselves).
    tension : float
        Cable tension of the design per unit stiffness (the forward solve's multiplier).
    target_angles : ndarray, shape (n_segments,)
        The target (fitted from the target points when those were given), rad.
    fit_error : float
        Largest distance of the fitted target rib centres from the target polyline, mm
        (0 for angle targets).
    lower_bound : float
        Certified lower bound of the error of any design allowed by the constraints, rad.
    n_forward_solves : int
        Calls of ``forward.solve_forward`` made by the design.
    n_tension_nodes : int
        Tensions at which the per-segment angle table was evaluated.
    n_candidates : int
        Threadings refined by the 1-D tension search.
    converged : bool
        True when the branch and bound closed the gap to ``GLOBAL_TOL_RAD``.
    message : str
        Human-readable summary, including any disagreement with the forward solver.
    solve_time : float
        Wall time of the design, s.
    sensitivity : DesignSensitivity or None
        Error under hole-position and cable-length tolerance, when
        ``design_threading`` was given a tolerance (None otherwise).
    """

    threading: np.ndarray
    holes: tuple
    cable_length: float
    angles: np.ndarray
    rib_centers: np.ndarray
    error: float
    position_error: float
    alternatives: tuple = ()
    tension: float = 0.0
    target_angles: np.ndarray | None = None
    fit_error: float = 0.0
    lower_bound: float = 0.0
    n_forward_solves: int = 0
    n_tension_nodes: int = 0
    n_candidates: int = 0
    converged: bool = True
    message: str = ''
    solve_time: float = 0.0
    sensitivity: DesignSensitivity | None = None


# --------------------------------------------------------------------------- inputs


def _as_target_angles(target_angles, n_segments):
    angles = np.asarray(target_angles, dtype=float)
    if angles.ndim != 1:
        raise ValueError(f'target_angles must be a 1-D sequence, got shape {angles.shape}')
    if angles.size != n_segments:
        raise ValueError(f'expected {n_segments} target angles (one per segment), '
                         f'got {angles.size}')
    if not np.all(np.isfinite(angles)):
        raise ValueError(f'target_angles must be finite, got {angles.tolist()}')
    return angles


def _as_points(target_points):
    points = np.asarray(target_points, dtype=float)
    if points.ndim != 2 or points.shape[1] not in (2, 3) or points.shape[0] < 2:
        raise ValueError('target_points must be an (N, 2) array of x, y in mm with N >= 2, '
                         f'got shape {points.shape}')
    if not np.all(np.isfinite(points)):
        raise ValueError('target_points must be finite, got non-finite values at rows '
                         f'{np.where(~np.all(np.isfinite(points), axis=1))[0].tolist()}')
    if points.shape[1] == 3:
        if np.any(np.abs(points[:, 2]) > ORIGIN_TOL_MM):
            raise ValueError('target_points must lie in the bending plane (z = 0), got z up '
                             f'to {np.max(np.abs(points[:, 2])):g} mm')
        points = points[:, :2]
    if np.hypot(*points[0]) > ORIGIN_TOL_MM:
        raise ValueError('target_points must start at the base rib centre (0, 0), got '
                         f'{points[0].tolist()} mm')
    return points


def _hole_table(skeleton):
    names = list(skeleton.holes_mm)
    if not names:
        raise ValueError('the skeleton has an empty hole set')
    offsets = np.array([float(skeleton.holes_mm[h]) for h in names])
    return names, offsets


def _allowed_mask(names, n_ribs, fixed_holes, forbidden_holes, allowed_holes):
    index = {h: j for j, h in enumerate(names)}

    def check(name, what):
        if name not in index:
            raise ValueError(f'{what}: unknown hole {name!r}, the skeleton has {names}')
        return index[name]

    mask = np.ones((n_ribs, len(names)), dtype=bool)
    if allowed_holes is not None:
        allowed_holes = [allowed_holes] if isinstance(allowed_holes, str) else allowed_holes
        keep = np.zeros(len(names), dtype=bool)
        for name in allowed_holes:
            keep[check(name, 'allowed_holes')] = True
        mask &= keep
    forbidden_holes = [forbidden_holes] if isinstance(forbidden_holes, str) else forbidden_holes
    for name in forbidden_holes or ():
        mask[:, check(name, 'forbidden_holes')] = False
    if fixed_holes:
        if isinstance(fixed_holes, Mapping):
            items = fixed_holes.items()
        else:
            if len(fixed_holes) != n_ribs:
                raise ValueError(f'fixed_holes as a sequence needs one entry per rib: expected '
                                 f'{n_ribs}, got {len(fixed_holes)}')
            items = enumerate(fixed_holes)
        for rib, name in items:
            if name is None or name == '':
                continue
            rib = int(rib)
            if not 0 <= rib < n_ribs:
                raise ValueError(f'fixed_holes: rib index {rib} outside 0..{n_ribs - 1}')
            j = check(name, f'fixed_holes[{rib}]')
            if not mask[rib, j]:
                raise ValueError(f'fixed_holes[{rib}] = {name!r} is forbidden or not allowed')
            row = np.zeros(len(names), dtype=bool)
            row[j] = True
            mask[rib] &= row
    empty = np.where(~mask.any(axis=1))[0]
    if empty.size:
        raise ValueError(f'no hole is allowed on rib(s) {empty.tolist()}')
    return mask


def _as_length_range(cable_length_range):
    if cable_length_range is None:
        return None
    lo, hi = (float(v) for v in cable_length_range)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0 or hi < lo:
        raise ValueError('cable_length_range must be (min_mm, max_mm) with '
                         f'0 <= min <= max, got ({lo}, {hi})')
    return lo, hi


# --------------------------------------------------------------------------- target fitting


def _resample(points, arc_mm):
    """Points of the polyline at the given arc lengths (linear extrapolation past its end)."""
    seg = np.diff(points, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    keep = seg_len > 0
    seg, seg_len = seg[keep], seg_len[keep]
    if seg_len.size == 0:
        raise ValueError('target_points must not all coincide')
    start = np.concatenate(([0.0], np.cumsum(seg_len)[:-1]))
    j = np.clip(np.searchsorted(start, arc_mm, side='right') - 1, 0, seg_len.size - 1)
    frac = (arc_mm - start[j]) / seg_len[j]
    return points[:-1][keep][j] + frac[:, None] * seg[j]


def _distance_to_polyline(query, points):
    a, b = points[:-1], points[1:]
    ab = b - a
    denom = np.maximum(np.einsum('ij,ij->i', ab, ab), 1e-300)
    rel = query[:, None, :] - a[None]
    u = np.clip(np.einsum('kij,ij->ki', rel, ab) / denom, 0.0, 1.0)
    nearest = a[None] + u[..., None] * ab[None]
    return np.min(np.linalg.norm(query[:, None, :] - nearest, axis=2), axis=1)


def fit_angles_to_points(target_points, n_segments, spacing_mm):
    """Fit bending angles so that the rib centres lie on a target polyline.

    The first guess puts rib ``k`` at arc length ``k * spacing_mm`` along the polyline
    (past its end, the last polyline segment is extended). Then, rib by rib from the
    base, each angle is moved (within 0.5 rad of the guess) to bring the next rib centre
    onto the polyline: rib centres given as the polyline are recovered exactly.

    Parameters
    ----------
    target_points : array_like, shape (N, 2)
        Polyline in the module base frame, mm, starting at the origin (rib 0 centre);
        the spine leaves the base along +x.
    n_segments : int
        Bending segments (ribs - 1).
    spacing_mm : float
        Spine arc length between adjacent ribs, mm.

    Returns
    -------
    angles : ndarray, shape (n_segments,)
        Fitted bending angles, rad.
    fit_error_mm : float
        Largest distance of a fitted rib centre from the polyline, mm.

    Examples
    --------
    >>> angles, err = fit_angles_to_points([[0, 0], [50, 0], [100, 0], [200, 0]], 11, 18.0)
    >>> float(abs(angles).max()) < 1e-9, err < 1e-9
    (True, True)
    """
    # Imported here: scipy.optimize takes ~0.5 s to import, and only polyline targets
    # need it (angle targets and every forward solve do not).
    from scipy.optimize import minimize_scalar
    points = _as_points(target_points)
    goal = _resample(points, spacing_mm * np.arange(n_segments + 1))
    chord = np.diff(goal, axis=0)
    heading = np.unwrap(np.arctan2(chord[:, 1], chord[:, 0]))
    angles = np.empty(n_segments)
    theta = 0.0
    for i in range(n_segments):  # chord i leaves rib i at heading theta + a_i / 2
        angles[i] = 2.0 * (heading[i] - theta)
        theta += angles[i]

    def gap(angle, i):
        trial = angles.copy()
        trial[i] = angle
        trial[i + 1:] = 0.0
        centre = geometry.rib_centers(trial[:i + 1], spacing_mm)[-1]
        return float(_distance_to_polyline(centre[None], points)[0])

    for i in range(n_segments):
        guess = angles[i]
        fit = minimize_scalar(lambda x: gap(x, i), bounds=(guess - 0.5, guess + 0.5),
                                       method='bounded', options={'xatol': 1e-12})
        if fit.fun < gap(guess, i):
            # Keep the rest of the chain on its guessed headings.
            delta = fit.x - guess
            angles[i] = fit.x
            if i + 1 < n_segments:
                angles[i + 1] -= delta
    fit_error = float(np.max(_distance_to_polyline(
        geometry.rib_centers(angles, spacing_mm), points)))
    return angles, fit_error


# --------------------------------------------------------------------------- tension tables


class _Problem:
    """Per-design data shared by the table, bound and refinement steps."""

    def __init__(self, skeleton, target, mask, length_range, n_best):
        self.skeleton = skeleton
        #: Called between steps of the search; raises to stop the design.
        self.check = _no_check
        #: report(fraction, stage): progress, then a check.
        self.report = lambda fraction, stage: None
        self.names, self.offsets = _hole_table(skeleton)
        self.spacing = skeleton.spacing_mm
        self.stiffness = skeleton.stiffness_array
        # a(lam; k) depends on lam / k only: tabulate each distinct stiffness once.
        self.unique_k, self.k_index = np.unique(self.stiffness, return_inverse=True)
        self.target = target
        self.mask = mask
        self.length_range = length_range
        self.n_best = n_best

        self.contact_rad = skeleton.contact_angle_rad
        m = self.offsets.size
        d1, d2 = np.broadcast_arrays(self.offsets[:, None], self.offsets[None, :])
        self.pair_d1, self.pair_d2 = d1.ravel(), d2.ravel()
        self.pair_grid = np.arange(m * m).reshape(m, m)
        branch = forward.segment_branch(self.pair_d1, self.pair_d2, self.spacing,
                                        self.contact_rad)
        #: Tension (per unit stiffness) beyond which no pair's angle changes any more.
        finite = branch.end_tension[np.isfinite(branch.end_tension)]
        self.saturation_tension = float(finite.max()) if finite.size else MAX_TENSION
        self.end_angle = (branch.direction * branch.end_angle_rad).reshape(m, m)

    def angles(self, lam, pair, k):
        """Branch angles (rad) of hole pairs (flat indices) at tensions, broadcasting;
        ``lam = inf`` gives the branch ends (every segment at contact)."""
        return forward.segment_angle_at_tension(lam, self.pair_d1[pair], self.pair_d2[pair],
                                                self.spacing, k, self.contact_rad)

    def table(self, lam):
        """Angles and segment lengths (N, n_seg, m, m) at tensions lam (N,)."""
        lam = np.asarray(lam, dtype=float)
        finite = np.isfinite(lam)
        a_u = self.angles(np.where(finite, lam, 0.0)[:, None, None, None],
                          self.pair_grid[None, None],
                          self.unique_k[None, :, None, None])
        a_u = np.where(finite[:, None, None, None], a_u, self.end_angle)
        a = a_u[:, self.k_index]
        d1 = self.offsets[:, None]
        d2 = self.offsets[None, :]
        return a, geometry.segment_length(a, d1, d2, self.spacing)

    def path_angles(self, paths, lam):
        """Angles (..., n_seg) of threadings paths (..., n_ribs) at tensions lam (...)."""
        m = self.offsets.size
        pair = paths[..., :-1] * m + paths[..., 1:]
        return self.angles(np.asarray(lam)[..., None], pair, self.stiffness)

    def path_length(self, paths, angles):
        d = self.offsets[paths]
        return np.sum(geometry.segment_length(angles, d[..., :-1], d[..., 1:], self.spacing),
                      axis=-1)

    def feasible(self, length):
        if self.length_range is None:
            return np.ones(np.shape(length), dtype=bool)
        lo, hi = self.length_range
        return (length >= lo) & (length <= hi)


def _angle_hull(a_lo, a_hi):
    """Range of a monotone-in-|a| branch between its values at the interval ends."""
    lo = np.minimum(a_lo, a_hi)
    hi = np.maximum(a_lo, a_hi)
    flip = (a_lo * a_hi) < 0.0
    if np.any(flip):
        big = np.maximum(np.abs(a_lo), np.abs(a_hi))
        lo = np.where(flip, -big, lo)
        hi = np.where(flip, big, hi)
    return lo, hi


# Lagrange multipliers (rad^2 per mm) tried for the cable-length bounds.
_LENGTH_MULTIPLIERS = np.array([1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])


# --------------------------------------------------------------------------- 1-D refinement


_REFINE_SAMPLES = 9
_REFINE_ROUNDS = 6
_GAUSS_NEWTON_STEPS = 8


def _refine(prob, paths, lam_lo, lam_hi, rounds=_REFINE_ROUNDS):
    """Best tension of each threading on its bracket: sampling, then Gauss-Newton.

    Returns (cost, lam) per threading; cost is inf where no tension in the bracket
    meets the cable-length range.
    """
    n_c = paths.shape[0]
    lo = np.asarray(lam_lo, dtype=float).copy()
    hi = np.asarray(lam_hi, dtype=float).copy()
    best_cost = np.full(n_c, np.inf)
    best_lam = lo.copy()
    u = np.linspace(0.0, 1.0, _REFINE_SAMPLES)

    def evaluate(lam):
        a = prob.path_angles(paths[:, None, :] if lam.ndim == 2 else paths, lam)
        cost = np.sum((a - prob.target) ** 2, axis=-1)
        if prob.length_range is not None:
            length = prob.path_length(paths[:, None, :] if lam.ndim == 2 else paths, a)
            cost = np.where(prob.feasible(length), cost, np.inf)
        return cost, a

    for _ in range(rounds):
        prob.check()
        geometric = lo > 0.0
        lam = np.where(geometric[:, None],
                       np.exp(np.log(np.where(geometric, lo, 1.0))[:, None]
                              + u * np.log(np.where(geometric, hi / np.where(geometric, lo, 1.0),
                                                    1.0))[:, None]),
                       lo[:, None] + u * (hi - lo)[:, None])
        cost, _ = evaluate(lam)
        j = np.argmin(cost, axis=1)
        rows = np.arange(n_c)
        better = cost[rows, j] < best_cost
        best_cost = np.where(better, cost[rows, j], best_cost)
        best_lam = np.where(better, lam[rows, j], best_lam)
        lo = lam[rows, np.maximum(j - 1, 0)]
        hi = lam[rows, np.minimum(j + 1, _REFINE_SAMPLES - 1)]

    # Gauss-Newton on the tension with da/dlam = -L'(a) / (2 k + lam L''(a)), kept
    # inside the last bracket and accepted only where it lowers the cost.
    d = prob.offsets[paths]
    lam = best_lam.copy()
    for _ in range(_GAUSS_NEWTON_STEPS):
        prob.check()
        a = prob.path_angles(paths, lam)
        _, dl, d2l = geometry.segment_length_derivatives(a, d[:, :-1], d[:, 1:], prob.spacing)
        denom = 2.0 * prob.stiffness + lam[:, None] * d2l
        slope = np.where(denom > 0.0, -dl / np.where(denom > 0.0, denom, 1.0), 0.0)
        res = a - prob.target
        num = np.sum(res * slope, axis=1)
        den = np.sum(slope * slope, axis=1)
        step = np.where(den > 0.0, -num / np.where(den > 0.0, den, 1.0), 0.0)
        trial = np.clip(lam + step, lo, hi)
        cost, _ = evaluate(trial)
        better = cost < best_cost
        if not np.any(better):
            break
        best_cost = np.where(better, cost, best_cost)
        best_lam = np.where(better, trial, best_lam)
        lam = best_lam.copy()
    return best_cost, best_lam


# --------------------------------------------------------------------------- branch and bound


class _Candidates:
    """Threadings refined so far: best cost (rad^2) and tension per threading."""

    def __init__(self, prob):
        self.prob = prob
        self.best = {}
        self.polished = set()

    def refine(self, paths, lam_lo, lam_hi, rounds=_REFINE_ROUNDS):
        if len(paths) == 0:
            return
        paths = np.asarray(paths, dtype=np.int64)
        cost, lam = _refine(self.prob, paths, np.asarray(lam_lo), np.asarray(lam_hi),
                            rounds)
        for path, c, x in zip(map(tuple, paths.tolist()), cost, lam):
            if np.isfinite(c) and (path not in self.best or c < self.best[path][0]):
                self.best[path] = (float(c), float(x))

    def ranked(self):
        return sorted(self.best.items(), key=lambda item: item[1][0])

    def record_nodes(self, lam, a, seg_len):
        """Exact k-best threadings at each tension node (length-feasible ones kept)."""
        prob = self.prob
        finite = np.isfinite(lam)
        cost = (a - prob.target[None, :, None, None]) ** 2
        if prob.length_range is not None:
            # Steer the list towards feasible lengths: penalise the excess outside range.
            lo, hi = prob.length_range
            n_seg = prob.target.size
            excess = (np.maximum(seg_len - hi / n_seg, 0.0)
                      + np.maximum(lo / n_seg - seg_len, 0.0))
            cost = cost + 1e-3 * excess
        values, paths = kbest_chain(cost, prob.mask, prob.n_best, check=prob.check)
        seg = np.arange(prob.target.size)
        for j in np.nonzero(finite)[0]:
            prob.check()
            for r in range(prob.n_best):
                if not np.isfinite(values[j, r]):
                    break
                path = paths[j, r]
                angles = a[j, seg, path[:-1], path[1:]]
                length = seg_len[j, seg, path[:-1], path[1:]].sum()
                if not prob.feasible(length):
                    continue
                c = float(np.sum((angles - prob.target) ** 2))
                key = tuple(path.tolist())
                if key not in self.best or c < self.best[key][0]:
                    self.best[key] = (c, float(lam[j]))
                    self.polished.discard(key)

    def polish(self, n, final=False):
        """Refine the tension of the n best threadings not refined since they changed."""
        todo = [(p, x) for p, (_, x) in self.ranked()[:n] if final or p not in self.polished]
        if not todo:
            return
        paths = [p for p, _ in todo]
        lam = np.array([x for _, x in todo])
        self.refine(paths, np.where(lam > 0, lam / 1.5, 0.0),
                    np.where(lam > 0, lam * 1.5, 10 * MIN_TENSION),
                    rounds=_REFINE_ROUNDS if final else 2)
        self.polished.update(paths)

    def thresholds(self, n, tol_rad):
        """Squared (r-th best error - tol) for r = 1..n (inf while fewer are known)."""
        errors = np.sqrt(sorted(c for c, _ in self.best.values())[:n])
        out = np.full(n, np.inf)
        out[:errors.size] = np.maximum(errors - tol_rad, 0.0) ** 2
        return out

    def kth_error(self, n):
        costs = sorted(c for c, _ in self.best.values())
        return math.sqrt(costs[n - 1]) if len(costs) >= n else math.inf


def _tension_nodes(prob):
    """Zero (slack), a geometric grid up to saturation, and infinity (every segment at
    its branch end: rib contact for the authors' module)."""
    k = prob.stiffness
    top = prob.saturation_tension * k.max() * (1.0 + 1e-9)
    inner = np.geomspace(MIN_TENSION * k.min(), top, INITIAL_TENSION_NODES)
    return np.concatenate(([0.0], inner, [np.inf]))


def _split(lam_lo, lam_hi):
    """Midpoints in log-tension (towards zero and infinity for the end intervals)."""
    safe_lo = np.where(lam_lo > 0.0, lam_lo, 1.0)
    safe_hi = np.where(np.isfinite(lam_hi), lam_hi, 1.0)
    mid = np.sqrt(safe_lo * safe_hi)
    mid = np.where(lam_lo > 0.0, mid, 1e-3 * lam_hi)
    return np.where(np.isfinite(lam_hi), mid, 10.0 * lam_lo)


def _finite_bracket(lam_lo, lam_hi):
    return lam_lo, np.where(np.isfinite(lam_hi), lam_hi, 10.0 * lam_lo)


def _branch_and_bound(prob, tol_rad):
    n_best = prob.n_best
    cands = _Candidates(prob)
    prob.report(0.05, 'tension tables')
    lam = _tension_nodes(prob)
    a, seg_len = prob.table(lam)
    n_nodes = lam.size
    cands.record_nodes(lam, a, seg_len)
    cands.polish(n_best)

    iv = dict(lo=lam[:-1], hi=lam[1:], a_lo=a[:-1], a_hi=a[1:],
              len_lo=seg_len[:-1], len_hi=seg_len[1:])
    lower_bound_cost = math.inf
    converged = True
    rounds = 0
    while iv['lo'].size:
        rounds += 1
        # Rounds are capped, so their count is an honest (pessimistic) measure of progress.
        prob.report(0.1 + 0.7 * (rounds - 1) / MAX_BB_ROUNDS, 'branch and bound')
        bounds = _interval_bounds(prob, iv)
        thresholds = cands.thresholds(n_best, tol_rad)
        # Prune an interval once, for every rank r, its r-th bound reaches the r-th best
        # error found minus the tolerance: then at most r - 1 threadings can beat that
        # error there, so every reported rank is within the tolerance of the true one.
        keep = np.any(bounds < thresholds[None, :], axis=1)
        done = ~keep
        if np.any(done):
            lower_bound_cost = min(lower_bound_cost, float(np.min(bounds[done, 0])))
        if not np.any(keep):
            break
        if rounds >= MAX_BB_ROUNDS or np.count_nonzero(keep) > MAX_BB_INTERVALS:
            lower_bound_cost = min(lower_bound_cost, float(np.min(bounds[keep, 0])))
            converged = False
            break
        iv = {key: value[keep] for key, value in iv.items()}
        mid = _split(iv['lo'], iv['hi'])
        a_mid, len_mid = prob.table(mid)
        n_nodes += mid.size
        cands.record_nodes(mid, a_mid, len_mid)
        cands.polish(n_best)
        iv = dict(lo=np.concatenate((iv['lo'], mid)), hi=np.concatenate((mid, iv['hi'])),
                  a_lo=np.concatenate((iv['a_lo'], a_mid)),
                  a_hi=np.concatenate((a_mid, iv['a_hi'])),
                  len_lo=np.concatenate((iv['len_lo'], len_mid)),
                  len_hi=np.concatenate((len_mid, iv['len_hi'])))
    best = cands.kth_error(1)
    lower = math.sqrt(max(lower_bound_cost, 0.0)) if math.isfinite(lower_bound_cost) else best
    return cands, dict(lower_bound=min(lower, best), converged=converged, rounds=rounds,
                       n_nodes=n_nodes, n_candidates=len(cands.best))


def _interval_bounds(prob, iv):
    """Lower bounds (B, K) of the k-best costs on each tension interval."""
    lo, hi = _angle_hull(iv['a_lo'], iv['a_hi'])
    t = prob.target[None, :, None, None]
    gap = np.maximum(lo - t, 0.0) + np.maximum(t - hi, 0.0)
    cost = gap * gap
    bounds, _ = kbest_chain(cost, prob.mask, prob.n_best, check=prob.check)
    if prob.length_range is None:
        return bounds
    # Lagrangian relaxation of  sum len_hi <= L_max  and  sum len_lo >= L_min (segment
    # lengths fall with tension): for any multiplier mu >= 0 the penalised k-best value
    # minus the constant is a valid lower bound of the length-feasible k-best value.
    l_min, l_max = prob.length_range
    for mu in _LENGTH_MULTIPLIERS:
        up, _ = kbest_chain(cost + mu * iv['len_hi'], prob.mask, prob.n_best, check=prob.check)
        bounds = np.maximum(bounds, up - mu * l_max)
        down, _ = kbest_chain(cost - mu * iv['len_lo'], prob.mask, prob.n_best,
                              check=prob.check)
        bounds = np.maximum(bounds, down + mu * l_min)
    return bounds


# --------------------------------------------------------------------------- public entry


def design_threading(skeleton, target_angles=None, target_points=None, *, k=3,
                     fixed_holes=None, forbidden_holes=(), allowed_holes=None,
                     cable_length_range=None, tol_rad=GLOBAL_TOL_RAD,
                     should_stop: Callable[[], bool] | None = None,
                     time_limit_s: float | None = None,
                     progress: Callable[[float, str], None] | None = None,
                     hole_tolerance_mm=0.0, length_tolerance_mm=0.0, robust_rank=True,
                     robust_candidates=ROBUST_CANDIDATES, robust_samples=ROBUST_SAMPLES,
                     robust_seed=ROBUST_SEED, robust_quantile=0.5):
    """Globally best threading and cable length for a desired module shape.

    Parameters
    ----------
    skeleton : Skeleton
        Hole set, geometry and stiffness of the module.
    target_angles : array_like, shape (n_segments,), optional
        Target bending angle per segment, rad (counter-clockwise positive).
    target_points : array_like, shape (N, 2), optional
        Target curve in the module base frame, mm, starting at the origin (rib 0 centre),
        spine leaving along +x. It is first fitted to angles (:func:`fit_angles_to_points`)
        and the fit error is reported. Give exactly one of the two targets.
    k : int
        Number of ranked alternatives (distinct threadings) returned besides the best.
    fixed_holes : mapping rib -> hole name, or sequence of names (None/'' = free), optional
        Holes imposed on some ribs.
    forbidden_holes : iterable of str
        Holes no rib may use.
    allowed_holes : iterable of str, optional
        Restrict every rib to these holes (default: all holes of the skeleton).
    cable_length_range : (float, float), optional
        Allowed cable lengths ``(min_mm, max_mm)``.
    tol_rad : float
        Global optimality tolerance on the L2 angle error, rad.
    should_stop : callable, optional
        Polled between the steps of the search; once it returns true the design stops
        and raises :class:`DesignCancelled` (e.g. ``threading.Event().is_set``).
    time_limit_s : float, optional
        Wall-time budget of the design from this call, s; past it the design stops at
        the next step and raises :class:`DesignTimedOut`.
    progress : callable, optional
        ``progress(fraction, stage)``: fraction done (0 to 1, never decreasing; 1 once
        the result is ready) and the step running, one of :data:`DESIGN_STAGES`.
    hole_tolerance_mm, length_tolerance_mm : float
        Printing tolerance of the hole positions and of the cable length (standard
        deviations of normal noise, mm, in [0, 5]). When either is > 0 every returned
        design carries its ``sensitivity`` (:func:`design_sensitivity`) and, with
        ``robust_rank``, the designs are ranked by their median error under that
        tolerance among the ``max(k + 1, robust_candidates)`` best designs of the exact
        search (ties: nominal error). 0 and 0 (default): nominal ranking, no
        sensitivity. Cost: the exact search for that many ranks (about 2-3x the search
        for ``k = 3``) plus one Monte Carlo per design (about 30-100 ms each).
    robust_rank : bool
        Re-rank by the error under tolerance (True) or only report it (False).
    robust_quantile : float
        Quantile of the error under tolerance that ranks the designs, in [0, 1]
        (default 0.5: the median; e.g. 0.9 for the tail).
    robust_candidates : int
        Designs of the exact search re-ranked under tolerance (1 to 64).
    robust_samples, robust_seed : int
        Monte Carlo samples per design and the seed (same noise draws for every design).

    Returns
    -------
    DesignResult
        The best design with ``alternatives`` (up to ``k`` results, best first).
        ``lower_bound`` and ``converged`` certify the nominal (noise-free) error.

    Raises
    ------
    ValueError
        Bad target (NaN, wrong length, not starting at the origin), unknown or
        over-constrained holes, bad length range, or no threading meets the constraints.
    DesignCancelled, DesignTimedOut
        (subclasses of :class:`DesignStopped`, itself a ValueError) the design was
        stopped by ``should_stop`` or ``time_limit_s``; no partial result is returned,
        since designs are not verified (forward-solved) before the end.

    Examples
    --------
    >>> from softsnap_model import Skeleton
    >>> sk = Skeleton(n_ribs=4, holes_mm={'L1': -3.0, 'R1': 3.0})
    >>> res = design_threading(sk, target_angles=[-0.1, -0.1, -0.1], k=1)
    >>> res.holes, len(res.alternatives), bool(res.error < 1e-9)
    (('R1', 'R1', 'R1', 'R1'), 1, True)
    """
    started = time.perf_counter()
    if not hasattr(skeleton, 'holes_mm') or not hasattr(skeleton, 'n_segments'):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')
    n_seg = skeleton.n_segments
    if (target_angles is None) == (target_points is None):
        raise ValueError('give exactly one of target_angles and target_points')
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
        raise ValueError(f'k must be an integer >= 0, got {k!r}')
    if isinstance(tol_rad, bool) or not isinstance(tol_rad, (int, float)) \
            or not math.isfinite(tol_rad) or tol_rad < 0:
        raise ValueError(f'tol_rad must be finite and >= 0, got {tol_rad!r}')
    if time_limit_s is not None and (
            isinstance(time_limit_s, bool) or not isinstance(time_limit_s, (int, float))
            or not time_limit_s > 0 or not math.isfinite(time_limit_s)):
        raise ValueError(f'time_limit_s must be a finite number > 0 s, got {time_limit_s!r}')
    if should_stop is not None and not callable(should_stop):
        raise ValueError(f'should_stop must be callable, got {type(should_stop).__name__}')
    monitor = _Monitor(should_stop, time_limit_s, progress, started)
    monitor.report(0.0, 'fit target')
    hole_tol = _check_tolerance('hole_tolerance_mm', hole_tolerance_mm)
    length_tol = _check_tolerance('length_tolerance_mm', length_tolerance_mm)
    robust_candidates = _check_count('robust_candidates', robust_candidates, 1, 64)
    robust_samples = _check_count('robust_samples', robust_samples, 1, 100000)
    robust_seed = _check_count('robust_seed', robust_seed, 0, 2 ** 63 - 1)
    robust_quantile = _check_quantile(robust_quantile)
    robust = hole_tol > 0.0 or length_tol > 0.0
    n_rank = int(k) + 1
    if robust and robust_rank:
        n_rank = max(n_rank, robust_candidates)
    fit_error = 0.0
    if target_points is not None:
        target, fit_error = fit_angles_to_points(target_points, n_seg, skeleton.spacing_mm)
    else:
        target = _as_target_angles(target_angles, n_seg)
    names, _ = _hole_table(skeleton)
    mask = _allowed_mask(names, skeleton.n_ribs, fixed_holes, forbidden_holes, allowed_holes)
    length_range = _as_length_range(cable_length_range)
    prob = _Problem(skeleton, target, mask, length_range, n_rank)
    prob.check, prob.report = monitor.check, monitor.report
    if length_range is not None:
        _check_length_range(prob)

    cands, stats = _branch_and_bound(prob, float(tol_rad))
    if not cands.best:
        raise ValueError('no threading allowed by the constraints reaches a cable length in '
                         f'[{length_range[0]}, {length_range[1]}] mm')
    monitor.report(0.8, 'polish')
    cands.polish(prob.n_best, final=True)
    designs, n_solves, off_branch = _verify(prob, cands.ranked(), prob.n_best, fit_error)
    notes = [f'global to {tol_rad:g} rad: no allowed design has an angle error below '
             f'{stats["lower_bound"]:.9g} rad' if stats['converged'] else
             f'branch and bound stopped after {stats["rounds"]} rounds; certified lower '
             f'bound {stats["lower_bound"]:.9g} rad']
    if off_branch:
        notes.append(f'{off_branch} design(s) forward-solved away from the tension-table '
                     'branch; their forward-solved error is reported')
    if target_points is not None:
        notes.append(f'target curve fitted to angles within {fit_error:.3g} mm')
    if robust:
        designs, note = _rank_under_tolerance(prob, designs, hole_tol, length_tol,
                                              robust_samples, robust_seed, bool(robust_rank),
                                              robust_quantile)
        designs = designs[:int(k) + 1]
        notes.append(note)
    result = dataclasses.replace(
        designs[0], alternatives=tuple(designs[1:]), lower_bound=stats['lower_bound'],
        n_forward_solves=n_solves, n_tension_nodes=stats['n_nodes'],
        n_candidates=stats['n_candidates'], converged=stats['converged'],
        message='; '.join(notes), solve_time=time.perf_counter() - started)
    if progress is not None:  # done: no check any more, the result is complete
        progress(1.0, 'done')
    return result


def _check_length_range(prob):
    """Refuse a length range no allowed threading reaches (shortest to straight)."""
    ends, ends_len = prob.table(np.array([0.0, np.inf]))
    shortest, _ = kbest_chain(ends_len[1:], prob.mask, 1)
    longest, _ = kbest_chain(-ends_len[:1], prob.mask, 1)
    lo, hi = float(shortest[0, 0]), float(-longest[0, 0])
    if prob.length_range[1] <= lo or prob.length_range[0] > hi:
        raise ValueError('no threading allowed by the constraints reaches a cable length in '
                         f'[{prob.length_range[0]}, {prob.length_range[1]}] mm; allowed '
                         f'threadings reach ({lo:.6g}, {hi:.6g}] mm')


def _verify(prob, ranked, n_wanted, fit_error):
    """Forward-solve the best candidates and rank them by their forward-solved error."""
    sk = prob.skeleton
    target_points = geometry.rib_centers(prob.target, prob.spacing)
    designs = []
    n_solves = 0
    off_branch = 0
    todo = ranked[:3 * n_wanted]
    for i, (path, (_, lam)) in enumerate(todo):
        prob.report(0.85 + 0.15 * i / len(todo), 'verify')
        path = np.asarray(path)
        offsets = prob.offsets[path]
        a_table = prob.path_angles(path, lam)
        length = float(prob.path_length(path, a_table))
        try:
            solved = forward.solve_forward(sk, offsets, length)
        except forward.InfeasibleLengthError as exc:
            # At infinite tension (every segment at contact) the length is the reachable
            # infimum; solve just above it.
            low = exc.reachable_range_mm[0] if hasattr(exc, 'reachable_range_mm') else length
            length = float(low) + 1e-7
            solved = forward.solve_forward(sk, offsets, length)
        n_solves += 1
        angles = np.asarray(solved.angles, dtype=float)
        agrees = np.max(np.abs(angles - a_table)) <= BRANCH_AGREEMENT_TOL_RAD
        off_branch += not agrees
        points = np.asarray(solved.rib_centers, dtype=float)
        designs.append(DesignResult(
            threading=offsets, holes=tuple(prob.names[j] for j in path),
            cable_length=length, angles=angles, rib_centers=points,
            error=float(np.linalg.norm(angles - prob.target)),
            position_error=float(np.max(np.linalg.norm(points - target_points, axis=1))),
            tension=float(solved.tension), target_angles=prob.target.copy(),
            fit_error=fit_error, converged=bool(solved.converged),
            message='' if solved.converged else f'forward solve: {solved.message}'))
        if len(designs) >= n_wanted and off_branch == 0:
            break
    designs.sort(key=lambda d: d.error)
    return designs[:n_wanted], n_solves, off_branch


# --------------------------------------------------------------------------- tolerance


def _perturbed_angles(skeleton, offsets, lengths, start_tension=None):
    """Forward-solved angles of many perturbed modules at once (quasi-static path).

    ``offsets`` (S, n_ribs) mm are arbitrary per-sample hole offsets and ``lengths`` (S,)
    the cable lengths. Same model as :func:`forward.solve_forward` (the separable branch
    ``a_i(lambda)`` per segment, one scalar equation ``T(lambda) = L`` per sample), but
    vectorised over the samples with each pair's branch table built without the
    process-wide profile cache, so Monte Carlo samples neither pollute nor evict it.
    Returns ``angles`` (S, n_segments) rad and ``at_limit`` (S,) bool: samples at or
    below the reachable range get the branch-end shape (every segment at contact).
    """
    s = skeleton.spacing_mm
    k = skeleton.stiffness_array
    n_s, n_ribs = offsets.shape
    shape = (n_s, n_ribs - 1)
    d1, d2 = offsets[:, :-1], offsets[:, 1:]
    prof = forward._pair_profile_array(d1.ravel(), d2.ravel(), s, skeleton.contact_angle_rad)
    direction = prof['direction'].reshape(shape)
    t_mu = prof['mu'].reshape(shape + (-1,))
    t_b = prof['b'].reshape(shape + (-1,))
    b_end = prof['b_end'].reshape(shape)
    lam_end = k * prof['mu_end'].reshape(shape)

    def branch(lam):
        b = forward._branch_solve(lam[:, None] / k, t_mu, t_b, direction, d1, d2, s)
        return (b,) + forward._branch_derivs(b, direction, d1, d2, s)

    straight = np.hypot(s, d2 - d1).sum(axis=1)
    shortest = forward._branch_derivs(b_end, direction, d1, d2, s)[0].sum(axis=1)
    slack = lengths >= straight
    at_limit = ~slack & (lengths <= shortest)
    active = ~slack & ~at_limit
    finite = np.isfinite(lam_end)
    top = np.where(finite, lam_end, 0.0).max(axis=1) * (1.0 + 1e-9)
    hi = np.where(top > 0.0, top, MAX_TENSION * float(k.max()))
    lo = np.zeros(n_s)
    lam = 0.5 * hi if start_tension is None else np.clip(
        np.full(n_s, float(start_tension)), 1e-9 * hi, 0.5 * hi)
    b = np.zeros(shape)
    with np.errstate(all='ignore'):
        for _ in range(200):
            b, length, lp, lpp = branch(lam)
            g = length.sum(axis=1) - lengths
            done = ~active | (np.abs(g) <= _ROBUST_LENGTH_TOL_MM) | (hi - lo <= 1e-15 * hi)
            if done.all():
                break
            lo = np.where(g > 0.0, lam, lo)
            hi = np.where(g < 0.0, lam, hi)
            # dT/dlambda: free segments move with db/dlambda = 1 / (k phi'(b)).
            free = (b > 0.0) & (b < b_end) & (lam[:, None] < lam_end)
            slope = np.sum(np.where(free, lp * lp * lp / (2.0 * k * (b * lpp - lp)), 0.0),
                           axis=1)
            step = lam - g / slope
            ok = np.isfinite(step) & (step > lo) & (step < hi)
            mid = np.where(lo > 0.0, np.sqrt(lo * hi), 0.5 * hi)
            lam = np.where(done, lam, np.where(ok, step, mid))
    # Bracket exhausted before the length was met: only where a branch has no finite end
    # tension (custom hole sets); the sample is then at its reachable limit.
    at_limit |= active & (np.abs(g) > 1e-6)
    b = np.where(at_limit[:, None], b_end, np.where(slack[:, None], 0.0, b))
    return direction * b, at_limit


def _check_tolerance(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) \
            or not math.isfinite(value) or not 0.0 <= value <= 5.0:
        raise ValueError(f'{name} must be a number in [0, 5] mm, got {value!r}')
    return float(value)


def _check_count(name, value, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) \
            or not low <= value <= high:
        raise ValueError(f'{name} must be an integer in [{low}, {high}], got {value!r}')
    return int(value)


def design_sensitivity(skeleton, threading, cable_length_mm, target_angles, *,
                       hole_tolerance_mm=0.0, length_tolerance_mm=0.0,
                       n_samples=ROBUST_SAMPLES, seed=ROBUST_SEED, quantile=0.5,
                       _start_tension=None):
    """Angle error of a design under hole-position and cable-length tolerance.

    Seeded Monte Carlo: each sample adds independent normal noise of standard deviation
    ``hole_tolerance_mm`` to every hole offset (along the rib) and of standard deviation
    ``length_tolerance_mm`` to the cable length, and forward-solves the perturbed module
    on its quasi-static path. A mirror pair (``d2 = -d1``) relied on to stay straight is
    no longer a mirror pair once its holes move: it bends from the start, the way the
    imperfection pulls, which is what this measures. The noise draws depend only on the
    seed and the module size (standard normals, then scaled), so designs compared with
    the same seed see the same perturbations.

    Parameters
    ----------
    skeleton : Skeleton
    threading : sequence of str or float
        One hole per rib (names or mm).
    cable_length_mm : float
        Designed cable length, mm.
    target_angles : array_like, shape (n_segments,)
        Target bending angles, rad.
    hole_tolerance_mm, length_tolerance_mm : float
        Standard deviations of the hole-offset and cable-length noise, mm, in [0, 5].
    n_samples : int
        Monte Carlo samples, 1 to 100000.
    seed : int
        Seed of ``numpy.random.default_rng``.
    quantile : float
        Extra quantile of the error to report (``quantile_error``), in [0, 1].

    Returns
    -------
    DesignSensitivity

    Notes
    -----
    Cost: one vectorised solve of all samples (branch tables of ``n_samples x
    n_segments`` new hole pairs, then a safeguarded Newton on the tension of each
    sample), roughly 1-3 ms per sample of the authors' module with both cores busy
    (``benchmarks/inverse_robust_bench.py``); each sample agrees with
    ``forward.solve_forward`` of the perturbed threading to 1e-8 rad (tested).
    A first-order (linearised) estimate would be cheaper but wrong here: a mirror
    segment's response to a hole offset is not differentiable at the straight state.

    Examples
    --------
    >>> from softsnap_model import Skeleton
    >>> sens = design_sensitivity(Skeleton(), ['R3'] * 12, 180.0, [-0.1] * 11,
    ...                           hole_tolerance_mm=0.2, n_samples=16)
    >>> sens.n_samples, sens.median_error >= 0.0
    (16, True)
    """
    if not hasattr(skeleton, 'threading_mm'):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')
    hole_tol = _check_tolerance('hole_tolerance_mm', hole_tolerance_mm)
    length_tol = _check_tolerance('length_tolerance_mm', length_tolerance_mm)
    n_samples = _check_count('n_samples', n_samples, 1, 100000)
    seed = _check_count('seed', seed, 0, 2 ** 63 - 1)
    quantile = _check_quantile(quantile)
    target = _as_target_angles(target_angles, skeleton.n_segments)
    offsets = np.asarray(skeleton.threading_mm(threading), dtype=float)
    nominal = forward.solve_forward(skeleton, offsets, cable_length_mm)
    rng = np.random.default_rng(seed)
    hole_noise = rng.standard_normal((n_samples, offsets.size))
    length_noise = rng.standard_normal(n_samples)
    angles, at_limit = _perturbed_angles(
        skeleton, offsets + hole_tol * hole_noise,
        nominal.cable_length_mm + length_tol * length_noise,
        nominal.tension if _start_tension is None else _start_tension)
    errors = np.linalg.norm(angles - target, axis=1)
    return DesignSensitivity(
        hole_tolerance_mm=hole_tol, length_tolerance_mm=length_tol, n_samples=n_samples,
        seed=seed, median_error=float(np.median(errors)),
        p90_error=float(np.quantile(errors, 0.9)), mean_error=float(np.mean(errors)),
        max_error=float(np.max(errors)),
        nominal_error=float(np.linalg.norm(nominal.angles - target)),
        n_at_limit=int(np.count_nonzero(at_limit)), quantile=quantile,
        quantile_error=float(np.quantile(errors, quantile)))


def _check_quantile(value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) \
            or not 0.0 <= value <= 1.0:
        raise ValueError(f'quantile must be a number in [0, 1], got {value!r}')
    return float(value)


def _rank_under_tolerance(prob, designs, hole_tol, length_tol, n_samples, seed, rerank,
                          quantile):
    """Attach each design's sensitivity; with ``rerank``, sort by the ``quantile`` of the
    error under tolerance (ties: nominal error). Returns (designs, note)."""
    out = []
    for design in designs:
        prob.check()  # each Monte Carlo takes 30-100 ms: a cancel or deadline stops here
        sens = design_sensitivity(prob.skeleton, design.threading, design.cable_length,
                                  prob.target, hole_tolerance_mm=hole_tol,
                                  length_tolerance_mm=length_tol, n_samples=n_samples,
                                  seed=seed, quantile=quantile,
                                  _start_tension=design.tension)
        out.append(dataclasses.replace(design, sensitivity=sens))
    what = (f'hole sigma {hole_tol:g} mm, length sigma {length_tol:g} mm, {n_samples} '
            f'samples, seed {seed}')
    if not rerank:
        return out, f'sensitivity under tolerance ({what})'
    nominal_best = out[0]
    out.sort(key=lambda d: (d.sensitivity.quantile_error, d.error))
    stat = 'median' if quantile == 0.5 else f'{quantile:g} quantile of the'
    return out, (f'ranked by {stat} error under tolerance ({what}) among the '
                 f'{len(out)} best designs of the exact search: '
                 f'{out[0].sensitivity.quantile_error:.4g} rad (nominal error '
                 f'{out[0].error:.4g} rad); the nominal best has '
                 f'{nominal_best.sensitivity.quantile_error:.4g} rad '
                 f'(nominal {nominal_best.error:.4g} rad)')


# --------------------------------------------------------------------------- command line


def add_cli(subparsers):
    """Register ``softsnap-model inverse`` (see :mod:`softsnap_model.cli`)."""
    parser = subparsers.add_parser(
        'inverse', help='globally best threading and cable length for a target shape')
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument('--angles', help='target angle per segment, rad ("a0 a1 ..." or '
                        'comma separated)')
    target.add_argument('--points', help='JSON file with the target polyline [[x, y], ...] '
                        'in mm, base frame, starting at the origin')
    parser.add_argument('--k', type=int, default=3, help='ranked alternatives (default 3)')
    parser.add_argument('--fixed', action='append', default=[],
                        help='RIB:HOLE, e.g. 0:R1 (repeatable)')
    parser.add_argument('--forbid', action='append', default=[], help='forbidden hole '
                        '(repeatable)')
    parser.add_argument('--allow', action='append', default=None, help='allowed hole '
                        '(repeatable; default all)')
    parser.add_argument('--length-range', nargs=2, type=float, metavar=('MIN_MM', 'MAX_MM'))
    parser.add_argument('--tol', type=float, default=GLOBAL_TOL_RAD,
                        help='global optimality tolerance, rad')
    parser.add_argument('--hole-tolerance', type=float, default=0.0, metavar='MM',
                        help='hole-position tolerance (1 sigma, mm): report each design\'s '
                        'error under it and rank by the median (default 0: nominal)')
    parser.add_argument('--length-tolerance', type=float, default=0.0, metavar='MM',
                        help='cable-length tolerance (1 sigma, mm), as --hole-tolerance')
    parser.set_defaults(handler=_cli_handler)


def _cli_handler(args, skeleton):
    import json

    kwargs = dict(k=args.k, forbidden_holes=args.forbid, allowed_holes=args.allow,
                  cable_length_range=args.length_range, tol_rad=args.tol,
                  hole_tolerance_mm=args.hole_tolerance,
                  length_tolerance_mm=args.length_tolerance)
    fixed = {}
    for item in args.fixed:
        rib, sep, hole = item.partition(':')
        if not sep or not rib.strip().lstrip('-').isdigit():
            raise ValueError(f'--fixed expects RIB:HOLE such as 0:R1, got {item!r}')
        fixed[int(rib)] = hole.strip()
    kwargs['fixed_holes'] = fixed or None
    if args.angles is not None:
        try:
            kwargs['target_angles'] = [float(v) for v in args.angles.replace(',', ' ').split()]
        except ValueError:
            raise ValueError(f'--angles must be numbers, got {args.angles!r}') from None
    else:
        with open(args.points) as handle:
            kwargs['target_points'] = json.load(handle)
    res = design_threading(skeleton, **kwargs)
    return result_to_dict(res)


def result_to_dict(res):
    """Plain-data (JSON-serialisable) form of a :class:`DesignResult`."""
    def one(d):
        out = {'holes': list(d.holes), 'threading_mm': d.threading.tolist(),
               'cable_length_mm': d.cable_length, 'angles_rad': d.angles.tolist(),
               'rib_centers_mm': d.rib_centers.tolist(), 'error_rad': d.error,
               'position_error_mm': d.position_error, 'tension': d.tension}
        if d.sensitivity is not None:
            # Field names carry the units: tolerances in mm, errors in rad.
            out['sensitivity'] = dataclasses.asdict(d.sensitivity)
        return out
    out = one(res)
    out.update(alternatives=[one(a) for a in res.alternatives], fit_error_mm=res.fit_error,
               target_angles_rad=res.target_angles.tolist(), lower_bound_rad=res.lower_bound,
               converged=res.converged, message=res.message, solve_time_s=res.solve_time,
               n_forward_solves=res.n_forward_solves, n_tension_nodes=res.n_tension_nodes)
    return out
