"""Public batch entry points: many (threading, length) pairs, and contraction sweeps.

Owns :func:`solve_forward_batch` and :func:`sweep`: input conversion, grouping the items
by distinct threading (tables are stacked once per threading), and packing the batch
engine's arrays into :class:`BatchResult` / :class:`SweepResult`; and
:class:`PreparedBatch`, for callers that solve small batches over the same few
threadings again and again (the model node, 100 times a second): it keeps the stacked
tables between calls and refuses bad rows one by one (:class:`PreparedBatchResult`).
"""
from __future__ import annotations

import numbers

import numpy as np

from ..skeleton import Skeleton
from .api import _check_skeleton, _frames
from .newton import _START_POWERS, _solve_arrays
from .path import _PER_ITEM, _check_length, _problem, _stack, _threading_tuple
from .results import MAX_ITER, BatchResult, PreparedBatchResult, SweepResult


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
        ds, index = _group_threadings(skeleton, items)
    probs = [_problem(skeleton, tuple(d.tolist())) for d in ds]
    for j, prob in enumerate(probs):
        sel = lengths[index == j]
        _check_length(prob, sel, skeleton, prob.d)
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


def _group_threadings(skeleton: Skeleton, items: list):
    """Distinct threadings (offset arrays) of ``items`` and each item's index into them.

    Converting a threading costs ~10-20 us (:meth:`Skeleton.threading_mm`), more than
    solving it in a batch, so each distinct item is converted once: items that are the
    same object (a list repeated) share one lookup, hashable ones go through the
    memoised conversion, and a 2-D array of offsets is grouped by rows at once.
    """
    first = items[0] if items else None
    if (isinstance(first, np.ndarray) and first.ndim == 1
            and all(isinstance(t, np.ndarray) and t.shape == first.shape
                    and t.dtype.kind in 'fiu' for t in items)):
        uniq, index = np.unique(np.asarray(items, dtype=float), axis=0, return_inverse=True)
        ds = [skeleton.threading_mm(row) for row in uniq]     # validates each once
        return ds, index.reshape(-1)
    keys: dict = {}
    by_id: dict = {}
    ds, index = [], np.empty(len(items), dtype=int)
    for i, t in enumerate(items):
        j = by_id.get(id(t))
        if j is None:
            key = _threading_tuple(skeleton, t)
            j = keys.get(key)
            if j is None:
                j = keys[key] = len(ds)
                ds.append(np.array(key))
            by_id[id(t)] = j     # items stay referenced by ``items``: ids are stable
        index[i] = j
    return ds, index


def _batch_result(cls, P, out, lengths, **extra):
    centers, holes = _frames(out['angles'], P['s'], P['d'])
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
        raise ValueError(f'contractions_mm must be finite, got {float(c[~np.isfinite(c)][0])!r}')
    if np.any(c < 0):
        raise ValueError(f'contractions_mm must be >= 0, got {float(c[c < 0][0])!r}')
    d = skeleton.threading_mm(threading)
    prob = _problem(skeleton, tuple(d.tolist()))
    lengths = prob.straight_mm - c
    _check_length(prob, lengths, skeleton, d)
    P = _stack([prob], np.zeros(c.shape[0], dtype=int))
    out = _solve_arrays(P, lengths, max_iter=int(max_iter))
    return _batch_result(SweepResult, P, out, lengths, contractions_mm=c)


#: Distinct threadings a :class:`PreparedBatch` keeps stacked. A call that brings the
#: total above this restacks from that call's threadings alone, so the tables never grow
#: without bound (a robot has a few; a loop over every threading is solve_forward_batch's
#: job).
PREPARED_THREADINGS = 256

#: Row patterns (the threadings of a call's rows, in order) whose gathered rows a
#: :class:`PreparedBatch` keeps; beyond it the memo starts again.
PATTERNS_CACHED = 16

# Per-row fields of the stacked tables that are float (U, n) arrays: gathered for a
# call's rows in one indexing operation (see PreparedBatch._rows_of).
_ROW_FLOATS = tuple(name for name in _PER_ITEM if name not in ('uid', 'd', 'mirror', 'straight'))


class PreparedBatch:
    """Batch solves over a slowly changing set of threadings, tables stacked once.

    :func:`solve_forward_batch` groups its items by threading and stacks their problem
    tables on every call: for the ten rows of a 5-module robot's tick that is most of
    the call (~0.7 of ~1.5 ms measured, with the per-threading start from the path
    tables). This object keeps, for every threading it has seen (up to
    :data:`PREPARED_THREADINGS`), the stacked per-segment tables and the path tables
    joined end to end, so a call gathers its rows with a few indexing operations and
    starts all of them with one search. A call bringing a new threading restacks once
    (:attr:`restacks` counts it); the answers do not depend on what is stacked.

    Parameters
    ----------
    skeleton : Skeleton
    threadings : sequence of threadings, optional
        Threadings to stack now (e.g. a robot's modules), so that the first call
        does not pay for it.

    Notes
    -----
    Not thread-safe: one caller (thread) per object.

    Examples
    --------
    >>> prepared = PreparedBatch(Skeleton(), [['R3'] * 12, ['L2'] * 12])
    >>> res = prepared.solve([['R3'] * 12, ['L2'] * 12, ['R3'] * 12], [170.0, 175.0, 1.0])
    >>> res.converged.tolist(), res.refused[:2], res.refused[2].startswith('cable length 1.0')
    ([True, True, False], ('', ''), True)
    """

    def __init__(self, skeleton: Skeleton, threadings=()):
        _check_skeleton(skeleton)
        self.skeleton = skeleton
        #: How many times the tables were (re)built (count).
        self.restacks = 0
        self._offsets: list[tuple] = []      # the stacked threadings (hole offsets, mm)
        self._by_offsets: dict[tuple, int] = {}
        self._by_key: dict = {}              # a threading as given -> its stacked index
        self._patterns: dict = {}            # row pattern -> its rows (see _rows_of)
        items = list(threadings)
        if items:
            _, reasons = self._rows(items)
            if reasons:
                raise ValueError(next(iter(reasons.values())))

    @property
    def threadings(self) -> tuple:
        """The stacked threadings, as hole offsets (mm) per rib."""
        return tuple(self._offsets)

    # ------------------------------------------------------------------ tables
    def _rows(self, items: list, fresh: bool = False):
        """Stacked index of each item ((B,) int, -1 where refused) and {row: reason}.

        Restacks if some item is new; items are looked up as given (hashable forms),
        so a tick of known threadings costs one dictionary look-up per row. ``fresh``:
        the stack was just emptied for this call, which then keeps all its threadings
        (even more than :data:`PREPARED_THREADINGS`).
        """
        index = np.empty(len(items), dtype=int)
        reasons: dict[int, str] = {}
        grown = False
        for i, t in enumerate(items):
            key = _hashable(t)
            j = self._by_key.get(key) if key is not None else None
            if j is None:
                try:
                    offsets = _threading_tuple(self.skeleton, t)
                except (TypeError, ValueError) as error:
                    index[i] = -1
                    reasons[i] = f'threading: {error}'
                    continue
                j = self._by_offsets.get(offsets)
                if j is None:
                    if len(self._offsets) >= PREPARED_THREADINGS and not fresh:
                        # Full: start again from this call's threadings alone.
                        self._offsets, self._by_offsets, self._by_key = [], {}, {}
                        return self._rows(items, fresh=True)
                    j = self._by_offsets[offsets] = len(self._offsets)
                    self._offsets.append(offsets)
                    grown = True
                if key is not None:
                    self._by_key[key] = j
            index[i] = j
        if grown:
            self._restack()
        return index, reasons

    def _restack(self) -> None:
        """Stack the tables of every known threading (row u of each is threading u)."""
        probs = [_problem(self.skeleton, offsets) for offsets in self._offsets]
        n_threadings = len(probs)
        P = _stack(probs, np.arange(n_threadings))
        self._table = np.ascontiguousarray(np.stack([P[name] for name in _ROW_FLOATS], axis=1))
        self._d = np.ascontiguousarray(P['d'])
        self._mirror = np.ascontiguousarray(P['mirror'])
        self._straight = np.ascontiguousarray(P['straight'])
        self._shared = dict(s=P['s'], has_mirror=P['has_mirror'], tables_mu=P['tables_mu'],
                            tables_b=P['tables_b'], paths=P['paths'])
        self._probs = probs
        self._min_mm = np.array([p.min_mm for p in probs])
        # Path tables joined end to end. A row's path cell is found for all rows at once
        # by searching complex keys: real part the threading, imaginary part minus the
        # path length. Complex numbers order by real part, then imaginary part, so the
        # search stays inside the row's own table and is exactly the per-threading
        # search of _start_from_table (the keys are exact copies, nothing is rounded).
        sizes = np.array([p.path_len.size for p in probs])
        first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self._path_len = np.concatenate([p.path_len for p in probs])
        self._path_lam = np.concatenate([p.path_lam for p in probs])
        self._path_keys = np.empty(self._path_len.size, dtype=complex)
        self._path_keys.real = np.repeat(np.arange(n_threadings), sizes)
        self._path_keys.imag = -self._path_len
        # Start polynomials (cells) end to end, padded to the widest column count.
        width = max(p.path_poly.shape[2] for p in probs)
        cells = np.zeros((int(np.sum(sizes - 1)), probs[0].path_poly.shape[1], width))
        columns = np.zeros((n_threadings, probs[0].path_columns.size), dtype=int)
        at = 0
        for u, p in enumerate(probs):
            cells[at:at + p.path_poly.shape[0], :, :p.path_poly.shape[2]] = p.path_poly
            columns[u] = p.path_columns
            at += p.path_poly.shape[0]
        self._cells = cells
        self._columns = columns
        # Per threading: first path sample, sample count, first cell.
        self._path_at = np.stack([first, sizes, first - np.arange(n_threadings)], axis=1)
        self._patterns = {}
        self.restacks += 1

    def _rows_of(self, uid):
        """Everything about a call's rows that depends only on their threadings
        ``uid``: the batch dictionary of ``newton`` and the row data of the start.

        Memoised per row pattern (a robot's ticks repeat a few patterns), so a tick of
        a known pattern gathers nothing.
        """
        key = uid.tobytes()
        rows = self._patterns.get(key)
        if rows is None:
            if len(self._patterns) >= PATTERNS_CACHED:
                self._patterns.clear()
            table = self._table[uid]
            P = {name: table[:, f] for f, name in enumerate(_ROW_FLOATS)}
            P.update(self._shared, uid=uid, d=self._d[uid], mirror=self._mirror[uid],
                     straight=self._straight[uid])
            first, size, cell0 = self._path_at[uid].T
            rows = self._patterns[key] = (P, self._min_mm[uid], uid.astype(float), first,
                                          size - 1, (cell0 - 1)[:, None], self._columns[uid])
        return rows

    def _start(self, rows, L):
        """:func:`.newton._start_from_table` for every row at once (same cells, weights
        and polynomials)."""
        _, _, real, first, last, cell0, columns = rows
        query = np.empty(L.shape[0], dtype=complex)
        query.real = real
        query.imag = -L
        j = np.searchsorted(self._path_keys, query, side='left') - first
        j = np.maximum(np.minimum(j, last), 1)
        at = first + j
        len_lo, len_hi = self._path_len[at - 1], self._path_len[at]
        span = len_lo - len_hi
        w = np.where(span > 0, (len_lo - L) / np.where(span > 0, span, 1.0), 0.5)
        # Each row's cell, its polynomials gathered per segment: (B, n + 1, degree + 1).
        cells = self._cells[cell0 + j[:, None], :, columns]
        start = np.einsum('bp,bcp->bc', w[:, None] ** _START_POWERS, cells)
        n = start.shape[1] - 1
        return start[:, n], start[:, :n], self._path_lam[at - 1], self._path_lam[at]

    # ------------------------------------------------------------------ solving
    def solve(self, threadings, cable_lengths_mm, *, max_iter: int = MAX_ITER
              ) -> PreparedBatchResult:
        """Solve (threading, length) pairs like :func:`solve_forward_batch`, refusing bad
        rows one by one.

        Parameters
        ----------
        threadings : sequence of threadings
            One per length (names or offsets; tuples are looked up fastest).
        cable_lengths_mm : array_like, shape (B,)

        Returns
        -------
        PreparedBatchResult
            Each good row as :func:`solve_forward` would give it; ``refused[i]`` says why
            row ``i`` was not solved ('' if it was).

        Raises
        ------
        ValueError
            Only for a malformed call: lengths not 1-D, a threading count that is not
            one per length, or a bad ``max_iter``. Bad rows never raise.
        """
        lengths = np.asarray(cable_lengths_mm, dtype=float)
        if lengths.ndim != 1:
            raise ValueError(f'cable_lengths_mm must be 1-D, got shape {lengths.shape}')
        if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) \
                or max_iter < 0:
            raise ValueError(f'max_iter must be an integer >= 0, got {max_iter!r}')
        items = threadings if isinstance(threadings, list) else list(threadings)
        nb = lengths.shape[0]
        if len(items) != nb:
            raise ValueError(f'expected {nb} threadings (one per length), got {len(items)}')
        if nb == 0:
            return _empty(PreparedBatchResult, self.skeleton.n_segments, refused=())
        uid, reasons = self._rows(items)
        if reasons and len(reasons) == nb:
            good = np.zeros(nb, dtype=bool)        # no good threading: nothing stacked
        else:
            rows = self._rows_of(uid)
            # False for NaN, and inf is refused like solve_forward refuses it.
            good = (lengths > rows[1]) & (lengths < np.inf)
        if reasons or not good.all():
            good[list(reasons)] = False
            for i in np.flatnonzero(~good).tolist():
                if i not in reasons:
                    reasons[i] = self._reason(int(uid[i]), float(lengths[i]))
            solved = np.flatnonzero(good)
            refused = tuple(reasons.get(i, '') for i in range(nb))
            if solved.size == 0:
                return _refused_rows(_empty(BatchResult, self.skeleton.n_segments), solved,
                                     lengths, refused)
            uid = uid[solved]
            rows = self._rows_of(uid)
            result = self._solve(rows, lengths[solved], max_iter, BatchResult)
            return _refused_rows(result, solved, lengths, refused)
        return self._solve(rows, lengths, max_iter, PreparedBatchResult, refused=('',) * nb)

    def _solve(self, rows, lengths, max_iter, cls, **extra):
        # Most ticks' table starts are the answer already: the batch engine then
        # certifies them without a Newton step (its early exit).
        P = rows[0]
        out = _solve_arrays(P, lengths, max_iter=int(max_iter), start=self._start(rows, lengths))
        return _batch_result(cls, P, out, lengths, **extra)

    def _reason(self, u: int, length: float) -> str:
        """Why a length is refused for stacked threading u: the message of the error
        a single solve raises for it."""
        prob = self._probs[u]
        try:
            _check_length(prob, np.array([length]), self.skeleton, prob.d)
        except ValueError as error:
            return str(error)
        return f'cable length {length!r} mm was refused'   # not reached: checks agree


def _hashable(threading):
    """A dictionary key for a threading as given (None if it has none)."""
    if isinstance(threading, (tuple, str)):
        return threading
    if isinstance(threading, list):
        try:
            key = tuple(threading)
            hash(key)
            return key
        except TypeError:
            return None
    if isinstance(threading, np.ndarray) and threading.ndim == 1:
        return ('array', threading.dtype.str) + tuple(threading.tolist())
    return None


def _empty(cls, n: int, **extra):
    empty = np.zeros((0,))
    return cls(np.zeros((0, n)), np.zeros((0, n + 1, 2)), np.zeros((0, n + 1, 2)),
               empty, empty, empty.astype(int), empty.astype(bool), empty, empty,
               empty, empty.astype(bool), empty, empty.astype(bool),
               np.zeros((0, n), bool), empty, np.zeros((0, n), bool), **extra)


def _refused_rows(result: BatchResult, rows, lengths, refused) -> PreparedBatchResult:
    """``result`` of the good ``rows`` spread to every row; refused rows get NaN (float
    fields), 0 (iterations) and False (flags), and their requested length."""
    nb = lengths.shape[0]
    fields = {}
    for name, value in result.__dict__.items():
        fill = np.nan if value.dtype.kind == 'f' else 0
        full = np.full((nb,) + value.shape[1:], fill, dtype=value.dtype)
        full[rows] = value
        fields[name] = full
    fields['cable_length_mm'] = lengths
    return PreparedBatchResult(**fields, refused=refused)
