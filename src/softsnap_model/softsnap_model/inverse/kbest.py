"""k-best min-sum dynamic programme over the rib chain (pure numpy).

A threading picks one hole per rib. With the per-segment cost of every hole pair given
as an array, the cost of a threading is the sum of its segment costs, and the k cheapest
distinct threadings follow from a list-Viterbi pass: every (rib, hole) state keeps its
k cheapest partial threadings, ranked. The pass is vectorised over a leading batch axis
(one batch entry per cable tension or per tension interval).
"""
from __future__ import annotations

import numpy as np

#: Largest candidate array (elements, 8 bytes each) one step of the pass builds: larger
#: batches are split into chunks of independent entries. This bounds the memory of a
#: step and the time between two ``check`` calls, whatever k and the batch size.
CHUNK_ELEMENTS = 1 << 20


def kbest_chain(edge_cost, allowed, k=1, check=None):
    """Return the k cheapest distinct hole sequences of a chain, for each batch entry.

    Parameters
    ----------
    edge_cost : ndarray, shape (B, n_segments, m, m)
        ``edge_cost[b, i, p, q]`` is the cost of segment ``i`` when rib ``i`` uses hole
        ``p`` and rib ``i + 1`` uses hole ``q``. ``inf`` forbids the pair.
    allowed : ndarray of bool, shape (n_segments + 1, m)
        Holes each rib may use.
    k : int
        Number of ranked sequences wanted (>= 1).
    check : callable, optional
        Called with no argument before each segment's step; it may raise to abandon the
        pass (how a cancelled or timed-out design stops within one step).

    Returns
    -------
    values : ndarray, shape (B, k)
        Costs, ascending; ``inf`` where fewer than ``k`` feasible sequences exist.
    paths : ndarray of int, shape (B, k, n_segments + 1)
        Hole index per rib of each sequence (meaningless where the value is ``inf``).

    Examples
    --------
    >>> cost = np.zeros((1, 2, 2, 2)); cost[0, :, 1, 1] = -1.0
    >>> values, paths = kbest_chain(cost, np.ones((3, 2), bool), k=2)
    >>> float(values[0, 0]), paths[0, 0].tolist()
    (-2.0, [1, 1, 1])
    """
    edge_cost = np.asarray(edge_cost, dtype=float)
    allowed = np.asarray(allowed, dtype=bool)
    n_batch, n_seg, m, _ = edge_cost.shape
    if allowed.shape != (n_seg + 1, m):
        raise ValueError(f'allowed must have shape {(n_seg + 1, m)}, got {allowed.shape}')
    if k < 1:
        raise ValueError(f'k must be at least 1, got {k}')
    chunk = max(1, CHUNK_ELEMENTS // (m * m * k))
    if n_batch > chunk:
        parts = [kbest_chain(edge_cost[start:start + chunk], allowed, k, check)
                 for start in range(0, n_batch, chunk)]
        return (np.concatenate([v for v, _ in parts]),
                np.concatenate([p for _, p in parts]))

    # value[b, p, r]: cost of the r-th best partial threading ending in hole p.
    value = np.full((n_batch, m, k), np.inf)
    value[:, allowed[0], 0] = 0.0
    back = np.empty((n_seg, n_batch, m, k), dtype=np.int64)
    for i in range(n_seg):
        if check is not None:
            check()
        # cand[b, q, p * k + r] = value[b, p, r] + cost[b, i, p, q]
        cand = value[:, :, None, :] + edge_cost[:, i, :, :, None]
        cand = cand.transpose(0, 2, 1, 3).reshape(n_batch, m, m * k)
        if k == 1:
            idx = np.argmin(cand, axis=2)[..., None]
        else:
            idx = np.argpartition(cand, k - 1, axis=2)[..., :k]
            order = np.argsort(np.take_along_axis(cand, idx, axis=2), axis=2, kind='stable')
            idx = np.take_along_axis(idx, order, axis=2)
        value = np.take_along_axis(cand, idx, axis=2)
        value[:, ~allowed[i + 1], :] = np.inf
        back[i] = idx

    flat = value.reshape(n_batch, m * k)
    if k == 1:
        last = np.argmin(flat, axis=1)[:, None]
    else:
        last = np.argpartition(flat, k - 1, axis=1)[:, :k]
        order = np.argsort(np.take_along_axis(flat, last, axis=1), axis=1, kind='stable')
        last = np.take_along_axis(last, order, axis=1)
    values = np.take_along_axis(flat, last, axis=1)

    paths = np.empty((n_batch, k, n_seg + 1), dtype=np.int64)
    hole, rank = last // k, last % k
    rows = np.arange(n_batch)[:, None]
    paths[:, :, n_seg] = hole
    for i in range(n_seg - 1, -1, -1):
        prev = back[i][rows, hole, rank]
        hole, rank = prev // k, prev % k
        paths[:, :, i] = hole
    return values, paths
