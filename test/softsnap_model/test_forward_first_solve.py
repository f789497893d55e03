"""The first solve of a threading builds only what it reads: the batch-of-one layout
``S['P']`` of the single-solve data waits for the rare path that needs it (kick, guess,
fallback), is built once under concurrent access, and the 1-D layout equals its row."""
import threading

import numpy as np

import softsnap_model.forward as fwd
from softsnap_model import Skeleton
from softsnap_model.forward import path as fpath
from softsnap_model.reference import PAPER_THREADINGS

SK = Skeleton()


def _fresh(threading_names):
    for cached in (fwd._problem, fwd._single, fwd._single_named, fwd._threading_cached):
        cached.cache_clear()
    d = tuple(SK.threading_mm(threading_names).tolist())
    return d


def test_first_solve_leaves_the_batch_layout_unbuilt():
    t = list(PAPER_THREADINGS['yellow'])
    d = _fresh(t)
    res = fwd.solve_forward(SK, t, SK.straight_length_mm(t) - 30.0)
    assert res.converged and res.iterations == 0
    _, S = fpath._single(SK, d)
    assert 'P' not in S          # a plain dict lookup: nothing built it


def test_single_layout_is_the_row_of_the_batch_layout_bit_for_bit():
    for name in ('yellow', 'blue', 'red', 'w'):
        t = list(PAPER_THREADINGS[name])
        d = _fresh(t)
        prob, S = fpath._single(SK, d)
        P = S['P']
        assert P is S['P']                        # built once, then kept
        ref = fpath._stack([prob], np.zeros(1, dtype=int), complete=False)
        assert sorted(P) == sorted(ref)
        for key in ('k', 'd', 'd1', 'd2', 'direction', 'lam_c', 'lam_end', 'b_end', 'mirror',
                    'lam_1', 'e1', 'e2', 'dd2', 'two_k', 'inv_two_k'):
            assert np.array_equal(S[key], P[key][0]), key
            assert S[key].dtype == P[key].dtype, key
            assert np.array_equal(P[key], ref[key]), key
        assert S['has_mirror'] == P['has_mirror'] and S['s'] == P['s']


def test_concurrent_first_reads_build_one_batch_layout():
    t = list(PAPER_THREADINGS['blue'])
    d = _fresh(t)
    _, S = fpath._single(SK, d)
    barrier = threading.Barrier(6)
    seen, errors = [], []

    def read():
        try:
            barrier.wait(timeout=60)
            seen.append(S['P'])
        except Exception as exc:         # surfaced below: a thread must not die silently
            errors.append(exc)

    threads = [threading.Thread(target=read) for _ in range(6)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=120)
    assert not errors
    assert len(seen) == 6 and all(P is seen[0] for P in seen)


def test_other_missing_keys_still_raise():
    t = list(PAPER_THREADINGS['red'])
    _, S = fpath._single(SK, _fresh(t))
    try:
        S['no such key']
    except KeyError:
        pass
    else:
        raise AssertionError('a missing key other than P must raise KeyError')
