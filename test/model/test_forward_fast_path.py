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
    for module in ('results', 'branch', 'path', 'newton', 'api', 'batch'):
        doc = getattr(fwd, module).__doc__
        assert doc and len(doc.split()) > 20, module
