"""Inverse design: global optimality, exact recovery, constraints and input checks."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import optimize

from softsnap_model import forward, geometry, reference
from softsnap_model.inverse import design_threading, fit_angles_to_points
from softsnap_model.inverse.search import _Problem
from softsnap_model.skeleton import Skeleton

AUTHORS = Skeleton(rib_thickness_mm=0.0)   # the paper's idealised model (Figure S4)

# Threadings of the paper's robots (FACTS.md), rib 0 first, as text.
PAPER_THREADINGS = {name: ' '.join(holes) for name, holes in reference.PAPER_THREADINGS.items()}


def forward_target(skeleton, threading, fraction):
    """Angles of a threading at a length a fraction of the way into its reachable range."""
    lo, hi = forward.reachable_range(skeleton, threading)
    res = forward.solve_forward(skeleton, threading, hi - fraction * (hi - lo))
    return res.angles


# ------------------------------------------------------------------ the bound's premise


def test_branch_angles_come_from_the_public_forward_function():
    # The design's tension tables are the forward model's own branch angles.
    prob = _Problem(AUTHORS, np.zeros(11), np.ones((12, 8), bool), None, 1)
    lam = np.array([0.0, 1e-3, 0.05, 0.4, 1.2, 5.0, np.inf])
    pairs = np.arange(64)
    table = prob.angles(lam[:, None], pairs[None, :], 1.0)
    public = forward.segment_angle_at_tension(lam[:, None], prob.pair_d1[None], prob.pair_d2[None],
                                              AUTHORS.spacing_mm, 1.0,
                                              AUTHORS.contact_angle_rad)
    np.testing.assert_array_equal(table, public)
    ends = forward.segment_branch(prob.pair_d1, prob.pair_d2, AUTHORS.spacing_mm,
                                  AUTHORS.contact_angle_rad)
    np.testing.assert_array_equal(table[-1], ends.direction * ends.end_angle_rad)


def test_importing_the_package_does_not_load_scipy_optimize():
    # Regression (first design in a fresh process took 1-3 s): scipy.optimize costs
    # ~0.5 s to import and only polyline targets need it.
    import subprocess
    import sys
    code = ('import sys, softsnap_model; from softsnap_model import design_threading; '
            'design_threading(softsnap_model.Skeleton(), target_angles=[0.1] * 11, k=0); '
            'print(any(m.startswith("scipy.optimize") for m in sys.modules))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.strip() == 'False'


def test_branch_angle_magnitude_is_monotone_in_tension():
    # The interval bound rests on |a| rising with tension on a side that never changes.
    prob = _Problem(AUTHORS, np.zeros(11), np.ones((12, 8), bool), None, 1)
    lam = np.concatenate(([0.0], np.geomspace(1e-5, 10.0, 400)))
    a = prob.angles(lam[:, None], np.arange(64)[None, :], 1.0)
    assert np.all(np.diff(np.abs(a), axis=0) >= -1e-12)
    side = np.sign(a[-1])
    assert np.all(a * side >= -1e-15)


# ------------------------------------------------------------------ brute force


SMALL = Skeleton(n_ribs=6, holes_mm={'L2': -6.5, 'R0': 0.5, 'R3': 10.0})


def _best_over_length(threading, targets):
    """Smallest forward-solved angle error of one threading over every cable length."""
    lo, hi = forward.reachable_range(SMALL, threading)
    lengths = np.concatenate((lo + (hi - lo) * np.linspace(0.002, 1.0, 48) ** 1.5, [hi + 1]))
    angles = np.array([forward.solve_forward(SMALL, threading, L).angles for L in lengths])
    out = []
    for t in targets:
        err = np.linalg.norm(angles - t, axis=1)
        j = int(np.argmin(err))
        a, b = lengths[max(j - 1, 0)], lengths[min(j + 1, len(lengths) - 2)]
        fit = optimize.minimize_scalar(
            lambda L: np.linalg.norm(forward.solve_forward(SMALL, threading, L).angles - t),
            bounds=(max(a, lo + 1e-9), b), method='bounded', options={'xatol': 1e-10})
        out.append(min(err[j], fit.fun))
    return out


@pytest.fixture(scope='module')
def brute_force():
    rng = np.random.default_rng(7)
    targets = [forward_target(SMALL, ['R3', 'R0', 'R3', 'L2', 'L2', 'R0'], 0.6),
               rng.normal(0.0, 0.4, SMALL.n_segments),
               np.array([-0.5, -0.3, 0.0, 0.4, 0.9])]
    threadings = list(itertools.product(SMALL.holes_mm, repeat=SMALL.n_ribs))
    errors = np.array([_best_over_length(list(t), targets) for t in threadings])
    return targets, threadings, errors


@pytest.mark.slow
def test_matches_brute_force_on_small_skeleton(brute_force):
    targets, threadings, errors = brute_force
    for j, target in enumerate(targets):
        res = design_threading(SMALL, target_angles=target, k=3)
        ranked = np.sort(errors[:, j])
        # Global: brute force over all 3^6 threadings and lengths finds nothing better,
        # for the best design and for every ranked alternative.
        got = [res.error] + [alt.error for alt in res.alternatives]
        assert len(got) == 4
        for r, err in enumerate(got):
            assert err <= ranked[r] + 1e-6, (j, r, err, ranked[r])
            assert err >= ranked[r] - 1e-6, (j, r, err, ranked[r])
        assert res.converged
        assert res.lower_bound <= res.error + 1e-12


# ------------------------------------------------------------------ exact recovery


@pytest.mark.parametrize('name', sorted(PAPER_THREADINGS))
def test_recovers_paper_threadings_exactly(name):
    threading = PAPER_THREADINGS[name].split()
    target = forward_target(AUTHORS, threading, 0.5)
    res = design_threading(AUTHORS, target_angles=target, k=1)
    assert res.error < 1e-8
    assert res.position_error < 1e-6
    # The reported shape is the forward solve of the reported design.
    again = forward.solve_forward(AUTHORS, list(res.holes), res.cable_length)
    np.testing.assert_allclose(again.angles, res.angles, atol=1e-12)
    np.testing.assert_allclose(res.rib_centers, geometry.rib_centers(res.angles, 18.0),
                               atol=1e-9)
    assert res.threading.tolist() == [AUTHORS.holes_mm[h] for h in res.holes]


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_recovers_random_threadings_exactly(seed):
    rng = np.random.default_rng(seed)
    threading = list(rng.choice(list(AUTHORS.holes_mm), AUTHORS.n_ribs))
    target = forward_target(AUTHORS, threading, rng.uniform(0.1, 0.9))
    res = design_threading(AUTHORS, target_angles=target, k=2)
    assert res.error < 1e-8
    assert [alt.error for alt in res.alternatives] == sorted(alt.error
                                                             for alt in res.alternatives)
    holes = {res.holes} | {alt.holes for alt in res.alternatives}
    assert len(holes) == 3  # distinct threadings


def test_recovers_from_points():
    threading = PAPER_THREADINGS['w'].split()
    shape = forward.solve_forward(AUTHORS, threading, 175.0)
    res = design_threading(AUTHORS, target_points=shape.rib_centers, k=0)
    assert res.fit_error < 1e-6
    assert res.error < 1e-6
    assert res.position_error < 1e-5
    assert res.alternatives == ()


def test_fit_arc_polyline():
    # A circular arc of radius 100 mm, densely sampled: constant angles s / R.
    theta = np.linspace(0.0, 198.0 / 100.0, 400)
    points = np.column_stack((100 * np.sin(theta), 100 * (1 - np.cos(theta))))
    angles, fit_error = fit_angles_to_points(points, 11, 18.0)
    np.testing.assert_allclose(angles, 0.18, atol=2e-4)
    assert fit_error < 0.01


# ------------------------------------------------------------------ unreachable targets


def test_unreachable_target_gives_closest_design_with_honest_error():
    target = np.full(11, -2.0)   # beyond rib contact (1.44 rad) on every segment
    res = design_threading(AUTHORS, target_angles=target, k=1)
    floor = np.sqrt(11) * (2.0 - AUTHORS.contact_angle_rad)
    assert res.error >= floor - 1e-9
    assert res.error == pytest.approx(np.linalg.norm(res.angles - target), abs=1e-12)
    assert res.lower_bound <= res.error
    assert res.position_error > 1.0


def test_mixed_unreachable_target_error_not_beaten_by_paper_threadings():
    target = np.array([0.3, -0.3] * 5 + [0.3])   # zigzag: alternating curvature
    res = design_threading(AUTHORS, target_angles=target, k=0)
    for threading in PAPER_THREADINGS.values():
        lo, hi = forward.reachable_range(AUTHORS, threading.split())
        for L in np.linspace(lo + 0.5, hi, 15):
            a = forward.solve_forward(AUTHORS, threading.split(), L).angles
            assert np.linalg.norm(a - target) >= res.error - 1e-9


# ------------------------------------------------------------------ constraints


def test_fixed_forbidden_and_allowed_holes_are_honoured():
    target = forward_target(AUTHORS, PAPER_THREADINGS['gripper'].split(), 0.5)
    res = design_threading(AUTHORS, target_angles=target, k=2,
                           fixed_holes={0: 'R3', 11: 'L0'}, forbidden_holes=['L3'],
                           allowed_holes=['L0', 'L1', 'L2', 'L3', 'R1', 'R2', 'R3'])
    for design in (res,) + res.alternatives:
        assert design.holes[0] == 'R3' and design.holes[11] == 'L0'
        assert 'L3' not in design.holes and 'R0' not in design.holes
    assert res.error > 1e-6   # the gripper threading itself is excluded
    sequence_form = design_threading(AUTHORS, target_angles=target, k=0,
                                     fixed_holes=['R3'] + [''] * 10 + ['L0'],
                                     forbidden_holes=['L3'],
                                     allowed_holes=['L0', 'L1', 'L2', 'L3', 'R1', 'R2', 'R3'])
    assert sequence_form.holes == res.holes


def test_cable_length_range_is_honoured():
    target = forward_target(AUTHORS, PAPER_THREADINGS['s'].split(), 0.6)
    free = design_threading(AUTHORS, target_angles=target, k=0)
    assert free.error < 1e-8
    lo, hi = free.cable_length + 5.0, free.cable_length + 15.0
    res = design_threading(AUTHORS, target_angles=target, k=1, cable_length_range=(lo, hi))
    for design in (res,) + res.alternatives:
        assert lo - 1e-9 <= design.cable_length <= hi + 1e-9
    assert res.error >= free.error - 1e-12
    assert abs(res.cable_length - free.cable_length) >= 5.0 - 1e-9
    # A range only long zigzag threadings reach (their straight length is ~268 mm).
    long = design_threading(AUTHORS, target_angles=target, k=0,
                            cable_length_range=(250.0, 300.0))
    assert 250.0 <= long.cable_length <= 300.0
    assert long.error >= res.error


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize('kwargs, match', [
    (dict(target_angles=[np.nan] + [0.1] * 10), 'finite'),
    (dict(target_angles=[0.1] * 10), 'expected 11 target angles'),
    (dict(), 'exactly one'),
    (dict(target_angles=[0.1] * 11, target_points=[[0, 0], [1, 0]]), 'exactly one'),
    (dict(target_points=[[5.0, 0.0], [20.0, 0.0]]), 'start at the base'),
    (dict(target_points=[[0.0, 0.0], [np.inf, 0.0]]), 'finite'),
    (dict(target_angles=[0.1] * 11, forbidden_holes=['X9']), 'unknown hole'),
    (dict(target_angles=[0.1] * 11, forbidden_holes=list(AUTHORS.holes_mm)), 'no hole'),
    (dict(target_angles=[0.1] * 11, fixed_holes={12: 'R1'}), 'rib index 12'),
    (dict(target_angles=[0.1] * 11, fixed_holes={3: 'R1'}, forbidden_holes=['R1']),
     'forbidden'),
    (dict(target_angles=[0.1] * 11, cable_length_range=(190.0, 150.0)), 'min <= max'),
    (dict(target_angles=[0.1] * 11, cable_length_range=(1.0, 2.0)), 'no threading'),
    (dict(target_angles=[0.1] * 11, k=-1), 'k must be'),
])
def test_bad_input_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        design_threading(AUTHORS, **kwargs)


def test_empty_hole_set_is_refused():
    with pytest.raises(ValueError, match='hole'):
        design_threading(Skeleton(holes_mm={}), target_angles=[0.0] * 11)
