"""Newton solve and certification on the path tables: the batch engine.

Owns the start from the path tables, the bordered Newton on the KKT system vectorised
over a batch (:mod:`.single` has its plain-float variant for one solve), with its early
exit when the start is already the answer (:func:`_solve_arrays_inner`), the
second-order check (:func:`_curvature`), the acceptance test against the public
contracts (:func:`_finish`) and the robust fallback (exact per-segment solves,
safeguarded Newton on the tension) for whatever Newton cannot certify. Every batch
solve goes through :func:`_solve_arrays`: ``solve_forward_batch``, ``sweep``,
``PreparedBatch`` and the single solve's fallback.
"""
from __future__ import annotations

import numpy as np

from ..geometry import _g_series, segment_length_derivatives
from .branch import _branch_solve
from .path import _PER_ITEM
from .start_polynomials import _START_DEGREE
from .results import CONSTRAINT_TOL_MM, MAX_ITER, STATIONARITY_TOL_RAD


# Internal targets, tighter than the public contracts, so results are accurate to a few
# ulp of the lengths; the loop stops early if rounding prevents reaching them.
_INNER_TOL_MM = 1e-12
_INNER_TOL_RAD = 1e-14

_START_POWERS = np.arange(_START_DEGREE + 1, dtype=float)
# The batch Newton iterates on the unconverged rows alone once they are at most this
# fraction of the batch (slicing the per-row data costs about one iteration).
_SHRINK_FRACTION = 0.5
#: Constraint target of the Newton loops in units in the last place of the cable length:
#: the inner target is ``max(1e-12 mm, _CONSTRAINT_ULPS ulp(L))`` (1e-12 mm up to 512 mm).
_CONSTRAINT_ULPS = 16


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


def _constraint_targets(L_t, tol_mm):
    """Per-row constraint target of the Newton loops (mm): ``tol_mm``, or
    :data:`_CONSTRAINT_ULPS` ulp of the cable length where that is larger."""
    # 1e-12 mm is ~2 ulp of a 3.5 m cable (192 ribs), below what a sum of 191 lengths
    # resolves.
    return np.maximum(tol_mm, _CONSTRAINT_ULPS * np.spacing(np.abs(L_t)))


def _evaluate(P, L_t, lam, b, kick=True):
    """One evaluation of the KKT system at ``(lam, b)``, as every Newton iteration
    starts: ``(state, fixed)``.

    Past its buckling tension a mirror segment at ``b = 0`` sits on the unstable trivial
    root: with ``kick`` it is first restarted on its branch (``b`` changed in place;
    the start of :func:`_solve_arrays_inner` has done that already). The other straight
    mirror segments are held. ``state`` holds the point, the first and second
    derivatives of the segment lengths, the constraint ``g`` (mm) and the stationarity
    residual ``stat`` (rad, over the free segments) per row, and the held and contact
    masks; ``fixed`` is held or at contact.
    """
    lamc = lam[:, None]
    if P['has_mirror']:
        mirror = P['mirror']
        held = mirror & (b <= 0.0)
        if kick:
            kicked = held & (lamc > P['lam_c'])
            if kicked.any():
                _restart_on_branch(P, lam, b, kicked)
                held = mirror & (b <= 0.0)
    else:
        held = np.zeros(b.shape, dtype=bool)
    contact = (b >= P['b_end']) & (lamc >= P['lam_end'])
    fixed = held | contact
    length, lp, l_aa = _branch_eval(b, P)
    g = length.sum(axis=1) - L_t
    f = b + lamc * lp * P['inv_two_k']
    f[fixed] = 0.0
    stat = np.abs(f).max(axis=1)
    return dict(lam=lam, b=b, lp=lp, l_aa=l_aa, g=g, stat=stat, held=held,
                contact=contact), fixed


def _restart_on_branch(P, lam, b, segments):
    """Set the mirror ``segments`` (mask) of ``b`` to their branch at tension ``lam``."""
    r = np.nonzero(segments.any(axis=1))[0]
    b[r] = np.where(segments[r], _kick_b(P, lam[r], r), b[r])


def _unmet(state, tol_mm, tol_rad, active=None):
    """Rows of an evaluation that miss the inner targets (constraint ``tol_mm`` per row,
    stationarity ``tol_rad``), among the ``active`` ones (all if None): Newton steps on
    these, and stops when there are none."""
    unmet = (np.abs(state['g']) > tol_mm) | (state['stat'] > tol_rad)
    return unmet if active is None else active & unmet


def _stopped(P, state, iters):
    """``state`` (an evaluation Newton stops at) with its curvatures and iteration counts."""
    state['curv'] = _curvature(P, state['lam'], state['b'], state['lp'], state['l_aa'],
                               state['held'])
    state['iters'] = iters
    return state


def _newton(P, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad, active=None,
            first=None):
    """Bordered Newton on the KKT system, active sets following the branch rule.

    Free segments solve ``k phi(b) = lambda`` with ``phi(b) = 2 b / -l'(b)``, which is
    ``2 k b + lambda l'(b) = 0`` divided by ``-l' > 0``: this removes the trivial root
    ``b = 0`` of mirror segments and keeps the Schur complement well conditioned right
    at a buckling point (there ``l'/phi'`` stays finite while both vanish). Mirror
    segments with ``b = 0`` and ``lambda <= lam_c`` are held straight; segments at
    ``b_end`` with ``lambda >= lam_end`` are held at contact. O(n) per iteration.

    ``tol_mm`` is the per-row constraint target (:func:`_constraint_targets`), ``active``
    the rows to iterate (all if None). ``first`` is the caller's :func:`_evaluate` of
    ``(lam, b)`` when it made one: the first iteration uses it instead of evaluating
    again.
    """
    b_end, two_k = P['b_end'], P['two_k']
    iters = np.zeros(L_t.shape, dtype=int)
    for it in range(max_iter + 1):
        if first is None:
            state, fixed = _evaluate(P, L_t, lam, b)
        else:
            (state, fixed), first = first, None
        g, lp, l_aa = state['g'], state['lp'], state['l_aa']
        active = _unmet(state, tol_mm, tol_rad, active)
        n_active = int(np.count_nonzero(active))
        if it == max_iter or n_active == 0:
            break
        if n_active <= _SHRINK_FRACTION * active.shape[0] and n_active < active.shape[0]:
            # Most rows are done: iterate on the rest only (converged rows keep this
            # evaluation, which is what certifies them).
            return _newton_rest(P, L_t, lam, b, lam_lo, lam_hi, max_iter - it, tol_mm,
                                tol_rad, active, iters, state)
        iters += active
        lamc = lam[:, None]
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
    return _stopped(P, state, iters)


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
    merged = iters.copy()
    merged[rows] += st['iters']
    return _stopped(P, out, merged)


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
    if not P['has_mirror']:
        return eq       # nothing held: only mirror segments can be
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
                  start=None, early_exit=True):
    """Solve a batch; returns a dict of result arrays (angles, tension, residuals...).

    ``start`` is ``(lambda, b, lam_lo, lam_hi)`` as :func:`_start_from_table` gives it,
    when the caller computed it another way (``batch.PreparedBatch``); its ``b`` may be
    changed in place. ``early_exit=False`` runs Newton's loop even when the start is
    certified (the same answers bit for bit; for tests).
    """
    # One floating-point context for the whole solve: divisions by zero only occur in
    # masked-out entries (held or contact segments) and are never used.
    with np.errstate(all='ignore'):
        return _solve_arrays_inner(P, L_t, max_iter, tol_mm, tol_rad, start, early_exit)


def _solve_arrays_inner(P, L_t, max_iter, tol_mm, tol_rad, start=None, early_exit=True):
    """:func:`_solve_arrays` inside its floating-point context.

    Newton's first evaluation is made here. When it already meets the inner targets on
    every row (slack rows aside), Newton would stop at it without a step: that is the
    common case (the quintic table start is accurate to about 1e-12 rad), and then the
    loop and its bookkeeping are skipped (an early exit, bit-identical to running it).
    Otherwise Newton starts from that evaluation. A small batch (the model node's ten
    rows) costs numpy's per-call overhead, not arithmetic, so fewer calls is what
    counts. The robust fallback takes whatever the acceptance test
    (:func:`_finish`'s ``converged``) refuses.
    """
    slack = L_t >= P['straight']
    lam, b, lam_lo, lam_hi = _start_from_table(P, L_t) if start is None else start
    tol_mm = _constraint_targets(L_t, tol_mm)
    if slack.any():
        lam = np.where(slack, 0.0, lam)
        active = ~slack      # slack rows are not iterated
    else:
        slack = active = None      # the common case: no row to mask
    if P['has_mirror']:
        # Mirror segments past their buckling tension start on their branch: straight
        # ones (the unstable trivial root, see _evaluate) and those in their first table
        # cell, where linear interpolation in lambda badly underestimates
        # b ~ sqrt(lambda - lam_c) just past the pitchfork.
        lamc = lam[:, None]
        restart = P['mirror'] & (lamc > P['lam_c']) & ((lamc < P['lam_1']) | (b <= 0.0))
        if restart.any():
            _restart_on_branch(P, lam, b, restart)
    first = _evaluate(P, L_t, lam, b, kick=False) if early_exit else None
    if first is not None and not _unmet(first[0], tol_mm, tol_rad, active).any():
        # Newton would stop at its first evaluation without a step: skip its loop.
        st = _stopped(P, first[0], np.zeros(L_t.shape, dtype=int))
    else:
        st = _newton(P, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad,
                     active=active, first=first)
    out = _finish(P, st, slack)
    if out['converged'].all():
        return out
    # Fallback on the items Newton could not certify.
    bad = ~out['converged']
    sub = {key: (val[bad] if key in _PER_ITEM else val) for key, val in P.items()}
    # Sub-batches keep the tables of every threading; only the row map is sliced.
    lam_r, b_r, lo_r, hi_r = _robust(sub, L_t[bad], lam_lo[bad], lam_hi[bad])
    st_r = _newton(sub, L_t[bad], lam_r, b_r, lo_r, hi_r, 4, tol_mm[bad], tol_rad)
    for key in st:
        st[key] = st[key].copy()
        st[key][bad] = st_r[key]
    st['iters'][bad] += max_iter
    return _finish(P, st, slack)


def _finish(P, st, slack):
    """The result arrays of a stopped Newton state ``st`` (:func:`_stopped`).

    ``converged`` is the acceptance test against the public contracts: constraint and
    stationarity residuals within them and a strict local minimum (every curvature
    positive, segments at contact aside). ``slack`` is the mask of the slack rows (None
    if there is none): they are straight, with no tension and nothing to certify.
    """
    lam, b, g, stat, contact = st['lam'], st['b'], st['g'], st['stat'], st['contact']
    min_curv = np.where(contact, np.inf, st['curv']).min(axis=1)
    if slack is None:
        slack = np.zeros(g.shape, dtype=bool)
    else:
        lam = np.where(slack, 0.0, lam)
        b = np.where(slack[:, None], 0.0, b)
        g = np.where(slack, 0.0, g)
        stat = np.where(slack, 0.0, stat)
        min_curv = np.where(slack, 1.0, min_curv)
        contact = contact & ~slack[:, None]
    angles = P['direction'] * b
    abs_g = np.abs(g)
    is_min = min_curv > 0
    converged = (abs_g <= CONSTRAINT_TOL_MM) & (stat <= STATIONARITY_TOL_RAD) & is_min
    return dict(angles=angles, tension=lam, energy=(P['k'] * angles * angles).sum(axis=1),
                iterations=st['iters'], converged=converged, constraint_residual=abs_g,
                stationarity_residual=stat, residual=np.maximum(abs_g, stat),
                is_minimum=is_min, min_curvature=min_curv, slack=slack, at_contact=contact)
