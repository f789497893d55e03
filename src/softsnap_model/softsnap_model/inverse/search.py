"""The certified search behind :func:`~softsnap_model.inverse.design_threading`: the
tension-parametrised problem, the 1-D refinement of a threading over the tension, the
k-best candidate list and the branch and bound over tension intervals (the method is
described in :mod:`softsnap_model.inverse`)."""
from __future__ import annotations

import math

import numpy as np

from .. import forward, geometry
from .kbest import kbest_chain
from .results import _no_check
from .targets import _hole_table

#: Optimality tolerance of the branch and bound: no design has an angle error (L2, rad)
#: below the returned error minus this.
GLOBAL_TOL_RAD = 1e-6

#: Largest difference (rad) accepted between the tension-table angles of a design and
#: the forward solve at its cable length before the design is flagged as off-branch.
BRANCH_AGREEMENT_TOL_RAD = 1e-6

#: Tension grid (per unit stiffness): geometric from MIN to MAX, plus zero (slack cable).
INITIAL_TENSION_NODES = 64

MIN_TENSION = 1e-4

MAX_TENSION = 1e3  # grid top when no hole pair saturates (custom hole sets)

#: Branch and bound stops after this many rounds of interval splitting (the certified
#: lower bound is reported either way).
MAX_BB_ROUNDS = 40

#: ... or once more intervals than this remain open.
MAX_BB_INTERVALS = 4096


class _Problem:
    """Per-design data shared by the table, bound and refinement steps."""

    def __init__(self, skeleton, target, mask, length_range, n_best):
        self.skeleton = skeleton
        #: Called between steps of the search; raises to stop the design.
        self.check = _no_check
        #: report(fraction, stage): progress, then a check.
        self.report = lambda fraction, stage: None
        self.names, self.offsets = _hole_table(skeleton)
        self.spacing = skeleton.spacing_mm
        self.stiffness = skeleton.stiffness_array
        # a(lam; k) depends on lam / k only: tabulate each distinct stiffness once.
        self.unique_k, self.k_index = np.unique(self.stiffness, return_inverse=True)
        self.target = target
        self.mask = mask
        self.length_range = length_range
        self.n_best = n_best

        self.contact_rad = skeleton.contact_angle_rad
        m = self.offsets.size
        d1, d2 = np.broadcast_arrays(self.offsets[:, None], self.offsets[None, :])
        self.pair_d1, self.pair_d2 = d1.ravel(), d2.ravel()
        self.pair_grid = np.arange(m * m).reshape(m, m)
        branch = forward.segment_branch(self.pair_d1, self.pair_d2, self.spacing,
                                        self.contact_rad)
        #: Tension (per unit stiffness) beyond which no pair's angle changes any more.
        finite = branch.end_tension[np.isfinite(branch.end_tension)]
        self.saturation_tension = float(finite.max()) if finite.size else MAX_TENSION
        self.end_angle = (branch.direction * branch.end_angle_rad).reshape(m, m)

    def angles(self, lam, pair, k):
        """Branch angles (rad) of hole pairs (flat indices) at tensions, broadcasting;
        ``lam = inf`` gives the branch ends (every segment at contact)."""
        return forward.segment_angle_at_tension(lam, self.pair_d1[pair], self.pair_d2[pair],
                                                self.spacing, k, self.contact_rad)

    def table(self, lam):
        """Angles and segment lengths (N, n_seg, m, m) at tensions lam (N,)."""
        lam = np.asarray(lam, dtype=float)
        finite = np.isfinite(lam)
        a_u = self.angles(np.where(finite, lam, 0.0)[:, None, None, None],
                          self.pair_grid[None, None],
                          self.unique_k[None, :, None, None])
        a_u = np.where(finite[:, None, None, None], a_u, self.end_angle)
        a = a_u[:, self.k_index]
        d1 = self.offsets[:, None]
        d2 = self.offsets[None, :]
        return a, geometry.segment_length(a, d1, d2, self.spacing)

    def path_angles(self, paths, lam):
        """Angles (..., n_seg) of threadings paths (..., n_ribs) at tensions lam (...)."""
        m = self.offsets.size
        pair = paths[..., :-1] * m + paths[..., 1:]
        return self.angles(np.asarray(lam)[..., None], pair, self.stiffness)

    def path_length(self, paths, angles):
        d = self.offsets[paths]
        return np.sum(geometry.segment_length(angles, d[..., :-1], d[..., 1:], self.spacing),
                      axis=-1)

    def feasible(self, length):
        if self.length_range is None:
            return np.ones(np.shape(length), dtype=bool)
        lo, hi = self.length_range
        return (length >= lo) & (length <= hi)


def _angle_hull(a_lo, a_hi):
    """Range of a monotone-in-|a| branch between its values at the interval ends."""
    lo = np.minimum(a_lo, a_hi)
    hi = np.maximum(a_lo, a_hi)
    flip = (a_lo * a_hi) < 0.0
    if np.any(flip):
        big = np.maximum(np.abs(a_lo), np.abs(a_hi))
        lo = np.where(flip, -big, lo)
        hi = np.where(flip, big, hi)
    return lo, hi


# Lagrange multipliers (rad^2 per mm) tried for the cable-length bounds.
_LENGTH_MULTIPLIERS = np.array([1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])

_REFINE_SAMPLES = 9

_REFINE_ROUNDS = 6

_GAUSS_NEWTON_STEPS = 8


def _refine(prob, paths, lam_lo, lam_hi, rounds=_REFINE_ROUNDS):
    """Best tension of each threading on its bracket: sampling, then Gauss-Newton.

    Returns (cost, lam) per threading; cost is inf where no tension in the bracket
    meets the cable-length range.
    """
    n_c = paths.shape[0]
    lo = np.asarray(lam_lo, dtype=float).copy()
    hi = np.asarray(lam_hi, dtype=float).copy()
    best_cost = np.full(n_c, np.inf)
    best_lam = lo.copy()
    u = np.linspace(0.0, 1.0, _REFINE_SAMPLES)

    def evaluate(lam):
        a = prob.path_angles(paths[:, None, :] if lam.ndim == 2 else paths, lam)
        cost = np.sum((a - prob.target) ** 2, axis=-1)
        if prob.length_range is not None:
            length = prob.path_length(paths[:, None, :] if lam.ndim == 2 else paths, a)
            cost = np.where(prob.feasible(length), cost, np.inf)
        return cost, a

    for _ in range(rounds):
        prob.check()
        geometric = lo > 0.0
        lam = np.where(geometric[:, None],
                       np.exp(np.log(np.where(geometric, lo, 1.0))[:, None]
                              + u * np.log(np.where(geometric, hi / np.where(geometric, lo, 1.0),
                                                    1.0))[:, None]),
                       lo[:, None] + u * (hi - lo)[:, None])
        cost, _ = evaluate(lam)
        j = np.argmin(cost, axis=1)
        rows = np.arange(n_c)
        better = cost[rows, j] < best_cost
        best_cost = np.where(better, cost[rows, j], best_cost)
        best_lam = np.where(better, lam[rows, j], best_lam)
        lo = lam[rows, np.maximum(j - 1, 0)]
        hi = lam[rows, np.minimum(j + 1, _REFINE_SAMPLES - 1)]

    # Gauss-Newton on the tension with da/dlam = -L'(a) / (2 k + lam L''(a)), kept
    # inside the last bracket and accepted only where it lowers the cost.
    d = prob.offsets[paths]
    lam = best_lam.copy()
    for _ in range(_GAUSS_NEWTON_STEPS):
        prob.check()
        a = prob.path_angles(paths, lam)
        _, dl, d2l = geometry.segment_length_derivatives(a, d[:, :-1], d[:, 1:], prob.spacing)
        denom = 2.0 * prob.stiffness + lam[:, None] * d2l
        slope = np.where(denom > 0.0, -dl / np.where(denom > 0.0, denom, 1.0), 0.0)
        res = a - prob.target
        num = np.sum(res * slope, axis=1)
        den = np.sum(slope * slope, axis=1)
        step = np.where(den > 0.0, -num / np.where(den > 0.0, den, 1.0), 0.0)
        trial = np.clip(lam + step, lo, hi)
        cost, _ = evaluate(trial)
        better = cost < best_cost
        if not np.any(better):
            break
        best_cost = np.where(better, cost, best_cost)
        best_lam = np.where(better, trial, best_lam)
        lam = best_lam.copy()
    return best_cost, best_lam


class _Candidates:
    """Threadings refined so far: best cost (rad^2) and tension per threading."""

    def __init__(self, prob):
        self.prob = prob
        self.best = {}
        self.polished = set()

    def refine(self, paths, lam_lo, lam_hi, rounds=_REFINE_ROUNDS):
        if len(paths) == 0:
            return
        paths = np.asarray(paths, dtype=np.int64)
        cost, lam = _refine(self.prob, paths, np.asarray(lam_lo), np.asarray(lam_hi),
                            rounds)
        for path, c, x in zip(map(tuple, paths.tolist()), cost, lam):
            if np.isfinite(c) and (path not in self.best or c < self.best[path][0]):
                self.best[path] = (float(c), float(x))

    def ranked(self):
        return sorted(self.best.items(), key=lambda item: item[1][0])

    def record_nodes(self, lam, a, seg_len):
        """Exact k-best threadings at each tension node (length-feasible ones kept)."""
        prob = self.prob
        finite = np.isfinite(lam)
        cost = (a - prob.target[None, :, None, None]) ** 2
        if prob.length_range is not None:
            # Steer the list towards feasible lengths: penalise the excess outside range.
            lo, hi = prob.length_range
            n_seg = prob.target.size
            excess = (np.maximum(seg_len - hi / n_seg, 0.0)
                      + np.maximum(lo / n_seg - seg_len, 0.0))
            cost = cost + 1e-3 * excess
        values, paths = kbest_chain(cost, prob.mask, prob.n_best, check=prob.check)
        seg = np.arange(prob.target.size)
        for j in np.nonzero(finite)[0]:
            prob.check()
            for r in range(prob.n_best):
                if not np.isfinite(values[j, r]):
                    break
                path = paths[j, r]
                angles = a[j, seg, path[:-1], path[1:]]
                length = seg_len[j, seg, path[:-1], path[1:]].sum()
                if not prob.feasible(length):
                    continue
                c = float(np.sum((angles - prob.target) ** 2))
                key = tuple(path.tolist())
                if key not in self.best or c < self.best[key][0]:
                    self.best[key] = (c, float(lam[j]))
                    self.polished.discard(key)

    def polish(self, n, final=False):
        """Refine the tension of the n best threadings not refined since they changed."""
        todo = [(p, x) for p, (_, x) in self.ranked()[:n] if final or p not in self.polished]
        if not todo:
            return
        paths = [p for p, _ in todo]
        lam = np.array([x for _, x in todo])
        self.refine(paths, np.where(lam > 0, lam / 1.5, 0.0),
                    np.where(lam > 0, lam * 1.5, 10 * MIN_TENSION),
                    rounds=_REFINE_ROUNDS if final else 2)
        self.polished.update(paths)

    def thresholds(self, n, tol_rad):
        """Squared (r-th best error - tol) for r = 1..n (inf while fewer are known)."""
        errors = np.sqrt(sorted(c for c, _ in self.best.values())[:n])
        out = np.full(n, np.inf)
        out[:errors.size] = np.maximum(errors - tol_rad, 0.0) ** 2
        return out

    def kth_error(self, n):
        costs = sorted(c for c, _ in self.best.values())
        return math.sqrt(costs[n - 1]) if len(costs) >= n else math.inf


def _tension_nodes(prob):
    """Zero (slack), a geometric grid up to saturation, and infinity (every segment at
    its branch end: rib contact for the authors' module)."""
    k = prob.stiffness
    top = prob.saturation_tension * k.max() * (1.0 + 1e-9)
    inner = np.geomspace(MIN_TENSION * k.min(), top, INITIAL_TENSION_NODES)
    return np.concatenate(([0.0], inner, [np.inf]))


def _split(lam_lo, lam_hi):
    """Midpoints in log-tension (towards zero and infinity for the end intervals)."""
    safe_lo = np.where(lam_lo > 0.0, lam_lo, 1.0)
    safe_hi = np.where(np.isfinite(lam_hi), lam_hi, 1.0)
    mid = np.sqrt(safe_lo * safe_hi)
    mid = np.where(lam_lo > 0.0, mid, 1e-3 * lam_hi)
    return np.where(np.isfinite(lam_hi), mid, 10.0 * lam_lo)


def _finite_bracket(lam_lo, lam_hi):
    return lam_lo, np.where(np.isfinite(lam_hi), lam_hi, 10.0 * lam_lo)


def _branch_and_bound(prob, tol_rad):
    n_best = prob.n_best
    cands = _Candidates(prob)
    prob.report(0.05, 'tension tables')
    lam = _tension_nodes(prob)
    a, seg_len = prob.table(lam)
    n_nodes = lam.size
    cands.record_nodes(lam, a, seg_len)
    cands.polish(n_best)

    iv = dict(lo=lam[:-1], hi=lam[1:], a_lo=a[:-1], a_hi=a[1:],
              len_lo=seg_len[:-1], len_hi=seg_len[1:])
    lower_bound_cost = math.inf
    converged = True
    rounds = 0
    while iv['lo'].size:
        rounds += 1
        # Rounds are capped, so their count is an honest (pessimistic) measure of progress.
        prob.report(0.1 + 0.7 * (rounds - 1) / MAX_BB_ROUNDS, 'branch and bound')
        bounds = _interval_bounds(prob, iv)
        thresholds = cands.thresholds(n_best, tol_rad)
        # Prune an interval once, for every rank r, its r-th bound reaches the r-th best
        # error found minus the tolerance: then at most r - 1 threadings can beat that
        # error there, so every reported rank is within the tolerance of the true one.
        keep = np.any(bounds < thresholds[None, :], axis=1)
        done = ~keep
        if np.any(done):
            lower_bound_cost = min(lower_bound_cost, float(np.min(bounds[done, 0])))
        if not np.any(keep):
            break
        if rounds >= MAX_BB_ROUNDS or np.count_nonzero(keep) > MAX_BB_INTERVALS:
            lower_bound_cost = min(lower_bound_cost, float(np.min(bounds[keep, 0])))
            converged = False
            break
        iv = {key: value[keep] for key, value in iv.items()}
        mid = _split(iv['lo'], iv['hi'])
        a_mid, len_mid = prob.table(mid)
        n_nodes += mid.size
        cands.record_nodes(mid, a_mid, len_mid)
        cands.polish(n_best)
        iv = dict(lo=np.concatenate((iv['lo'], mid)), hi=np.concatenate((mid, iv['hi'])),
                  a_lo=np.concatenate((iv['a_lo'], a_mid)),
                  a_hi=np.concatenate((a_mid, iv['a_hi'])),
                  len_lo=np.concatenate((iv['len_lo'], len_mid)),
                  len_hi=np.concatenate((len_mid, iv['len_hi'])))
    best = cands.kth_error(1)
    lower = math.sqrt(max(lower_bound_cost, 0.0)) if math.isfinite(lower_bound_cost) else best
    return cands, dict(lower_bound=min(lower, best), converged=converged, rounds=rounds,
                       n_nodes=n_nodes, n_candidates=len(cands.best))


def _interval_bounds(prob, iv):
    """Lower bounds (B, K) of the k-best costs on each tension interval."""
    lo, hi = _angle_hull(iv['a_lo'], iv['a_hi'])
    t = prob.target[None, :, None, None]
    gap = np.maximum(lo - t, 0.0) + np.maximum(t - hi, 0.0)
    cost = gap * gap
    bounds, _ = kbest_chain(cost, prob.mask, prob.n_best, check=prob.check)
    if prob.length_range is None:
        return bounds
    # Lagrangian relaxation of  sum len_hi <= L_max  and  sum len_lo >= L_min (segment
    # lengths fall with tension): for any multiplier mu >= 0 the penalised k-best value
    # minus the constant is a valid lower bound of the length-feasible k-best value.
    l_min, l_max = prob.length_range
    for mu in _LENGTH_MULTIPLIERS:
        up, _ = kbest_chain(cost + mu * iv['len_hi'], prob.mask, prob.n_best, check=prob.check)
        bounds = np.maximum(bounds, up - mu * l_max)
        down, _ = kbest_chain(cost - mu * iv['len_lo'], prob.mask, prob.n_best,
                              check=prob.check)
        bounds = np.maximum(bounds, down + mu * l_min)
    return bounds
