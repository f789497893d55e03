"""What solve_loaded reports beyond the shape, against references built here: the cable
tension as the Lagrange multiplier of the reference energy, the curvature at the answer
as the smallest eigenvalue of the reference Lagrangian's finite-difference Hessian on the
constraint's tangent space, non-uniform stiffness against the independent optimiser of
test_loads.py, and the input checks at their boundaries."""
from __future__ import annotations

import numpy as np
import pytest

from softsnap_model import Skeleton, rib_centers, segment_length
from softsnap_model.loads import Loads, solve_loaded
from softsnap_model.reference import PAPER_THREADINGS
from test_loads import ON_LEFT_SIDE, ON_RIGHT_SIDE, assert_contract, reference_solve

SK = Skeleton()


def _forces(sk, loads):
    w = loads.masses_kg(sk.n_ribs)[:, None] * np.array(loads.gravity_mps2[:2])
    w[loads.load_rib] += loads.load_n[:2]
    return w


def _lagrangian(sk, d, loads, lam_nmm, target):
    """Reference E(a) + lam (L(a) - target), N mm, from the geometry alone."""
    K, w = loads.bending_stiffness_nmm, _forces(sk, loads)

    def f(a):
        energy = K * float(np.sum(sk.stiffness_array * a * a)) \
            - float(np.sum(w * rib_centers(a, sk.spacing_mm)))
        cable = float(np.sum(segment_length(a, d[:-1], d[1:], sk.spacing_mm)))
        return energy + lam_nmm * (cable - target)
    return f


def _gradient(f, x, h=1e-5):
    return np.array([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(x.size)])


def _hessian(f, x, h=1e-4):
    n = x.size
    H = np.empty((n, n))
    for i in range(n):
        ei = h * np.eye(n)[i]
        H[i] = (_gradient(f, x + ei) - _gradient(f, x - ei)) / (2 * h)
    return 0.5 * (H + H.T)


def _reference_curvature(sk, d, loads, tension, length, a, free, taut):
    """Smallest eigenvalue of the reference Lagrangian's Hessian over the free segments,
    on the tangent space of the cable constraint when taut."""
    H = _hessian(_lagrangian(sk, d, loads, tension, length), a)
    idx = np.flatnonzero(free)
    H = H[np.ix_(idx, idx)]
    if taut:
        grad_l = _gradient(lambda x: float(np.sum(segment_length(x, d[:-1], d[1:],
                                                                 sk.spacing_mm))), a)[idx]
        q, _ = np.linalg.qr(np.column_stack([grad_l, np.eye(idx.size)]))
        Z = q[:, 1:idx.size]
        H = Z.T @ H @ Z
    return float(np.min(np.linalg.eigvalsh(H)))


@pytest.mark.parametrize('name, contraction, loads', [
    ('yellow', 30.0, Loads(gravity_mps2=ON_RIGHT_SIDE)),
    ('blue', 40.0, Loads(gravity_mps2=ON_LEFT_SIDE, load_n=(0.0, -0.1, 0.0))),
    ('red', 25.0, Loads(load_n=(0.05, 0.2, 0.0), load_rib=6, bending_stiffness_nmm=9.0)),
    # A soft module: segments held at contact, a curvature below 1 N mm/rad^2.
    ('yellow', 40.0, Loads(gravity_mps2=ON_RIGHT_SIDE, bending_stiffness_nmm=0.3)),
    ('yellow', 20.0, Loads(gravity_mps2=ON_RIGHT_SIDE, bending_stiffness_nmm=0.3)),
    # Slack: no constraint, no tension.
    ('yellow', 5.0, Loads(gravity_mps2=ON_RIGHT_SIDE, bending_stiffness_nmm=0.3)),
    # No load at all: the unloaded solve, reported in the loaded result's units.
    ('blue', 30.0, Loads()),
])
def test_tension_and_curvature_are_the_reference_lagrangians(name, contraction, loads):
    t = PAPER_THREADINGS[name]
    d = SK.threading_mm(t)
    length = SK.straight_length_mm(t) - contraction
    res = solve_loaded(SK, t, length, loads)
    assert_contract(res, length)
    a = np.asarray(res.angles)
    free = ~np.asarray(res.at_contact)
    grad_e = _gradient(_lagrangian(SK, d, loads, 0.0, length), a)
    if res.slack:
        tension = 0.0
        assert res.tension_n == 0.0
        assert res.constraint_residual_mm == max(res.cable_length_mm - length, 0.0)
    else:
        # grad E + T grad L = 0 on the free segments (T in N mm per mm = N): the
        # multiplier of the reference energy by least squares.
        grad_l = _gradient(lambda x: float(np.sum(segment_length(x, d[:-1], d[1:],
                                                                 SK.spacing_mm))), a)
        ge, gl = grad_e[free], grad_l[free]
        tension = -float(ge @ gl) / float(gl @ gl)
        assert res.tension_n == pytest.approx(tension, rel=1e-5)
        assert np.max(np.abs(ge + tension * gl)) < 1e-5 * np.max(np.abs(ge))
        assert res.constraint_residual_mm == abs(res.cable_length_mm - length)
    curvature = _reference_curvature(SK, d, loads, tension, length, a, free, not res.slack)
    assert curvature > 0.0 and res.is_minimum
    assert res.min_curvature == pytest.approx(curvature, rel=1e-3)
    if loads.is_zero:
        assert res.load_steps == 0
    elif loads.bending_stiffness_nmm < 1.0:
        # Weight alone on a soft module: the full load converges at once, one step.
        assert res.load_steps == 1
    else:
        assert res.load_steps >= 1
    assert res.iterations >= (0 if loads.is_zero else 1)


def test_uneven_stiffness_matches_the_independent_optimiser():
    k = (1.0, 1.6, 0.7, 1.0, 2.2, 0.5, 1.0, 1.3, 0.8, 1.0, 1.9)
    sk = Skeleton(stiffness=k)
    t = PAPER_THREADINGS['yellow']
    length = sk.straight_length_mm(t) - 35.0
    loads = Loads(gravity_mps2=ON_RIGHT_SIDE, load_n=(0.0, -0.05, 0.0))
    res = solve_loaded(sk, t, length, loads)
    assert_contract(res, length)
    from softsnap_model import solve_forward
    start = solve_forward(sk, t, length).angles
    ref_a, _ = reference_solve(sk, t, length, loads, start)
    assert np.max(np.abs(res.angles - ref_a)) < 1e-6
    assert np.max(np.abs(res.angles - start)) > 1e-3      # the loads matter here


def test_load_inputs_at_their_boundaries():
    assert Loads().gravity_mps2 == (0.0, 0.0, 0.0) and Loads().load_n == (0.0, 0.0, 0.0)
    assert Loads().is_zero
    for bad in ('abc', (1.0, 2.0), (0.0, float('nan'), 0.0), object()):
        with pytest.raises(ValueError, match='gravity_mps2 must be 3'):
            Loads(gravity_mps2=bad)
    assert Loads(bending_stiffness_nmm=0.5).bending_stiffness_nmm == 0.5
    for bad in (0.0, -1.0, True, float('inf')):
        with pytest.raises(ValueError, match='bending_stiffness_nmm'):
            Loads(bending_stiffness_nmm=bad)
    assert Loads(load_rib=1).load_rib == 1
    for bad in (0, -2, True, 1.5):
        with pytest.raises(ValueError, match='load_rib'):
            Loads(load_rib=bad)
    # Weight counts as a load when any rib but the clamped one has mass.
    on_rib_1 = [0.0] * 12
    on_rib_1[1] = 1e-3
    assert not Loads(gravity_mps2=ON_RIGHT_SIDE, rib_masses_kg=on_rib_1).is_zero
    only_base = [0.0] * 12
    only_base[0] = 1e-3
    assert Loads(gravity_mps2=ON_RIGHT_SIDE, rib_masses_kg=only_base).is_zero
    assert Loads(gravity_mps2=ON_RIGHT_SIDE, rib_masses_kg=[0.0] * 12).is_zero
    for bad in ('abc', [[1e-3]], [1e-3] * 11 + [-1e-3], [float('nan')] * 12):
        with pytest.raises(ValueError, match='rib_masses_kg must be'):
            Loads(rib_masses_kg=bad)


def test_max_iter_is_a_whole_number_from_one():
    t = PAPER_THREADINGS['yellow']
    length = SK.straight_length_mm(t) - 30.0
    loads = Loads(gravity_mps2=ON_RIGHT_SIDE)
    one = solve_loaded(SK, t, length, loads, max_iter=1)      # allowed; may not converge
    assert one.converged or 'fold or buckling' in one.message or one.message
    for bad in (None, Loads, {'gravity_mps2': (0.0, -9.8, 0.0)}):
        with pytest.raises(ValueError, match='loads must be a Loads'):
            solve_loaded(SK, t, length, bad)
    for bad in (0, -3, 2.5, 'ten'):
        with pytest.raises(ValueError, match='max_iter must be an integer >= 1'):
            solve_loaded(SK, t, length, loads, max_iter=bad)


def test_reduced_curvature_on_hand_built_matrices():
    """The curvature helper against numpy on matrices whose answer is known: the smallest
    eigenvalue over the free coordinates, on the plane normal to the constraint gradient
    when the cable is taut; infinite with nothing free."""
    from softsnap_model.loads import _reduced_hessian_min_eig
    H = np.diag([1.0, 2.0, 3.0, 5.0])
    free = np.array([True, True, True, True])
    assert _reduced_hessian_min_eig(H, free, np.zeros(4), False) == pytest.approx(1.0)
    # Taut, the gradient along the first axis (norm exactly 1, either sign): that axis
    # is removed.
    for g in ([1.0, 0.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 2.0]):
        expected = 2.0 if g[0] else 1.0
        assert _reduced_hessian_min_eig(H, free, np.array(g), True) == pytest.approx(expected)
    # A gradient at 45 degrees in the first two coordinates: the tangent direction
    # (1, -1)/sqrt(2) has curvature (1 + 2)/2 = 1.5, below the other two.
    g = np.array([1.0, 1.0, 0.0, 0.0])
    assert _reduced_hessian_min_eig(H, free, g, True) == pytest.approx(1.5)
    # Held segments are left out; a zero gradient over the free ones removes nothing.
    held = np.array([False, True, True, True])
    assert _reduced_hessian_min_eig(H, held, np.array([3.0, 0.0, 0.0, 0.0]), True) \
        == pytest.approx(2.0)
    assert _reduced_hessian_min_eig(H, np.zeros(4, bool), np.ones(4), True) == np.inf
    assert _reduced_hessian_min_eig(H[:1, :1], np.array([True]), np.array([1.0]), True) \
        == np.inf                                  # one free coordinate, constrained away


def test_a_load_that_fails_from_the_first_step_reports_the_unloaded_state():
    """So soft that the first sliver of a raised module's weight buckles it: nothing of
    the load is taken, and the result reports the straight, unloaded state (residuals 0,
    curvature 2 K k of the straight slack module) with the reason."""
    t = PAPER_THREADINGS['yellow']
    K = 1e-3
    res = solve_loaded(SK, t, SK.straight_length_mm(t) + 2.0,
                       Loads(gravity_mps2=(9.80665 * -1.0, 0.0, 0.0), bending_stiffness_nmm=K))
    assert not res.converged and res.load_steps == 0
    assert np.all(res.angles == 0.0) and res.slack
    assert res.constraint_residual_mm == 0.0 and res.stationarity_residual_rad == 0.0
    assert res.min_curvature == pytest.approx(2.0 * K * float(np.min(SK.stiffness_array)))
    assert 'beyond 0 of the load (the equilibrium stops being a minimum)' in res.message
