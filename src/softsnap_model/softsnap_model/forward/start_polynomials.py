"""Quintic start polynomials of the path: the series of the cable-length terms, the
derivatives of the path along the tension and the polynomial of each cell of a path
table, in numpy (whole tables) and in plain floats (the single solve's cells)."""
from __future__ import annotations

import functools
import math

import numpy as np

from ..geometry import _G_COEF

#: Degree of the start polynomials of the path cells (quintic Hermite, :func:`_path_polynomials`).
_START_DEGREE = 5


def _g_series_coefficients():
    """(terms, 4) power-series coefficients in ``x = b^2`` of ``g, g'/b, g'', g'''/b`` for
    ``g(b) = (2 sin(b/2)/b)^2 = sum_j gamma_j b^(2j)`` (the first three columns are
    :data:`softsnap_model.geometry._G_COEF`)."""
    gamma = _G_COEF[:, 0]
    j = np.arange(gamma.shape[0])
    third = np.zeros_like(gamma)
    # g''' = sum_j gamma_j (2j)(2j-1)(2j-2) b^(2j-3), so g'''/b has x^(j-2) terms.
    third[:-2] = (gamma * (2 * j) * (2 * j - 1) * (2 * j - 2))[2:]
    return np.column_stack([_G_COEF, third])


_G_COEF4 = _g_series_coefficients()


def _series_pairs(coef):
    """``coef`` (terms, C) split into its even and odd rows, shaped (terms/2, C, 1) to
    multiply flat ``x`` (constants of :func:`_series`)."""
    return (np.ascontiguousarray(coef[0::2, :, None]),
            np.ascontiguousarray(coef[1::2, :, None]))


_G_PAIRS4 = _series_pairs(_G_COEF4)

_G_PAIRS3 = _series_pairs(_G_COEF4[:, :3])


def _series(x, pairs):
    """Columns ``sum_j coef[j, c] x^j`` (C, N) for flat ``x`` (N,) by Estrin's scheme,
    ``pairs`` the even and odd rows of ``coef`` (:func:`_series_pairs`).

    Pairs of terms, then pairs of pairs with ``x^2``, ``x^4``, ...: about 11 numpy calls
    for 16 terms (Horner takes 30), each element-wise, so an entry's rounding does not
    depend on how many are evaluated together (``geometry._power_series`` picks its
    algorithm by size). ``coef`` has a power-of-two number of rows.
    """
    even, odd = pairs
    p = even + odd * x
    power = x
    while p.shape[0] > 1:
        power = power * power
        p = p[0::2] + p[1::2] * power
    return p[0]


def _branch_eval(b, direction, d1, d2, s, pre=None):
    """``l, l', l''`` along the branches for the path-table refinement: the series of
    :func:`_path_derivatives`, whose rounding (unlike ``segment_length_derivatives``,
    which picks its algorithm by array size) is the same for any number of entries."""
    return _path_derivatives(b, direction, d1, d2, s, third=False, pre=pre)


def _path_derivatives(b, direction, d1, d2, s, third=True, pre=None):
    """``l, l', l'', l'''`` along the branches (in the magnitude ``b``), one series pass.

    Product form of :func:`.newton._branch_eval`: ``Q = l^2 = (d1 - d2)^2 + g(b) p(b)``
    with ``p = (s + e1 b)(s + e2 b)``, ``e = d * direction`` (``g`` is even), so
    ``Q' = g' p + g p'``, ``Q'' = g'' p + 2 g' p' + g p''``, ``Q''' = g''' p + 3 g'' p' +
    3 g' p''`` (``p'' = 2 e1 e2``), and ``l' = Q'/2l``, ``l'' = (Q'' - 2 l'^2)/2l``,
    ``l''' = (Q''' - 6 l' l'')/2l``. Agrees with ``segment_length_derivatives`` to a few ulp.
    Element-wise, whatever the size (:func:`_series`). Without ``third``: ``l, l', l''`` only.
    ``pre``: ``(e1, e2, (d1 - d2)^2, 2 e1 e2)`` computed once per table (``seg``), the
    same values this computes otherwise.
    """
    x = (b * b).ravel()
    series = _series(x, _G_PAIRS4 if third else _G_PAIRS3).reshape((-1,) + b.shape)
    g, g1_over_b, g2 = series[:3]
    g1 = b * g1_over_b
    if pre is None:
        e1, e2 = d1 * direction, d2 * direction
        dd2, p_bb = (d1 - d2) ** 2, 2.0 * e1 * e2
    else:
        e1, e2, dd2, p_bb = pre
    p1, p2 = s + e1 * b, s + e2 * b
    p = p1 * p2
    p_b = e1 * p2 + e2 * p1
    length = np.sqrt(dd2 + g * p)
    half_inv = 0.5 / length
    lp = (g1 * p + g * p_b) * half_inv
    lpp = (g2 * p + 2.0 * g1 * p_b + g * p_bb - 2.0 * lp * lp) * half_inv
    if not third:
        return length, lp, lpp
    g3 = b * series[3]
    l3 = (g3 * p + 3.0 * g2 * p_b + 3.0 * g1 * p_bb - 6.0 * lp * lpp) * half_inv
    return length, lp, lpp, l3


@functools.lru_cache(maxsize=64)
def _cell_ends(n_cells):
    """(2, n_cells) indices of the start and end sample of each cell (memoised by size)."""
    ends = np.arange(n_cells) + np.array([[0], [1]])
    ends.flags.writeable = False
    return ends


# Powers of the interior points t = 1/4, 1/2, 3/4 where the start polynomials are checked.
_HULL_POWERS = np.array([0.25, 0.5, 0.75])[:, None] ** np.arange(_START_DEGREE + 1)

_HULL_POWERS_LIST = _HULL_POWERS.tolist()


def _hull_points(c):
    """(P-1, 3, n+1) values of the polynomials ``c`` (P-1, 6, n+1) at the points of
    :data:`_HULL_POWERS`, summed term by term in a fixed order (``c_0 + t c_1 + ...``;
    a matrix product may round differently), as :func:`_cell_polynomial` sums them."""
    terms = _HULL_POWERS[:, :, None] * c[:, None]       # (P-1, 3, 6, n+1)
    inner = terms[:, :, 0].copy()
    for p in range(1, _START_DEGREE + 1):
        inner += terms[:, :, p]
    return inner


def _path_polynomials(lam, length, b, lp, lpp, l3, k, lam_c, lam_end, count):
    """Quintic Hermite start polynomials of the path cells, in ``t in [0, 1]`` across a cell.

    Cell ``j`` joins samples ``j`` and ``j + 1``. Along the path every free segment has
    ``k phi(b) = lambda`` with ``phi = 2 b / -l'``, so ``u = db/dlambda = 1 / (k phi')``
    and ``v = d2b/dlambda2 = -k phi'' u^3``; the total length ``T`` has ``T' = sum l' u``
    and ``T'' = sum (l'' u^2 + l' v)``. So the exact samples (with the third derivative
    ``l3``) also give the first and second derivatives of ``lambda`` and ``b`` in the
    length, one-sided at the cell ends (a segment stops at contact, a mirror one starts
    at its buckling tension), and the quintic through values, slopes and curvatures at
    both ends is accurate to about rounding (error ~ h^6): a cold solve then usually
    certifies its start with one evaluation and no Newton step.
    The columns are distinct segments, ``count`` (n,) of them each (the sums ``T'``,
    ``T''`` weight them so).
    Returns ``c`` (P-1, 6, n+1): ``[b, lambda](t) = sum_p t^p c[j, p]``. Cells where a
    derivative is not finite (a pitchfork starts, nothing moves) or where the quintic
    would leave the cell's hull keep the linear interpolant; constant entries stay exact.
    Called under ``np.errstate(all='ignore')`` (those cells divide by zero).
    """
    vals = np.concatenate([b, lam[:, None]], axis=1)               # (P, n+1)
    p0, p1 = vals[:-1], vals[1:]
    h = (length[1:] - length[:-1])[:, None]                        # < 0 in a moving cell
    n_cells, n_cols = p0.shape
    lp2 = lp * lp
    phi1 = 2.0 * (b * lpp - lp) / lp2                          # phi'(b)
    phi2 = 2.0 * (b * l3 * lp - 2.0 * lpp * (b * lpp - lp)) / (lp2 * lp)
    u_all = 1.0 / (k * phi1)
    # Cubes as products here and in _cell_polynomial: numpy's float64 power may use
    # another pow (SIMD) than Python's float; products round the same everywhere.
    v_all = -k * phi2 * (u_all * u_all * u_all)
    # Segments moving across the whole cell (bent, not yet at their branch end).
    free = (lam[:-1, None] >= lam_c) & (lam[1:, None] <= lam_end)
    # Both cell ends at once (leading axis: cell start, cell end).
    ends = _cell_ends(n_cells)
    lp_e = lp[ends]
    u = np.where(free, u_all[ends], 0.0)
    v = np.where(free, v_all[ends], 0.0)
    # T' and T'' summed together, segments on the leading axis (contiguous rows).
    sums = np.empty((count.size, 2) + u.shape[:-1])
    rows = sums.transpose(1, 2, 3, 0)      # (2, 2, P-1, U) view of it
    np.multiply(u, lp_e, out=rows[0])
    np.add(u * u * lpp[ends], v * lp_e, out=rows[1])
    t1, t2 = _weighted_rows(sums, count)[..., None]
    # d/dlambda and d2/dlambda2 of [b, lambda]: (1, 0) for lambda.
    du, dv = np.empty(u.shape[:-1] + (n_cols,)), np.empty(u.shape[:-1] + (n_cols,))
    du[..., :-1], du[..., -1] = u, 1.0
    dv[..., :-1], dv[..., -1] = v, 0.0
    # In t: d/dt = h d/dL and d/dL = (d/dlambda) / T'.
    d0, d1 = h * du / t1
    s0, s1 = h * h * (dv / (t1 * t1) - du * t2 / (t1 * t1 * t1))
    # Quintic with the values, slopes d and second derivatives s (in t) at both ends.
    e_val = p1 - p0 - d0 - 0.5 * s0
    e_slope = d1 - d0 - s0
    e_curv = s1 - s0
    c = np.empty((n_cells, _START_DEGREE + 1, n_cols))
    c[:, 0], c[:, 1] = p0, d0
    np.multiply(0.5, s0, out=c[:, 2])
    c[:, 3] = 10.0 * e_val - 4.0 * e_slope + 0.5 * e_curv
    c[:, 4] = -15.0 * e_val + 7.0 * e_slope - e_curv
    c[:, 5] = 6.0 * e_val - 3.0 * e_slope + 0.5 * e_curv
    # Check the quintic on a few interior points: it must stay in the cell's hull.
    inner = _hull_points(c)                                 # (P-1, 3, n+1)
    lo, hi = np.minimum(p0, p1)[:, None], np.maximum(p0, p1)[:, None]
    tol = 1e-12 * (1.0 + np.abs(hi))
    smooth = (np.isfinite(c).all(axis=(1, 2)) & (h[:, 0] < 0)
              & ((inner >= lo - tol) & (inner <= hi + tol)).all(axis=(1, 2)))
    rough = ~smooth
    if rough.any():
        c[rough] = 0.0
        c[rough, 0], c[rough, 1] = p0[rough], (p1 - p0)[rough]      # the linear interpolant
    # Entries constant over a cell (held straight, at contact) stay exactly constant.
    np.copyto(c[:, 1:], 0.0, where=(p0 == p1)[:, None, :])
    return c


def _cell_polynomial(lam, length, b, derivs, k, lam_c, lam_end, count):
    """:func:`_path_polynomials` of one cell in plain Python floats (lists): the one
    cell a single solve reads of its table block, at a fraction of the cost of the
    numpy version on the whole block (~60 calls on small arrays: overhead, not
    arithmetic). The numpy version stays for whole tables (a batch's ~500 cells).

    ``lam``, ``length`` hold the cell's two samples, ``b`` and ``derivs`` (the rows of
    ``l'``, ``l''``, ``l'''``, each laid out as ``b``) their values for the U distinct
    segments; ``k``, ``lam_c``, ``lam_end``, ``count`` are lists of U. The same
    operations in the same order as :func:`_path_polynomials`, so the same bits
    (test_forward_lazy_table.py compares the two over whole tables). Returns the
    (6, U+1) rows as lists. Raises ZeroDivisionError or OverflowError where numpy
    would divide by zero or overflow (such a cell is built by :func:`_path_polynomials`).
    """
    lam0, lam1 = lam
    h = length[1] - length[0]
    free = [lam0 >= lc and lam1 <= le for lc, le in zip(lam_c, lam_end)]
    du, dv, t1, t2 = [], [], [], []     # per cell end (start, end)
    for bq, lp, lpp, l3 in zip(b, *derivs):
        u_row, v_row = [], []
        # T' and T'' summed in _weighted_rows' order (-0.0 + x is x, bit for bit).
        s1 = s2 = -0.0
        for is_free, bi, p, pp, p3, ki, w in zip(free, bq, lp, lpp, l3, k, count):
            if is_free:
                lp2 = p * p
                bend = bi * pp - p
                phi1 = 2.0 * bend / lp2
                phi2 = 2.0 * (bi * p3 * p - 2.0 * pp * bend) / (lp2 * p)
                u = 1.0 / (ki * phi1)
                v = -ki * phi2 * (u * u * u)
            else:
                u = v = 0.0
            s1 += u * p * w
            s2 += (u * u * pp + v * p) * w
            u_row.append(u)
            v_row.append(v)
        du.append(u_row + [1.0])
        dv.append(v_row + [0.0])
        t1.append(s1)
        t2.append(s2)
    hh = h * h
    d0, d1 = ([h * x / t for x in row] for row, t in zip(du, t1))
    s0, s1 = ([hh * (y / (t * t) - x * tt / (t * t * t)) for x, y in zip(rx, ry)]
              for rx, ry, t, tt in zip(du, dv, t1, t2))
    p0, p1 = b[0] + [lam0], b[1] + [lam1]
    rows = [[] for _ in range(_START_DEGREE + 1)]
    smooth = h < 0
    for a0, a1, e0, e1, c0, c1 in zip(p0, p1, d0, d1, s0, s1):
        e_val = a1 - a0 - e0 - 0.5 * c0
        e_slope = e1 - e0 - c0
        e_curv = c1 - c0
        col = (a0, e0, 0.5 * c0, 10.0 * e_val - 4.0 * e_slope + 0.5 * e_curv,
               -15.0 * e_val + 7.0 * e_slope - e_curv,
               6.0 * e_val - 3.0 * e_slope + 0.5 * e_curv)
        for row, x in zip(rows, col):
            row.append(x)
        if not smooth:
            continue
        if not all(map(math.isfinite, col)):
            smooth = False
            continue
        # The quintic at the hull points (summed in _hull_points' order; the first
        # power is 1) within the cell's hull.
        lo, hi = (a0, a1) if a0 <= a1 else (a1, a0)
        tol = 1e-12 * (1.0 + abs(hi))
        lo, hi = lo - tol, hi + tol
        q0, q1, q2, q3, q4, q5 = col
        for _, w1, w2, w3, w4, w5 in _HULL_POWERS_LIST:
            x = q0 + w1 * q1 + w2 * q2 + w3 * q3 + w4 * q4 + w5 * q5
            if not lo <= x <= hi:
                smooth = False
                break
    if not smooth:      # the linear interpolant
        rows = [p0, [a1 - a0 for a0, a1 in zip(p0, p1)]] + [[0.0] * len(p0)
                                                            for _ in range(4)]
    # Entries constant over the cell (held straight, at contact) stay exactly constant.
    for col, (a0, a1) in enumerate(zip(p0, p1)):
        if a0 == a1:
            for row in rows[1:]:
                row[col] = 0.0
    return rows


def _weighted_sum(values, weights):
    """``values @ weights`` for (..., U) values, summed column by column in a fixed order
    (a BLAS product may round differently with the number of rows): the products in
    one call, then added up in place, ``((v0 w0 + v1 w1) + v2 w2) + ...``."""
    terms = values * weights
    out = terms[..., 0]
    for j in range(1, weights.size):
        out += terms[..., j]
    return out


def _weighted_rows(values, weights):
    """:func:`_weighted_sum` of (U, ...) values, the segments on the leading axis (each
    term a contiguous row: cheaper to add), the same sums in the same order."""
    terms = values * weights.reshape((-1,) + (1,) * (values.ndim - 1))
    out = terms[0]
    for j in range(1, weights.size):
        out += terms[j]
    return out
