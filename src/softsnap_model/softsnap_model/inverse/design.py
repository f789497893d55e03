"""``design_threading``: the globally best threadings and cable lengths for a target shape,
re-solved by the forward solver and verified (the method: :mod:`softsnap_model.inverse`)."""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import numpy as np

from .. import forward, geometry
from .kbest import kbest_chain
from .results import DesignResult, _Monitor
from .robustness import (ROBUST_CANDIDATES, ROBUST_SAMPLES, ROBUST_SEED, _check_count,
                         _check_quantile, _check_tolerance, _rank_under_tolerance)
from .search import BRANCH_AGREEMENT_TOL_RAD, GLOBAL_TOL_RAD, _Problem, _branch_and_bound
from .targets import (_allowed_mask, _as_length_range, _as_target_angles, _hole_table,
                      fit_angles_to_points)


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
