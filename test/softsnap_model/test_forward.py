"""Forward solver: known answers, branch rules, failure modes, API contract."""
import math
import sys
from pathlib import Path

import mpmath as mp
import numpy as np
import pytest

import softsnap_model as sm
from softsnap_model import (CONSTRAINT_TOL_MM, STATIONARITY_TOL_RAD, InfeasibleLengthError,
                            Skeleton, reachable_range, segment_angle_at_tension,
                            segment_branch, segment_length, solve_forward,
                            solve_forward_batch, sweep)

sys.path.insert(0, str(Path(__file__).parent))
from mp_reference import kkt_reference, rib_centers_mp  # noqa: E402

from softsnap_model.reference import PAPER_THREADINGS  # noqa: E402

SK = Skeleton(rib_thickness_mm=0.0)   # the paper's idealised model (thin ribs)
PAPER = {name: ' '.join(PAPER_THREADINGS[name])
         for name in ('yellow', 'blue', 'red', 'gripper', 'snake', 's', 'w')}
PAPER['alternating'] = 'R3 L3 R3 L3 R3 L3 R3 L3 R3 L3 R3 L3'


def threading(name):
    return PAPER[name].split()


def assert_certified(res, length):
    assert res.converged and res.is_minimum, res.message
    assert res.constraint_residual <= CONSTRAINT_TOL_MM
    assert res.stationarity_residual <= STATIONARITY_TOL_RAD
    # Independent constraint check from the returned geometry (hole polyline).
    poly = float(np.sum(np.linalg.norm(np.diff(res.cable_path, axis=0), axis=1)))
    assert abs(poly - length) <= 1e-9


def test_top_level_api():
    for name in ['Skeleton', 'solve_forward', 'solve_forward_batch', 'sweep',
                 'reachable_range', 'segment_angle_at_tension']:
        assert hasattr(sm, name)
    res = solve_forward(SK, threading('s'), 150.0)
    for field in ['angles', 'rib_centers', 'cable_path', 'energy', 'tension', 'iterations',
                  'converged', 'residual']:
        assert hasattr(res, field)
    assert res.angles.shape == (11,) and res.rib_centers.shape == (12, 2)
    assert res.cable_path.shape == (12, 2)
    assert res.energy == pytest.approx(float(np.sum(res.angles ** 2)))


@pytest.mark.parametrize('name', list(PAPER))
def test_matches_mpmath_reference(name):
    t = threading(name)
    lo, hi = reachable_range(SK, t)
    for length in [hi - 0.3, 0.5 * (lo + hi), lo + 0.2 * (hi - lo)]:
        res = solve_forward(SK, t, length)
        assert_certified(res, length)
        free = [i for i in range(11) if not res.at_contact[i]]
        a_ref, lam_ref = kkt_reference(SK.threading_mm(t), [1.0] * 11, 18, length,
                                       res.angles, res.tension, free=free)
        assert max(abs(float(x) - y) for x, y in zip(a_ref, res.angles)) < 1e-12
        ref_p = rib_centers_mp(a_ref, mp.mpf(18))
        err = max(math.hypot(float(p[0]) - q[0], float(p[1]) - q[1])
                  for p, q in zip(ref_p, res.rib_centers))
        assert err < 1e-11


def test_right_holes_bend_clockwise_and_left_counter():
    assert np.all(solve_forward(SK, ['R2'] * 12, 190.0).angles < 0)
    assert np.all(solve_forward(SK, ['L2'] * 12, 190.0).angles > 0)


def test_slack_cable_is_straight_with_zero_tension():
    t = threading('yellow')
    straight = SK.straight_length_mm(t)
    for length in [straight, straight + 5.0, 1e6]:
        res = solve_forward(SK, t, length)
        assert res.slack and res.converged and res.tension == 0.0
        assert np.all(res.angles == 0.0)
        assert np.allclose(res.rib_centers[:, 0], 18.0 * np.arange(12))


def test_hair_below_straight_is_not_slack():
    t = threading('yellow')
    straight = SK.straight_length_mm(t)
    res = solve_forward(SK, t, straight - 1e-9)
    assert not res.slack and res.converged and res.tension > 0
    assert np.all(res.angles <= 0) and np.any(res.angles < 0)


def test_infeasible_length_names_reachable_range():
    t = threading('yellow')
    lo, hi = reachable_range(SK, t)
    assert 0 < lo < hi == SK.straight_length_mm(t)
    with pytest.raises(InfeasibleLengthError) as info:
        solve_forward(SK, t, lo - 1.0)
    assert info.value.reachable_range_mm == pytest.approx((lo, hi))
    assert f'{lo:.6f}' in str(info.value) and f'{hi:.6f}' in str(info.value)
    assert isinstance(info.value, ValueError)
    # Just above the infimum still solves, with every segment at (or near) contact.
    res = solve_forward(SK, t, lo + 1e-6)
    assert res.converged and np.max(np.abs(res.angles)) == pytest.approx(SK.contact_angle_rad,
                                                                         abs=1e-3)


@pytest.mark.parametrize('bad', [float('nan'), float('inf'), -1.0, 0.0, 'abc', None])
def test_bad_length_raises_value_error(bad):
    with pytest.raises(ValueError):
        solve_forward(SK, threading('s'), bad)


def test_bad_threading_and_initial_raise_value_error():
    with pytest.raises(ValueError, match='expected 12 holes, got 11'):
        solve_forward(SK, ['R3'] * 11, 150.0)
    with pytest.raises(ValueError, match='finite'):
        solve_forward(SK, [np.inf] + [0.0] * 11, 150.0)
    with pytest.raises(ValueError, match='initial'):
        solve_forward(SK, threading('s'), 150.0, initial=np.zeros(10))
    with pytest.raises(ValueError, match='initial'):
        solve_forward(SK, threading('s'), 150.0, initial=np.full(11, np.nan))
    with pytest.raises(ValueError, match='Skeleton'):
        solve_forward('not a skeleton', threading('s'), 150.0)


def test_mirror_segment_straight_until_buckling_then_clockwise():
    t = threading('s')   # segment 5 is R3 -> L3, a mirror pair
    lam_c = segment_branch(10.0, -10.0, 18.0).buckling_tension
    lo, hi = reachable_range(SK, t)
    low_tension = solve_forward(SK, t, hi - 20.0)
    assert low_tension.tension < lam_c and low_tension.angles[5] == 0.0
    assert low_tension.is_minimum
    high = solve_forward(SK, t, lo + 0.5)   # past the contact plateau of the others
    assert high.tension > lam_c and high.angles[5] < 0   # d1 = +10 >= 0: clockwise
    assert high.converged


def test_alternating_threading_degenerate_rule_and_minimum():
    t = threading('alternating')
    hi = SK.straight_length_mm(t)
    for length in [hi - 1e-9, hi - 1e-3, hi - 10.0, hi - 40.0]:
        res = solve_forward(SK, t, length)
        assert res.converged and res.is_minimum and res.min_curvature > 0
        # R3 -> L3 bends clockwise, L3 -> R3 counter-clockwise, all equally (tie).
        assert np.all(res.angles[0::2] < 0) and np.all(res.angles[1::2] > 0)
        assert np.allclose(np.abs(res.angles), abs(res.angles[0]), rtol=1e-9)


def test_default_holes_have_no_fold_and_supercritical_pitchforks():
    names = list(SK.holes_mm)
    d1 = np.array([SK.holes_mm[a] for a in names for b in names])
    d2 = np.array([SK.holes_mm[b] for a in names for b in names])
    br = segment_branch(d1, d2, 18.0)
    assert np.all(br.end_kind == 'contact') and not br.fold.any()
    assert br.mirror.sum() == 8
    # Supercritical: the tension rises past buckling along every mirror branch.
    lam = br.buckling_tension[br.mirror] * 1.001
    a = segment_angle_at_tension(lam, d1[br.mirror], d2[br.mirror], 18.0)
    assert np.all(np.abs(a) > 0)


def test_segment_angle_at_tension_matches_solver():
    t = threading('blue')
    res = solve_forward(SK, t, 170.0)
    d = SK.threading_mm(t)
    a = segment_angle_at_tension(res.tension, d[:-1], d[1:], 18.0)
    assert np.allclose(a, res.angles, atol=1e-12)


def branch_angle_reference(mu, d1, d2, s=18.0):
    """Branch angle by bracketing, element by element (no tables, no Newton)."""
    from scipy.optimize import brentq
    sign = -1.0 if d1 + d2 > 0 or (d1 + d2 == 0 and d1 >= 0) else 1.0
    b_end = SK.contact_angle_rad

    def phi(b):
        return 2.0 * b / -(sign * sm.segment_length_derivatives(sign * b, d1, d2, s)[1])

    if mu == 0.0 or phi(1e-9) >= mu:
        return 0.0
    if phi(b_end) <= mu:
        return sign * b_end
    return sign * brentq(lambda b: phi(b) - mu, 1e-9, b_end, xtol=1e-15, rtol=1e-15)


def test_segment_angle_at_tension_broadcast_matches_per_element():
    # Regression (inverse design took 10-12 s): the broadcast call builds each distinct
    # pair's profile once; it must give what every element computed alone gives.
    names = list(SK.holes_mm)
    d = np.array([SK.holes_mm[h] for h in names])
    lam = np.concatenate(([0.0], np.geomspace(1e-4, 20.0, 24)))
    k = np.array([0.5, 1.0, 3.0])
    a = segment_angle_at_tension(lam[:, None, None, None], d[None, :, None, None],
                                 d[None, None, :, None], 18.0, k)
    assert a.shape == (lam.size, 8, 8, 3)
    rng = np.random.default_rng(7)
    for idx in zip(*(rng.integers(0, n, 150) for n in a.shape)):
        i, p, q, j = idx
        alone = segment_angle_at_tension(lam[i], d[p], d[q], 18.0, k[j])
        assert abs(a[idx] - alone) <= 1e-13, (idx, a[idx], alone)
        # Independent per-element reference: the root of phi(b) = 2 b / -L'(b) = mu on
        # the bend side (brentq), 0 below buckling, the contact angle beyond the branch.
        assert abs(a[idx] - branch_angle_reference(lam[i] / k[j], d[p], d[q])) <= 1e-12
    # Tension-monotone magnitude, constant side, and nothing rebuilt per element.
    assert np.all(np.diff(np.abs(a), axis=0) >= -1e-15)
    with pytest.raises(ValueError, match='NaN'):
        segment_angle_at_tension([0.1, np.nan], 3.0, 6.5, 18.0)


def test_cold_solve_equals_path_following():
    t = threading('snake')
    lo, hi = reachable_range(SK, t)
    lengths = np.linspace(hi - 0.05, lo + 1.0, 120)
    prev = None
    for length in lengths:
        warm = solve_forward(SK, t, length, initial=prev)
        cold = solve_forward(SK, t, length)
        assert np.allclose(warm.angles, cold.angles, atol=1e-11)
        prev = warm


@pytest.mark.parametrize('name', ['yellow', 'blue', 'snake', 's', 'w'])
@pytest.mark.parametrize('step_mm', [0.26, 1e-3, 1e-9, 0.0])
def test_warm_start_needs_no_more_newton_iterations_than_cold(name, step_mm):
    # Regression (warm starts were ~25% slower than cold ones): a warm start from the
    # previous shape, as the model node does every tick, is never more Newton work and
    # gives the cold answer, certified.
    t = threading(name)
    lo, hi = reachable_range(SK, t)
    prev = solve_forward(SK, t, hi - 0.3)
    for length in np.linspace(hi - 0.5, lo + 1.0, 40):
        before = solve_forward(SK, t, length + step_mm, initial=prev)
        for initial in (before.angles, before):
            warm = solve_forward(SK, t, length, initial=initial)
            cold = solve_forward(SK, t, length)
            assert_certified(warm, length)
            assert warm.iterations <= cold.iterations, (length, warm.iterations,
                                                        cold.iterations)
            assert np.allclose(warm.angles, cold.angles, rtol=0, atol=1e-12)
        prev = warm
    # The same length again: the previous answer is accepted without a Newton step.
    again = solve_forward(SK, t, length, initial=warm)
    assert again.iterations == 0 and np.array_equal(again.angles, warm.angles)


def test_path_following_with_slsqp_agrees():
    # Independent method (the paper's: constrained minimisation, small steps, warm
    # start) on a threading without mirror segments.
    from scipy.optimize import minimize
    t = threading('w')
    d = SK.threading_mm(t)
    hi = SK.straight_length_mm(t)
    a = np.zeros(11)
    for length in np.linspace(hi - 1.0, hi - 60.0, 60):
        cons = {'type': 'eq', 'fun': lambda x: np.sum(segment_length(x, d[:-1], d[1:], 18.0))
                - length}
        a = minimize(lambda x: np.sum(x * x), a, jac=lambda x: 2 * x, constraints=[cons],
                     method='SLSQP', options={'ftol': 1e-14, 'maxiter': 200}).x
    res = solve_forward(SK, t, hi - 60.0)
    assert np.allclose(res.angles, a, atol=1e-6)


def test_result_is_a_constrained_minimum_by_perturbation():
    # Feasible perturbations (projected back onto the constraint) never lower the energy.
    t = threading('gripper')
    res = solve_forward(SK, t, 160.0)
    d = SK.threading_mm(t)
    rng = np.random.default_rng(3)
    total = lambda x: np.sum(segment_length(x, d[:-1], d[1:], 18.0))  # noqa: E731
    free = ~res.at_contact
    for _ in range(50):
        x = res.angles + np.where(free, rng.normal(scale=1e-3, size=11), 0.0)
        for _ in range(20):   # Newton back onto sum L = 160 along the length gradient
            from softsnap_model import segment_length_derivatives
            _, dl, _ = segment_length_derivatives(x, d[:-1], d[1:], 18.0)
            dl = np.where(free, dl, 0.0)
            x = x - (total(x) - 160.0) * dl / (dl @ dl)
        assert np.sum(x * x) >= res.energy - 1e-12


def test_stiffness_scaling_and_stiff_segment():
    t = threading('yellow')
    base = solve_forward(SK, t, 170.0)
    scaled = solve_forward(Skeleton(stiffness=[3.0] * 11, rib_thickness_mm=0.0), t, 170.0)
    assert np.allclose(scaled.angles, base.angles, atol=1e-12)
    assert scaled.tension == pytest.approx(3.0 * base.tension, rel=1e-12)
    k = [1.0] * 11
    k[0] = 10.0
    stiff = solve_forward(Skeleton(stiffness=k, rib_thickness_mm=0.0), t, 170.0)
    assert stiff.converged and abs(stiff.angles[0]) < abs(base.angles[0])
    assert stiff.energy == pytest.approx(float(np.sum(np.array(k) * stiff.angles ** 2)))


def test_batch_and_sweep_match_single():
    ts = [threading(n) for n in ['yellow', 's', 'alternating', 'red']]
    lengths = [170.0, 150.0, 290.0, 160.0]
    batch = solve_forward_batch(SK, ts, lengths)
    assert batch.angles.shape == (4, 11) and batch.converged.all()
    for i, (t, length) in enumerate(zip(ts, lengths)):
        assert np.allclose(batch.angles[i], solve_forward(SK, t, length).angles, atol=1e-12)
    c = np.linspace(0.0, 80.0, 81)
    sw = sweep(SK, threading('yellow'), c)
    assert sw.converged.all() and sw.slack[0] and not sw.slack[1:].any()
    straight = SK.straight_length_mm(threading('yellow'))
    for i in [1, 40, 80]:
        single = solve_forward(SK, threading('yellow'), straight - c[i])
        assert np.allclose(sw.angles[i], single.angles, atol=1e-12)
    with pytest.raises(InfeasibleLengthError):
        sweep(SK, ['R1'] * 12, c)   # R1 only reaches about 60 mm of contraction
    with pytest.raises(ValueError, match='expected 2 threadings'):
        solve_forward_batch(SK, ts, [170.0, 150.0])
