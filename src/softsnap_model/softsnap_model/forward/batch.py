"""Public batch entry points: many (threading, length) pairs, and contraction sweeps.

Owns :func:`solve_forward_batch` and :func:`sweep`: input conversion, grouping the items
by distinct threading (tables are stacked once per threading), and packing the batch
engine's arrays into :class:`BatchResult` / :class:`SweepResult`.
"""
from __future__ import annotations

import numbers

import numpy as np

from ..skeleton import Skeleton
from .api import _check_skeleton, _frames
from .newton import _solve_arrays
from .path import _check_length, _problem, _stack, _threading_tuple
from .results import MAX_ITER, BatchResult, SweepResult


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
        raise ValueError(f'contractions_mm must be finite, got {c[~np.isfinite(c)][0]!r}')
    if np.any(c < 0):
        raise ValueError(f'contractions_mm must be >= 0, got {c[c < 0][0]!r}')
    d = skeleton.threading_mm(threading)
    prob = _problem(skeleton, tuple(d.tolist()))
    lengths = prob.straight_mm - c
    _check_length(prob, lengths, skeleton, d)
    P = _stack([prob], np.zeros(c.shape[0], dtype=int))
    out = _solve_arrays(P, lengths, max_iter=int(max_iter))
    return _batch_result(SweepResult, P, out, lengths, contractions_mm=c)
