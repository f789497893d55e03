"""Design targets: angles or a polyline (fitted to segment angles), the hole set a design
may use (fixed, forbidden, allowed holes) and the allowed cable-length range."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from .. import geometry

#: Distance (mm) the first target point may lie from the base rib centre (the origin).
ORIGIN_TOL_MM = 1e-6


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
