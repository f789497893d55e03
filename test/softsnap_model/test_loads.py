"""Gravity and point loads (softsnap_model.loads) against an independent optimiser.

The reference minimises the same energy written here from the FACTS.md geometry
(softsnap_model.geometry.rib_centers and segment_length), with scipy's SLSQP at tight
tolerance and central-difference gradients: nothing of the solver's own derivatives,
active sets or continuation is used.
"""
import math

import numpy as np
import pytest
from scipy.optimize import minimize

from softsnap_model import Skeleton, reachable_range, rib_centers, segment_length, solve_forward
from softsnap_model.loads import (CONSTRAINT_TOL_MM, STATIONARITY_TOL_RAD, Loads,
                                  loaded_energy, solve_loaded)
from softsnap_model.reference import PAPER_THREADINGS

SK = Skeleton()                        # the authors' module, 3.0 mm ribs
G = 9.80665
ON_RIGHT_SIDE = (0.0, -G, 0.0)         # lying on its right side: gravity towards -y
ON_LEFT_SIDE = (0.0, G, 0.0)
HANGING = (G, 0.0, 0.0)                # tip below the base
RAISED = (-G, 0.0, 0.0)                # tip above the base
FLAT = (0.0, 0.0, -G)                  # lying on a table: out of plane, no effect


def reference_energy(sk, a, K, forces):
    a = np.asarray(a, dtype=float)
    p = rib_centers(a, sk.spacing_mm)
    return K * float(np.sum(sk.stiffness_array * a * a)) - float(np.sum(forces * p))


def reference_cable(sk, d, a):
    return float(np.sum(segment_length(np.asarray(a), d[:-1], d[1:], sk.spacing_mm)))


def central_gradient(f, x, h=1e-6):
    g = np.empty_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = h
        g[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


def reference_solve(sk, threading, length, loads, start):
    """SLSQP on E(a) with L(a) <= length and |a_i| <= contact angle."""
    d = sk.threading_mm(threading)
    forces = np.zeros((sk.n_ribs, 2))
    masses = np.full(sk.n_ribs, 1.187e-3)
    masses[0] = masses[-1] = 0.967e-3
    if loads.rib_masses_kg is not None:
        masses = np.array(loads.rib_masses_kg)
    forces += masses[:, None] * np.array(loads.gravity_mps2[:2])
    forces[loads.load_rib] += loads.load_n[:2]
    K = loads.bending_stiffness_nmm
    scale = 2 * K         # energies of order 1: SLSQP's ftol is absolute

    def f(a):
        return reference_energy(sk, a, K, forces) / scale

    def c(a):
        return length - reference_cable(sk, d, a)

    amax = sk.contact_angle_rad
    for ftol in (1e-15, 1e-13):    # 1e-15 can stall on rounding ("positive directional
        res = minimize(            # derivative"); 1e-13 still agrees to ~1e-8 rad
            f, np.asarray(start, dtype=float), jac=lambda a: central_gradient(f, a),
            method='SLSQP', bounds=[(-amax, amax)] * sk.n_segments,
            constraints=[{'type': 'ineq', 'fun': c, 'jac': lambda a: central_gradient(c, a)}],
            options={'ftol': ftol, 'maxiter': 1000})
        if res.success:
            break
    assert res.success, res.message
    assert c(res.x) >= -1e-8
    return res.x, reference_energy(sk, res.x, K, forces)


def assert_contract(res, length):
    assert res.converged and res.is_minimum, res.message
    assert res.stationarity_residual_rad <= STATIONARITY_TOL_RAD
    assert res.constraint_residual_mm <= CONSTRAINT_TOL_MM
    poly = float(np.sum(np.linalg.norm(np.diff(res.cable_path, axis=0), axis=1)))
    if res.slack:
        assert poly <= length + CONSTRAINT_TOL_MM and res.tension_n == 0.0
    else:
        assert abs(poly - length) <= 1e-9 and res.tension_n > 0.0


CASES = [
    # (threading, contraction mm, loads)
    ('yellow', 30.0, Loads(gravity_mps2=ON_RIGHT_SIDE)),
    ('yellow', 30.0, Loads(gravity_mps2=ON_LEFT_SIDE)),
    ('yellow', 50.0, Loads(gravity_mps2=HANGING)),
    ('yellow', 50.0, Loads(gravity_mps2=RAISED)),
    ('blue', 40.0, Loads(gravity_mps2=ON_LEFT_SIDE, load_n=(0.0, -0.1, 0.0))),
    ('red', 20.0, Loads(gravity_mps2=HANGING, load_n=(0.05, 0.1, 0.0), load_rib=6)),
    ('gripper', 35.0, Loads(gravity_mps2=(4.0, -7.0, 5.0), bending_stiffness_nmm=30.0,
                            load_n=(0.0, 0.2, 0.0))),
    ('s', 25.0, Loads(gravity_mps2=ON_RIGHT_SIDE, load_n=(0.0, 0.0, 0.0))),
    ('w', 45.0, Loads(load_n=(-0.1, -0.3, 0.0), load_rib=9)),
    ('snake', 10.0, Loads(gravity_mps2=ON_RIGHT_SIDE, bending_stiffness_nmm=8.0)),
    # Slack cable: gravity bends the module the way that shortens the path.
    ('yellow', -1.0, Loads(gravity_mps2=ON_RIGHT_SIDE)),
    # Slack at first, then the weight pulls the path taut.
    ('yellow', -0.3, Loads(gravity_mps2=ON_LEFT_SIDE)),
]


@pytest.mark.parametrize('case', range(len(CASES)))
def test_matches_independent_optimiser(case):
    name, contraction, loads = CASES[case]
    t = PAPER_THREADINGS[name]
    length = SK.straight_length_mm(t) - contraction
    res = solve_loaded(SK, t, length, loads)
    assert_contract(res, length)
    start = solve_forward(SK, t, length).angles
    ref_a, ref_e = reference_solve(SK, t, length, loads, start)
    assert np.max(np.abs(res.angles - ref_a)) < 1e-6
    assert np.max(np.linalg.norm(res.rib_centers - rib_centers(ref_a, SK.spacing_mm),
                                 axis=1)) < 2e-4
    # Ours is at least as low as the optimiser's point (to the optimiser's tolerance).
    assert res.energy_nmm <= ref_e + 1e-9 * max(1.0, abs(ref_e))
    assert res.energy_nmm == pytest.approx(loaded_energy(SK, res.angles, loads), abs=1e-12)
    # The loads really change the shape (else the comparison would prove nothing).
    assert np.max(np.abs(res.angles - start)) > 1e-3


def test_contact_set_with_gravity_matches_optimiser():
    t = PAPER_THREADINGS['yellow']
    lo, hi = reachable_range(SK, t)
    length = lo + 0.5
    loads = Loads(gravity_mps2=ON_LEFT_SIDE, bending_stiffness_nmm=5.0)
    res = solve_loaded(SK, t, length, loads)
    assert_contract(res, length)
    assert res.at_contact.any()
    assert np.all(np.abs(res.angles) <= SK.contact_angle_rad + 1e-15)
    ref_a, ref_e = reference_solve(SK, t, length, loads, solve_forward(SK, t, length).angles)
    assert np.max(np.abs(res.angles - ref_a)) < 1e-6
    assert res.energy_nmm <= ref_e + 1e-9


@pytest.mark.parametrize('gravity', [(0.0, 0.0, 0.0), FLAT])
@pytest.mark.parametrize('name', ['yellow', 'blue', 's', 'gripper'])
def test_no_in_plane_load_is_the_unloaded_solve_exactly(name, gravity):
    t = PAPER_THREADINGS[name]
    for contraction in (-2.0, 0.0, 20.0, 50.0):
        length = SK.straight_length_mm(t) - contraction
        try:
            base = solve_forward(SK, t, length)
        except ValueError:
            continue
        res = solve_loaded(SK, t, length, Loads(gravity_mps2=gravity,
                                                load_n=(0.0, 0.0, 3.0)))
        assert np.array_equal(res.angles, base.angles)
        assert np.array_equal(res.rib_centers, base.rib_centers)
        assert res.tension_n == base.tension * Loads().bending_stiffness_nmm
        assert res.converged and res.slack == base.slack


def test_weight_bends_the_module_towards_gravity():
    t = PAPER_THREADINGS['yellow']
    length = SK.straight_length_mm(t) - 20.0
    base = solve_forward(SK, t, length)
    for gravity, sign in ((ON_RIGHT_SIDE, -1.0), (ON_LEFT_SIDE, 1.0)):
        res = solve_loaded(SK, t, length, Loads(gravity_mps2=gravity))
        assert res.converged, res.message
        # The tip moves along gravity (y), and the base segment turns that way.
        assert sign * (res.rib_centers[-1, 1] - base.rib_centers[-1, 1]) > 1.0
        assert sign * (res.angles[0] - base.angles[0]) > 0.01
    # Slack straight module lying on its right side sags clockwise, every segment.
    slack = solve_loaded(SK, t, SK.straight_length_mm(t) + 1.0,
                         Loads(gravity_mps2=ON_RIGHT_SIDE))
    assert slack.converged and slack.slack and np.all(slack.angles < 0.0)


def test_larger_tip_load_bends_more():
    t = PAPER_THREADINGS['green']
    length = SK.straight_length_mm(t) - 30.0
    tips, tensions = [], []
    for f in (0.0, 0.05, 0.1, 0.2, 0.4):
        res = solve_loaded(SK, t, length, Loads(load_n=(0.0, -f, 0.0)))
        assert res.converged, res.message
        tips.append(res.rib_centers[-1, 1])
        tensions.append(res.tension_n)
    assert np.all(np.diff(tips) < 0.0)           # tip lower (more clockwise) each time
    assert tips[-1] < tips[0] - 5.0


def test_raised_slack_module_buckles_is_reported_not_answered():
    # Standing straight up on a slack cable, a soft module falls over: the straight
    # equilibrium stops being a minimum, and the solver says so instead of answering.
    t = PAPER_THREADINGS['yellow']
    res = solve_loaded(SK, t, SK.straight_length_mm(t) + 1.0,
                       Loads(gravity_mps2=RAISED, bending_stiffness_nmm=5.0))
    assert not res.converged
    assert 'fold or buckling' in res.message
    # A stiff enough module stands straight.
    stiff = solve_loaded(SK, t, SK.straight_length_mm(t) + 1.0,
                         Loads(gravity_mps2=RAISED, bending_stiffness_nmm=100.0))
    assert stiff.converged and np.all(stiff.angles == 0.0)


def test_rib_load_position_matters():
    t = PAPER_THREADINGS['w']
    length = SK.straight_length_mm(t) - 20.0
    tip = solve_loaded(SK, t, length, Loads(load_n=(0.0, 0.2, 0.0)))
    mid = solve_loaded(SK, t, length, Loads(load_n=(0.0, 0.2, 0.0), load_rib=5))
    same = solve_loaded(SK, t, length, Loads(load_n=(0.0, 0.2, 0.0), load_rib=11))
    assert tip.converged and mid.converged
    assert np.array_equal(tip.angles, same.angles)
    # A load at rib 5 does not bend segments 5.. beyond what the cable does: less sag.
    assert abs(mid.rib_centers[-1, 1] - tip.rib_centers[-1, 1]) > 1.0


def test_bad_input_is_refused_with_the_value():
    t = PAPER_THREADINGS['yellow']
    with pytest.raises(ValueError, match='bending_stiffness_nmm'):
        Loads(bending_stiffness_nmm=0.0)
    with pytest.raises(ValueError, match='gravity_mps2'):
        Loads(gravity_mps2=(0.0, float('nan'), 0.0))
    with pytest.raises(ValueError, match='load_n'):
        Loads(load_n=(1.0, 2.0))
    with pytest.raises(ValueError, match='load_rib'):
        Loads(load_rib=0)
    with pytest.raises(ValueError, match='beyond the tip'):
        solve_loaded(SK, t, 180.0, Loads(load_n=(0.0, 1.0, 0.0), load_rib=12))
    with pytest.raises(ValueError, match='rib masses'):
        solve_loaded(SK, t, 180.0, Loads(gravity_mps2=ON_LEFT_SIDE, rib_masses_kg=[1e-3] * 3))
    with pytest.raises(ValueError, match='rib_masses_kg'):
        Loads(rib_masses_kg=[-1e-3] * 12)
    lo, _ = reachable_range(SK, t)
    with pytest.raises(ValueError):
        solve_loaded(SK, t, lo - 1.0, Loads(gravity_mps2=ON_LEFT_SIDE))
    with pytest.raises(ValueError):
        solve_loaded(SK, t, math.nan, Loads(gravity_mps2=ON_LEFT_SIDE))


def test_idealised_skeleton_also_solved():
    sk = Skeleton(rib_thickness_mm=0.0)
    t = PAPER_THREADINGS['yellow']
    length = sk.straight_length_mm(t) - 60.0
    loads = Loads(gravity_mps2=ON_LEFT_SIDE, load_n=(0.0, 0.05, 0.0))
    res = solve_loaded(sk, t, length, loads)
    assert_contract(res, length)
    ref_a, _ = reference_solve(sk, t, length, loads, solve_forward(sk, t, length).angles)
    assert np.max(np.abs(res.angles - ref_a)) < 1e-6


def test_slack_cable_stays_slack_or_is_pulled_taut_by_the_sag():
    t = PAPER_THREADINGS['yellow']
    straight = SK.straight_length_mm(t)
    # Sagging clockwise shortens the right-side path: the cable stays slack.
    sag = solve_loaded(SK, t, straight + 1.0, Loads(gravity_mps2=ON_RIGHT_SIDE))
    assert sag.converged and sag.slack and sag.tension_n == 0.0
    assert sag.cable_length_mm < straight + 1.0
    # Sagging counter-clockwise lengthens it: 0.3 mm of slack is taken up, then the
    # cable holds the module with a tension.
    held = solve_loaded(SK, t, straight + 0.3, Loads(gravity_mps2=ON_LEFT_SIDE))
    assert held.converged and not held.slack and held.tension_n > 0.0
    assert held.cable_length_mm == pytest.approx(straight + 0.3, abs=1e-9)


def test_random_problems_meet_the_contract_or_say_why():
    # Random threadings, lengths (down to the reachable minimum, up to slack), gravity
    # directions, stiffness 3-80 N mm/rad^2 and loads: every answer meets the contract,
    # every refusal says why (near full contact a soft module can pass a fold and
    # snap; SLSQP finds no minimum there either), nothing raises.
    rng = np.random.default_rng(1)
    names = list(SK.holes_mm)
    converged = 0
    for k in range(60):
        t = [names[i] for i in rng.integers(0, 8, 12)]
        lo, hi = reachable_range(SK, t)
        length = lo + (hi - lo) * rng.uniform(0.002, 1.02)
        g = rng.normal(size=3)
        loads = Loads(gravity_mps2=g / np.linalg.norm(g) * G,
                      bending_stiffness_nmm=float(np.exp(rng.uniform(np.log(3), np.log(80)))),
                      load_n=rng.normal(size=3) * rng.choice([0.0, 0.1, 0.5]),
                      load_rib=int(rng.choice([-1, 3, 7])))
        res = solve_loaded(SK, t, length, loads)
        if not res.converged:
            assert 'fold or buckling' in res.message
            continue
        converged += 1
        assert_contract(res, length)
        assert np.all(np.abs(res.angles) <= SK.contact_angle_rad)
        if k % 6 == 0:
            ref_a, ref_e = reference_solve(SK, t, length, loads,
                                           solve_forward(SK, t, length).angles)
            assert np.max(np.abs(res.angles - ref_a)) < 1e-6
            assert res.energy_nmm <= ref_e + 1e-9 * max(1.0, abs(ref_e))
    assert converged >= 55
