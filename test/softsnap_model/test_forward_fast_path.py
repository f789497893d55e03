"""Regression tests of the forward fast path (issue 17): batch Newton at 192 ribs, the
threading forms of mixed batches, the caches, and the subpackage's public face."""
import numpy as np

import softsnap_model.forward as fwd
from softsnap_model import Skeleton
from softsnap_model.reference import PAPER_THREADINGS

SK = Skeleton()


def test_192_rib_batch_rows_stop_before_the_iteration_cap():
    # Regression: with a 1e-12 mm target (~2 ulp of a 3.5 m cable) some rows ran all 40
    # iterations; the target now scales with the cable's ulp.
    sk = Skeleton(n_ribs=192)
    t = ['R1', 'R2', 'R3', 'R2'] * 48
    lo, hi = fwd.reachable_range(sk, t)
    lengths = np.linspace(hi - 0.01, lo + 0.02 * (hi - lo), 300)
    res = fwd.solve_forward_batch(sk, t, lengths)
    assert res.converged.all()
    assert res.iterations.max() < 5, np.bincount(res.iterations)
    assert res.constraint_residual.max() <= fwd.CONSTRAINT_TOL_MM
    single = fwd.solve_forward(sk, t, lengths[137])
    assert np.max(np.abs(single.angles - res.angles[137])) <= 1e-12


def test_mixed_batch_accepts_every_threading_form_alike():
    names = [list(PAPER_THREADINGS[n]) for n in ('yellow', 'blue', 'snake')]
    offsets = np.array([SK.threading_mm(t) for t in names])
    lengths = [170.0, 175.0, 160.0] * 4
    forms = {
        'repeated list objects': [names[0], names[1], names[2]] * 4,
        'tuples': [tuple(names[i % 3]) for i in range(12)],
        '2-D offsets': offsets[np.arange(12) % 3],
    }
    expected = np.array([fwd.solve_forward(SK, names[i % 3], lengths[i]).angles
                         for i in range(12)])
    for label, threadings in forms.items():
        res = fwd.solve_forward_batch(SK, threadings, lengths)
        assert res.converged.all(), label
        assert np.max(np.abs(res.angles - expected)) <= 1e-12, label


def test_clear_caches_changes_no_answer():
    t = list(PAPER_THREADINGS['w'])
    before = fwd.solve_forward(SK, t, 172.0)
    fwd.clear_caches()
    assert fwd._single.cache_info().currsize == 0 and not fwd._PROFILE_CACHE
    after = fwd.solve_forward(SK, t, 172.0)
    assert np.array_equal(before.angles, after.angles)
    assert np.array_equal(before.rib_centers, after.rib_centers)


def test_rib_frames_match_the_geometry_module():
    from softsnap_model.geometry import rib_centers
    res = fwd.solve_forward(SK, list(PAPER_THREADINGS['red']), 165.0)
    assert np.max(np.abs(res.rib_centers - rib_centers(res.angles, SK.spacing_mm))) <= 1e-12
    # Holes sit d to the right of each rib centre, across the rib direction.
    d = SK.threading_mm(list(PAPER_THREADINGS['red']))
    assert np.allclose(np.linalg.norm(res.cable_path - res.rib_centers, axis=1), np.abs(d))


def test_public_face_of_the_subpackage():
    for name in ('solve_forward', 'solve_forward_batch', 'sweep', 'reachable_range',
                 'segment_angle_at_tension', 'segment_branch', 'ForwardResult', 'BatchResult',
                 'SweepResult', 'InfeasibleLengthError', 'SnapThroughError',
                 'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD', 'MAX_ITER',
                 'WARM_START_RADIUS_RAD', 'clear_caches'):
        assert name in fwd.__all__ and hasattr(fwd, name), name
    for module in ('results', 'branch', 'path', 'newton', 'single', 'api', 'batch'):
        doc = getattr(fwd, module).__doc__
        assert doc and len(doc.split()) > 20, module


def test_quintic_path_start_is_the_answer_for_most_cold_solves():
    # Regression for the single-solve cost (issue 17): the path cells' quintic Hermite
    # start is accurate to rounding, so most cold solves certify it with one evaluation
    # (no Newton step), and those answers agree with an independent solver (bracketing,
    # no tables, no Newton: benchmarks/accuracy_check.py) to rounding.
    import sys
    from pathlib import Path
    from benchmark_scripts import load
    reference_solve = load('accuracy_check').reference_solve
    n_solves = zero_steps = 0
    for name in ('yellow', 'blue', 'red', 'snake', 'w'):
        t = list(PAPER_THREADINGS[name])
        lo, hi = fwd.reachable_range(SK, t)
        _, S = fwd._single(SK, tuple(SK.threading_mm(t).tolist()))
        for i, length in enumerate(np.linspace(lo + 0.5, hi - 0.5, 40)):
            res = fwd.solve_forward(SK, t, length)
            assert res.converged
            n_solves += 1
            zero_steps += res.iterations == 0
            if res.iterations == 0:
                start = fwd._solve_single(S, length, max_iter=0, fallback=False)
                assert np.array_equal(start['angles'], res.angles)
                if name in ('yellow', 'red', 'w') and i % 4 == 0:
                    ref = np.asarray(reference_solve(SK, t, length)[0])
                    assert np.max(np.abs(res.angles - ref)) <= 1e-13, (name, length)
    assert zero_steps >= 0.9 * n_solves, (zero_steps, n_solves)


def test_path_table_columns_shared_by_equal_segments_are_exact():
    # The path is solved once per distinct (d1, d2, k) segment and gathered back: every
    # segment's column must still be its exact branch angle at each path tension.
    t = list(PAPER_THREADINGS['yellow'])     # 11 segments, 5 distinct
    prob = fwd._problem(SK, tuple(SK.threading_mm(t).tolist()))
    lam = prob.path_lam[1:-1:7]
    for i in range(prob.d1.size):
        exact = np.abs(fwd.segment_angle_at_tension(lam, prob.d1[i], prob.d2[i], SK.spacing_mm,
                                                    max_angle_rad=SK.contact_angle_rad))
        assert np.max(np.abs(prob.path_b[1:-1:7, i] - exact)) <= 1e-13, i
    # Equal segments share their column exactly.
    same = [i for i in range(11) if (prob.d1[i], prob.d2[i]) == (prob.d1[0], prob.d2[0])]
    assert len(same) > 1
    assert all(np.array_equal(prob.path_b[:, i], prob.path_b[:, 0]) for i in same)
    assert all(prob.path_columns[i] == prob.path_columns[0] for i in same)
    assert prob.path_poly.shape[2] == len(set(zip(prob.d1, prob.d2))) + 1


def test_single_solve_result_is_a_complete_frozen_result():
    import dataclasses
    res = fwd.solve_forward(SK, list(PAPER_THREADINGS['blue']), 170.0)
    assert type(res) is fwd.ForwardResult
    assert set(vars(res)) == {f.name for f in dataclasses.fields(res)}
    try:
        res.tension = 0.0
    except dataclasses.FrozenInstanceError:
        pass
    else:
        raise AssertionError('ForwardResult must stay frozen')
    assert res.tie_break_segments == tuple(int(i) for i in np.flatnonzero(
        (SK.threading_mm(list(PAPER_THREADINGS['blue']))[:-1]
         + SK.threading_mm(list(PAPER_THREADINGS['blue']))[1:] == 0) & (res.angles != 0)))
