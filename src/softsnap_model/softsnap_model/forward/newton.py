"""Newton solve and certification on the path tables.

Owns the start from the path tables, the bordered Newton on the KKT system (vectorised
over a batch, and a plain-float variant for one solve), the second-order check
(:func:`_curvature`), the acceptance test against the public contracts and the robust
fallback (exact per-segment solves, safeguarded Newton on the tension) for whatever
Newton cannot certify.
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from ..geometry import _g_series, segment_length_derivatives
from .branch import _branch_solve
from .path import _PER_ITEM, _Q_DEGREE, _START_DEGREE
from .results import CONSTRAINT_TOL_MM, MAX_ITER, STATIONARITY_TOL_RAD


# Internal targets, tighter than the public contracts, so results are accurate to a few
# ulp of the lengths; the loop stops early if rounding prevents reaching them.
_INNER_TOL_MM = 1e-12
_INNER_TOL_RAD = 1e-14

#: A warm start (``initial``) is checked as the answer only when its branch magnitudes
#: are within this distance (rad, max norm) of the table start, which is itself
#: accurate to about 1e-12 rad (1e-5 in the few linear cells): a previous shape further
#: away (any real length change: one encoder count moves the angles by ~1e-4 rad) is a
#: worse start than the table and is left unused, at no cost.
WARM_START_RADIUS_RAD = 1e-6

_START_POWERS = np.arange(_START_DEGREE + 1, dtype=float)
# The batch Newton iterates on the unconverged rows alone once they are at most this
# fraction of the batch (slicing the per-row data costs about one iteration).
_SHRINK_FRACTION = 0.5
#: Constraint target of the Newton loops in units in the last place of the cable length:
#: the inner target is ``max(1e-12 mm, _CONSTRAINT_ULPS ulp(L))`` (1e-12 mm up to 512 mm).
_CONSTRAINT_ULPS = 16
# Reductions without the ndarray-method wrappers (a single solve is call overhead).
_add_reduce = np.add.reduce
_max_reduce = np.maximum.reduce
_min_reduce = np.minimum.reduce
_mul_accumulate = np.multiply.accumulate


def _start_from_table(P, L_t):
    """Initial (lambda, b) and a tension bracket from the exact path tables.

    The path tables are exact samples of the path, so ``[lam_lo, lam_hi]`` brackets the
    root of ``T(lambda) = L_t``; lambda and b come from the cell's quintic Hermite
    polynomial in the length (:func:`_path_polynomials`). Vectorised per threading
    group (tables are stored once per distinct threading).
    """
    nb, n = L_t.shape[0], P['k'].shape[1]
    lam_lo, lam_hi = np.empty(nb), np.empty(nb)
    start = np.empty((nb, n + 1))
    uid = P['uid']
    for u, (path_len, path_lam, path_poly, columns) in enumerate(P['paths']):
        sel = uid == u if len(P['paths']) > 1 else slice(None)
        L = L_t[sel]
        m = path_len.shape[0]
        j = np.clip(np.searchsorted(-path_len, -L, side='left'), 1, m - 1)
        len_lo, len_hi = path_len[j - 1], path_len[j]
        span = len_lo - len_hi
        w = np.where(span > 0, (len_lo - L) / np.where(span > 0, span, 1.0), 0.5)
        lam_lo[sel], lam_hi[sel] = path_lam[j - 1], path_lam[j]
        start[sel] = np.einsum('bp,bpc->bc', w[:, None] ** _START_POWERS,
                               path_poly[j - 1])[:, columns]
    return start[:, n], start[:, :n], lam_lo, lam_hi


def _tables(P, rows):
    """Per-segment branch tables (len(rows), n, M) of the given batch rows."""
    u = P['uid'][rows]
    return P['tables_mu'][u], P['tables_b'][u]


def _guess_b(P, lam, rows=None):
    """Branch magnitudes interpolated from the per-segment tables (no solve).

    ``lam`` holds the tensions of batch ``rows`` (all rows when None).
    """
    rows = np.arange(lam.shape[0]) if rows is None else rows
    tm, tb = _tables(P, rows)
    mu = lam[:, None] / P['k'][rows]
    m = tm.shape[-1]
    idx = np.clip(np.sum(tm < mu[..., None], axis=-1), 1, m - 1)[..., None]
    mu_lo = np.take_along_axis(tm, idx - 1, -1)[..., 0]
    mu_hi = np.take_along_axis(tm, idx, -1)[..., 0]
    b_lo = np.take_along_axis(tb, idx - 1, -1)[..., 0]
    b_hi = np.take_along_axis(tb, idx, -1)[..., 0]
    w = (mu - mu_lo) / (mu_hi - mu_lo)
    w = np.where(np.isfinite(w), np.clip(w, 0.0, 1.0), 0.5)
    return b_lo + w * (b_hi - b_lo)


def _branch_eval(b, P):
    """``l, l', l''`` along the branches (derivatives in ``b``), for ``0 <= b <= pi``.

    Same algebra as :func:`segment_length_derivatives` (product form) with the
    per-segment constants precomputed: ``e1, e2`` are the offsets times the direction,
    so ``(s + e1 b)(s + e2 b)`` is the product along the branch.
    """
    g, g_b, g_bb = _g_series(b)
    e1, e2, s = P['e1'], P['e2'], P['s']
    p1 = s + e1 * b
    p2 = s + e2 * b
    prod = p1 * p2
    prod_b = e1 * p2 + e2 * p1
    length = np.sqrt(P['dd2'] + g * prod)
    half_inv = 0.5 / length
    lp = (g_b * prod + g * prod_b) * half_inv
    lpp = (g_bb * prod + 2.0 * g_b * prod_b + P['two_e1e2'] * g - 2.0 * lp * lp) * half_inv
    return length, lp, lpp


def _newton(P, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad, active=None):
    """Bordered Newton on the KKT system, active sets following the branch rule.

    Free segments solve ``k phi(b) = lambda`` with ``phi(b) = 2 b / -l'(b)``, which is
    ``2 k b + lambda l'(b) = 0`` divided by ``-l' > 0``: this removes the trivial root
    ``b = 0`` of mirror segments and keeps the Schur complement well conditioned right
    at a buckling point (there ``l'/phi'`` stays finite while both vanish). Mirror
    segments with ``b = 0`` and ``lambda <= lam_c`` are held straight; segments at
    ``b_end`` with ``lambda >= lam_end`` are held at contact. O(n) per iteration.
    """
    lam_c, lam_end, b_end = P['lam_c'], P['lam_end'], P['b_end']
    two_k, inv_two_k = P['two_k'], P['inv_two_k']
    mirror = P['mirror']
    has_mirror = P['has_mirror']
    iters = np.zeros(L_t.shape, dtype=int)
    active = np.ones(L_t.shape, dtype=bool) if active is None else active.copy()
    held = np.zeros(b.shape, dtype=bool)
    # The constraint target scales with the cable: 1e-12 mm is ~2 ulp of a 3.5 m cable
    # (192 ribs), below what a sum of 191 lengths resolves.
    tol_mm = np.maximum(tol_mm, _CONSTRAINT_ULPS * np.spacing(np.abs(L_t)))
    for it in range(max_iter + 1):
        lamc = lam[:, None]
        if has_mirror:
            # Past its buckling tension a mirror segment at b = 0 sits on the unstable
            # trivial root: restart it on its branch.
            kick = mirror & (b <= 0.0) & (lamc > lam_c)
            if kick.any():
                r = np.nonzero(kick.any(axis=1))[0]
                b[r] = np.where(kick[r], _kick_b(P, lam[r], r), b[r])
            held = mirror & (b <= 0.0)
        contact = (b >= b_end) & (lamc >= lam_end)
        fixed = held | contact
        length, lp, l_aa = _branch_eval(b, P)
        g = length.sum(axis=1) - L_t
        f = b + lamc * lp * inv_two_k
        f[fixed] = 0.0
        stat = np.abs(f).max(axis=1)
        active &= (np.abs(g) > tol_mm) | (stat > tol_rad)
        n_active = int(np.count_nonzero(active))
        if it == max_iter or n_active == 0:
            break
        if n_active <= _SHRINK_FRACTION * active.shape[0] and n_active < active.shape[0]:
            # Most rows are done: iterate on the rest only (converged rows keep this
            # evaluation, which is what certifies them).
            return _newton_rest(P, L_t, lam, b, lam_lo, lam_hi, max_iter - it, tol_mm,
                                tol_rad, active, iters, dict(
                                    lam=lam, b=b, length=length, lp=lp, l_aa=l_aa, g=g,
                                    stat=stat, held=held, contact=contact))
        iters += active
        inv = 1.0 / lp
        ft = -two_k * b * inv - lamc                  # k phi(b) - lambda
        jac = two_k * (b * l_aa - lp) * inv * inv     # k phi'(b) > 0 on the branch
        w = lp / jac
        ft[fixed] = 0.0
        w[fixed] = 0.0
        dlam = ((w * ft).sum(axis=1) - g) / w.sum(axis=1)
        db = (dlam[:, None] - ft) / jac
        db[fixed] = 0.0
        new_lam = np.where(active, lam + dlam, lam)
        b = np.where(active[:, None], b + db, b)
        # Keep the tension inside the exact bracket; outside it (or with no free segment
        # to move, e.g. every segment a straight mirror one), bisect and restart the
        # angles from the tables instead of trusting a far Newton step.
        out = active & ~((new_lam > lam_lo) & (new_lam < lam_hi))
        if out.any():
            new_lam = np.where(out, 0.5 * (lam_lo + lam_hi), new_lam)
            r = np.nonzero(out)[0]
            b[r] = _guess_b(P, new_lam[r], r)
            # Shrink the bracket with the sign of the constraint at the rejected point.
            lam_lo = np.where(out & (g > 0), np.maximum(lam_lo, lam), lam_lo)
            lam_hi = np.where(out & (g < 0), np.minimum(lam_hi, lam), lam_hi)
        lam = new_lam
        b = np.fmin(np.fmax(b, 0.0), b_end)   # fmax also maps a NaN step to 0
    curv = _curvature(P, lam, b, lp, l_aa, held)
    return dict(lam=lam, b=b, length=length, lp=lp, l_aa=l_aa, g=g, stat=stat,
                held=held, contact=contact, curv=curv, iters=iters)


def _eval_single(b, S):
    """``l, l', l''`` of one problem's segments: :func:`_branch_eval` in fewer numpy calls.

    A single solve costs numpy's per-call overhead, not arithmetic (11-element arrays),
    so this evaluates ``Q = l^2 = (d1 - d2)^2 + g(b) (s + e1 b)(s + e2 b)`` as one
    polynomial in ``b`` per segment, whose coefficients for ``Q, Q', Q''``
    (``S['q_coef']``, :func:`.path._q_coefficients`) are the same truncated series of ``g``
    multiplied out: powers of ``b`` by one cumulative product (``pow`` costs more than
    the rest on small arrays), the three polynomials by one batched matrix product.
    Then ``l = sqrt(Q)``, ``l' = Q' / 2l``, ``l'' = (Q'' - 2 l'^2) / 2l``, the algebra
    of :func:`_branch_eval`; the two agree to a few ulp.
    """
    powers = np.empty((b.shape[0], _Q_DEGREE + 1))
    powers[:, 0] = 1.0
    powers[:, 1:] = b[:, None]
    _mul_accumulate(powers, axis=1, out=powers)
    q = np.matmul(powers[:, None, :], S['q_coef'])
    length = np.sqrt(q[:, 0, 0])
    half_inv = 0.5 / length
    lp = q[:, 0, 1] * half_inv
    lpp = (q[:, 0, 2] - 2.0 * lp * lp) * half_inv
    return length, lp, lpp


def _newton_rest(P, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad, active,
                 iters, state):
    """Finish :func:`_newton` on its still-active rows as a sub-batch; merge the rest."""
    rows = np.nonzero(active)[0]
    sub = {key: (val[rows] if key in _PER_ITEM else val) for key, val in P.items()}
    st = _newton(sub, L_t[rows], lam[rows], b[rows], lam_lo[rows], lam_hi[rows], max_iter,
                 tol_mm[rows], tol_rad)
    out = {key: val.copy() for key, val in state.items()}
    for key in out:
        out[key][rows] = st[key]
    out['iters'] = iters.copy()
    out['iters'][rows] += st['iters']
    out['curv'] = _curvature(P, out['lam'], out['b'], out['lp'], out['l_aa'], out['held'])
    return out


def _newton_single(S, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad,
                   derive_lam=False):
    """:func:`_newton` for one problem with plain-float control flow.

    Same iteration and safeguards; 1-D arrays over segments and Python floats for the
    tension (a single solve is numpy's per-call overhead: ~25 small calls a step).
    The stationarity residual is computed only once the constraint is met, and the
    second-order check (:func:`_curvature_single`) only on the evaluation returned.
    A start taken without a Newton step (the path tables' quintic, or a warm start) is
    accepted only if its stationarity residual is within ``tol_rad`` times the smallest
    curvature: that bounds its angle error by about ``tol_rad`` even next to a buckling
    or contact point (where a small residual alone allows a larger error); otherwise
    Newton steps polish it to rounding. With ``derive_lam`` the tension is first
    replaced by the least-squares multiplier of the angles ``b`` (``min ||2 k b +
    lambda l'||`` over the segments neither straight nor at their branch end), from
    the first evaluation. Divisions by zero occur only in masked entries, so the
    caller enters ``np.errstate`` when segments can be held (:func:`_solve_single`).
    """
    lam_c, lam_end, b_end = S['lam_c'], S['lam_end'], S['b_end']
    two_k, inv_two_k = S['two_k'], S['inv_two_k']
    mirror, has_mirror = S['mirror'], S['has_mirror']
    lam_end_min = S['lam_end_min']
    held = contact = None
    it = 0
    first = None
    if derive_lam:
        first = _eval_single(b, S)
        lp = np.where((b < b_end) & ((b > 0.0) | ~mirror), first[1], 0.0)
        den = float(lp @ lp)
        if den > 0:
            lam = min(max(float(-(two_k * b) @ lp) / den, lam_lo), lam_hi)
    while True:
        # Mirror segments all bent (the usual case): none can be held or kicked.
        if has_mirror and float(_min_reduce(b[S['mirror_idx']])) <= 0.0:
            kick = mirror & (b <= 0.0) & (lam > lam_c)
            if kick.any():
                b = np.where(kick, _kick_b(S['P'], np.array([lam]))[0], b)
                first = None
            held = mirror & (b <= 0.0)
        else:
            held = None
        contact = (b >= b_end) & (lam >= lam_end) if lam >= lam_end_min else None
        fixed = held if contact is None else (contact if held is None else held | contact)
        if fixed is not None and not fixed.any():
            fixed = None
        if first is None:
            length, lp, l_aa = _eval_single(b, S)
        else:
            (length, lp, l_aa), first = first, None
        g = float(_add_reduce(length)) - L_t
        stat = math.inf
        if abs(g) <= tol_mm or it == max_iter:
            f = b + lam * inv_two_k * lp
            if fixed is not None:
                f[fixed] = 0.0
            stat = float(_max_reduce(np.abs(f)))
            if stat <= tol_rad or it == max_iter:
                curv_min = _curvature_single(S, lam, b, lp, l_aa, held, contact)
                if it > 0 or it == max_iter or stat <= tol_rad * min(curv_min, 1.0):
                    break
        it += 1
        inv = 1.0 / lp
        u = two_k * b * inv
        ft = -lam - u                                 # k phi(b) - lambda
        jac = (u * l_aa - two_k) * inv                # k phi'(b) > 0 on the branch
        w = lp / jac
        if fixed is not None:
            ft[fixed] = 0.0
            w[fixed] = 0.0
        dlam = (float(w @ ft) - g) / float(_add_reduce(w))
        db = (dlam - ft) / jac
        if fixed is not None:
            db[fixed] = 0.0
        new_lam = lam + dlam
        b = b + db
        if not lam_lo < new_lam < lam_hi:
            # Outside the exact bracket (or NaN): bisect, angles from the tables.
            if g > 0:
                lam_lo = max(lam_lo, lam)
            elif g < 0:
                lam_hi = min(lam_hi, lam)
            new_lam = 0.5 * (lam_lo + lam_hi)
            b = _guess_b(S['P'], np.array([new_lam]))[0]
        lam = new_lam
        b = np.fmin(np.fmax(b, 0.0), b_end)
    if held is None:
        held = np.zeros(b.shape, dtype=bool)
    if contact is None:
        contact = np.zeros(b.shape, dtype=bool)
    return dict(lam=lam, b=b, length=length, lp=lp, l_aa=l_aa, g=g, stat=stat,
                held=held, contact=contact, iters=it, curv_min=curv_min)


def _curvature_single(S, lam, b, lp, l_aa, held, contact):
    """Smallest ``1 + lambda l''/(2k)`` over the segments not at contact: the second-order
    check of :func:`_curvature` for one problem (the equilibrium form ``(l' - b l'')/l'``
    per free segment, its series next to a pitchfork, the plain form for mirror segments
    held straight); ``inf`` when every segment is at contact."""
    curv = (lp - b * l_aa) / lp
    if S['has_mirror']:
        near_pitchfork = S['mirror'] & (b < 1e-3)
        curv = np.where(near_pitchfork, S['two_beta'] * b * b, curv)
        if held is not None:
            curv = np.where(held, 1.0 + lam * l_aa * S['inv_two_k'], curv)
    if contact is None:
        return float(_min_reduce(curv))
    return float(np.min(curv, where=~contact, initial=np.inf))


def _kick_b(P, lam, rows=None):
    """Branch magnitude of mirror segments past buckling (0 where not past it).

    In the first table cell after the pitchfork (where linear interpolation of
    ``b ~ sqrt(lambda - lam_c)`` is poor) the quadratic ``phi = mu_c (1 + beta b^2)`` is
    used; beyond it the per-segment table. ``lam`` holds the tensions of ``rows``.
    """
    rows = np.arange(lam.shape[0]) if rows is None else rows
    mu = lam[:, None] / P['k'][rows]
    near = np.sqrt(np.maximum(mu / P['mu_c_safe'][rows] - 1.0, 0.0) / P['beta_safe'][rows])
    near = np.minimum(near, P['b_1'][rows])
    first = mu < P['mu_1'][rows]
    if first.all():
        return near
    return np.where(first, near, _guess_b(P, lam, rows))


def _curvature(P, lam, b, lp, l_aa, held):
    """``1 + lambda l''/(2k)`` per segment: the Lagrangian Hessian scaled by ``2k``.

    For a free segment at equilibrium this equals ``(l' - b l'')/l'``; that form is used
    (it does not depend on the accuracy of lambda) and, for a mirror segment within
    1e-3 rad of straight where ``l' - b l''`` cancels, its series ``2 beta b^2``.
    """
    eq = (lp - b * l_aa) / lp
    near_pitchfork = (P['lam_c'] > 0) & (b < 1e-3)
    eq = np.where(near_pitchfork, 2.0 * P['beta'] * b * b, eq)
    straight = 1.0 + lam[:, None] * l_aa / (2.0 * P['k'])
    return np.where(held, straight, eq)


def _robust(P, L_t, lam_lo, lam_hi, max_iter=200):
    """Safeguarded Newton/bisection on T(lambda) with exact per-segment branch solves.

    Slow (each evaluation solves every segment to machine precision) but cannot leave
    the path; used when the bordered Newton does not certify its answer.
    """
    d1, d2, k, s, direction = P['d1'], P['d2'], P['k'], P['s'], P['direction']
    lam = 0.5 * (lam_lo + lam_hi)
    for _ in range(max_iter):
        mu = lam[:, None] / k
        tm, tb = _tables(P, np.arange(lam.shape[0]))
        b = _branch_solve(mu, tm, tb, direction, d1, d2, s)
        length, l_a, l_aa = segment_length_derivatives(direction * b, d1, d2, s)
        lp = direction * l_a
        g = length.sum(axis=1) - L_t
        lam_lo = np.where(g > 0, lam, lam_lo)
        lam_hi = np.where(g < 0, lam, lam_hi)
        if np.all(np.abs(g) <= _INNER_TOL_MM) or np.all(lam_hi - lam_lo <= 1e-15 * lam_hi):
            break
        held = lam[:, None] <= P['lam_c']
        contact = lam[:, None] >= P['lam_end']
        h = 2.0 * k + lam[:, None] * l_aa
        slope = -np.sum(np.where(held | contact, 0.0, lp * lp / h), axis=1)
        step = lam - g / slope
        ok = np.isfinite(step) & (step > lam_lo) & (step < lam_hi)
        lam = np.where(ok, step, 0.5 * (lam_lo + lam_hi))
    return lam, b, lam_lo, lam_hi


def _solve_arrays(P, L_t, max_iter=MAX_ITER, tol_mm=_INNER_TOL_MM, tol_rad=_INNER_TOL_RAD,
                  start=None):
    """Solve a batch; returns a dict of result arrays (angles, tension, residuals...).

    ``start`` is ``(lambda, b, lam_lo, lam_hi)`` as :func:`_start_from_table` gives it,
    when the caller computed it another way (``batch.PreparedBatch``).
    """
    # One floating-point context for the whole solve: divisions by zero only occur in
    # masked-out entries (held or contact segments) and are never used.
    with np.errstate(all='ignore'):
        return _solve_arrays_inner(P, L_t, max_iter, tol_mm, tol_rad, start)


def _solve_arrays_inner(P, L_t, max_iter, tol_mm, tol_rad, start=None):
    slack = L_t >= P['straight']
    lam, b, lam_lo, lam_hi = _start_from_table(P, L_t) if start is None else start
    lam = np.where(slack, 0.0, lam)
    if P['has_mirror']:
        # Linear interpolation in lambda badly underestimates b ~ sqrt(lambda - lam_c)
        # just past a pitchfork; start mirror segments from their own branch instead.
        past = P['mirror'] & (lam[:, None] > P['lam_c']) & (lam[:, None] < P['lam_1'])
        if past.any():
            r = np.nonzero(past.any(axis=1))[0]
            b[r] = np.where(past[r], _kick_b(P, lam[r], r), b[r])
    st = _newton(P, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad, active=~slack)
    ok = _accept(st, slack)
    bad = ~ok
    if bad.any():
        # Fallback on the items Newton could not certify.
        sub = {key: (val[bad] if key in _PER_ITEM else val) for key, val in P.items()}
        # Sub-batches keep the tables of every threading; only the row map is sliced.
        lam_r, b_r, lo_r, hi_r = _robust(sub, L_t[bad], lam_lo[bad], lam_hi[bad])
        st_r = _newton(sub, L_t[bad], lam_r, b_r, lo_r, hi_r, 4, tol_mm, tol_rad)
        for key in st:
            st[key] = st[key].copy()
            st[key][bad] = st_r[key]
        st['iters'][bad] += max_iter
    return _finish(P, L_t, st, slack)


def _accept(st, slack):
    curv_ok = np.all(np.where(st['contact'], True, st['curv'] > 0), axis=1)
    return slack | ((np.abs(st['g']) <= CONSTRAINT_TOL_MM)
                    & (st['stat'] <= STATIONARITY_TOL_RAD) & curv_ok)


def _finish(P, L_t, st, slack):
    k = P['k']
    lam = np.where(slack, 0.0, st['lam'])
    b = np.where(slack[:, None], 0.0, st['b'])
    angles = P['direction'] * b
    length = np.where(slack[:, None], np.hypot(P['s'], P['d2'] - P['d1']), st['length'])
    contact = st['contact'] & ~slack[:, None]
    g = np.where(slack, 0.0, st['g'])
    stat = np.where(slack, 0.0, st['stat'])
    curv = np.where(contact | slack[:, None], np.inf, st['curv'])
    min_curv = np.where(slack, 1.0, np.min(curv, axis=1))
    is_min = min_curv > 0
    converged = slack | ((np.abs(g) <= CONSTRAINT_TOL_MM) & (stat <= STATIONARITY_TOL_RAD)
                         & is_min)
    energy = np.sum(k * angles * angles, axis=1)
    del length
    return dict(angles=angles, tension=lam, energy=energy, iterations=st['iters'],
                converged=converged, constraint_residual=np.abs(g),
                stationarity_residual=stat, residual=np.maximum(np.abs(g), stat),
                is_minimum=is_min, min_curvature=min_curv, slack=slack, at_contact=contact)


def _solve_single(S, L, lam0=None, a0=None, max_iter=MAX_ITER, fallback=True):
    """One solve on the plain-float path; falls back to the batch engine (with its
    robust fallback) when the result is not certified. Returns the result dict.

    ``a0`` (angles) and ``lam0`` (tension or None) are a warm start. It is used only
    when ``a0`` is within :data:`WARM_START_RADIUS_RAD` of the table start, and then
    only if it already meets the inner tolerances (no Newton step); otherwise the solve
    is exactly the cold one. So a warm start never costs Newton iterations or accuracy.
    """
    if S['has_mirror'] or L <= S['all_free_above_mm']:
        # Segments can be held straight or at contact: divisions by zero then occur in
        # their masked-out entries, never used. Above ``all_free_above_mm`` the tension
        # stays below every branch end (Newton keeps it inside the path cell), so the
        # common case skips the context (entering one costs a few numpy calls).
        with np.errstate(all='ignore'):
            return _solve_single_inner(S, L, lam0, a0, max_iter, fallback)
    return _solve_single_inner(S, L, lam0, a0, max_iter, fallback)


def _solve_single_inner(S, L, lam0, a0, max_iter, fallback):
    tol_mm = max(_INNER_TOL_MM, _CONSTRAINT_ULPS * math.ulp(L))
    # The path cell of L: path lengths decrease along the path (bisect on the negated
    # Python list, cheaper than a numpy search for one value).
    j = min(max(bisect.bisect_left(S['neg_path_len_list'], -L), 1), S['n_path'] - 1)
    len_lo, len_hi = S['path_len_list'][j - 1], S['path_len_list'][j]
    lam_lo, lam_hi = S['path_lam_list'][j - 1], S['path_lam_list'][j]
    w = (len_lo - L) / (len_lo - len_hi) if len_lo > len_hi else 0.5
    w2 = w * w
    # The polynomials are stored once per distinct segment: gather them per segment.
    start = (np.array([1.0, w, w2, w2 * w, w2 * w2, w2 * w2 * w])
             @ S['path_poly'][j - 1])[S['path_columns']]
    b, lam = start[:-1], float(start[-1])
    st = None
    if a0 is not None:
        # Cheap screen first: the max-norm distance can be within the radius only if
        # the sums are within n times it (a NaN or inf angle fails here and raises).
        gap = float(S['direction'] @ a0) - float(b.sum())
        if not math.isfinite(gap):
            raise ValueError(f'initial: angles must be finite, got {a0.tolist()}')
        if (abs(gap) <= b.size * WARM_START_RADIUS_RAD
                and float(np.max(np.abs(S['direction'] * a0 - b))) <= WARM_START_RADIUS_RAD):
            # Close enough to be the answer: check it (one evaluation, with its own
            # tension, given or derived from it); keep it only if it already is.
            b_w = np.fmin(np.fmax(S['direction'] * a0, 0.0), S['b_end'])
            given = lam0 is not None and lam_lo <= lam0 <= lam_hi
            st = _newton_single(S, L, lam0 if given else lam, b_w, lam_lo, lam_hi, 0,
                                tol_mm, _INNER_TOL_RAD, not given)
            if not (abs(st['g']) <= tol_mm and st['stat'] <= _INNER_TOL_RAD
                    * min(st['curv_min'], 1.0)):
                st = None
    if st is None:
        # Just past a mirror segment's buckling tension (its first table cell), start it
        # from its own branch (see :func:`_solve_arrays_inner`).
        if S['has_mirror'] and any(lo < lam < hi for lo, hi in S['mirror_first_cells']):
            past = S['mirror'] & (lam > S['lam_c']) & (lam < S['lam_1'])
            b = np.where(past, _kick_b(S['P'], np.array([lam]))[0], b)
        st = _newton_single(S, L, lam, b, lam_lo, lam_hi, max_iter, tol_mm,
                            _INNER_TOL_RAD)
    curv_min = st['curv_min']
    g = abs(st['g'])
    ok = g <= CONSTRAINT_TOL_MM and st['stat'] <= STATIONARITY_TOL_RAD and curv_min > 0
    if not ok and fallback:
        with np.errstate(all='ignore'):
            out = _solve_arrays_inner(S['P'], np.array([L]), max_iter, _INNER_TOL_MM,
                                      _INNER_TOL_RAD)
        return {key: val[0] for key, val in out.items()}
    b = st['b']
    angles = S['direction'] * b
    return dict(angles=angles, tension=st['lam'], energy=float(S['k'] @ (b * b)),
                iterations=st['iters'], converged=ok, constraint_residual=g,
                stationarity_residual=st['stat'], residual=max(g, st['stat']),
                is_minimum=curv_min > 0, min_curvature=curv_min if curv_min < math.inf else 1.0,
                slack=False, at_contact=st['contact'])
