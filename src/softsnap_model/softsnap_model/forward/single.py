"""One solve in plain Python floats: the path-table start, the evaluation, the
second-order check and the bordered Newton of :func:`solve_forward`.

A single 12-rib solve is numpy's per-call overhead, not arithmetic (11-element arrays):
so here the angles are Python lists, and the only numpy calls are the start polynomial
of the path cell (one product) and the series of the segment lengths (one product of
the powers of ``b`` with their coefficients). Everything else (lengths and their
derivatives from ``Q = l^2``, the constraint, the stationarity residual, the curvature
check, the Newton step) is a loop over the segments: the iteration of the batch's
:func:`.newton._newton`, with which it agrees to rounding, and the operations, in the
same order, of the numpy single solve it replaced (cf2cb37), whose results it repeats
bit for bit. Owns :data:`WARM_START_RADIUS_RAD` and :func:`_solve_single`; whatever this
path cannot certify (or a division by zero in a degenerate skeleton) goes to the batch
engine and its robust fallback.
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from .newton import (_CONSTRAINT_ULPS, _INNER_TOL_MM, _INNER_TOL_RAD, _guess_b, _kick_b,
                     _solve_arrays_inner)
from .path import _Q_DEGREE
from .results import CONSTRAINT_TOL_MM, MAX_ITER, STATIONARITY_TOL_RAD

#: A warm start (``initial``) is checked as the answer only when its branch magnitudes
#: are within this distance (rad, max norm) of the table start, which is itself
#: accurate to about 1e-12 rad (1e-5 in the few linear cells): a previous shape further
#: away (any real length change: one encoder count moves the angles by ~1e-4 rad) is a
#: worse start than the table and is left unused, at no cost.
WARM_START_RADIUS_RAD = 1e-6

_mul_accumulate = np.multiply.accumulate
_sqrt = math.sqrt


class _Scalars:
    """Per-threading constants of the single solve as Python lists (built once per
    threading, on its first single solve, and kept in its memoised problem data)."""

    __slots__ = ('n', 'segments', 'b_cols', 'lam_col', 'q_coef', 'direction', 'k',
                 'two_k', 'inv_two_k', 'b_end', 'lam_end', 'lam_end_min', 'has_mirror',
                 'mirror', 'mirror_idx', 'mirror_cells', 'kick_range', 'two_beta', 'none')

    def __init__(self, S):
        columns = S['path_columns'].tolist()
        self.n = len(columns) - 1
        self.segments = range(self.n)
        self.b_cols, self.lam_col = columns[:-1], columns[-1]
        self.q_coef = S['q_coef']
        for name in ('direction', 'k', 'two_k', 'inv_two_k', 'b_end', 'lam_end', 'mirror',
                     'two_beta'):
            setattr(self, name, S[name].tolist())
        self.none = [False] * self.n      # no segment held, none at contact
        self.lam_end_min = S['lam_end_min']
        self.has_mirror = S['has_mirror']
        self.mirror_idx = S['mirror_idx'].tolist()
        # (segment, buckling tension, tension of its first table sample) per mirror
        # segment: past buckling, its first cell is started from its own branch.
        self.mirror_cells = [(i, lo, hi) for i, (lo, hi)
                             in zip(self.mirror_idx, S['mirror_first_cells'])]
        # The tensions of those cells together, for a one-comparison test.
        self.kick_range = (min([lo for _, lo, _ in self.mirror_cells], default=math.inf),
                           max([hi for _, _, hi in self.mirror_cells], default=-math.inf))


def _scalars(S) -> _Scalars:
    sc = S.get('scalars')
    if sc is None:
        sc = S['scalars'] = _Scalars(S)
    return sc


def _sum(values, start=0, count=None):
    """Sum of a list of floats in numpy's order (``np.add.reduce`` of a contiguous
    array: pairwise, eight running sums per block of up to 128), so that the constraint
    of a single solve is bit-identical to the batch engine's."""
    count = len(values) - start if count is None else count
    if 8 <= count < 16 and start == 0:       # 9 to 16 ribs: one block and a tail
        v = values
        total = ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]))
        for x in v[8:]:
            total += x
        return total
    if count < 8:
        total = 0.0
        for x in values[start:start + count]:
            total += x
        return total
    if count <= 128:
        r = values[start:start + 8]
        stop = start + count - count % 8
        for i in range(start + 8, stop, 8):
            r = [x + y for x, y in zip(r, values[i:i + 8])]
        total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        for x in values[stop:start + count]:
            total += x
        return total
    half = count // 2
    half -= half % 8
    return _sum(values, start, half) + _sum(values, start + half, count - half)


def _evaluate(b, sc):
    """Lists ``l, l', l''`` (derivatives in ``b``) of the segments at magnitudes ``b``.

    ``Q = l^2 = (d1 - d2)^2 + g(b) (s + e1 b)(s + e2 b)`` is one polynomial in ``b`` per
    segment whose coefficients for ``Q, Q', Q''`` are the series of ``g`` multiplied out
    (``S['q_coef']``, :func:`.path._q_coefficients`): powers of ``b`` by one cumulative
    product, the three polynomials by one batched matrix product. Then ``l = sqrt(Q)``,
    ``l' = Q' / 2l``, ``l'' = (Q'' - 2 l'^2) / 2l``: the algebra of
    :func:`.newton._branch_eval`, with which it agrees to a few ulp.
    """
    powers = np.empty((sc.n, 1, _Q_DEGREE + 1))     # (n, 1, m): rows for the product
    powers[:, 0, 0] = 1.0
    powers.T[1:] = b
    _mul_accumulate(powers, axis=2, out=powers)
    length, lp, lpp = [], [], []
    for ((q, q_b, q_bb),) in np.matmul(powers, sc.q_coef).tolist():
        if not q > 0.0:     # coinciding holes (a degenerate skeleton), or NaN
            raise ZeroDivisionError(f'segment length^2 {q!r} mm^2 is not positive')
        root = _sqrt(q)
        half_inv = 0.5 / root
        p = q_b * half_inv
        length.append(root)
        lp.append(p)
        lpp.append((q_bb - 2.0 * p * p) * half_inv)
    return length, lp, lpp


def _certify(sc, lam, b, lp, lpp, held, contact):
    """(stationarity residual, smallest curvature) of one evaluation, in one pass.

    The residual is ``max |b + lambda l'/(2k)|`` over the free segments (neither held
    nor at contact); the curvature the smallest ``1 + lambda l''/(2k)`` over the
    segments not at contact (``inf`` if none): :func:`.newton._curvature` for one
    problem, i.e. the equilibrium form ``(l' - b l'')/l'`` of a free segment, its series
    ``2 beta b^2`` within 1e-3 rad of a pitchfork, the plain form for a mirror segment
    held straight. A NaN in either stays NaN (and fails every test).
    """
    worst, lowest = 0.0, math.inf
    none = sc.none
    for bi, p, pp, ik, mirror, two_beta, is_held, at_contact in zip(
            b, lp, lpp, sc.inv_two_k, sc.mirror, sc.two_beta, held or none,
            contact or none):
        if at_contact:
            continue
        if is_held:
            c = 1.0 + lam * pp * ik
        else:
            f = abs(bi + lam * ik * p)
            if f > worst or f != f:
                worst = f
            c = two_beta * bi * bi if mirror and bi < 1e-3 else (p - bi * pp) / p
        if c < lowest or c != c:
            lowest = c
    return worst, lowest


def _newton_single(S, sc, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad,
                   derive_lam=False):
    """:func:`.newton._newton` for one problem, the angles ``b`` a list of floats.

    Same iteration and safeguards, one loop over the segments per step. The
    stationarity residual and the second-order check (:func:`_certify`) are computed
    only once the constraint is met. A start taken without a Newton
    step (the path tables' quintic, or a warm start) is accepted only if its
    stationarity residual is within ``tol_rad`` times the smallest curvature: that
    bounds its angle error by about ``tol_rad`` even next to a buckling or contact
    point (where a small residual alone allows a larger error); otherwise Newton steps
    polish it to rounding. With ``derive_lam`` the tension is first replaced by the
    least-squares multiplier of the angles ``b`` (``min ||2 k b + lambda l'||`` over the
    segments neither straight nor at their branch end), from the first evaluation.
    Held and contact segments are skipped, never divided by; a free segment with
    ``l' = 0`` (a degenerate skeleton) raises ZeroDivisionError for the caller.
    """
    segments, two_k, b_end, lam_end = sc.segments, sc.two_k, sc.b_end, sc.lam_end
    mirror, mirror_idx = sc.mirror, sc.mirror_idx
    held = contact = None
    it = 0
    first = None
    if derive_lam:
        first = _evaluate(b, sc)
        lp = first[1]
        num = den = 0.0
        for i in segments:
            if b[i] < b_end[i] and (b[i] > 0.0 or not mirror[i]):
                num -= two_k[i] * b[i] * lp[i]
                den += lp[i] * lp[i]
        if den > 0:
            lam = min(max(num / den, lam_lo), lam_hi)
    while True:
        held = None
        # Mirror segments all bent (the usual case): none can be held or kicked.
        if sc.has_mirror and min([b[i] for i in mirror_idx]) <= 0.0:
            lam_c = S['lam_c']
            kick = [i for i in mirror_idx if b[i] <= 0.0 and lam > lam_c[i]]
            if kick:
                # Past its buckling tension a straight mirror segment sits on the
                # unstable trivial root: restart it on its branch.
                with np.errstate(all='ignore'):    # table lookups, 0/0 in unused cells
                    kicked = _kick_b(S['P'], np.array([lam]))[0].tolist()
                b = list(b)
                for i in kick:
                    b[i] = kicked[i]
                first = None
            held = [mirror[i] and b[i] <= 0.0 for i in segments]
            if not any(held):
                held = None
        contact = None
        if lam >= sc.lam_end_min:
            contact = [b[i] >= b_end[i] and lam >= lam_end[i] for i in segments]
            if not any(contact):
                contact = None
        fixed = held if contact is None else (
            contact if held is None else [h or c for h, c in zip(held, contact)])
        if first is None:
            length, lp, lpp = _evaluate(b, sc)
        else:
            (length, lp, lpp), first = first, None
        g = _sum(length) - L_t
        stat = math.inf
        if abs(g) <= tol_mm or it == max_iter:
            stat, curv = _certify(sc, lam, b, lp, lpp, held, contact)
            if stat <= tol_rad or it == max_iter:
                curv_min = curv
                if it > 0 or it == max_iter or stat <= tol_rad * min(curv_min, 1.0):
                    break
        it += 1
        # Bordered step: free segments solve k phi(b) = lambda (phi = 2 b / -l'), the
        # tension from the Schur complement of the length constraint.
        ft, jac, w, wf = ([0.0] * sc.n for _ in range(4))
        for i in segments:
            if fixed is not None and fixed[i]:
                continue
            inv = 1.0 / lp[i]
            u = two_k[i] * b[i] * inv
            ft[i] = f = -lam - u                          # k phi(b) - lambda
            jac[i] = d = (u * lpp[i] - two_k[i]) * inv    # k phi'(b) > 0 on the branch
            w[i] = lp[i] / d
            wf[i] = w[i] * f
        sum_w = _sum(w)
        # No free segment to move: NaN, so the tension is bisected below.
        dlam = (_sum(wf) - g) / sum_w if sum_w != 0.0 else math.nan
        new_lam = lam + dlam
        new_b = [b[i] if fixed is not None and fixed[i] else b[i] + (dlam - ft[i]) / jac[i]
                 for i in segments]
        if not lam_lo < new_lam < lam_hi:
            # Outside the exact bracket (or NaN): bisect, angles from the tables.
            if g > 0:
                lam_lo = max(lam_lo, lam)
            elif g < 0:
                lam_hi = min(lam_hi, lam)
            new_lam = 0.5 * (lam_lo + lam_hi)
            with np.errstate(all='ignore'):
                new_b = _guess_b(S['P'], np.array([new_lam]))[0].tolist()
        lam = new_lam
        # Back into [0, b_end]; a NaN step maps to 0 (like np.fmax).
        b = [x if 0.0 < x <= end else (end if x > end else 0.0)
             for x, end in zip(new_b, b_end)]
    return dict(lam=lam, b=b, g=g, stat=stat, contact=contact, iters=it, curv_min=curv_min)


def _solve_single(S, L, lam0=None, a0=None, max_iter=MAX_ITER, fallback=True):
    """One solve on the plain-float path; falls back to the batch engine (with its
    robust fallback) when the result is not certified. Returns the result dict.
    ``fallback=False`` returns the plain path's own result, certified or not, and lets
    its ArithmeticError through.

    ``a0`` (angles) and ``lam0`` (tension or None) are a warm start. It is used only
    when ``a0`` is within :data:`WARM_START_RADIUS_RAD` of the table start, and then
    only if it already meets the inner tolerances (no Newton step); otherwise the solve
    is exactly the cold one. So a warm start never costs Newton iterations or accuracy.
    """
    sc = _scalars(S)
    S['path'].ensure(L)     # the path table is built lazily, around the lengths asked
    tol_mm = max(_INNER_TOL_MM, _CONSTRAINT_ULPS * math.ulp(L))
    # The path cell of L: path lengths decrease along the path (bisect on the negated
    # Python list, cheaper than a numpy search for one value).
    j = min(max(bisect.bisect_left(S['neg_path_len_list'], -L), 1), S['n_path'] - 1)
    len_lo, len_hi = S['path_len_list'][j - 1], S['path_len_list'][j]
    path_lam = S['path_lam']    # two items of the array (a list of it: ~5 us a new threading)
    lam_lo, lam_hi = float(path_lam[j - 1]), float(path_lam[j])
    w = (len_lo - L) / (len_lo - len_hi) if len_lo > len_hi else 0.5
    w2 = w * w
    # The polynomials are stored once per distinct segment: gather them per segment.
    start = (np.array([1.0, w, w2, w2 * w, w2 * w2, w2 * w2 * w])
             @ S['path_poly'][j - 1]).tolist()
    b = [start[c] for c in sc.b_cols]
    lam = start[sc.lam_col]
    st = None
    try:
        if a0 is not None:
            st = _warm_start(S, sc, L, lam0, a0.tolist(), b, lam, lam_lo, lam_hi, tol_mm)
        if st is None:
            # Just past a mirror segment's buckling tension (its first table cell),
            # start it from its own branch (see :func:`.newton._solve_arrays_inner`).
            if (sc.kick_range[0] < lam < sc.kick_range[1]
                    and any(lo < lam < hi for _, lo, hi in sc.mirror_cells)):
                with np.errstate(all='ignore'):
                    kicked = _kick_b(S['P'], np.array([lam]))[0].tolist()
                for i, lo, hi in sc.mirror_cells:
                    if lo < lam < hi:
                        b[i] = kicked[i]
            st = _newton_single(S, sc, L, lam, b, lam_lo, lam_hi, max_iter, tol_mm,
                                _INNER_TOL_RAD)
        curv_min = st['curv_min']
        g = abs(st['g'])
        ok = g <= CONSTRAINT_TOL_MM and st['stat'] <= STATIONARITY_TOL_RAD and curv_min > 0
    except ArithmeticError:     # l = 0 or l' = 0 (a degenerate skeleton): batch engine
        if not fallback:
            raise               # the plain path's own failure, for its tests
        ok = False
    if not ok and fallback:
        with np.errstate(all='ignore'):
            out = _solve_arrays_inner(S['P'], np.array([L]), max_iter, _INNER_TOL_MM,
                                      _INNER_TOL_RAD)
        return {key: val[0] for key, val in out.items()}
    b = st['b']
    contact = st['contact']
    return dict(angles=np.array([d * x for d, x in zip(sc.direction, b)]),
                tension=st['lam'], energy=sum([k * (x * x) for k, x in zip(sc.k, b)]),
                iterations=st['iters'], converged=ok, constraint_residual=g,
                stationarity_residual=st['stat'], residual=max(g, st['stat']),
                is_minimum=curv_min > 0, min_curvature=curv_min if curv_min < math.inf else 1.0,
                slack=False, at_contact=(np.zeros(sc.n, dtype=bool) if contact is None
                                         else np.array(contact)))


def _warm_start(S, sc, L, lam0, a0, b, lam, lam_lo, lam_hi, tol_mm):
    """The Newton state of the warm start ``a0`` (list of angles) if it already is the
    answer at the inner tolerances, else None (then the cold solve runs)."""
    # Cheap screen first: the max-norm distance can be within the radius only if the
    # sums are within n times it (a NaN or inf angle fails here and raises).
    direction = sc.direction
    gap = sum([d * a for d, a in zip(direction, a0)]) - sum(b)
    if not math.isfinite(gap):
        raise ValueError(f'initial: angles must be finite, got {a0}')
    if abs(gap) > sc.n * WARM_START_RADIUS_RAD or max(
            abs(d * a - x) for d, a, x in zip(direction, a0, b)) > WARM_START_RADIUS_RAD:
        return None
    # Close enough to be the answer: check it (one evaluation, with its own tension,
    # given or derived from it); keep it only if it already is.
    b_w = [min(max(d * a, 0.0), end) for d, a, end in zip(direction, a0, sc.b_end)]
    given = lam0 is not None and lam_lo <= lam0 <= lam_hi
    st = _newton_single(S, sc, L, lam0 if given else lam, b_w, lam_lo, lam_hi, 0, tol_mm,
                        _INNER_TOL_RAD, not given)
    if abs(st['g']) <= tol_mm and st['stat'] <= _INNER_TOL_RAD * min(st['curv_min'], 1.0):
        return st
    return None
