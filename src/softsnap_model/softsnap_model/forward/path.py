"""Per-threading problem data: the path tables and their caches.

Owns :class:`_Problem` (everything about one skeleton and threading that does not depend
on the length: per-segment tensions where branches start and end, and the path table
:class:`_PathTable`, the exact samples of the whole quasi-static path and its quintic
start polynomials, built as lengths ask for them: a single solve's cell, its two or
three samples and its polynomial, in plain floats; else samples block by block in
numpy), the memoised builders
(:func:`_problem`, :func:`_single`, :func:`_single_named`,
:func:`_threading_cached`), the batch layout of
problem data (:func:`_stack`) and the length checks that raise the documented errors.
Every cache here is a pure function of its key: a lazily built table gives the answers
of a full one, bit for bit.
"""
from __future__ import annotations

import bisect
import functools
import math
import threading
from dataclasses import dataclass

import numpy as np

from ..geometry import _G_COEF, _G_TERMS
from ..skeleton import Skeleton
from .branch import (_BRANCH_SAMPLES, _PairMemo, _branch_derivs, _branch_refine,
                     _pair_profiles, _segment_cells)
from .results import InfeasibleLengthError, SnapThroughError


try:    # np.interp without its Python wrapper (a check for complex values)
    from numpy._core.multiarray import interp as _interp
except ImportError:     # pragma: no cover - another numpy layout
    _interp = np.interp


#: Threadings whose problem data and path tables stay cached (least recently used
#: first out; about 0.3 MB each, so a full cache holds about 0.7 GB). Large enough that a
#: loop over every threading of 7 ribs with 3 holes (3^7 = 2187) or a robot's modules
#: never rebuilds a table per solve (a rebuild costs a few ms).
_THREADINGS_CACHED = 2560


#: Path samples per block of a lazily built path table (:class:`_PathTable`): a first
#: solve builds one or two blocks, a few percent of the table's entries.
_BLOCK = 16

#: Margin (mm) of a single solve's cell guess from approximate lengths (each distinct
#: segment's length interpolated linearly in its profile table: some 1e-4 mm off a
#: segment), and the most cells it builds the samples of in plain floats.
_GUESS_MARGIN_MM = 2e-3
_GUESS_CELLS = 3


class _PathTable:
    """Exact samples of the quasi-static path of one threading and their start
    polynomials, built on demand.

    The tensions ``lam`` (P,) of every sample are known from the branch profiles; a
    sample's branch magnitudes ``b`` (per distinct segment) and total length cost a
    refinement, and a cell's quintic start polynomial needs its two end samples. A
    single solve asks for its length (:meth:`ensure`), which finds the one to three
    cells whose approximate lengths bracket it (:meth:`_guess_cells`, no refinement),
    builds their samples in plain floats (:meth:`_build_run`: a few entries, where
    numpy's ~150 calls for any number of them cost more) and, confirmed on the exact
    lengths, the polynomial of the one cell (:meth:`_build_cell`, plain floats). An
    entry that needs numpy (the refinement) has those samples built by numpy
    (:meth:`_build_samples`); where the guess misses, the samples of the block of
    :data:`_BLOCK` cells holding the cell are built in one numpy pass (:meth:`_guess`,
    :meth:`_build_blocks`); a batch builds the rest
    (:meth:`complete`, numpy). Every entry is computed on its own (the refinement, the
    derivatives and the polynomials are element-wise, the length sums in a fixed
    order; the float and numpy builders do the same operations in the same order), so
    a partly built table agrees bit for bit with a full one wherever it is built.

    ``len`` (P,) and its Python-list copies ``len_list``, ``neg_len_list`` (what the
    solves search) are exact at built samples; a sample not built holds the length of
    the last built sample before it (``inf`` before the first). So they stay
    non-increasing and never below the exact lengths, and where a search for ``L``
    lands on a built cell (both ends exact, ``len[j-1] > L >= len[j]``), that is the
    cell a search of the full table finds. ``poly`` (P-1, 6, U+1) rows of cells not
    built yet are undefined (never read: a solve searches after :meth:`ensure`, a batch
    after :meth:`complete`). Lengths along the path are taken as computed (non-increasing in
    every table checked); should built ones ever rise, the whole table is built and made
    monotone (cumulative minimum).
    """

    def __init__(self, lam, straight, s, seg):
        self.lam = lam
        self.straight = straight
        self.s = s
        # Per distinct segment: holes, stiffness, direction, profile tables, the
        # tensions where it starts bending and reaches its end, and how many share it.
        self.seg = seg
        n_samples, n_cols = lam.size, seg['k'].size
        self.n_cells = n_samples - 1
        # Allocated, not filled: a row is written when its sample or cell is built (and
        # the ~0.2 MB of polynomials, above malloc's mmap threshold, cost no page
        # faults for the blocks never built).
        self._exact = np.empty(n_samples)                    # exact lengths where built
        self.b = np.empty((n_samples, n_cols))
        self._derivs = np.empty((3, n_samples, n_cols))      # l', l'', l''' at the samples
        self.poly = np.empty((n_samples - 1, _START_DEGREE + 1, n_cols + 1))
        # Which samples are built: bytes (a reverse search for the last built one is one
        # call) seen by numpy as a bool array (masks), the same memory.
        self._built = bytearray(n_samples)
        self._sample_built = np.frombuffer(self._built, dtype=bool)
        self._cell_built = [False] * self.n_cells            # a list: one cheap lookup
        self.len = np.empty(n_samples)
        self.len.fill(math.inf)
        self.len_list = [math.inf] * n_samples
        self.neg_len_list = [-math.inf] * n_samples
        self.complete_ = False
        # What a single cell's polynomial reads of the segments (_build_cell).
        self._seg_lists = [seg[name].tolist() for name in ('k', 'lam_c', 'lam_end', 'count')]
        self._float_rows = None     # the float sample builder's rows (_build_run)
        self._run_lists = {}        # its last samples as lists: index -> (lam, total, b, ...)
        self._unpublished = False   # built samples not yet in the searchable lengths
        self._lock = threading.RLock()

    def ensure(self, length):
        """Build what a search for ``length`` (mm) in ``len_list`` needs to find the
        full table's cell: the cell and its block."""
        if self.complete_:
            return
        j = min(max(bisect.bisect_left(self.neg_len_list, -length), 1), self.n_cells)
        if self._cell_built[j - 1]:
            return
        # One errstate for the whole build (the path arithmetic divides 0 by 0 where a
        # cell has zero width or nothing moves; those entries are handled).
        with self._lock, np.errstate(all='ignore'):
            if self._unpublished:
                self._publish()     # every built sample searchable (length_at_tension)
            for attempt in range(4):
                j = min(max(bisect.bisect_left(self.neg_len_list, -length), 1), self.n_cells)
                if self._cell_built[j - 1]:
                    return
                if self._built[j - 1] and self._built[j]:
                    # Both ends exact: the full table's cell. Its polynomial alone.
                    self._build_cell(j - 1)
                    return
                # Sample j is built (or this is the first build); the exact cell is
                # after the last built sample before it: cells p .. j - 1.
                p = max(self._built.rfind(1, 0, j), 0)
                if attempt == 0:
                    run = self._guess_cells(length, p, j)
                    if run is not None:
                        self._build_run(*run)
                        continue
                blocks = range(p // _BLOCK, (j - 1) // _BLOCK + 1)
                if len(blocks) > 2:
                    blocks = self._guess(length, blocks)
                self._build_blocks(blocks)
                if self.complete_:
                    return
            self._complete()    # not reached: a guess is off by one block at most

    def _approx_lengths(self, lam):
        """Approximate path lengths at the tensions ``lam`` (samples of the table): each
        distinct segment's length interpolated linearly in its profile table (off by
        some 1e-4 mm a segment, a cell's curvature; about as close as its angle
        interpolated and the exact length of that), no refinement: one interpolation
        per distinct segment."""
        seg = self.seg
        mu = lam / seg['k'][:, None]          # (U, n)
        return np.dot(seg['count'], np.array([
            _interp(m, table_mu, table_len)
            for m, table_mu, table_len in zip(mu, seg['table_mu'], seg['table_len'])]))

    def _guess(self, length, blocks):
        """The blocks whose approximate boundary lengths (:meth:`_approx_lengths`)
        bracket ``length``, with a margin (all of them if none does)."""
        at = np.minimum(np.arange(blocks[0], blocks[-1] + 2) * _BLOCK, self.n_cells)
        approx = self._approx_lengths(self.lam[at])
        margin = 0.05 + 1e-6 * abs(length)
        hit = _bracketing(approx, length, margin)
        if not hit.size:
            return blocks
        return range(blocks[0] + int(hit[0]), blocks[0] + int(hit[-1]) + 1)

    def _guess_cells(self, length, p, j):
        """Samples ``(first, last)`` of the cells among ``p .. j - 1`` whose approximate
        lengths (:meth:`_approx_lengths`) bracket ``length`` with a margin of
        :data:`_GUESS_MARGIN_MM`, or None if none does or more than
        :data:`_GUESS_CELLS` do (then whole blocks are built). In two steps: the
        lengths every :data:`_BLOCK` samples, then at every sample between the two
        that bracket ``length`` (fewer points to interpolate than all of them)."""
        margin = _GUESS_MARGIN_MM + 1e-9 * abs(length)
        at = list(range(p, j, _BLOCK)) + [j]
        approx = self._approx_lengths(self.lam[at])
        hit = _bracketing(approx, length, margin)
        if not hit.size or hit[-1] - hit[0] > 1:
            return None
        lo, hi = at[hit[0]], at[hit[-1] + 1]
        approx = self._approx_lengths(self.lam[lo:hi + 1])
        hit = _bracketing(approx, length, margin)
        if not hit.size or hit[-1] - hit[0] >= _GUESS_CELLS:
            return None
        return lo + int(hit[0]), lo + int(hit[-1]) + 1

    def _build_run(self, first, last):
        """The samples ``first .. last`` (a few), in plain floats
        (:func:`_path_samples_float`; by :meth:`_build_samples` if an entry needs
        numpy), made searchable."""
        idx = [i for i in range(first, last + 1) if not self._built[i]]
        if idx:
            if self._float_rows is None:
                self._float_rows = _float_rows(self.seg)
            lam = self.lam[idx].tolist()
            try:
                samples = _path_samples_float(lam, self._float_rows, self._seg_lists[0],
                                              self._seg_lists[3], self.s, self.straight)
            except (_HardEntry, ArithmeticError):
                self._build_samples(np.array(idx))
            else:
                at = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] == len(idx) - 1 else idx
                total, b, lp, lpp, l3 = zip(*samples)
                self._exact[at] = total
                self.b[at] = b
                self._derivs[:, at] = (lp, lpp, l3)
                self._sample_built[at] = True
                # The same values as lists, for the cell's polynomial (_build_cell).
                self._run_lists = dict(zip(idx, zip(lam, *zip(*samples))))
        self._publish_built(first, last)

    def _build_blocks(self, blocks):
        """The samples of ``blocks`` (consecutive), in one pass, made searchable (the
        cells' polynomials are built one by one, :meth:`_build_cell`)."""
        first = blocks[0] * _BLOCK
        last = min((blocks[-1] + 1) * _BLOCK, self.n_cells)
        self._build_samples(np.arange(first, last + 1))
        self._publish_built(first, last)

    def _publish_built(self, first, last):
        """After samples ``first .. last`` were built: publish them (:meth:`_publish_block`),
        or build the whole table should the built lengths ever rise along the path."""
        built = self._exact[self._sample_built]
        if (built[1:] > built[:-1]).any():
            self._complete()
            return
        self._publish_block(first, last)

    def _build_cell(self, j):
        """The start polynomial of cell ``j`` (both its samples built), in plain floats
        (:func:`_cell_polynomial`; by :func:`_path_polynomials` where that divides by
        zero). The row first, then the flag: a solve that sees the cell built without
        the lock (ensure's fast path) reads it."""
        at = slice(j, j + 2)
        ends = self._run_lists.get(j), self._run_lists.get(j + 1)
        if ends[0] and ends[1]:     # just built in floats: the lists at hand
            lam, length, b, lp, lpp, l3 = zip(*ends)
            derivs = [lp, lpp, l3]
        else:
            lam, length, b = self.lam[at].tolist(), self._exact[at].tolist(), self.b[at].tolist()
            derivs = self._derivs[:, at].tolist()
        try:
            self.poly[j] = _cell_polynomial(lam, length, b, derivs, *self._seg_lists)
        except ArithmeticError:
            self._build_cells(j, j + 1)
        self._cell_built[j] = True

    def _publish(self):
        """Searchable lengths from the built samples (in place: the single-solve layout
        holds this very array and these lists)."""
        built = self._sample_built
        last = np.maximum.accumulate(np.where(built, np.arange(built.size), -1))
        self.len[:] = np.where(last >= 0, self._exact[last], np.inf)
        self.len_list[:] = self.len.tolist()
        self.neg_len_list[:] = (-self.len).tolist()
        self._unpublished = False

    def _publish_block(self, first, last):
        """:meth:`_publish` after samples ``first .. last`` were built, every other built
        sample being published already: only the entries from ``first`` up to the next
        built sample change (to the new exact lengths, then the last of them), so only
        those are written. Each write leaves the arrays non-increasing and never below
        the exact lengths (the tail first, then the block; each list in one slice
        assignment), for a solve searching them without the lock."""
        nxt = self._built.find(1, last + 1)
        nxt = self.len.size if nxt < 0 else nxt
        exact = self._exact[first:last + 1]
        self.len[last + 1:nxt] = exact[-1]
        self.len[first:last + 1] = exact
        values = exact.tolist()
        tail = nxt - last - 1
        self.len_list[first:nxt] = values + [values[-1]] * tail
        self.neg_len_list[first:nxt] = [-x for x in values] + [-values[-1]] * tail

    def _build_samples(self, idx):
        """Refine the samples ``idx`` (sorted indices) not built yet."""
        if not idx.size:
            return
        if self._built.find(1, int(idx[0]), int(idx[-1]) + 1) >= 0:
            idx = idx[~self._sample_built[idx]]
            if not idx.size:
                return
        # A run of consecutive samples (a block) is written through slices.
        at = slice(int(idx[0]), int(idx[-1]) + 1) if idx[-1] - idx[0] == idx.size - 1 else idx
        seg = self.seg
        b, (lengths, lp, lpp, l3) = _path_samples(self.lam[at, None] / seg['k'], seg,
                                                  self.s)
        total = _weighted_sum(lengths, seg['count'])
        # Every segment straight (the start of the path, before a mirror segment
        # buckles): the straight length, exactly.
        total[np.logical_and.reduce(b == 0.0, axis=1)] = self.straight
        self._exact[at] = total
        self.b[at] = b
        derivs = self._derivs
        derivs[0, at], derivs[1, at], derivs[2, at] = lp, lpp, l3
        self._sample_built[at] = True

    def _build_cells(self, first, last):
        """Start polynomials of cells ``first .. last - 1`` (their samples built)."""
        seg = self.seg
        at = slice(first, last + 1)
        lp, lpp, l3 = self._derivs[:, at]
        self.poly[first:last] = _path_polynomials(
            self.lam[at], self._exact[at], self.b[at], lp, lpp, l3, seg['k'], seg['lam_c'],
            seg['lam_end'], seg['count'])

    def complete(self):
        """Build every sample and cell (the batch solver and the full views use them)."""
        if not self.complete_:
            with self._lock, np.errstate(all='ignore'):
                self._complete()
        return self

    def _complete(self):
        if self.complete_:
            return
        self._build_samples(np.arange(self.lam.size))
        if np.any(np.diff(self._exact) > 0):
            # Never seen: rounding making a length rise along the path. Keep it monotone.
            self._exact[:] = np.minimum.accumulate(self._exact)
            self._build_cells(0, self.n_cells)
        elif not any(self._cell_built):
            self._build_cells(0, self.n_cells)
        else:
            for c in range(0, self.n_cells, _BLOCK):
                if not all(self._cell_built[c:c + _BLOCK]):
                    self._build_cells(c, min(c + _BLOCK, self.n_cells))
        self._publish()     # before the flags, as in _build_blocks
        self._cell_built[:] = [True] * self.n_cells
        self.complete_ = True

    def length_at_tension(self, lam):
        """Path length (mm) at tension ``lam``: ``np.interp`` on the full table (only the
        samples next to ``lam`` are read, so only those are built)."""
        j = int(np.searchsorted(self.lam, lam))
        near = np.arange(max(j - 1, 0), min(j + 2, self.lam.size))
        with self._lock, np.errstate(all='ignore'):
            self._build_samples(near)
            self._unpublished = True    # the next publish must be a full one
        return float(np.interp(lam, self.lam[near], self._exact[near]))


def _bracketing(approx, length, margin):
    """Indices ``i`` of the intervals ``approx[i] .. approx[i + 1]`` (non-increasing
    approximate lengths) that hold ``length`` within ``margin`` (mm)."""
    return ((approx[:-1] >= length - margin) & (approx[1:] <= length + margin)).nonzero()[0]


def _path_samples(mu, seg, s):
    """Exact branch magnitudes ``b`` (P, U) of the distinct segments at tensions ``mu``
    per unit stiffness, and ``l, l', l'', l'''`` there (:func:`_path_derivatives`).

    One Newton step from the cubic start of the cell (:func:`.branch._segment_cells`,
    about 1e-10 rad off) lands at rounding level; the evaluation at that point, which the
    table needs anyway, gives the next step, and the entry is kept where that step is at
    rounding level too. Of the rest, an entry whose cubic start already is the root to
    rounding (a start on a table sample) keeps that start, as the refinement would; the
    others (near a pitchfork, a start outside its cell; about one 16-cell block in a
    hundred) take the safeguarded refinement. Entries outside a segment's table
    (straight before buckling, at contact) take its end values. Everything is per entry.
    Called under ``np.errstate(all='ignore')`` (0/0 in cells of zero width, at a
    pitchfork).
    """
    direction, d1, d2 = seg['direction'], seg['d1'], seg['d2']
    start, cell = _segment_cells(mu, seg['tables'])
    b_lo, b_hi, _, _, mu_first, mu_last, b_first, b_last = cell
    out = mu <= mu_first
    ends = np.where(out, b_first, b_last)
    out |= mu >= mu_last
    b0 = np.fmin(np.fmax(start, b_lo), b_hi)
    _, lp, lpp = _branch_eval(b0, direction, d1, d2, s, seg['pre'])
    r0 = 2.0 * b0 + mu * lp
    b = np.where(out, ends, np.fmin(np.fmax(b0 - r0 / (2.0 + mu * lpp), b_lo), b_hi))
    ev = _path_derivatives(b, direction, d1, d2, s, pre=seg['pre'])
    step = (2.0 * b + mu * ev[1]) / (2.0 + mu * ev[2])
    # The root is inside the cell (mu_lo < mu), never at b_lo: this also turns away
    # the straight root b = 0 of a mirror segment just past its pitchfork.
    ok = out | ((np.abs(step) <= 1e-15 * (1.0 + np.abs(b))) & (b > b_lo))
    if not ok.all():
        rest = ~ok
        shape = mu.shape
        # Most of these start on a table sample, the root to rounding: the refinement
        # would keep that start after its first evaluation (its residual test, on the
        # same values as r0 here), so they keep it without the refinement's ~40 numpy
        # calls. (A zero start is left to the refinement: fmax may change its sign.)
        kept = rest & (start >= b_lo) & (start <= b_hi) & (start != 0.0) & (
            np.abs(r0) <= 1e-15 * (2.0 * np.abs(b0) + np.abs(mu * lp)))
        b[kept] = start[kept]
        hard = rest & ~kept
        if hard.any():
            sub = tuple(np.broadcast_to(c, shape)[hard] for c in cell)
            dd = [np.broadcast_to(c, shape)[hard] for c in (direction, d1, d2)]
            b[hard] = _branch_refine(mu[hard], sub, *dd, s, 30, start[hard], _branch_eval)
        dd = [np.broadcast_to(c, shape)[rest] for c in (direction, d1, d2)]
        for full, part in zip(ev, _path_derivatives(b[rest], *dd, s)):
            full[rest] = part
    return b, ev


class _HardEntry(Exception):
    """An entry the float path sample builder leaves to the numpy one (a zero clamp,
    whose sign numpy's fmax may set otherwise; an entry needing the refinement)."""


def _derivs_float(b, series, e1, e2, dd2, p_bb, s):
    """:func:`_path_derivatives` of one entry in plain floats from its series values
    ``series`` (``g, g'/b, g''`` and, for the third derivative, ``g'''/b`` at ``b^2``;
    numpy's :func:`_series`, element-wise), ``pre`` given: the same operations in the
    same order. Raises ArithmeticError (:class:`_HardEntry` for a ``l^2`` not positive)
    where numpy would carry inf or NaN. Returns ``l, l', l'', l'''`` (the last None
    without the fourth series column)."""
    g, g1_over_b, g2 = series[:3]
    g1 = b * g1_over_b
    p1, p2 = s + e1 * b, s + e2 * b
    p = p1 * p2
    p_b = e1 * p2 + e2 * p1
    q = dd2 + g * p
    if not q > 0.0:
        raise _HardEntry
    length = math.sqrt(q)
    half_inv = 0.5 / length
    lp = (g1 * p + g * p_b) * half_inv
    lpp = (g2 * p + 2.0 * g1 * p_b + g * p_bb - 2.0 * lp * lp) * half_inv
    if len(series) == 3:
        return length, lp, lpp, None
    g3 = b * series[3]
    l3 = (g3 * p + 3.0 * g2 * p_b + 3.0 * g1 * p_bb - 6.0 * lp * lpp) * half_inv
    return length, lp, lpp, l3


def _series_lists(b, pairs):
    """:func:`_series` at ``b^2`` for a list of floats ``b``: one numpy pass over all
    of them (element-wise, so each value is the one a table build computes), returned
    per entry as tuples of the columns."""
    return list(zip(*_series(np.array([x * x for x in b]), pairs).tolist()))


def _clamp_float(x, lo, hi):
    """``np.fmin(np.fmax(x, lo), hi)`` for floats (NaN gives way to the bound); a zero
    result is left to numpy (:class:`_HardEntry`: which zero's sign it keeps is the SIMD
    loop's business)."""
    y = lo if x != x or lo > x else x
    z = hi if y != y or hi < y else y
    if z == 0.0:
        raise _HardEntry
    return z


def _float_rows(seg):
    """Per distinct segment, what :func:`_path_samples_float` reads: its table rows
    ``b, mu, dmu`` (memoryviews: Python floats when indexed, ``bisect`` searches them),
    their first and last ``mu`` and ``b``, and ``pre``."""
    pre = [x.tolist() for x in seg['pre']]
    return [(tb, tm, tdmu, tm[0], tm[-1], tb[0], tb[-1], *p)
            for (tb, tm, tdmu), *p in zip(seg['table_lists'], *pre)]


def _path_samples_float(lam, rows, k, count, s, straight):
    """:func:`_path_samples` and the total length of :meth:`_PathTable._build_samples`
    at the tensions ``lam`` (a list: the two or three samples of a single solve's cell)
    in plain floats, bit for bit (the same operations in the same order;
    test_forward_lazy_table.py compares them), the series of the lengths in numpy, one
    pass over every entry per evaluation. Per entry: the cubic start of
    :func:`.branch._segment_cells`, one Newton step, the check of the next step, a start
    that already is the root kept. ``rows`` (:func:`_float_rows`), ``k``, ``count``:
    per distinct segment. Returns ``(total, b, l', l'', l''')`` lists per sample; raises
    :class:`_HardEntry` or ArithmeticError where an entry needs numpy (the refinement, a
    division by zero that numpy carries as inf or NaN; rare)."""
    entries = []        # (mu, row, cell or None outside the table, start, b0)
    for lam_i in lam:
        for row, k_u in zip(rows, k):
            mu = lam_i / k_u
            tb, tm, tdmu, mu_first, mu_last, b_first, b_last = row[:7]
            if mu <= mu_first or mu >= mu_last:     # outside the table: its end value
                b = b_first if mu <= mu_first else b_last
                entries.append((mu, row, None, b, b))
                continue
            # In 1 .. M - 1 (searchsorted's cell, clamped): tm[0] < mu < tm[-1] here.
            i = bisect.bisect_left(tm, mu)
            b_lo, b_hi, mu_lo, mu_hi = tb[i - 1], tb[i], tm[i - 1], tm[i]
            span = mu_hi - mu_lo
            t = (mu - mu_lo) / span
            t2 = t * t
            t3 = t2 * t
            start = ((2.0 * t3 - 3.0 * t2 + 1.0) * b_lo + (t3 - 2.0 * t2 + t) * span
                     / tdmu[i - 1] + (3.0 * t2 - 2.0 * t3) * b_hi
                     + (t3 - t2) * span / tdmu[i])
            entries.append((mu, row, (b_lo, b_hi), start, _clamp_float(start, b_lo, b_hi)))
    # One Newton step from the start (entries outside the table keep their end value).
    b1, r0s = [], []
    for (mu, row, cell, _, b0), ser in zip(entries, _series_lists([e[4] for e in entries],
                                                                  _G_PAIRS3)):
        if cell is None:
            b1.append(b0)
            r0s.append(None)
            continue
        _, lp, lpp, _ = _derivs_float(b0, ser, *row[7:], s)
        r0 = 2.0 * b0 + mu * lp
        b1.append(_clamp_float(b0 - r0 / (2.0 + mu * lpp), *cell))
        r0s.append((r0, lp))
    # The evaluation there; an entry keeps b1 where the next step is at rounding level,
    # else its start where that is the root to rounding.
    values = []
    for (mu, row, cell, start, b0), b, r0, ser in zip(entries, b1, r0s,
                                                      _series_lists(b1, _G_PAIRS4)):
        ev = _derivs_float(b, ser, *row[7:], s)
        if cell is not None:
            try:
                step = (2.0 * b + mu * ev[1]) / (2.0 + mu * ev[2])
                ok = abs(step) <= 1e-15 * (1.0 + abs(b)) and b > cell[0]
            except ZeroDivisionError:   # numpy: an inf or NaN step, not at rounding level
                ok = False
            if not ok:
                r0, lp = r0
                if not (cell[0] <= start <= cell[1] and start != 0.0
                        and abs(r0) <= 1e-15 * (2.0 * abs(b0) + abs(mu * lp))):
                    raise _HardEntry    # the safeguarded refinement: numpy's
                b = start
                ev = _derivs_float(b, _series_lists([b], _G_PAIRS4)[0], *row[7:], s)
        values.append((b,) + ev)
    out = []
    n = len(rows)
    for i in range(len(lam)):
        b, length, lp, lpp, l3 = (list(col) for col in zip(*values[i * n:(i + 1) * n]))
        total = length[0] * count[0]
        for x, w in zip(length[1:], count[1:]):
            total += x * w
        if not any(b):      # every segment straight: the straight length, exactly
            total = straight
        out.append((total, b, lp, lpp, l3))
    return out


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


def _check_length(prob: _Problem, length: np.ndarray, skeleton, d):
    """Raise the documented errors for NaN/inf and unreachable lengths.

    The threading `d` is named in the message only when one is raised: naming it costs
    ~50 µs, which every batch used to pay for lengths that were fine.
    """
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
