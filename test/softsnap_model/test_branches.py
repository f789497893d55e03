"""Mirror-segment tie-breaks, the other mirror branch, and other (higher) energy minima."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import optimize

from softsnap_model import forward, geometry
from softsnap_model.skeleton import Skeleton

AUTHORS = Skeleton()
# R0/L0, L1/R1 and L3/R3 pairs are mirror segments (d2 = -d1): 0, 1, 2, 5, 8, 9, 10.
MIRRORED = 'R0 L0 R0 L0 L2 L1 R1 L3 L3 R3 L3 R3'.split()
MIRROR_SEGMENTS = (0, 1, 2, 5, 8, 9, 10)


def idealised_skeleton():
    """The authors' module with the paper's idealised ribs (no rib thickness).

    Numbers quoted from issue 13 are for the contact angle 2 s / rib_length = 1.44 rad;
    a rib-thickness field (if the Skeleton has one) is set to zero explicitly.
    """
    extra = {f.name: 0.0 for f in dataclasses.fields(Skeleton) if 'thick' in f.name}
    sk = Skeleton(n_ribs=12, spacing_mm=18.0, rib_length_mm=25.0, **extra)
    assert sk.contact_angle_rad == pytest.approx(1.44, abs=1e-12)
    return sk


def certify(sk, d, length_mm, angles, tension):
    """Independent first- and second-order check of a constrained minimum.

    Energy ``sum k a^2``, constraint ``sum L_i(a_i) = length``, bounds ``|a_i| <= c``.
    Returns (constraint residual mm, stationarity residual rad over free segments,
    smallest bound multiplier, smallest projected-Hessian eigenvalue).
    """
    d = np.asarray(d, dtype=float)
    k = sk.stiffness_array
    c = sk.contact_angle_rad
    seg, l_a, l_aa = geometry.segment_length_derivatives(angles, d[:-1], d[1:], sk.spacing_mm)
    at_bound = np.abs(np.abs(angles) - c) <= 1e-9
    free = ~at_bound
    stat = np.abs(angles + tension * l_a / (2 * k))[free]
    # Lagrangian gradient 2 k a + lam L'; at an active bound it must push outwards.
    grad = 2 * k * angles + tension * l_a
    bound_mult = (-grad * np.sign(angles))[at_bound]
    hess = np.diag(2 * k + tension * l_aa)[np.ix_(free, free)]
    g = l_a[free][None, :]
    if g.size and np.any(g):
        z = np.linalg.svd(g)[2][1:].T           # tangent space of the length constraint
    else:
        z = np.eye(int(free.sum()))
    eig = np.linalg.eigvalsh(z.T @ hess @ z) if z.size else np.array([np.inf])
    return (abs(seg.sum() - length_mm), float(stat.max(initial=0.0)),
            float(bound_mult.min(initial=np.inf)), float(eig.min()))


# ------------------------------------------------------------------ mirror branches


def _lengths(sk, threading, n=9):
    lo, hi = forward.reachable_range(sk, threading)
    return lo + (hi - lo) * np.linspace(0.02, 0.98, n)


def test_tie_break_flags_only_bent_mirror_segments():
    seen_partial = False
    for length in _lengths(AUTHORS, MIRRORED, 15):
        res = forward.solve_forward(AUTHORS, MIRRORED, length)
        bent = {j for j in MIRROR_SEGMENTS if res.angles[j] != 0.0}
        assert set(res.tie_break_segments) == bent
        assert set(res.tie_break_segments) <= set(MIRROR_SEGMENTS)
        seen_partial |= 0 < len(bent) < len(MIRROR_SEGMENTS)
        # Non-mirror segments are never flagged, even when bent.
        assert np.any(res.angles[[3, 4, 6, 7]] != 0.0)
    assert seen_partial   # some lengths have bent and still-straight mirror segments
    straight = forward.solve_forward(AUTHORS, MIRRORED, _lengths(AUTHORS, MIRRORED)[-1])
    assert straight.tie_break_segments == ()
    slack = forward.solve_forward(AUTHORS, MIRRORED, 1000.0)
    assert slack.tie_break_segments == ()
    no_mirror = forward.solve_forward(AUTHORS, ['R3'] * 12, 170.0)
    assert no_mirror.tie_break_segments == ()


@pytest.mark.parametrize('threading', [MIRRORED, ['R3', 'L3'] * 6,
                                       'R3 R3 R3 R3 R3 R3 L3 L3 L3 L3 L3 L3'.split()])
def test_both_mirror_branches_are_constrained_minima_with_equal_energy(threading):
    d = AUTHORS.threading_mm(threading)
    checked = 0
    for length in _lengths(AUTHORS, threading, 15):
        res = forward.solve_forward(AUTHORS, threading, length)
        if not res.tie_break_segments:
            continue
        flip = res.tie_break_segments
        other = forward.solve_forward(AUTHORS, threading, length, mirror_flip=flip)
        assert other.converged and other.mirror_flip == tuple(sorted(flip))
        assert other.tie_break_segments == res.tie_break_segments
        # The flagged segments are bent the other way, nothing else changes.
        np.testing.assert_array_equal(other.angles[list(flip)], -res.angles[list(flip)])
        keep = np.setdiff1d(np.arange(AUTHORS.n_segments), flip)
        np.testing.assert_array_equal(other.angles[keep], res.angles[keep])
        assert other.energy == res.energy          # symmetry: exactly tied
        assert other.tension == res.tension
        assert np.max(np.abs(other.rib_centers - res.rib_centers)) > 1.0   # a new shape
        for shape in (res, other):
            g, stat, mult, eig = certify(AUTHORS, d, length, shape.angles, shape.tension)
            assert g <= forward.CONSTRAINT_TOL_MM
            assert stat <= forward.STATIONARITY_TOL_RAD
            assert mult >= -1e-9
            assert eig > 0
        # A single flagged segment flipped alone is also a minimum of the same energy.
        one = forward.solve_forward(AUTHORS, threading, length, mirror_flip=[flip[0]])
        assert one.energy == res.energy
        assert certify(AUTHORS, d, length, one.angles, one.tension)[3] > 0
        checked += 1
    assert checked >= 1


def test_flipping_a_straight_mirror_segment_changes_nothing():
    length = _lengths(AUTHORS, MIRRORED)[-2]
    res = forward.solve_forward(AUTHORS, MIRRORED, length)
    straight = [j for j in MIRROR_SEGMENTS if j not in res.tie_break_segments]
    assert straight
    other = forward.solve_forward(AUTHORS, MIRRORED, length, mirror_flip=straight)
    np.testing.assert_array_equal(np.abs(other.angles), np.abs(res.angles))
    np.testing.assert_allclose(other.rib_centers, res.rib_centers, atol=0.0)


def test_batch_items_carry_the_tie_break():
    lengths = _lengths(AUTHORS, MIRRORED)
    batch = forward.solve_forward_batch(AUTHORS, MIRRORED, lengths)
    for i, length in enumerate(lengths):
        single = forward.solve_forward(AUTHORS, MIRRORED, length)
        assert batch.item(i).tie_break_segments == single.tie_break_segments


@pytest.mark.parametrize('flip, match', [([3], 'not a mirror segment'),
                                         ([11], r'integer in \[0, 10\]'),
                                         ([-1], 'integer'), ([True], 'integer'),
                                         (5, 'sequence')])
def test_bad_mirror_flip_is_refused(flip, match):
    with pytest.raises(ValueError, match=match):
        forward.solve_forward(AUTHORS, MIRRORED, 200.0, mirror_flip=flip)


# ------------------------------------------------------------------ other energy minima


ISSUE_13_THREADING = [-6.5, 10, 6.5, -10, 6.5, -10, -0.5, 6.5, -3, -0.5, -10, -0.5]


def test_higher_local_minimum_exists_beside_the_answer():
    # Issue 13: "each length has exactly one answer" holds along the shortening path,
    # not for the energy: at 164.8 mm this threading has a second, higher minimum.
    sk = idealised_skeleton()
    d = np.array(ISSUE_13_THREADING, dtype=float)
    length = 164.8
    res = forward.solve_forward(sk, d, length)
    assert res.converged
    assert res.energy == pytest.approx(20.37, abs=0.005)
    c = sk.contact_angle_rad

    def constraint(a):
        return geometry.segment_length(a, d[:-1], d[1:], sk.spacing_mm).sum() - length

    def constraint_jac(a):
        return geometry.segment_length_derivatives(a, d[:-1], d[1:], sk.spacing_mm)[1]

    # Start from the answer with segment 0 bent against its first-order preference
    # (its holes -6.5 -> 10 mm pull it clockwise).
    # At ftol=1e-15 SLSQP's line search stops with status 8 ("positive directional
    # derivative", nothing left to gain at this precision) or succeeds depending on the
    # last bits of its start: a few-ulp change of the solver's answer flipped it, and so
    # did OpenBLAS's kernels with the same start rounded to 1e-12 rad (status 8 with
    # OPENBLAS_CORETYPE=SkylakeX, the choice on an AVX-512 CPU; success with Haswell or
    # Prescott). The test is about the minimum, not that line search: either end is
    # taken, and what follows certifies the point on its own (stationarity, multipliers,
    # curvature, feasible neighbours).
    start = np.round(res.angles, 12)
    start[0] = -start[0]
    other = optimize.minimize(lambda a: a @ a, start, jac=lambda a: 2 * a, method='SLSQP',
                              bounds=[(-c, c)] * sk.n_segments,
                              constraints=[dict(type='eq', fun=constraint,
                                                jac=constraint_jac)],
                              options=dict(ftol=1e-15, maxiter=500))
    assert other.success or other.status == 8, other.message
    a = other.x
    assert a @ a == pytest.approx(22.80, abs=0.005)
    assert a @ a > res.energy + 2.0
    assert a[0] > 0 > res.angles[0]
    # A true constrained local minimum: the multiplier from the free segments makes
    # them stationary, every bound multiplier is positive (strict complementarity),
    # and the Hessian is positive on what the active constraints leave free.
    free = np.abs(np.abs(a) - c) > 1e-7
    assert free.sum() >= 1
    _, l_a, _ = geometry.segment_length_derivatives(a, d[:-1], d[1:], sk.spacing_mm)
    tension = float(-(2 * a[free]) @ l_a[free] / (l_a[free] @ l_a[free]))
    polished = np.where(free, a, np.sign(a) * c)
    g, stat, mult, eig = certify(sk, d, length, polished, tension)
    assert g <= 1e-7
    assert stat <= 1e-6
    assert mult > 0.1
    assert eig > 0
    # And feasible neighbours (inside the bounds, same cable length: the free segment
    # takes up the change) all have more energy.
    rng = np.random.default_rng(3)
    j = int(np.nonzero(free)[0][-1])
    index = np.arange(a.size)
    feasible = 0
    for _ in range(300):
        trial = np.clip(polished + rng.normal(0.0, 3e-4, a.size), -c, c)

        def gap(x):
            return constraint(np.where(index == j, x, trial))
        lo, hi = polished[j] - 0.2, min(polished[j] + 0.2, c)
        if gap(lo) * gap(hi) > 0:
            continue      # no angle of the free segment restores the length
        trial[j] = optimize.brentq(gap, lo, hi, xtol=1e-14)
        feasible += 1
        assert trial @ trial > polished @ polished - 1e-9
    assert feasible >= 100
