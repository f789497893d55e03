"""Per-segment branches: the angle of one segment as a function of the tension.

Owns the branch rule of the package docstring in code: bend direction, mirror buckling,
the branch end (contact, shortest length or fold), the per-pair profile tables
``b_j, mu_j`` (with the slopes ``d mu/db`` there) and their process-wide cache
(:data:`_PROFILE_CACHE`), the exact per-segment solve ``2 b + mu l'(b) = 0`` inside a
table cell (from a cubic start in the cell for the path tables), and the public
:func:`segment_branch` and :func:`segment_angle_at_tension`.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from ..geometry import segment_length_derivatives
from ..skeleton import Skeleton


# Samples along a branch for detecting its end and folds, and for the start tables.
_BRANCH_SAMPLES = 129


@dataclass(frozen=True)
class SegmentBranch:
    """The quasi-static branch of one segment (arrays broadcast over the inputs).

    Tensions are per unit stiffness: multiply by ``k`` for a segment of stiffness ``k``.

    Attributes
    ----------
    direction : ndarray of int
        Bend direction, -1 clockwise or +1 counter-clockwise (rule in the module doc).
    mirror : ndarray of bool
        ``d1 + d2 == 0``: straight until ``buckling_tension``.
    buckling_tension : ndarray
        Tension at which the segment starts to bend (0 unless mirror).
    end_angle_rad : ndarray
        Angle magnitude where the branch ends (contact, shortest length or fold).
    end_tension : ndarray
        Tension at the branch end; beyond it the segment stays at the end angle.
    end_kind : ndarray of str
        'contact', 'shortest' or 'fold'.
    """

    direction: np.ndarray
    mirror: np.ndarray
    buckling_tension: np.ndarray
    end_angle_rad: np.ndarray
    end_tension: np.ndarray
    end_kind: np.ndarray

    @property
    def fold(self) -> np.ndarray:
        """True where the branch folds before contact (tension is then not monotone)."""
        return self.end_kind == 'fold'


def _direction(d1, d2):
    sigma = d1 + d2
    return np.where(sigma > 0, -1.0, np.where(sigma < 0, 1.0, np.where(d1 >= 0, -1.0, 1.0)))


def _branch_derivs(b, direction, d1, d2, s):
    """Length and derivatives along a branch, in the magnitude ``b = direction * a``."""
    length, l_a, l_aa = segment_length_derivatives(direction * b, d1, d2, s)
    return length, direction * l_a, l_aa


def _pair_profile_array(d1, d2, s, b_max, n_samples=_BRANCH_SAMPLES):
    """Branch summary and a table ``b_j, mu_j = tension/k, length_j`` on its stable part.

    Works on 1-D arrays of pairs; returns a dict of arrays, tables of shape (n, M).
    """
    d1 = np.asarray(d1, dtype=float)
    d2 = np.asarray(d2, dtype=float)
    direction = _direction(d1, d2)
    mirror = (d1 + d2) == 0.0
    # L''(0) in closed form: Q''(0)/(2 L0) with Q''(0) = 2 d1 d2 - s^2/6 when d1 = -d2.
    l0 = np.hypot(s, d1 - d2)
    curv0 = (2.0 * d1 * d2 - s * s / 6.0) / (2.0 * l0)
    mu_c = np.where(mirror, 2.0 / np.abs(np.where(mirror, curv0, 1.0)), 0.0)
    # Pitchfork coefficient of a mirror segment, phi(b) = mu_c (1 + beta b^2 + ...), from
    # the Taylor series of Q = L^2 (c^2 = 1 - a^2/12 + a^4/360, P = s^2 + d1 d2 a^2):
    # beta = L''''(0) / (6 |L''(0)|) > 0 means a supercritical (stable) pitchfork.
    q2 = d1 * d2 - s * s / 12.0
    q4 = s * s / 360.0 - d1 * d2 / 12.0
    l4 = 24.0 * (q4 / (2.0 * l0) - q2 * q2 / (8.0 * l0 ** 3))
    beta = np.where(mirror, l4 / (6.0 * np.abs(np.where(mirror, curv0, 1.0))), 0.0)

    t = np.linspace(0.0, 1.0, n_samples)[1:]
    b = b_max * t[None, :] + 0.0 * d1[:, None]
    dcol, d1c, d2c = direction[:, None], d1[:, None], d2[:, None]
    _, lp, lpp = _branch_derivs(b, dcol, d1c, d2c, s)
    shortening = lp < 0.0
    # d(mu)/db has the sign of b l'' - l' on a shortening branch (mu = 2 b / -l').
    rising = b * lpp - lp > 0.0
    good = shortening & rising
    all_good = good.all(axis=1)
    first_bad = np.where(all_good, b.shape[1], np.argmax(~good, axis=1))
    kind = np.where(all_good, 'contact', 'contact').astype(object)
    b_end = np.full(d1.shape, float(b_max))
    for i in np.nonzero(~all_good)[0]:
        # Rare (never for the authors' holes): refine the end by bisection on the sign.
        j = first_bad[i]
        lo = 0.0 if j == 0 else b[i, j - 1]
        hi = b[i, j]
        is_short = not shortening[i, j]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            _, p, pp = _branch_derivs(mid, direction[i], d1[i], d2[i], s)
            ok = (p < 0.0) if is_short else (mid * pp - p > 0.0 and p < 0.0)
            lo, hi = (mid, hi) if ok else (lo, mid)
        # The end is the last point still on the stable shortening branch; past it the
        # segment is held there like at contact (at a smooth length minimum the end
        # tension is huge but finite, at coinciding holes L' jumps and it is moderate).
        b_end[i] = lo
        kind[i] = 'shortest' if is_short else 'fold'
    # Table over the stable part [0, b_end].
    tt = np.linspace(0.0, 1.0, n_samples)
    bt = b_end[:, None] * tt[None, :]
    length, lp, lpp = _branch_derivs(bt, dcol, d1c, d2c, s)
    with np.errstate(divide='ignore', invalid='ignore'):
        mu = 2.0 * bt / -lp
        # d(mu)/db = phi'(b): the slopes for the cubic starts of _segment_cells
        # (inf or 0 where mu is not smooth in b, at a pitchfork; those cells start linear).
        dmu = 2.0 * (bt * lpp - lp) / (lp * lp)
    mu[:, 0] = mu_c
    mu_end = mu[:, -1].copy()
    return dict(direction=direction, mirror=mirror, mu_c=mu_c, beta=beta, b_end=b_end,
                mu_end=mu_end, kind=kind.astype(str), b=bt, mu=mu, dmu=dmu, length=length)


# Per-pair profiles, memoised for the process: a threading's tables are a function of its
# distinct hole pairs, so threadings (and the inverse design) share them. FIFO-bounded
# (documented cache; :func:`softsnap_model.forward.clear_caches` empties it). An entry is
# ``(scalars, tables, kind)``: the (7,) values of :data:`_SCALAR_KEYS`, the (4, M) tables
# ``b, mu, dmu, length`` and the end kind, so that a threading's profiles are gathered by two
# numpy calls (a new threading's first solve is numpy call overhead).
class _PairMemo:
    """A process-wide memo of a pure function of hole pairs, FIFO-bounded and safe
    across threads: :meth:`get_many` looks the keys up, has the missing ones built
    together (one vectorised call), stores them and evicts the oldest beyond
    ``max_size``. The lock is not held while building: two threads may build the
    same key, with the same value."""

    def __init__(self, max_size: int):
        self.max_size = max_size
        self._entries: dict = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    def get_many(self, keys: list, build) -> list:
        """The values of ``keys``, in order; ``build(missing)`` returns the values of
        the distinct missing keys, in the order given."""
        with self._lock:
            found = [self._entries.get(key) for key in keys]
        missing = list(dict.fromkeys(key for key, f in zip(keys, found) if f is None))
        if missing:
            new = dict(zip(missing, build(missing)))
            with self._lock:
                self._entries.update(new)
                while len(self._entries) > self.max_size:
                    del self._entries[next(iter(self._entries))]
            found = [f if f is not None else new[key] for key, f in zip(keys, found)]
        return found


_PROFILE_CACHE = _PairMemo(16384)
_SCALAR_KEYS = ('direction', 'mirror', 'mu_c', 'beta', 'b_end', 'mu_end', 'end_length')
_TABLE_KEYS = ('b', 'mu', 'dmu', 'length')


def _pair_profiles(d1, d2, s: float, b_max: float) -> dict:
    """Profiles of the hole pairs ``(d1[j], d2[j])``, stacked along the first axis.

    Each distinct pair is built once per process (pure function of ``(d1, d2, s,
    b_max)``); the pairs not seen before are built together, vectorised. The tables
    ``b, mu, dmu`` (n, M) are views of ``tables`` (n, 4, M), whose last row is the
    segment length at the samples; ``end_length`` is the segment's length at its branch
    end as the table has it (within rounding of the one :func:`.path._problem` sums for
    the reachable minimum); ``kinds`` the tuple of end kinds; ``table_lists`` per pair
    its rows ``b, mu, dmu`` as memoryviews (indexing gives Python floats).
    """
    s, b_max = float(s), float(b_max)
    keys = [(x, y, s, b_max) for x, y in zip(np.asarray(d1, dtype=float).tolist(),
                                                np.asarray(d2, dtype=float).tolist())]

    def build(missing):
        built = _pair_profile_array(np.array([key[0] for key in missing]),
                                    np.array([key[1] for key in missing]), s, b_max)
        # The length at the branch end (a bound for the threading's minimum length).
        built['end_length'] = built['length'][:, -1]
        scalars = np.stack([built[name] for name in _SCALAR_KEYS], axis=1)
        tables = np.stack([built[name] for name in _TABLE_KEYS], axis=1)
        # Rows b, mu, dmu also as sequences of Python floats (what a single solve's float
        # sample builder reads): read-only memoryviews of the table, no copy.
        return [(scalars[j], tables[j], str(built['kind'][j]),
                 tuple(memoryview(tables[j, r]).toreadonly() for r in range(3)))
                for j in range(len(missing))]

    found = _PROFILE_CACHE.get_many(keys, build)
    scalars = np.array([f[0] for f in found]).T
    tables = np.array([f[1] for f in found])
    out = dict(zip(_SCALAR_KEYS, scalars))
    out['mirror'] = scalars[1] != 0.0
    out['kinds'] = tuple([f[2] for f in found])     # end kinds (str)
    out['table_lists'] = [f[3] for f in found]      # per pair: rows as memoryviews
    out.update(tables=tables, b=tables[:, 0], mu=tables[:, 1], dmu=tables[:, 2])
    return out


def segment_branch(d1_mm, d2_mm, spacing_mm, max_angle_rad=None) -> SegmentBranch:
    """Describe the quasi-static branch of segments with holes ``d1``, ``d2``.

    Parameters
    ----------
    d1_mm, d2_mm : array_like
        Hole offsets on the proximal and distal rib (mm).
    spacing_mm : float
        Spine arc length (mm).
    max_angle_rad : float, optional
        Contact angle; default ``min(2 s / 25 mm, pi)`` for the authors' rib length.

    Returns
    -------
    SegmentBranch
    """
    d1, d2 = np.broadcast_arrays(np.asarray(d1_mm, float), np.asarray(d2_mm, float))
    shape = d1.shape
    b_max = _default_max_angle(spacing_mm, max_angle_rad)
    p = _pair_profiles(d1.ravel(), d2.ravel(), float(spacing_mm), b_max)
    return SegmentBranch(
        direction=p['direction'].reshape(shape).astype(int),
        mirror=p['mirror'].reshape(shape),
        buckling_tension=p['mu_c'].reshape(shape),
        end_angle_rad=p['b_end'].reshape(shape),
        end_tension=p['mu_end'].reshape(shape),
        end_kind=np.array(p['kinds']).reshape(shape))


def _default_max_angle(spacing_mm, max_angle_rad):
    if max_angle_rad is None:
        return min(2.0 * float(spacing_mm) / Skeleton().rib_length_mm, math.pi)
    value = float(max_angle_rad)
    if not (0.0 < value <= math.pi):
        raise ValueError(f'max_angle_rad must be in (0, pi], got {max_angle_rad!r}')
    return value


def _branch_solve(mu, table_mu, table_b, direction, d1, d2, s, iters=30):
    """Exact branch magnitude ``b`` with ``mu = 2 b / -l'(b)`` (per unit stiffness).

    All arrays share the leading shape; tables have one more trailing axis (M samples,
    ``table_mu`` non-decreasing). Safeguarded Newton inside the table cell that brackets
    the root, so it cannot leave the branch.
    """
    m = table_mu.shape[-1]
    idx = np.clip(np.sum(table_mu < mu[..., None], axis=-1), 1, m - 1)

    def take(table, i):
        return np.take_along_axis(table, i[..., None], -1)[..., 0]

    cell = (take(table_b, idx - 1), take(table_b, idx), take(table_mu, idx - 1),
            take(table_mu, idx), table_mu[..., 0], table_mu[..., -1], table_b[..., 0],
            table_b[..., -1])
    return _branch_refine(mu, cell, direction, d1, d2, s, iters)


def _segment_cells(mu, tables):
    """Table cells and cubic starts for tensions ``mu`` (P, n) on per-segment tables
    ``tables`` (n, 3 or more, M): rows ``b``, ``mu``, ``dmu`` (the profiles' tables).

    The cells of :func:`_branch_solve` (the cell tuple of :func:`_branch_refine`), found by
    one binary search per segment column instead of comparing every tension with every
    table entry (the path-table build of a new threading), and the cubic Hermite
    interpolant of ``b(mu)`` in the cell (slopes ``1 / dmu``; about 1e-10 rad off,
    against 1e-4 for the linear one). Returns ``(start, cell)``, element-wise. A cell of
    zero width (at a pitchfork) divides 0 by 0: call under ``np.errstate(all='ignore')``.
    """
    n, m = tables.shape[0], tables.shape[2]
    table_b, table_mu = tables[:, 0], tables[:, 1]
    idx = np.empty(mu.shape, dtype=np.intp)
    for i in range(n):
        idx[:, i] = table_mu[i].searchsorted(mu[:, i], side='left')
    # Clamped to 1 .. m - 1 in place (np.clip of integers costs two type lookups).
    np.maximum(idx, 1, out=idx)
    np.minimum(idx, m - 1, out=idx)
    cols = np.arange(n)
    # Both ends of every cell, each in one gather: (P, n, 3) of b, mu, dmu.
    lo, hi = tables[cols, :3, idx - 1], tables[cols, :3, idx]
    b_lo, mu_lo, b_hi, mu_hi = lo[..., 0], lo[..., 1], hi[..., 0], hi[..., 1]
    cell = (b_lo, b_hi, mu_lo, mu_hi, table_mu[:, 0], table_mu[:, -1], table_b[:, 0],
            table_b[:, -1])
    span = mu_hi - mu_lo
    t = (mu - mu_lo) / span
    t2 = t * t
    t3 = t2 * t
    start = ((2.0 * t3 - 3.0 * t2 + 1.0) * b_lo + (t3 - 2.0 * t2 + t) * span
             / lo[..., 2] + (3.0 * t2 - 2.0 * t3) * b_hi + (t3 - t2) * span / hi[..., 2])
    return start, cell


def _branch_solve_pairs(mu, pair, prof, s, iters=30):
    """:func:`_branch_solve` for flat ``mu`` (N,) on the stacked profiles ``prof`` of U
    distinct pairs, ``pair`` (N,) indexing them: each pair's table is searched once per
    pair (binary search), never copied per element."""
    table_mu, table_b = prof['mu'], prof['b']
    n_pairs, m = table_mu.shape
    if n_pairs == 1:
        idx = np.searchsorted(table_mu[0], mu, side='left')
    else:
        idx = np.empty(mu.shape, dtype=np.intp)
        order = np.argsort(pair, kind='stable')
        bounds = np.searchsorted(pair[order], np.arange(n_pairs + 1))
        for u in range(n_pairs):
            sel = order[bounds[u]:bounds[u + 1]]
            idx[sel] = np.searchsorted(table_mu[u], mu[sel], side='left')
    flat = pair * m + np.clip(idx, 1, m - 1)
    tm, tb = table_mu.ravel(), table_b.ravel()
    cell = (tb[flat - 1], tb[flat], tm[flat - 1], tm[flat], table_mu[pair, 0],
            table_mu[pair, -1], table_b[pair, 0], table_b[pair, -1])
    return _branch_refine(mu, cell, prof['direction'][pair], prof['d1'][pair],
                          prof['d2'][pair], s, iters)


def _branch_refine(mu, cell, direction, d1, d2, s, iters, start=None, derivs=_branch_derivs):
    """Safeguarded Newton for ``2 b + mu l'(b) = 0`` inside the table cell ``cell`` =
    ``(b_lo, b_hi, mu_lo, mu_hi, mu_first, mu_last, b_first, b_last)``, from the linear
    interpolant in the cell, or from ``start`` where that is finite and in the cell.

    Strictly per entry: an entry stops changing in the iteration it settles, so its
    answer is the one it would get alone, whatever else is solved with it (a lazily
    built path table equals a full one, bit for bit).
    """
    lo, hi, mu_lo, mu_hi, mu_first, mu_last, b_first, b_last = cell
    below = mu <= mu_first
    above = mu >= mu_last
    active = ~(below | above)      # entries outside the table take its end values
    with np.errstate(invalid='ignore', divide='ignore'):
        w = np.where(np.isfinite(mu_hi), (mu - mu_lo) / (mu_hi - mu_lo), 0.5)
    w = np.clip(np.nan_to_num(w, nan=0.5), 0.0, 1.0)
    b = lo + w * (hi - lo)
    if start is not None:
        b = np.where((start >= lo) & (start <= hi), start, b)    # False for NaN
    for _ in range(iters):
        with np.errstate(invalid='ignore'):
            _, lp, lpp = derivs(b, direction, d1, d2, s)
            r = 2.0 * b + mu * lp
            dr = 2.0 + mu * lpp
        lo = np.where(r < 0.0, b, lo)
        hi = np.where(r > 0.0, b, hi)
        with np.errstate(invalid='ignore', divide='ignore'):
            step = b - r / dr
        # A Newton step past the bracket by rounding only (root on a cell end: every
        # path sample is some segment's table sample) is clamped, not bisected, which
        # would creep towards the end one halving per iteration.
        tol = 1e-15 * (1.0 + np.abs(b))
        ok = (step > lo - tol) & (step < hi + tol) & np.isfinite(step)
        new = np.where(ok, np.fmin(np.fmax(step, lo), hi), 0.5 * (lo + hi))
        # Done when the step is at rounding level, or the residual is (near a pitchfork,
        # where r' is small, the step would keep bouncing by a few ulp): then keep b.
        # Entries outside the table (returned as its end values) never hold the loop.
        settled = np.abs(r) <= 1e-15 * (2.0 * np.abs(b) + np.abs(mu * lp))
        new = np.where(settled, b, new)
        done = settled | (np.abs(new - b) <= tol)
        b = np.where(active, new, b)
        active &= ~done
        if not active.any():
            break
    b = np.where(below, b_first, np.where(above, b_last, b))
    return b


def segment_angle_at_tension(tension, d1_mm, d2_mm, spacing_mm, stiffness=1.0,
                             max_angle_rad=None):
    """Equilibrium angle (rad) of segments under cable tension, on the followed branch.

    Solves ``2 k a + tension * dL/da(a; d1, d2) = 0`` on the branch the quasi-static
    path follows (module docstring: direction rule, mirror buckling, contact). The
    energy convention is ``E = sum k_i a_i^2``, so ``tension`` is the multiplier of the
    length constraint in rad^2/mm; only ``tension / stiffness`` matters.

    Parameters
    ----------
    tension : array_like
        Multiplier ``lambda >= 0`` (rad^2/mm); ``inf`` gives the branch end angle.
    d1_mm, d2_mm : array_like
        Hole offsets (mm).
    spacing_mm : float
        Spine arc length (mm).
    stiffness : array_like, optional
        Relative stiffness ``k > 0``.
    max_angle_rad : float, optional
        Contact angle (rad); default that of the authors' rib (``2 s / 25``).

    Returns
    -------
    ndarray
        Angle (rad), broadcast shape of the inputs. Beyond the branch end tension
        (:func:`segment_branch`) the end angle is returned: the contact angle, or the
        fold angle where the branch folds (then ``a(lambda)`` is not single valued past
        it; none of the authors' hole pairs folds before contact).

    Notes
    -----
    Cost: each distinct ``(d1, d2)`` pair's branch profile is built once per process
    (shared with the forward solver's tables); then all tensions are solved together,
    so many tensions on a few pairs cost little more than the Newton on the output.

    Examples
    --------
    >>> a = segment_angle_at_tension(0.1, 10.0, 10.0, 18.0)
    >>> bool(a < 0)     # right-side holes bend clockwise
    True
    >>> segment_angle_at_tension([[0.0], [0.1]], [10.0, -3.0], [10.0, 3.0], 18.0).shape
    (2, 2)
    """
    lam = np.asarray(tension, dtype=float)
    k = np.asarray(stiffness, dtype=float)
    d1, d2 = np.broadcast_arrays(np.asarray(d1_mm, dtype=float),
                                 np.asarray(d2_mm, dtype=float))
    shape = np.broadcast_shapes(lam.shape, d1.shape, k.shape)
    for name, v in (('tension', lam), ('d1_mm', d1), ('d2_mm', d2), ('stiffness', k)):
        bad = np.isnan(v) if name == 'tension' else ~np.isfinite(v)
        if np.any(bad):
            what = 'must not be NaN' if name == 'tension' else 'must be finite'
            raise ValueError(f'{name} {what}, got {float(v[bad].ravel()[0])!r}')
    if np.any(lam < 0):
        raise ValueError(f'tension must be >= 0, got {float(lam[lam < 0].ravel()[0])!r}')
    if np.any(k <= 0):
        raise ValueError(f'stiffness must be > 0, got {float(k[k <= 0].ravel()[0])!r}')
    s = float(spacing_mm)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f'spacing_mm must be finite and > 0, got {spacing_mm!r}')
    b_max = _default_max_angle(s, max_angle_rad)
    # Distinct pairs of the (unbroadcast) hole arrays, then one index per output element.
    u1, i1 = np.unique(d1.ravel(), return_inverse=True)
    u2, i2 = np.unique(d2.ravel(), return_inverse=True)
    key_u, pair = np.unique(i1 * u2.size + i2, return_inverse=True)
    pu1, pu2 = u1[key_u // u2.size], u2[key_u % u2.size]
    prof = _pair_profiles(pu1, pu2, s, b_max)
    prof['d1'], prof['d2'] = pu1, pu2
    pair = np.broadcast_to(pair.reshape(d1.shape), shape).ravel()
    with np.errstate(invalid='ignore'):
        mu = np.broadcast_to(lam / k, shape).ravel()
    b = _branch_solve_pairs(mu, pair, prof, s)
    return (prof['direction'][pair] * b).reshape(shape)
