"""Quasi-static forward model of a SoftSnap module (pure numpy).

Model (paper, Algorithm 1; FACTS.md): the shape minimises the bending energy
``E = sum_i k_i a_i^2`` subject to ``sum_i L(a_i; d_i, d_{i+1}) = L_target``.

The problem is separable. With the multiplier ``lambda`` (the *tension*), stationarity
reads ``2 k_i a_i + lambda dL/da(a_i; d_i, d_{i+1}) = 0`` for every segment on its own,
so each segment's angle is a function of ``lambda`` and of its two holes only, and the
shape reached by shortening the cable quasi-statically from straight is the family
``a_i(lambda)``, ``lambda`` rising from 0. A forward solve is one scalar equation
``T(lambda) = sum_i L_i(a_i(lambda)) = L_target``, with ``T`` non-increasing, so the
answer is unique along the path and a cold solve equals path following. (The energy can
have other, higher local minima off the path, e.g. a segment held at rib contact on
the side against its holes' pull; docs/model.md.)

Units and conventions
---------------------
Angles in rad (counter-clockwise positive), lengths in mm, stiffness ``k_i`` is
dimensionless relative stiffness. ``tension`` is ``lambda`` in rad^2/mm: the physical
cable tension is ``lambda * K`` where ``K`` (N mm/rad^2) is the bending stiffness that
makes ``E = K sum k_i a_i^2`` an energy in N mm.

Branch rule (per segment, so segments stay independent)
-------------------------------------------------------
* Bend direction: ``-sign(d1 + d2)`` (right-side holes bend clockwise). A mirror
  segment (``d1 + d2 == 0``) has no first-order preference; it bends clockwise when
  ``d1 >= 0`` and counter-clockwise when ``d1 < 0``: the way a cable through only its
  proximal (base-side) hole would pull it. Both directions are exact, equally good
  answers (the segment length is even in the angle when ``d2 = -d1``): a result lists
  the bent mirror segments in ``tie_break_segments`` and ``solve_forward(...,
  mirror_flip=...)`` gives the other branch.
* A mirror segment stays straight until ``lambda`` reaches its buckling tension
  ``lambda_c = 2 k / |L''(0)|`` (pitchfork), then follows the branch in its direction.
  For the authors' hole set every mirror pitchfork is supercritical (verified in the
  tests), so the buckled state is a true minimum.
* A segment stops at the rib-contact angle ``Skeleton.contact_angle_rad`` (the ribs
  meet at the centre of curvature); beyond the tension where it gets there it stays
  at contact, like a hard stop, and the other segments take up further shortening.
* If a segment's branch turns back (a fold: ``d lambda / d a = 0`` before contact) the
  quasi-static path snaps there; lengths past the fold raise :class:`SnapThroughError`.
  No pair of the authors' holes folds before contact.
"""
from __future__ import annotations

import functools
import math
import numbers
import threading
from dataclasses import dataclass, field

import numpy as np

from .geometry import _g_series, half_angle_functions, segment_length_derivatives
from .skeleton import Skeleton

__all__ = [
    'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD', 'MAX_ITER', 'WARM_START_RADIUS_RAD',
    'InfeasibleLengthError', 'SnapThroughError',
    'SegmentBranch', 'segment_branch', 'segment_angle_at_tension',
    'ForwardResult', 'BatchResult', 'SweepResult',
    'reachable_range', 'solve_forward', 'solve_forward_batch', 'sweep',
]

#: Constraint contract: ``|sum_i L_i - L_target| <= CONSTRAINT_TOL_MM`` (mm) on success.
CONSTRAINT_TOL_MM = 1e-9
#: Stationarity contract: ``max_i |a_i + lambda L_i'(a_i) / (2 k_i)| <= STATIONARITY_TOL_RAD``
#: (rad) over the segments that are not held straight or at contact.
STATIONARITY_TOL_RAD = 1e-10
#: Default cap on Newton iterations of one solve.
MAX_ITER = 40
# Samples along a branch for detecting its end and folds, and for the start tables.
_BRANCH_SAMPLES = 129


class InfeasibleLengthError(ValueError):
    """Cable length below what the threading reaches along the quasi-static path.

    Attributes
    ----------
    reachable_range_mm : tuple of float
        ``(min_length_mm, straight_length_mm)``; the minimum itself is approached as
        the tension grows without bound and is not attained.
    """

    def __init__(self, message, reachable_range_mm):
        super().__init__(message)
        self.reachable_range_mm = tuple(float(v) for v in reachable_range_mm)


class SnapThroughError(InfeasibleLengthError):
    """The quasi-static path folds (snap-through) before reaching the requested length.

    ``reachable_range_mm[0]`` is the cable length at the fold.
    """


# ----------------------------------------------------------------------------------------
# Per-segment branch
# ----------------------------------------------------------------------------------------
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
    length, lp, _ = _branch_derivs(bt, dcol, d1c, d2c, s)
    with np.errstate(divide='ignore', invalid='ignore'):
        mu = 2.0 * bt / -lp
    mu[:, 0] = mu_c
    mu_end = mu[:, -1].copy()
    return dict(direction=direction, mirror=mirror, mu_c=mu_c, beta=beta, b_end=b_end,
                mu_end=mu_end, kind=kind.astype(str), b=bt, mu=mu, length=length)


# Per-pair profiles, memoised for the process: a threading's tables are a function of its
# distinct hole pairs, so threadings (and the inverse design) share them. FIFO-bounded.
_PROFILE_CACHE: dict = {}
_PROFILE_CACHE_MAX = 16384
_PROFILE_LOCK = threading.Lock()
_PROFILE_KEYS = ('direction', 'mirror', 'mu_c', 'beta', 'b_end', 'mu_end', 'kind', 'b', 'mu')


def _pair_profiles(d1, d2, s: float, b_max: float) -> dict:
    """Profiles of the hole pairs ``(d1[j], d2[j])``, stacked along the first axis.

    Each distinct pair is built once per process (pure function of ``(d1, d2, s,
    b_max)``); the pairs not seen before are built together, vectorised.
    """
    keys = [(float(x), float(y), float(s), float(b_max)) for x, y in zip(d1, d2)]
    with _PROFILE_LOCK:
        found = [_PROFILE_CACHE.get(key) for key in keys]
    missing = list(dict.fromkeys(key for key, f in zip(keys, found) if f is None))
    if missing:
        built = _pair_profile_array(np.array([key[0] for key in missing]),
                                    np.array([key[1] for key in missing]), float(s),
                                    float(b_max))
        new = {key: {name: built[name][j] for name in _PROFILE_KEYS}
               for j, key in enumerate(missing)}
        with _PROFILE_LOCK:
            _PROFILE_CACHE.update(new)
            while len(_PROFILE_CACHE) > _PROFILE_CACHE_MAX:
                del _PROFILE_CACHE[next(iter(_PROFILE_CACHE))]
        found = [f if f is not None else new[key] for key, f in zip(keys, found)]
    out = {name: np.array([f[name] for f in found]) for name in _PROFILE_KEYS
           if name not in ('b', 'mu')}
    out['b'] = np.stack([f['b'] for f in found])
    out['mu'] = np.stack([f['mu'] for f in found])
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
        end_kind=p['kind'].reshape(shape))


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


def _branch_refine(mu, cell, direction, d1, d2, s, iters):
    """Safeguarded Newton for ``2 b + mu l'(b) = 0`` inside the table cell ``cell`` =
    ``(b_lo, b_hi, mu_lo, mu_hi, mu_first, mu_last, b_first, b_last)``."""
    lo, hi, mu_lo, mu_hi, mu_first, mu_last, b_first, b_last = cell
    below = mu <= mu_first
    above = mu >= mu_last
    with np.errstate(invalid='ignore', divide='ignore'):
        w = np.where(np.isfinite(mu_hi), (mu - mu_lo) / (mu_hi - mu_lo), 0.5)
    w = np.clip(np.nan_to_num(w, nan=0.5), 0.0, 1.0)
    b = lo + w * (hi - lo)
    for _ in range(iters):
        with np.errstate(invalid='ignore'):
            _, lp, lpp = _branch_derivs(b, direction, d1, d2, s)
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
        done = settled | (np.abs(new - b) <= tol) | below | above
        b = new
        if done.all():
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
            raise ValueError(f'{name} {what}, got {v[bad].ravel()[0]!r}')
    if np.any(lam < 0):
        raise ValueError(f'tension must be >= 0, got {lam[lam < 0].ravel()[0]!r}')
    if np.any(k <= 0):
        raise ValueError(f'stiffness must be > 0, got {k[k <= 0].ravel()[0]!r}')
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


# ----------------------------------------------------------------------------------------
# Per-threading problem data and the path table (memoised, pure functions of the inputs)
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Problem:
    """Everything about one (skeleton, threading) that does not depend on the length."""

    d: np.ndarray            # (n_ribs,) offsets mm
    d1: np.ndarray           # (n,) proximal holes
    d2: np.ndarray           # (n,) distal holes
    k: np.ndarray            # (n,) stiffness
    s: float
    direction: np.ndarray    # (n,) +-1
    lam_c: np.ndarray        # (n,) tension where the segment starts bending
    mu_c: np.ndarray         # (n,) lam_c / k
    beta: np.ndarray         # (n,) pitchfork coefficient (mirror segments), else 0
    lam_end: np.ndarray      # (n,) tension where it reaches its branch end
    b_end: np.ndarray        # (n,) angle magnitude at the branch end
    kind: tuple              # per segment 'contact' | 'shortest' | 'fold'
    table_mu: np.ndarray     # (n, M) per-unit-stiffness tension along each branch
    table_b: np.ndarray      # (n, M) angle magnitude along each branch
    straight_mm: float
    min_mm: float            # infimum of reachable lengths (or length at the fold)
    snap: bool               # the path ends at a fold (snap-through), not at contact
    path_lam: np.ndarray     # (P,) increasing tensions along the whole path
    path_len: np.ndarray     # (P,) non-increasing total length there
    path_b: np.ndarray       # (P, n) exact branch magnitudes there
    path_poly: np.ndarray    # (P-1, 4, n+1) start polynomial per cell, see _path_polynomials


@functools.lru_cache(maxsize=256)
def _problem(skeleton: Skeleton, d: tuple) -> _Problem:
    s = skeleton.spacing_mm
    b_max = skeleton.contact_angle_rad
    d_arr = np.array(d, dtype=float)
    d1, d2 = d_arr[:-1], d_arr[1:]
    k = skeleton.stiffness_array
    prof = _pair_profiles(d1, d2, s, b_max)
    direction, mu_c, beta = prof['direction'], prof['mu_c'], prof['beta']
    mu_end, b_end = prof['mu_end'], prof['b_end']
    kind = tuple(str(x) for x in prof['kind'])
    table_mu, table_b = prof['mu'], prof['b']
    lam_c, lam_end = k * mu_c, k * mu_end
    straight = float(np.sum(np.hypot(s, d2 - d1)))
    folds = [i for i, kd in enumerate(kind) if kd == 'fold']
    snap = bool(folds)
    # Path table: every tension where some segment's table has a sample, up to where the
    # path ends (all segments at their ends, or the first fold).
    lam_all = (k[:, None] * table_mu).ravel()
    lam_all = lam_all[np.isfinite(lam_all)]
    if snap:
        lam_top = float(np.min(lam_end[folds]))
    else:
        finite = lam_end[np.isfinite(lam_end)]
        lam_top = float(finite.max()) if finite.size else float(lam_all.max())
    lam_path = np.unique(np.concatenate([[0.0], lam_all[lam_all <= lam_top], [lam_top]]))
    if lam_path.size > 4 * _BRANCH_SAMPLES:
        # Thin to a bounded table; keep the ends and every buckling tension.
        keep = np.unique(np.concatenate([np.linspace(0, lam_path.size - 1,
                                                     4 * _BRANCH_SAMPLES).astype(int)]))
        lam_path = np.unique(np.concatenate([lam_path[keep], lam_c, lam_end, [lam_top]]))
        lam_path = lam_path[lam_path <= lam_top]
    mu = lam_path[:, None] / k[None, :]
    shape = mu.shape
    tm = np.broadcast_to(table_mu, shape + table_mu.shape[-1:])
    tb = np.broadcast_to(table_b, shape + table_b.shape[-1:])
    bb = _branch_solve(mu, tm, tb, np.broadcast_to(direction, shape),
                       np.broadcast_to(d1, shape), np.broadcast_to(d2, shape), s)
    lengths, lp, lpp = _branch_derivs(bb, direction, d1, d2, s)
    path_len = np.minimum.accumulate(lengths.sum(axis=1))
    path_len[0] = straight
    poly = _path_polynomials(lam_path, path_len, bb, lp, lpp, k, lam_c, lam_end)
    if snap:
        min_mm = float(path_len[-1])
    else:
        end_len, _, _ = _branch_derivs(b_end, direction, d1, d2, s)
        min_mm = float(end_len.sum())
    return _Problem(d=d_arr, d1=d1, d2=d2, k=k, s=s, direction=direction, lam_c=lam_c,
                    mu_c=mu_c, beta=beta,
                    lam_end=lam_end, b_end=b_end, kind=kind, table_mu=table_mu,
                    table_b=table_b, straight_mm=straight, min_mm=min_mm, snap=snap,
                    path_lam=lam_path, path_len=path_len, path_b=bb, path_poly=poly)


def _path_polynomials(lam, length, b, lp, lpp, k, lam_c, lam_end):
    """Cubic Hermite start polynomials of the path cells, in ``t in [0, 1]`` across a cell.

    Cell ``j`` joins samples ``j`` and ``j + 1``. Along the path every free segment has
    ``db/dlambda = 1 / (k phi'(b))`` and ``dT/dlambda = sum l' db/dlambda``, so the exact
    samples also give the slopes of ``lambda`` and ``b`` in the length, one-sided at the
    cell ends (a segment stops at contact, a mirror one starts at its buckling tension).
    Returns ``c`` (P-1, 4, n+1): ``[b, lambda](t) = sum_p t^p c[j, p]``. Cells where a
    slope is not finite (a pitchfork starts, nothing moves) or where the cubic would
    leave the cell's hull keep the linear interpolant; constant entries stay exact.
    """
    vals = np.concatenate([b, lam[:, None]], axis=1)               # (P, n+1)
    p0, p1 = vals[:-1], vals[1:]
    h = (length[1:] - length[:-1])[:, None]                        # < 0 in a moving cell
    with np.errstate(all='ignore'):
        db_dlam = 1.0 / (2.0 * k * (b * lpp - lp) / (lp * lp))      # 1 / (k phi'(b))
        # Segments moving across the whole cell (bent, not yet at their branch end).
        free = (lam[:-1, None] >= lam_c) & (lam[1:, None] <= lam_end)
        slopes = []
        for at in (slice(None, -1), slice(1, None)):     # cell start, cell end
            dbl = np.where(free, db_dlam[at], 0.0)
            dT = np.sum(np.where(free, lp[at] * dbl, 0.0), axis=1, keepdims=True)
            slopes.append(h * np.concatenate([dbl, np.ones_like(dT)], axis=1) / dT)
        d0, d1 = slopes
        c = np.stack([p0, d0, 3.0 * (p1 - p0) - 2.0 * d0 - d1, 2.0 * (p0 - p1) + d0 + d1],
                     axis=1)
        # Check the cubic on a few interior points: it must stay in the cell's hull.
        t = np.array([0.25, 0.5, 0.75])
        inner = np.einsum('tp,jpc->jtc', t[:, None] ** np.arange(4), c)
        lo, hi = np.minimum(p0, p1)[:, None], np.maximum(p0, p1)[:, None]
        tol = 1e-12 * (1.0 + np.abs(hi))
        cubic = (np.all(np.isfinite(c), axis=(1, 2)) & (h[:, 0] < 0)
                 & np.all((inner >= lo - tol) & (inner <= hi + tol), axis=(1, 2)))
    linear = np.stack([p0, p1 - p0, np.zeros_like(p0), np.zeros_like(p0)], axis=1)
    c = np.where(cubic[:, None, None], c, linear)
    # Entries constant over a cell (held straight, at contact) stay exactly constant.
    c[:, 1:] = np.where((p0 == p1)[:, None, :], 0.0, c[:, 1:])
    return c


def _check_length(prob: _Problem, length: np.ndarray, skeleton, threading_desc):
    """Raise the documented errors for NaN/inf and unreachable lengths."""
    if not np.all(np.isfinite(length)):
        bad = length[~np.isfinite(length)].ravel()[0]
        raise ValueError(f'cable_length_mm must be finite, got {bad!r}')
    if np.any(length <= 0):
        bad = length[length <= 0].ravel()[0]
        raise ValueError(f'cable_length_mm must be > 0, got {bad!r}')
    low = length <= prob.min_mm
    if np.any(low):
        bad = float(length[low].ravel()[0])
        rng = (prob.min_mm, prob.straight_mm)
        if prob.snap:
            raise SnapThroughError(
                f'cable length {bad!r} mm is past a snap-through of threading '
                f'{threading_desc}: the quasi-static path folds at {rng[0]:.6f} mm; '
                f'reachable range ({rng[0]:.6f}, {rng[1]:.6f}] mm', rng)
        raise InfeasibleLengthError(
            f'cable length {bad!r} mm is below what threading {threading_desc} can reach: '
            f'reachable range ({rng[0]:.6f}, {rng[1]:.6f}] mm (the minimum is approached '
            f'as every segment reaches rib contact)', rng)


def _describe(skeleton: Skeleton, d: np.ndarray) -> str:
    names = skeleton.hole_names(d)
    return ' '.join(n if n is not None else f'{v:g}' for n, v in zip(names, d))


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


# ----------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ForwardResult:
    """Result of :func:`solve_forward` (scipy.optimize style).

    Attributes
    ----------
    angles : ndarray, shape (n_segments,)
        Bending angles (rad, counter-clockwise positive).
    rib_centers : ndarray, shape (n_ribs, 2)
        Rib centres (mm) in the base frame.
    cable_path : ndarray, shape (n_ribs, 2)
        Threaded hole positions (mm); the cable runs straight between them.
    energy : float
        ``sum k_i a_i^2`` (rad^2).
    tension : float
        Multiplier ``lambda`` (rad^2/mm); 0 when slack. See the module docstring.
    iterations : int
        Newton iterations (0 for a slack cable).
    converged : bool
        Both residual contracts hold and the point is a constrained local minimum.
    residual : float
        ``max(constraint_residual, stationarity_residual)``.
    constraint_residual : float
        ``|sum L_i - L_target|`` (mm); contract ``CONSTRAINT_TOL_MM``.
    stationarity_residual : float
        ``max |a_i + lambda L_i' / (2 k_i)|`` (rad) over segments that are neither held
        straight nor at contact; contract ``STATIONARITY_TOL_RAD``.
    is_minimum : bool
        Second-order check: the Lagrangian Hessian ``diag(2 k_i + lambda L_i'')`` is
        positive on the tangent space of the constraint (segments at contact are on
        an active bound and excluded).
    min_curvature : float
        Smallest ``1 + lambda L_i'' / (2 k_i)`` over non-contact segments (> 0 for a
        strict minimum; near 0 next to a buckling or fold point).
    slack : bool
        The requested length is at or above the straight length.
    at_contact : ndarray of bool
        Segments held at the rib-contact angle.
    cable_length_mm : float
        Requested length.
    message : str
    tie_break_segments : tuple of int
        Mirror segments (``d2 = -d1``) that are bent: their direction was a tie-break
        (the rule in the module docstring), and bending them the other way is an equally
        good answer (same length, energy and tension; ``solve_forward(...,
        mirror_flip=...)``). Mirror segments still straight are not listed.
    mirror_flip : tuple of int
        Mirror segments bent against the tie-break rule on request (``mirror_flip``).
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    energy: float
    tension: float
    iterations: int
    converged: bool
    residual: float
    constraint_residual: float
    stationarity_residual: float
    is_minimum: bool
    min_curvature: float
    slack: bool
    at_contact: np.ndarray
    cable_length_mm: float
    message: str
    tie_break_segments: tuple = ()
    mirror_flip: tuple = ()

    @property
    def success(self) -> bool:
        """Alias of ``converged`` (scipy naming)."""
        return self.converged


@dataclass(frozen=True)
class BatchResult:
    """Result of :func:`solve_forward_batch`: the ForwardResult fields as arrays.

    ``angles`` (B, n_segments), ``rib_centers`` and ``cable_path`` (B, n_ribs, 2), the
    scalar fields of :class:`ForwardResult` as (B,) arrays, ``at_contact`` (B, n),
    ``tie_break`` (B, n): bent mirror segments (``ForwardResult.tie_break_segments``).
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    energy: np.ndarray
    tension: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    residual: np.ndarray
    constraint_residual: np.ndarray
    stationarity_residual: np.ndarray
    is_minimum: np.ndarray
    min_curvature: np.ndarray
    slack: np.ndarray
    at_contact: np.ndarray
    cable_length_mm: np.ndarray
    tie_break: np.ndarray = None

    def __len__(self):
        return self.angles.shape[0]

    def item(self, i: int, message: str = '') -> ForwardResult:
        """The i-th solve as a :class:`ForwardResult`."""
        return ForwardResult(
            angles=self.angles[i], rib_centers=self.rib_centers[i],
            cable_path=self.cable_path[i], energy=float(self.energy[i]),
            tension=float(self.tension[i]), iterations=int(self.iterations[i]),
            converged=bool(self.converged[i]), residual=float(self.residual[i]),
            constraint_residual=float(self.constraint_residual[i]),
            stationarity_residual=float(self.stationarity_residual[i]),
            is_minimum=bool(self.is_minimum[i]), min_curvature=float(self.min_curvature[i]),
            slack=bool(self.slack[i]), at_contact=self.at_contact[i],
            cable_length_mm=float(self.cable_length_mm[i]), message=message,
            tie_break_segments=(() if self.tie_break is None else
                                tuple(int(j) for j in np.nonzero(self.tie_break[i])[0])))


@dataclass(frozen=True)
class SweepResult(BatchResult):
    """Result of :func:`sweep`; ``contractions_mm`` (B,) is the swept input."""

    contractions_mm: np.ndarray = field(default=None)


# ----------------------------------------------------------------------------------------
# Solver engine, vectorised over a batch axis: arrays (B, n) and (B,)
# ----------------------------------------------------------------------------------------
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
_CUBIC = np.arange(4, dtype=float)


def _start_from_table(P, L_t):
    """Initial (lambda, b) and a tension bracket from the exact path tables.

    The path tables are exact samples of the path, so ``[lam_lo, lam_hi]`` brackets the
    root of ``T(lambda) = L_t``; lambda and b come from the cell's cubic Hermite
    polynomial in the length (:func:`_path_polynomials`). Vectorised per threading
    group (tables are stored once per distinct threading).
    """
    nb, n = L_t.shape[0], P['k'].shape[1]
    lam_lo, lam_hi = np.empty(nb), np.empty(nb)
    start = np.empty((nb, n + 1))
    uid = P['uid']
    for u, (path_len, path_lam, path_poly) in enumerate(P['paths']):
        sel = uid == u if len(P['paths']) > 1 else slice(None)
        L = L_t[sel]
        m = path_len.shape[0]
        j = np.clip(np.searchsorted(-path_len, -L, side='left'), 1, m - 1)
        len_lo, len_hi = path_len[j - 1], path_len[j]
        span = len_lo - len_hi
        w = np.where(span > 0, (len_lo - L) / np.where(span > 0, span, 1.0), 0.5)
        lam_lo[sel], lam_hi[sel] = path_lam[j - 1], path_lam[j]
        start[sel] = np.einsum('bp,bpc->bc', w[:, None] ** _CUBIC, path_poly[j - 1])
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
        if it == max_iter or not active.any():
            break
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


def _newton_single(S, L_t, lam, b, lam_lo, lam_hi, max_iter, tol_mm, tol_rad,
                   derive_lam=False):
    """:func:`_newton` for one problem with plain-float control flow.

    Same iteration and safeguards; 1-D arrays over segments and Python floats for the
    tension, so an iteration is ~40 small numpy calls (the cost of a single solve).
    With ``derive_lam`` the tension is first replaced by the least-squares multiplier
    of the angles ``b`` (``min ||2 k b + lambda l'||`` over the segments neither
    straight nor at their branch end), from the first evaluation.
    """
    lam_c, lam_end, b_end = S['lam_c'], S['lam_end'], S['b_end']
    two_k, inv_two_k = S['two_k'], S['inv_two_k']
    mirror, has_mirror = S['mirror'], S['has_mirror']
    lam_end_min = S['lam_end_min']
    held = contact = None
    it = 0
    first = None
    if derive_lam:
        first = _branch_eval(b, S)
        lp = np.where((b < b_end) & ((b > 0.0) | ~mirror), first[1], 0.0)
        den = float(lp @ lp)
        if den > 0:
            lam = min(max(float(-(two_k * b) @ lp) / den, lam_lo), lam_hi)
    while True:
        if has_mirror:
            kick = mirror & (b <= 0.0) & (lam > lam_c)
            if kick.any():
                b = np.where(kick, _kick_b(S['P'], np.array([lam]))[0], b)
                first = None
            held = mirror & (b <= 0.0)
        contact = (b >= b_end) & (lam >= lam_end) if lam >= lam_end_min else None
        fixed = held if contact is None else (contact if held is None else held | contact)
        if fixed is not None and not fixed.any():
            fixed = None
        if first is None:
            length, lp, l_aa = _branch_eval(b, S)
        else:
            (length, lp, l_aa), first = first, None
        g = float(length.sum()) - L_t
        f = b + lam * inv_two_k * lp
        if fixed is not None:
            f[fixed] = 0.0
        stat = float(np.abs(f).max())
        if (abs(g) <= tol_mm and stat <= tol_rad) or it == max_iter:
            break
        it += 1
        inv = 1.0 / lp
        ft = -two_k * b * inv - lam                   # k phi(b) - lambda
        jac = two_k * (b * l_aa - lp) * inv * inv     # k phi'(b) > 0 on the branch
        w = lp / jac
        if fixed is not None:
            ft[fixed] = 0.0
            w[fixed] = 0.0
        dlam = (float(w @ ft) - g) / float(w.sum())
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
                held=held, contact=contact, iters=it)


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


_PER_ITEM = ('uid', 'k', 'd', 'd1', 'd2', 'direction', 'lam_c', 'lam_end', 'mu_c', 'beta',
             'b_end', 'mirror', 'mu_c_safe', 'beta_safe', 'mu_1', 'lam_1', 'b_1', 'e1', 'e2',
             'two_e1e2', 'dd2', 'two_k', 'inv_two_k', 'straight')


def _stack(probs, index):
    """Batch arrays: small per-item (B, n) arrays, tables once per distinct threading.

    ``index`` (B,) maps batch rows to ``probs``; keys in :data:`_PER_ITEM` have the
    batch as leading axis (and are what a sub-batch slices).
    """
    def rows(attr):
        return np.stack([getattr(p, attr) for p in probs])[index]
    k, mu_c, beta = rows('k'), rows('mu_c'), rows('beta')
    d1, d2, direction = rows('d1'), rows('d2'), rows('direction')
    tables_mu = np.stack([p.table_mu for p in probs])
    tables_b = np.stack([p.table_b for p in probs])
    mirror = mu_c > 0
    return dict(
        uid=np.asarray(index), s=probs[0].s, has_mirror=bool(mirror.any()),
        tables_mu=tables_mu, tables_b=tables_b,
        paths=[(p.path_len, p.path_lam, p.path_poly) for p in probs],
        k=k, d=rows('d'), d1=d1, d2=d2, direction=direction, lam_c=rows('lam_c'),
        lam_end=rows('lam_end'), mu_c=mu_c, beta=beta, b_end=rows('b_end'), mirror=mirror,
        mu_c_safe=np.where(mirror, mu_c, 1.0), beta_safe=np.where(mirror, beta, 1.0),
        mu_1=tables_mu[index, :, 1], lam_1=k * tables_mu[index, :, 1],
        b_1=tables_b[index, :, 1],
        e1=d1 * direction, e2=d2 * direction, two_e1e2=2.0 * d1 * d2, dd2=(d1 - d2) ** 2,
        two_k=2.0 * k, inv_two_k=0.5 / k,
        straight=np.array([p.straight_mm for p in probs])[index])


def _solve_arrays(P, L_t, max_iter=MAX_ITER, tol_mm=_INNER_TOL_MM, tol_rad=_INNER_TOL_RAD):
    """Solve a batch; returns a dict of result arrays (angles, tension, residuals...)."""
    # One floating-point context for the whole solve: divisions by zero only occur in
    # masked-out entries (held or contact segments) and are never used.
    with np.errstate(all='ignore'):
        return _solve_arrays_inner(P, L_t, max_iter, tol_mm, tol_rad)


def _solve_arrays_inner(P, L_t, max_iter, tol_mm, tol_rad):
    slack = L_t >= P['straight']
    lam, b, lam_lo, lam_hi = _start_from_table(P, L_t)
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


# ----------------------------------------------------------------------------------------
# Public solvers
# ----------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=256)
def _single(skeleton: Skeleton, d: tuple):
    """Problem data stacked as a batch of one, plus 1-D views for the single-solve path
    (memoised with the problem)."""
    prob = _problem(skeleton, d)
    P = _stack([prob], np.zeros(1, dtype=int))
    S = {key: (val[0] if isinstance(val, np.ndarray) and val.ndim >= 1 else val)
         for key, val in P.items()}
    finite_end = prob.lam_end[np.isfinite(prob.lam_end)]
    S.update(P=P, lam_end_min=float(prob.lam_end.min()),
             neg_path_len=-prob.path_len, path_lam=prob.path_lam, path_poly=prob.path_poly,
             straight=prob.straight_mm, n_path=prob.path_len.size,
             ones=np.ones(prob.k.shape), has_finite_end=bool(finite_end.size))
    return prob, P, S


def _solve_single(S, L, lam0=None, a0=None, max_iter=MAX_ITER, fallback=True):
    """One solve on the plain-float path; falls back to the batch engine (with its
    robust fallback) when the result is not certified. Returns the result dict.

    ``a0`` (angles) and ``lam0`` (tension or None) are a warm start. It is used only
    when ``a0`` is within :data:`WARM_START_RADIUS_RAD` of the table start, and then
    only if it already meets the inner tolerances (no Newton step); otherwise the solve
    is exactly the cold one. So a warm start never costs Newton iterations or accuracy.
    """
    m = S['n_path']
    j = int(np.searchsorted(S['neg_path_len'], -L, side='left'))
    j = min(max(j, 1), m - 1)
    len_lo, len_hi = -S['neg_path_len'][j - 1], -S['neg_path_len'][j]
    lam_lo, lam_hi = float(S['path_lam'][j - 1]), float(S['path_lam'][j])
    w = (len_lo - L) / (len_lo - len_hi) if len_lo > len_hi else 0.5
    start = (w ** _CUBIC) @ S['path_poly'][j - 1]
    b, lam = start[:-1], float(start[-1])
    st = None
    if a0 is not None:
        # Cheap screen first: the max-norm distance can be within the radius only if
        # the sums are within n times it (a NaN or inf angle fails here and raises).
        gap = float(S['direction'] @ a0) - float(S['ones'] @ b)
        if not math.isfinite(gap):
            raise ValueError(f'initial: angles must be finite, got {a0.tolist()}')
        if (abs(gap) <= b.size * WARM_START_RADIUS_RAD
                and float(np.max(np.abs(S['direction'] * a0 - b))) <= WARM_START_RADIUS_RAD):
            # Close enough to be the answer: check it (one evaluation, with its own
            # tension, given or derived from it); keep it only if it already is.
            b_w = np.fmin(np.fmax(S['direction'] * a0, 0.0), S['b_end'])
            given = lam0 is not None and lam_lo <= lam0 <= lam_hi
            with np.errstate(all='ignore'):
                st = _newton_single(S, L, lam0 if given else lam, b_w, lam_lo, lam_hi, 0,
                                    _INNER_TOL_MM, _INNER_TOL_RAD, not given)
            if not (abs(st['g']) <= _INNER_TOL_MM and st['stat'] <= _INNER_TOL_RAD):
                st = None
    if st is None:
        if S['has_mirror']:
            past = S['mirror'] & (lam > S['lam_c']) & (lam < S['lam_1'])
            if past.any():
                b = np.where(past, _kick_b(S['P'], np.array([lam]))[0], b)
        with np.errstate(all='ignore'):
            st = _newton_single(S, L, lam, b, lam_lo, lam_hi, max_iter, _INNER_TOL_MM,
                                _INNER_TOL_RAD)
    with np.errstate(all='ignore'):
        curv = _curvature(S['P'], np.array([st['lam']]), st['b'][None], st['lp'][None],
                          st['l_aa'][None], st['held'][None])[0]
    curv_min = float(np.min(curv, where=~st['contact'], initial=np.inf))
    ok = (abs(st['g']) <= CONSTRAINT_TOL_MM and st['stat'] <= STATIONARITY_TOL_RAD
          and curv_min > 0)
    if not ok and fallback:
        out = _solve_arrays(S['P'], np.array([L]), max_iter=max_iter)
        return {key: val[0] for key, val in out.items()}
    b = st['b']
    angles = S['direction'] * b
    g = abs(st['g'])
    return dict(angles=angles, tension=st['lam'], energy=float(S['k'] @ (angles * angles)),
                iterations=st['iters'], converged=ok, constraint_residual=g,
                stationarity_residual=st['stat'], residual=max(g, st['stat']),
                is_minimum=curv_min > 0, min_curvature=curv_min if curv_min < np.inf else 1.0,
                slack=False, at_contact=st['contact'])


def _frames_single(angles, s, d):
    """Rib centres and hole positions for one shape (few numpy calls)."""
    n = angles.shape[0]
    theta = np.zeros(n + 1)
    np.cumsum(angles, out=theta[1:])
    half = 0.5 * angles
    chord = s * half_angle_functions(half)[0]
    mid = theta[:-1] + half
    centers = np.zeros((n + 1, 2))
    np.cumsum(chord * np.cos(mid), out=centers[1:, 0])
    np.cumsum(chord * np.sin(mid), out=centers[1:, 1])
    holes = centers.copy()
    holes[:, 0] += d * np.sin(theta)
    holes[:, 1] -= d * np.cos(theta)
    return centers, holes


def _as_length(value, name='cable_length_mm') -> float:
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
        the answer is the same shape as a cold solve. The cold start is already a cubic
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
    d = _threading_tuple(skeleton, threading)
    L = _as_length(cable_length_mm)
    if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) \
            or max_iter < 0:
        raise ValueError(f'max_iter must be an integer >= 0, got {max_iter!r}')
    prob, P, S = _single(skeleton, d)
    flip = _mirror_flip_indices(mirror_flip, S['mirror'])
    if not (math.isfinite(L) and L > prob.min_mm):
        _check_length(prob, np.array([L]), skeleton, _describe(skeleton, prob.d))
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
    tie_break = S['mirror'] & (angles != 0.0)
    if flip:
        # The mirror image of those segments: L(-a) = L(a) when d2 = -d1, so every
        # residual and the second-order check carry over unchanged.
        angles = angles.copy()
        angles[list(flip)] *= -1.0
    centers, holes = _frames_single(angles, prob.s, prob.d)
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
    return ForwardResult(
        angles=angles, rib_centers=centers, cable_path=holes,
        energy=float(out['energy']), tension=float(out['tension']),
        iterations=int(out['iterations']), converged=converged,
        residual=float(out['residual']),
        constraint_residual=float(out['constraint_residual']),
        stationarity_residual=float(out['stationarity_residual']),
        is_minimum=bool(out['is_minimum']), min_curvature=float(out['min_curvature']),
        slack=slack, at_contact=out['at_contact'], cable_length_mm=L, message=message,
        tie_break_segments=tuple(int(j) for j in np.nonzero(tie_break)[0]),
        mirror_flip=flip)


def _mirror_flip_indices(mirror_flip, mirror) -> tuple:
    """Validated, sorted distinct segment indices of ``mirror_flip`` (mirror segments)."""
    if mirror_flip is None:
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


@functools.lru_cache(maxsize=1024)
def _threading_cached(skeleton: Skeleton, key: tuple) -> tuple:
    return tuple(skeleton.threading_mm(list(key)).tolist())


def _threading_tuple(skeleton: Skeleton, threading) -> tuple:
    """Offsets as a tuple via :meth:`Skeleton.threading_mm` (memoised for hashable input)."""
    if isinstance(threading, (list, tuple)):
        try:
            return _threading_cached(skeleton, tuple(threading))
        except TypeError:   # unhashable items: convert (and fail) the normal way
            pass
    return tuple(skeleton.threading_mm(threading).tolist())


def solve_forward_batch(skeleton: Skeleton, threadings, cable_lengths_mm, *,
                        max_iter: int = MAX_ITER) -> BatchResult:
    """Solve many (threading, length) pairs at once, vectorised over the batch.

    Parameters
    ----------
    skeleton : Skeleton
    threadings : sequence of threadings, or one threading
        Either B threadings (one per length) or a single threading used for all.
    cable_lengths_mm : array_like, shape (B,)

    Returns
    -------
    BatchResult
        ``angles`` of shape (B, n_segments) and the other fields as (B,) arrays.

    Raises
    ------
    InfeasibleLengthError, SnapThroughError, ValueError
        As :func:`solve_forward`, for the first offending item (all are validated
        before any solving).
    """
    _check_skeleton(skeleton)
    lengths = np.asarray(cable_lengths_mm, dtype=float)
    if lengths.ndim != 1:
        raise ValueError(f'cable_lengths_mm must be 1-D, got shape {lengths.shape}')
    nb = lengths.shape[0]
    single = _is_single_threading(threadings)
    if single:
        ds = [skeleton.threading_mm(threadings)]
        index = np.zeros(nb, dtype=int)
    else:
        items = list(threadings)
        if len(items) != nb:
            raise ValueError(f'expected {nb} threadings (one per length), got {len(items)}')
        keys: dict = {}
        ds, index = [], np.empty(nb, dtype=int)
        for i, t in enumerate(items):
            key = tuple(skeleton.threading_mm(t).tolist())
            if key not in keys:
                keys[key] = len(ds)
                ds.append(np.array(key))
            index[i] = keys[key]
    probs = [_problem(skeleton, tuple(d.tolist())) for d in ds]
    for j, prob in enumerate(probs):
        sel = lengths[index == j]
        _check_length(prob, sel, skeleton, _describe(skeleton, prob.d))
    if nb == 0:
        n = skeleton.n_segments
        empty = np.zeros((0,))
        return BatchResult(np.zeros((0, n)), np.zeros((0, n + 1, 2)), np.zeros((0, n + 1, 2)),
                           empty, empty, empty.astype(int), empty.astype(bool), empty, empty,
                           empty, empty.astype(bool), empty, empty.astype(bool),
                           np.zeros((0, n), bool), empty)
    P = _stack(probs, index)
    out = _solve_arrays(P, lengths, max_iter=int(max_iter))
    return _batch_result(BatchResult, P, out, lengths)


def _batch_result(cls, P, out, lengths, **extra):
    from .geometry import _rib_frames
    centers, theta = _rib_frames(out['angles'], P['s'])
    holes = centers + P['d'][..., None] * np.stack([np.sin(theta), -np.cos(theta)], axis=-1)
    return cls(angles=out['angles'], rib_centers=centers, cable_path=holes,
               energy=out['energy'], tension=out['tension'], iterations=out['iterations'],
               converged=out['converged'], residual=out['residual'],
               constraint_residual=out['constraint_residual'],
               stationarity_residual=out['stationarity_residual'],
               is_minimum=out['is_minimum'], min_curvature=out['min_curvature'],
               slack=out['slack'], at_contact=out['at_contact'], cable_length_mm=lengths,
               tie_break=P['mirror'] & (out['angles'] != 0.0), **extra)


def _is_single_threading(threadings) -> bool:
    if isinstance(threadings, str):
        return True
    if isinstance(threadings, np.ndarray):
        return threadings.ndim == 1
    try:
        first = next(iter(threadings))
    except (TypeError, StopIteration):
        return False
    return isinstance(first, (str, numbers.Real))


def sweep(skeleton: Skeleton, threading, contractions_mm, *,
          max_iter: int = MAX_ITER) -> SweepResult:
    """Follow a contraction range (e.g. the paper's 0-80 mm workspace plot).

    Parameters
    ----------
    skeleton : Skeleton
    threading : sequence of str or float
    contractions_mm : array_like, shape (B,)
        Cable shortening from the straight length (mm), ``>= 0``.

    Returns
    -------
    SweepResult
        Fields of :class:`BatchResult` plus ``contractions_mm``.

    Notes
    -----
    Every step is warm-started from the exact samples of the traced path of this
    threading (memoised), i.e. from the nearest already-traced shapes, and all steps are
    polished together, vectorised. Since the path is a single-valued function of the
    tension, the result equals small-step path following.
    """
    _check_skeleton(skeleton)
    c = np.asarray(contractions_mm, dtype=float)
    if c.ndim != 1:
        raise ValueError(f'contractions_mm must be 1-D, got shape {c.shape}')
    if not np.all(np.isfinite(c)):
        raise ValueError(f'contractions_mm must be finite, got {c[~np.isfinite(c)][0]!r}')
    if np.any(c < 0):
        raise ValueError(f'contractions_mm must be >= 0, got {c[c < 0][0]!r}')
    d = skeleton.threading_mm(threading)
    prob = _problem(skeleton, tuple(d.tolist()))
    lengths = prob.straight_mm - c
    _check_length(prob, lengths, skeleton, _describe(skeleton, d))
    P = _stack([prob], np.zeros(c.shape[0], dtype=int))
    out = _solve_arrays(P, lengths, max_iter=int(max_iter))
    return _batch_result(SweepResult, P, out, lengths, contractions_mm=c)
