"""Designs under manufacturing tolerance: each design's error when hole positions and the
cable length are perturbed (Monte Carlo, a fixed seed), and the re-ranking of the exact
search's designs by that error."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import forward
from .results import DesignSensitivity
from .search import MAX_TENSION
from .targets import _as_target_angles

#: Tolerance sensitivity (:func:`design_sensitivity`): Monte Carlo samples per design,
#: the default seed (the same noise draws for every design, so rankings compare like with
#: like), and how many designs of the exact search are re-ranked under tolerance.
ROBUST_SAMPLES = 128

ROBUST_SEED = 0

ROBUST_CANDIDATES = 12

#: Cable-length residual (mm) of the perturbed-module solves of the sensitivity.
_ROBUST_LENGTH_TOL_MM = 1e-9


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
