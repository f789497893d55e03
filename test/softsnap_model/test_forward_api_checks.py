"""solve_forward / reachable_range: argument checks, the slack result and the returned
poses, each against an independent check (geometry's own pose functions, the FACTS.md
cable-length sum). Written for the survivors of mutation testing (docs/testing.md)."""
import math

import numpy as np
import pytest

from softsnap_model import (InfeasibleLengthError, Skeleton, cable_path, reachable_range,
                            rib_centers, segment_length, solve_forward, solve_forward_batch)

SK = Skeleton()
MIXED = ['R1', 'R2', 'R2', 'L2', 'L3', 'L3', 'L3', 'L3', 'L3', 'L3', 'L2', 'R2']   # blue
MIRROR = ['R3', 'L3'] * 6                                                          # alternating


def independent_poses(res, threading_names):
    d = SK.threading_mm(threading_names)
    return rib_centers(res.angles, SK.spacing_mm), cable_path(res.angles, d, SK.spacing_mm), d


def within_range(names, fraction):
    low, high = reachable_range(SK, names)
    return low + fraction * (high - low)


@pytest.mark.parametrize('names', [['R3'] * 12, MIXED, MIRROR, ['L1'] * 12])
def test_returned_poses_are_the_geometry_of_the_returned_angles(names):
    length = within_range(names, 0.6)
    res = solve_forward(SK, names, length)
    assert res.converged and not res.slack and res.message == 'converged'
    centres, holes, d = independent_poses(res, names)
    np.testing.assert_allclose(res.rib_centers, centres, atol=1e-9)
    np.testing.assert_allclose(res.cable_path, holes, atol=1e-9)
    assert float(np.sum(segment_length(res.angles, d[:-1], d[1:], SK.spacing_mm))) == \
        pytest.approx(length, abs=1e-7)
    assert res.cable_length_mm == length and res.tension > 0
    assert res.energy == pytest.approx(float(np.sum(res.angles ** 2)), rel=1e-9)   # k_i = 1


def test_slack_result_is_the_straight_module():
    names = ['R3'] * 12
    _, straight = reachable_range(SK, names)
    for length in (straight, straight + 5.0, 1e6):
        res = solve_forward(SK, names, length)
        assert res.slack and res.converged and res.is_minimum
        assert res.message.startswith('slack cable')
        assert (res.tension, res.energy, res.iterations) == (0.0, 0.0, 0)
        assert (res.residual, res.constraint_residual, res.stationarity_residual) == (0, 0, 0)
        assert res.min_curvature == 1.0 and not res.at_contact.any()
        assert res.at_contact.shape == (11,) and res.angles.tolist() == [0.0] * 11
        np.testing.assert_allclose(res.rib_centers[:, 0], SK.spacing_mm * np.arange(12))
        np.testing.assert_allclose(res.cable_path[:, 1], -SK.threading_mm(names))
    with pytest.raises(ValueError, match='initial: angles must be finite'):
        solve_forward(SK, names, straight + 1.0, initial=np.full(11, np.nan))
    assert solve_forward(SK, names, straight + 1.0, initial=np.zeros(11)).slack


@pytest.mark.parametrize('length', [170, np.float64(170.0), np.float32(170.0), np.int64(170)])
def test_lengths_of_any_real_type_solve_alike(length):
    res = solve_forward(SK, ['R3'] * 12, length)
    assert type(res.cable_length_mm) is float and res.cable_length_mm == 170.0
    np.testing.assert_array_equal(res.angles, solve_forward(SK, ['R3'] * 12, 170.0).angles)


@pytest.mark.parametrize('bad', [True, False, '170', b'170', [170.0], 170 + 0j])
def test_lengths_that_are_not_real_numbers_are_refused(bad):
    with pytest.raises(ValueError, match='cable_length_mm must be a real number'):
        solve_forward(SK, ['R3'] * 12, bad)


@pytest.mark.parametrize('bad', [-1, True, 2.0, '3', None])
def test_bad_max_iter_is_refused(bad):
    with pytest.raises(ValueError, match='max_iter must be an integer >= 0'):
        solve_forward(SK, ['R3'] * 12, 170.0, max_iter=bad)


def test_max_iter_accepts_integers_and_zero():
    cold = solve_forward(SK, ['R3'] * 12, 170.0)
    for max_iter in (np.int64(50), 0, 1):
        res = solve_forward(SK, ['R3'] * 12, 170.0, max_iter=max_iter)
        np.testing.assert_allclose(res.angles, cold.angles, atol=1e-9)


def test_warm_start_from_a_result_or_angles():
    cold = solve_forward(SK, MIXED, 185.0)
    near = solve_forward(SK, MIXED, 185.2)
    for initial in (near, near.angles, near.angles.tolist()):
        res = solve_forward(SK, MIXED, 185.0, initial=initial)
        np.testing.assert_allclose(res.angles, cold.angles, atol=1e-9)
        assert res.converged
    slack = solve_forward(SK, MIXED, 500.0)            # tension 0: a usable warm start
    np.testing.assert_allclose(solve_forward(SK, MIXED, 185.0, initial=slack).angles,
                               cold.angles, atol=1e-9)
    for bad in (np.zeros(10), np.zeros((11, 1)), np.zeros(12)):
        with pytest.raises(ValueError, match=r'initial: expected 11 angles, got shape'):
            solve_forward(SK, MIXED, 185.0, initial=bad)


def test_reachable_range_and_refusals():
    low, high = reachable_range(SK, ['R3'] * 12)
    assert high == 198.0 and 0 < low < high
    assert solve_forward(SK, ['R3'] * 12, low + 0.5).converged
    with pytest.raises(InfeasibleLengthError):
        solve_forward(SK, ['R3'] * 12, low)
    for call in (lambda: reachable_range('skeleton', ['R3'] * 12),
                 lambda: solve_forward(None, ['R3'] * 12, 170.0)):
        with pytest.raises(ValueError, match='skeleton must be a Skeleton, got'):
            call()


def test_mirror_flip_gives_the_mirror_image_of_the_tie_break_segments():
    length = within_range(MIRROR, 0.5)
    res = solve_forward(SK, MIRROR, length)
    assert res.tie_break_segments and res.mirror_flip == ()
    flip = list(res.tie_break_segments[:2])
    flipped = solve_forward(SK, MIRROR, length, mirror_flip=flip[::-1] + flip[:1])
    assert flipped.mirror_flip == tuple(sorted(flip))
    assert flipped.tie_break_segments == res.tie_break_segments
    expected = res.angles.copy()
    expected[flip] *= -1
    np.testing.assert_array_equal(flipped.angles, expected)
    centres, holes, d = independent_poses(flipped, MIRROR)
    np.testing.assert_allclose(flipped.cable_path, holes, atol=1e-9)
    assert (flipped.energy, flipped.tension) == (res.energy, res.tension)
    for empty in ((), [], None):
        assert solve_forward(SK, MIRROR, length, mirror_flip=empty).mirror_flip == ()
    for bad, why in ((5, 'must be a sequence'), ([True], 'segment index must be an integer'),
                     ([11], r'in \[0, 10\], got 11'), ([-1], 'got -1'), ([1.0], 'got 1.0')):
        with pytest.raises(ValueError, match=why):
            solve_forward(SK, MIRROR, length, mirror_flip=bad)
    with pytest.raises(ValueError, match=r'segment 0 is not a mirror segment .*: \[\]'):
        solve_forward(SK, ['R3'] * 12, 175.0, mirror_flip=[0])
    assert not solve_forward(SK, ['R3'] * 12, 175.0).tie_break_segments
    assert math.isfinite(res.min_curvature) and res.is_minimum


def test_batch_poses_are_the_geometry_of_the_batch_angles():
    # The batch's vectorised rib frames (forward.api._frames) against geometry's own,
    # with a straight (slack) item, a mirror threading and both bend directions.
    from softsnap_model import solve_forward_batch
    names = [['R3'] * 12, MIXED, MIRROR, ['L1'] * 12, ['R3'] * 12]
    lengths = [within_range(n, f) for n, f in zip(names, (0.3, 0.6, 0.5, 0.8, 2.0))]
    batch = solve_forward_batch(SK, names, lengths)
    assert batch.converged.all() and batch.rib_centers.shape == (5, 12, 2)
    for i, n in enumerate(names):
        d = SK.threading_mm(n)
        np.testing.assert_allclose(batch.rib_centers[i], rib_centers(batch.angles[i], SK.spacing_mm),
                                   atol=1e-9)
        np.testing.assert_allclose(batch.cable_path[i],
                                   cable_path(batch.angles[i], d, SK.spacing_mm), atol=1e-9)
        single = solve_forward(SK, n, lengths[i])
        np.testing.assert_allclose(batch.cable_path[i], single.cable_path, atol=1e-9)
    assert not batch.angles[4].any()


def test_length_refusals_say_which_length_and_which_threading():
    # A length <= 0 is a bad value (ValueError naming it), not an unreachable one; the
    # first offending length of a batch is the one named; an unreachable length names
    # the threading by its holes and gives the reachable range.
    sk = Skeleton()
    t = ['R1', 'R2', 'R3', 'L1', 'L2', 'L3'] * 2
    lo, hi = reachable_range(sk, t)
    for bad in (0.0, -2.5):
        with pytest.raises(ValueError, match=rf'cable_length_mm must be > 0, got {bad!r}') as err:
            solve_forward(sk, t, bad)
        assert not isinstance(err.value, InfeasibleLengthError)
    with pytest.raises(ValueError, match=r'must be > 0, got -2\.5') as err:
        solve_forward_batch(sk, t, [hi - 1.0, 0.5, -2.5])
    assert not isinstance(err.value, InfeasibleLengthError)
    with pytest.raises(InfeasibleLengthError, match='R1 R2 R3 L1 L2 L3 R1') as err:
        solve_forward_batch(sk, t, [hi - 1.0, 0.5])
    assert 'cable length 0.5 mm' in str(err.value)
    assert err.value.reachable_range_mm == pytest.approx((lo, hi))
