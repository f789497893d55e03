"""Per-threading problem data: the problem, its caches and its batch layout.

Owns :class:`_Problem` (everything about one skeleton and threading that does not depend
on the length: per-segment tensions where branches start and end, and the path table
:class:`~.path_table._PathTable`), the memoised builders (:func:`_problem`,
:func:`_single`, :func:`_single_named`, :func:`_threading_cached`), the batch layout of
problem data (:func:`_stack`) and the length checks that raise the documented errors.
Every cache here is a pure function of its key: a lazily built table gives the answers
of a full one, bit for bit.
"""
from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass

import numpy as np

from ..geometry import _G_COEF, _G_TERMS
from ..skeleton import Skeleton
from .branch import _BRANCH_SAMPLES, _PairMemo, _branch_derivs, _pair_profiles
from .path_table import _PathTable
from .results import InfeasibleLengthError, SnapThroughError

#: Threadings whose problem data and path tables stay cached (least recently used
#: first out; about 0.3 MB each, so a full cache holds about 0.7 GB). Large enough that a
#: loop over every threading of 7 ribs with 3 holes (3^7 = 2187) or a robot's modules
#: never rebuilds a table per solve (a rebuild costs a few ms).
_THREADINGS_CACHED = 2560


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
    snap: bool               # the path ends at a fold (snap-through), not at contact
    path_lam: np.ndarray     # (P,) increasing tensions along the whole path
    path: '_PathTable'       # samples there and start polynomials, built on demand
    path_columns: np.ndarray  # (n+1,) column of path_poly for each segment, then lambda
    min_mm_above: float      # a bound above min_mm (a check that need not compute it)

    @property
    def min_mm(self) -> float:
        """Infimum of reachable lengths (mm): every segment at its branch end (or the
        length at the fold). Computed on first read (a first solve whose length is
        above :attr:`min_mm_above` never needs it) and kept; a pure function of the
        problem, so concurrent first reads agree."""
        value = self.__dict__.get('_min_mm')
        if value is None:
            end_len, _, _ = _branch_derivs(self.b_end, self.direction, self.d1, self.d2,
                                           self.s)
            value = self.__dict__['_min_mm'] = float(end_len.sum())
        return value

    @property
    def path_len(self) -> np.ndarray:
        """(P,) non-increasing total length at the path samples (full table)."""
        return self.path.complete().len

    @property
    def path_b(self) -> np.ndarray:
        """(P, n) exact branch magnitudes at the path samples (full table)."""
        return self.path.complete().b[:, self.path_columns[:-1]]

    @property
    def path_poly(self) -> np.ndarray:
        """(P-1, 6, U+1) start polynomials per cell of the U distinct segments and
        lambda (full table), see :func:`_path_polynomials`."""
        return self.path.complete().poly


def _sorted_unique(values):
    """``np.unique`` of finite numbers: a sort in place and one comparison (cheaper for
    ~1000, and numpy 2.4's ``unique`` imports ``numpy.ma`` on first use, 70 ms).
    ``values`` is a new array (it is sorted in place)."""
    values.sort(kind='stable')    # merges the sorted runs of the segments' tables
    keep = np.empty(values.size, dtype=bool)
    keep[0] = True
    np.not_equal(values[1:], values[:-1], out=keep[1:])
    return values[keep]


@functools.lru_cache(maxsize=64)
def _thinned(size):
    """Indices keeping :data:`_PATH_SAMPLES` of ``size`` path tensions, ends included
    (a pure function of the size, memoised: ``np.linspace`` costs ~10 us a call)."""
    keep = np.linspace(0, size - 1, _PATH_SAMPLES).astype(int)
    keep.flags.writeable = False
    return keep


#: Most samples of a path table (before the buckling and end tensions are added back).
_PATH_SAMPLES = 4 * _BRANCH_SAMPLES


@functools.lru_cache(maxsize=_THREADINGS_CACHED)
def _problem(skeleton: Skeleton, d: tuple) -> _Problem:
    s = skeleton.spacing_mm
    b_max = skeleton.contact_angle_rad
    d_arr = np.array(d, dtype=float)
    d1, d2 = d_arr[:-1], d_arr[1:]
    k = skeleton.stiffness_array
    prof = _pair_profiles(d1, d2, s, b_max)
    direction, mu_c, beta = prof['direction'], prof['mu_c'], prof['beta']
    mu_end, b_end = prof['mu_end'], prof['b_end']
    kind = prof['kinds']
    table_mu, table_b = prof['mu'], prof['b']
    lam_c, lam_end = k * mu_c, k * mu_end
    straight = float(np.add.reduce(np.hypot(s, d2 - d1)))   # np.sum, without its wrapper
    folds = [i for i, kd in enumerate(kind) if kd == 'fold'] if 'fold' in kind else []
    snap = bool(folds)
    # Segments with the same holes and stiffness have the same angle at every tension:
    # the path is solved once per distinct segment (5 to 7 of 11 for the paper's
    # threadings; the table build is arithmetic on (samples, segments) arrays) and
    # gathered back, the totals weighted by how many segments share each column.
    position, first, inverse = {}, [], []
    for i, key in enumerate(zip(d1.tolist(), d2.tolist(), k.tolist())):
        if key not in position:
            position[key] = len(position)
            first.append(i)
        inverse.append(position[key])
    # Per distinct segment: holes, stiffness, direction, the tensions where it starts
    # bending and reaches its end (one gather of the stacked rows), its profile tables.
    rows = np.array([d1, d2, k, direction, lam_c, lam_end])[:, first]
    seg = dict(zip(('d1', 'd2', 'k', 'direction', 'lam_c', 'lam_end'), rows))
    tables = prof['tables'][first]
    seg['table_lists'] = [prof['table_lists'][i] for i in first]
    seg.update(table_b=tables[:, 0], table_mu=tables[:, 1], dmu=tables[:, 2],
               table_len=tables[:, 3], tables=tables,
               count=np.array([inverse.count(u) for u in range(len(first))], dtype=float))
    # Path table: every tension where some segment's table has a sample (the distinct
    # segments' tables hold them all), up to where the path ends (all segments at their
    # ends, or the first fold).
    lam_all = (seg['k'][:, None] * seg['table_mu']).ravel()
    if snap:
        lam_top = float(np.min(lam_end[folds]))
    else:
        finite = [x for x in lam_end.tolist() if math.isfinite(x)]
        lam_top = max(finite) if finite else float(lam_all[np.isfinite(lam_all)].max())
    # (lam_all <= lam_top also drops the tables' inf and NaN tensions.)
    lam_path = _sorted_unique(np.concatenate([[0.0], lam_all[lam_all <= lam_top], [lam_top]]))
    if lam_path.size > _PATH_SAMPLES:
        # Thin to a bounded table; keep the ends and every buckling tension (the kept
        # indices are strictly increasing: their step is above 1).
        lam_path = _sorted_unique(np.concatenate([lam_path[_thinned(lam_path.size)],
                                                  seg['lam_c'], seg['lam_end'], [lam_top]]))
        lam_path = lam_path[lam_path <= lam_top]
    e1, e2 = seg['d1'] * seg['direction'], seg['d2'] * seg['direction']
    seg.update(e1=e1, e2=e2, dd2=(seg['d1'] - seg['d2']) ** 2)
    seg['pre'] = (e1, e2, seg['dd2'], 2.0 * e1 * e2)
    table = _PathTable(lam_path, straight, s, seg)
    columns = np.array(inverse + [len(first)])     # [b of each segment..., lambda]
    prob = _Problem(d=d_arr, d1=d1, d2=d2, k=k, s=s, direction=direction, lam_c=lam_c,
                    mu_c=mu_c, beta=beta, lam_end=lam_end, b_end=b_end, kind=kind,
                    table_mu=table_mu, table_b=table_b, straight_mm=straight, snap=snap,
                    path_lam=lam_path, path=table, path_columns=columns,
                    min_mm_above=math.fsum(prof['end_length'].tolist()) + 1e-9 * straight)
    if snap:
        prob.__dict__['_min_mm'] = table.length_at_tension(lam_path[-1])
    return prob


def _check_length(prob: _Problem, length: np.ndarray, skeleton, d):
    """Raise the documented errors for NaN/inf and unreachable lengths.

    The threading `d` is named in the message only when one is raised: naming it costs
    ~50 µs, which every batch used to pay for lengths that were fine.
    """
    # (float(): numpy 2 would print a numpy scalar as np.float64(...).)
    if not np.all(np.isfinite(length)):
        bad = float(length[~np.isfinite(length)].ravel()[0])
        raise ValueError(f'cable_length_mm must be finite, got {bad!r}')
    if np.any(length <= 0):
        bad = float(length[length <= 0].ravel()[0])
        raise ValueError(f'cable_length_mm must be > 0, got {bad!r}')
    low = length <= prob.min_mm
    if np.any(low):
        bad = float(length[low].ravel()[0])
        rng = (prob.min_mm, prob.straight_mm)
        threading_desc = _describe(skeleton, d)
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


@functools.lru_cache(maxsize=2 * _THREADINGS_CACHED)
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


_PER_ITEM = ('uid', 'k', 'd', 'd1', 'd2', 'direction', 'lam_c', 'lam_end', 'mu_c', 'beta',
             'b_end', 'mirror', 'mu_c_safe', 'beta_safe', 'mu_1', 'lam_1', 'b_1', 'e1', 'e2',
             'two_e1e2', 'dd2', 'two_k', 'inv_two_k', 'straight')


def _one(arrays):
    """``np.stack`` of a one-element list (a read-only view with a leading axis)."""
    out = arrays[0][None]
    out.flags.writeable = False
    return out


def _stack(probs, index, complete=True):
    """Batch arrays: per-item (B, n) arrays, tables once per distinct threading.

    ``index`` (B,) maps batch rows to ``probs``; keys in :data:`_PER_ITEM` have the
    batch as leading axis (and are what a sub-batch slices). The per-segment fields are
    computed once per threading and gathered for the rows in one indexing operation
    (read-only views of it); with one threading they are broadcast views, no copy.
    The path tables are built in full unless ``complete`` is false (the single-solve
    layout, whose lengths are made ready one by one, :meth:`_PathTable.ensure`).
    """
    index = np.asarray(index)
    nb = index.shape[0]
    # One threading (a new threading's first solve builds this): no copies to stack.
    stack = _one if len(probs) == 1 else np.stack
    tables_mu = stack([p.table_mu for p in probs])
    tables_b = stack([p.table_b for p in probs])
    k = stack([p.k for p in probs])
    mu_c = stack([p.mu_c for p in probs])
    beta = stack([p.beta for p in probs])
    d1 = stack([p.d1 for p in probs])
    d2 = stack([p.d2 for p in probs])
    direction = stack([p.direction for p in probs])
    mirror = mu_c > 0
    fields = dict(
        k=k, d1=d1, d2=d2, direction=direction, lam_c=stack([p.lam_c for p in probs]),
        lam_end=stack([p.lam_end for p in probs]), mu_c=mu_c, beta=beta,
        b_end=stack([p.b_end for p in probs]),
        mu_c_safe=np.where(mirror, mu_c, 1.0), beta_safe=np.where(mirror, beta, 1.0),
        mu_1=tables_mu[:, :, 1], lam_1=k * tables_mu[:, :, 1], b_1=tables_b[:, :, 1],
        e1=d1 * direction, e2=d2 * direction, two_e1e2=2.0 * d1 * d2, dd2=(d1 - d2) ** 2,
        two_k=2.0 * k, inv_two_k=0.5 / k)
    names = list(fields)
    table = np.stack([fields[name] for name in names], axis=1)        # (U, F, n)
    d = stack([p.d for p in probs])
    straight = np.array([p.straight_mm for p in probs])
    if len(probs) == 1:
        rows = np.broadcast_to(table[0], (nb,) + table.shape[1:])
        out = dict(d=np.broadcast_to(d[0], (nb, d.shape[1])),
                   mirror=np.broadcast_to(mirror[0], (nb, mirror.shape[1])),
                   straight=np.broadcast_to(straight[0], (nb,)))
    else:
        rows = table[index]
        out = dict(d=d[index], mirror=mirror[index], straight=straight[index])
    out.update({name: rows[:, f] for f, name in enumerate(names)})
    out.update(uid=index, s=probs[0].s, has_mirror=bool(mirror.any()),
               tables_mu=tables_mu, tables_b=tables_b,
               paths=[((p.path.complete() if complete else p.path).len, p.path_lam,
                       p.path.poly, p.path_columns) for p in probs])
    return out


#: Degree in ``b`` of ``Q = l^2`` as evaluated by :func:`.single._evaluate` (the series of
#: ``g`` to ``b^(2 (_G_TERMS - 1))`` times a quadratic).
_Q_DEGREE = 2 * _G_TERMS


def _q_coefficients(dd2, s, e1, e2):
    """(n, _Q_DEGREE + 1, 3) coefficients of ``Q, Q', Q''`` in powers of ``b`` per segment.

    ``Q = dd2 + sum_j gamma_j b^(2j) (s^2 + s (e1 + e2) b + e1 e2 b^2)`` with ``gamma_j``
    the series of ``g`` (:data:`softsnap_model.geometry._G_COEF`, column 0).
    """
    n = dd2.shape[0]
    gamma = _G_COEF[:, 0]
    q = np.zeros((n, _Q_DEGREE + 3))
    q[:, 0] = dd2
    t = gamma.shape[0]
    q[:, 0:2 * t:2] += gamma * (s * s)
    q[:, 1:2 * t + 1:2] += gamma * (s * (e1 + e2))[:, None]
    q[:, 2:2 * t + 2:2] += gamma * (e1 * e2)[:, None]
    m = np.arange(_Q_DEGREE + 1)
    out = np.empty((n, _Q_DEGREE + 1, 3))
    out[:, :, 0] = q[:, :_Q_DEGREE + 1]
    out[:, :, 1] = (m + 1) * q[:, 1:_Q_DEGREE + 2]
    out[:, :, 2] = (m + 1) * (m + 2) * q[:, 2:_Q_DEGREE + 3]
    return out


#: ``Q`` coefficients (:func:`_q_coefficients`) per hole pair ``(d1, d2, s)``, memoised
#: for the process (a pure function of the pair: its direction is; rows are computed
#: element-wise, so a threading's stack of them is what one call on its segments gives).
#: FIFO-bounded; :func:`softsnap_model.forward.clear_caches` empties it.
_Q_CACHE = _PairMemo(16384)


def _q_stack(d1, d2, direction, s):
    """(n, _Q_DEGREE + 1, 3) :func:`_q_coefficients` of the segments, from
    :data:`_Q_CACHE` (the pairs not seen before computed together)."""
    s = float(s)
    keys = [(x, y, s) for x, y in zip(d1.tolist(), d2.tolist())]

    def build(missing):
        first = {}   # a missing pair's first segment (its direction is the pair's)
        for i, key in enumerate(keys):
            first.setdefault(key, i)
        at = [first[key] for key in missing]
        e1, e2 = (d1 * direction)[at], (d2 * direction)[at]
        return list(_q_coefficients((d1[at] - d2[at]) ** 2, s, e1, e2))

    return np.array(_Q_CACHE.get_many(keys, build))


class _SingleLayout(dict):
    """The single-solve layout of one threading (:func:`_single`): a dict of 1-D arrays
    and lists, whose batch-of-one layout ``'P'`` (:func:`_stack`, only read by the rare
    kick, guess and fallback paths of :mod:`.single`) is built on first access, once,
    under a lock (concurrent first solves share it)."""

    __slots__ = ('_prob', '_lock')

    def __init__(self, prob):
        super().__init__()
        self._prob = prob
        self._lock = threading.Lock()

    def __missing__(self, key):
        if key != 'P':
            raise KeyError(key)
        with self._lock:
            P = dict.get(self, 'P')
            if P is None:
                P = self['P'] = _stack([self._prob], np.zeros(1, dtype=int), complete=False)
        return P


@functools.lru_cache(maxsize=_THREADINGS_CACHED)
def _single(skeleton: Skeleton, d: tuple):
    """``(problem, S)``: the single-solve layout ``S`` of the problem data, 1-D
    (memoised with the problem). The batch-of-one layout is ``S['P']``, built when a
    solve first reads it. Its path table is built lazily: ``S['path'].ensure(L)``
    builds the cell of a length ``L`` (:func:`.single._solve_single` calls it)."""
    prob = _problem(skeleton, d)
    table = prob.path
    k, d1, d2, direction = prob.k, prob.d1, prob.d2, prob.direction
    # The per-segment fields of _stack's row, computed the same way on 1-D arrays (the
    # same element-wise operations: bit for bit the batch layout's row).
    mirror = prob.mu_c > 0
    lam_1 = k * prob.table_mu[:, 1]
    e1, e2 = d1 * direction, d2 * direction
    dd2 = (d1 - d2) ** 2
    mirror_idx = mirror.nonzero()[0]       # np.flatnonzero, without its wrapper
    S = _SingleLayout(prob)
    S.update(k=k, d=prob.d, d1=d1, d2=d2, direction=direction, lam_c=prob.lam_c,
             lam_end=prob.lam_end, b_end=prob.b_end, mirror=mirror, lam_1=lam_1,
             e1=e1, e2=e2, dd2=dd2, two_k=2.0 * k, inv_two_k=0.5 / k, s=prob.s,
             has_mirror=bool(mirror_idx.size),
             lam_end_min=float(np.minimum.reduce(prob.lam_end)), path=table,
             path_lam=prob.path_lam, path_poly=table.poly,
             path_columns=prob.path_columns,
             straight=prob.straight_mm, n_path=prob.path_lam.size,
             # For the single-solve evaluation (single._evaluate): l^2 as polynomials
             # in b; the cell search reads Python floats (cheaper than array items), the
             # table's own lists, filled in as its blocks are built.
             q_coef=_q_stack(d1, d2, direction, prob.s),
             two_beta=2.0 * prob.beta, path_len_list=table.len_list,
             neg_path_len_list=table.neg_len_list,
             minus_i_d=-1j * prob.d,
             # Mirror segments (index array) and their first table cells in tension,
             # for the cheap tests of the single-solve path.
             mirror_idx=mirror_idx,
             mirror_first_cells=[(float(prob.lam_c[i]), float(lam_1[i]))
                                 for i in mirror_idx],
             )
    return prob, S


@functools.lru_cache(maxsize=2 * _THREADINGS_CACHED)
def _single_named(skeleton: Skeleton, key: tuple):
    """:func:`_single` for a threading given as a hashable tuple of names or offsets
    (one cache lookup per solve instead of two; shares the entries of :func:`_single`)."""
    return _single(skeleton, _threading_cached(skeleton, key))


def _single_for(skeleton: Skeleton, threading):
    """``(problem, S)`` of any accepted threading form (memoised for hashable input,
    and for a string of names or a 1-D array of offsets, by their items)."""
    if isinstance(threading, str):
        threading = threading.split()
    elif isinstance(threading, np.ndarray) and threading.ndim == 1:
        threading = threading.tolist()
    if isinstance(threading, (list, tuple)):
        try:
            return _single_named(skeleton, tuple(threading))
        except TypeError:   # unhashable items: convert (and fail) the normal way
            pass
    return _single(skeleton, tuple(skeleton.threading_mm(threading).tolist()))
