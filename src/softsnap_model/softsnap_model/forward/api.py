"""Public single-solve entry points: :func:`solve_forward` and :func:`reachable_range`.

Owns input validation (skeleton, threading, length, warm start, ``mirror_flip``), the
slack case, the mirror flip, rib frames of one shape and the packing of
:class:`ForwardResult`.
"""
from __future__ import annotations

import cmath
import math
import numbers

import numpy as np

from ..skeleton import Skeleton
from .path import _check_length, _problem, _single_for
from .results import MAX_ITER, ForwardResult, _forward_result
from .single import _scalars, _solve_single



def reachable_range(skeleton: Skeleton, threading) -> tuple[float, float]:
    """Range of cable lengths (mm) the quasi-static path of a threading covers.

    Returns
    -------
    (min_length_mm, straight_length_mm) : tuple of float
        Lengths in ``(min_length_mm, straight_length_mm]`` have a solution; longer
        lengths leave the cable slack (straight shape). The minimum is the length with
        every segment at its branch end (rib contact for the authors' module), an
        infimum reached only as the tension grows without bound; if the path folds
        first, it is the length at the fold.

    Examples
    --------
    >>> lo, hi = reachable_range(Skeleton(), ['R3'] * 12)
    >>> hi
    198.0
    """
    if not isinstance(skeleton, Skeleton):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')
    d = skeleton.threading_mm(threading)
    prob = _problem(skeleton, tuple(d.tolist()))
    return (prob.min_mm, prob.straight_mm)


def _frames(angles, s, d):
    """Rib centres and hole positions (..., n + 1, 2) for angles (..., n), few numpy calls.

    Points are complex numbers ``x + i y`` here: one ``exp`` gives both the cosine and
    the sine of every rib orientation ``theta``, and the chord of segment ``i`` points
    along ``theta_i + a_i / 2`` (``exp(i theta_i) exp(i a_i / 2)``) with length
    ``s sin(a_i/2) / (a_i/2)`` (closed form, well conditioned; 1 at ``a_i = 0``). The
    hole of rib ``k`` is ``d_k`` to its right: ``-i d_k exp(i theta_k)``.
    """
    lead, n = angles.shape[:-1], angles.shape[-1]
    theta = np.zeros(lead + (n + 1,))
    np.cumsum(angles, axis=-1, out=theta[..., 1:])
    half = 0.5 * angles
    rot = np.exp(1j * theta)
    sinc = np.divide(np.sin(half), half, out=np.ones(half.shape), where=half != 0.0)
    points = np.zeros((2,) + lead + (n + 1,), dtype=complex)
    centers = points[0]
    np.cumsum((s * sinc) * (rot[..., :-1] * np.exp(1j * half)), axis=-1,
              out=centers[..., 1:])
    points[1] = centers - 1j * d * rot
    xy = points.view(float).reshape((2,) + lead + (n + 1, 2))
    return xy[0], xy[1]


def _frames_single(angles, s, minus_i_d):
    """:func:`_frames` of one shape (a list of angles) as a scalar loop (a single solve
    is call overhead).

    For 11 segments a loop over Python complex numbers is half the time of the dozen
    numpy calls of the vectorised form (15 against 30-35 us) and bit-identical to it:
    the same additions in the same order (the running half-angle sum gives the chord
    direction ``theta_i + a_i / 2`` and then the next rib's ``theta_{i+1}``), the same
    ``exp``, ``sin`` and closed-form chord. ``minus_i_d`` is ``-i d`` (the holes, per
    threading).
    """
    exp, sin = cmath.exp, math.sin
    mid = minus_i_d.tolist()
    phase = 0.0
    centre = 0j
    centres = [centre]
    holes = [mid[0]]
    for a, hole in zip(angles, mid[1:]):
        h = 0.5 * a
        phase += h
        chord = exp(1j * phase)
        phase += h
        centre += (s * (sin(h) / h if h != 0.0 else 1.0)) * chord
        centres.append(centre)
        holes.append(centre + hole * exp(1j * phase))
    xy = np.array((centres, holes)).view(float).reshape(2, len(centres), 2)
    return xy[0], xy[1]


def _as_length(value, name='cable_length_mm') -> float:
    if type(value) is float:    # the common case, without the abstract-class checks
        return value
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating,
                                                         np.integer)):
        raise ValueError(f'{name} must be a real number (mm), got {value!r}')
    return float(value)


def _check_skeleton(skeleton):
    if not isinstance(skeleton, Skeleton):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')


def _initial_state(initial, n_segments):
    """(lambda0 or None, angles) from a ForwardResult or an array of angles.

    Only the shape is checked here; finiteness is checked where the angles are first
    used (:func:`_solve_single`), so a warm start costs no extra pass over them.
    """
    if isinstance(initial, ForwardResult):
        a = np.asarray(initial.angles, dtype=float)
        lam = float(initial.tension)
        lam = lam if math.isfinite(lam) else None
    else:
        a = np.asarray(initial, dtype=float)
        lam = None
    if a.shape != (n_segments,):
        raise ValueError(f'initial: expected {n_segments} angles, got shape {a.shape}')
    return lam, a


def solve_forward(skeleton: Skeleton, threading, cable_length_mm, initial=None, *,
                  max_iter: int = MAX_ITER, mirror_flip=()) -> ForwardResult:
    """Quasi-static shape of a module for a given cable length.

    Parameters
    ----------
    skeleton : Skeleton
        Module description (``Skeleton()`` is the authors' module).
    threading : sequence of str or float
        One hole per rib, rib 0 first: hole names (``'R3'``) or offsets in mm.
    cable_length_mm : float
        Cable length between the holes of rib 0 and the last rib (mm).
    initial : ForwardResult or array_like of shape (n_segments,), optional
        Warm start (e.g. the previous shape of the module). It only changes the cost:
        the answer is the same shape as a cold solve. The cold start is already a quintic
        interpolation of exact samples of the path, so a previous shape is used only
        when it is within ``WARM_START_RADIUS_RAD`` of that start and already solves
        this length (then no Newton step is taken: e.g. the same length again);
        otherwise the solve is the cold one, for about 1 us more.
    max_iter : int, optional
        Cap on bordered-Newton iterations before the robust fallback.
    mirror_flip : sequence of int, optional
        Mirror segments (``d2 = -d1``, see ``tie_break_segments``) to bend against the
        tie-break rule: the other exact branch. A mirror segment's length is even in its
        angle, so the flipped shape has the same lengths, energy, tension and
        residuals, and is a constrained minimum too. A listed segment that is still
        straight at this length stays straight.

    Returns
    -------
    ForwardResult
        Check ``converged``; residuals and the second-order check are included. A
        length at or above the straight length gives the straight shape with zero
        tension and ``slack=True``.

    Raises
    ------
    InfeasibleLengthError
        Length at or below the reachable minimum (``reachable_range_mm`` attached).
    SnapThroughError
        The path folds before the requested length (custom skeletons only).
    ValueError
        Bad skeleton, threading, length (NaN, inf, <= 0) or initial guess, or a
        ``mirror_flip`` index that is not a mirror segment.

    Examples
    --------
    >>> res = solve_forward(Skeleton(), ['R3'] * 12, 170.0)
    >>> bool(res.converged), res.angles.shape, bool(res.angles[0] < 0)
    (True, (11,), True)
    """
    _check_skeleton(skeleton)
    prob, S = _single_for(skeleton, threading)
    L = _as_length(cable_length_mm)
    if type(max_iter) is not int and (isinstance(max_iter, bool)
                                      or not isinstance(max_iter, numbers.Integral)) \
            or max_iter < 0:
        raise ValueError(f'max_iter must be an integer >= 0, got {max_iter!r}')
    flip = _mirror_flip_indices(mirror_flip, S['mirror'])
    # The bound first: the exact minimum is computed only for a length near it.
    if not (math.isfinite(L) and (L > prob.min_mm_above or L > prob.min_mm)):
        _check_length(prob, np.array([L]), skeleton, prob.d)
    lam0 = a0 = None
    if initial is not None:
        lam0, a0 = _initial_state(initial, skeleton.n_segments)
    if L >= prob.straight_mm:
        if a0 is not None and not np.isfinite(a0).all():
            raise ValueError(f'initial: angles must be finite, got {a0.tolist()}')
        n = skeleton.n_segments
        out = dict(angles=np.zeros(n), tension=0.0, energy=0.0, iterations=0,
                   converged=True, constraint_residual=0.0, stationarity_residual=0.0,
                   residual=0.0, is_minimum=True, min_curvature=1.0, slack=True,
                   at_contact=np.zeros(n, dtype=bool))
    else:
        out = _solve_single(S, L, lam0, a0, max_iter=int(max_iter))
    angles = out['angles']
    values = angles.tolist()
    # Bent mirror segments, whose direction was the tie-break (before any flip).
    tie_break = (tuple(i for i in _scalars(S).mirror_idx if values[i] != 0.0)
                 if S['has_mirror'] else ())
    if flip:
        # The mirror image of those segments: L(-a) = L(a) when d2 = -d1, so every
        # residual and the second-order check carry over unchanged.
        angles = angles.copy()
        angles[list(flip)] *= -1.0
        values = angles.tolist()
    centers, holes = _frames_single(values, prob.s, S['minus_i_d'])
    slack = bool(out['slack'])
    converged = bool(out['converged'])
    if slack:
        message = 'slack cable: length at or above the straight length, straight shape'
    elif converged:
        message = 'converged'
    else:
        message = ('not converged: residuals or the second-order check failed '
                   f'(constraint {out["constraint_residual"]:.3g} mm, stationarity '
                   f'{out["stationarity_residual"]:.3g} rad, min curvature '
                   f'{out["min_curvature"]:.3g})')
    return _forward_result(
        angles=angles, rib_centers=centers, cable_path=holes,
        energy=float(out['energy']), tension=float(out['tension']),
        iterations=int(out['iterations']), converged=converged,
        residual=float(out['residual']),
        constraint_residual=float(out['constraint_residual']),
        stationarity_residual=float(out['stationarity_residual']),
        is_minimum=bool(out['is_minimum']), min_curvature=float(out['min_curvature']),
        slack=slack, at_contact=out['at_contact'], cable_length_mm=L, message=message,
        tie_break_segments=tie_break,
        mirror_flip=flip)


def _mirror_flip_indices(mirror_flip, mirror) -> tuple:
    """Validated, sorted distinct segment indices of ``mirror_flip`` (mirror segments)."""
    if mirror_flip is None or (type(mirror_flip) is tuple and not mirror_flip):
        return ()
    try:
        items = list(mirror_flip)
    except TypeError:
        raise ValueError(f'mirror_flip must be a sequence of segment indices, '
                         f'got {mirror_flip!r}') from None
    n = mirror.shape[0]
    out = set()
    for j in items:
        if isinstance(j, bool) or not isinstance(j, numbers.Integral) or not 0 <= j < n:
            raise ValueError(f'mirror_flip: segment index must be an integer in '
                             f'[0, {n - 1}], got {j!r}')
        if not mirror[int(j)]:
            raise ValueError(f'mirror_flip: segment {int(j)} is not a mirror segment '
                             f'(d2 = -d1); mirror segments: '
                             f'{np.nonzero(mirror)[0].tolist()}')
        out.add(int(j))
    return tuple(sorted(out))
