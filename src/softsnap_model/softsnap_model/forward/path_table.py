"""The path table of one threading: exact samples of the whole quasi-static path.

:class:`_PathTable` holds the samples and their start polynomials
(:mod:`.start_polynomials`), built as lengths ask for them: a single solve's cell, its two
or three samples and its polynomial, in plain floats; else samples block by block in
numpy. A lazily built table gives the answers of a full one, bit for bit.
"""
from __future__ import annotations

import bisect
import math
import threading

import numpy as np

from .branch import _branch_refine, _segment_cells
from .start_polynomials import (_G_PAIRS3, _G_PAIRS4, _START_DEGREE, _branch_eval,
                                _cell_polynomial, _path_derivatives, _path_polynomials, _series,
                                _weighted_sum)

try:    # np.interp without its Python wrapper (a check for complex values)
    from numpy._core.multiarray import interp as _interp
except ImportError:     # pragma: no cover - another numpy layout
    _interp = np.interp

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
