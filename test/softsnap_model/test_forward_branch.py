"""Per-segment branches (forward/branch.py) against independent references: branch ends
against dense sampling of the geometry module's segment length, angles at a tension
against scipy's brentq on the segment's equilibrium equation, the in-cell Newton's
iteration budget and warm start, the path tables' cells and cubic starts, and the
public functions' input checks."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from softsnap_model import segment_length_derivatives
from softsnap_model.forward import segment_angle_at_tension, segment_branch
from softsnap_model.forward.branch import (_branch_refine, _branch_solve, _pair_profiles,
                                           _segment_cells)

S = 18.0
CONTACT = 2.0 * S / 25.0     # the default contact angle of the authors' rib, rad


def _l_prime(b, direction, d1, d2, s=S):
    """dl/db along the branch (b = direction * a) from the geometry module."""
    with np.errstate(all='ignore'):     # at pi the holes of some pairs meet: l = 0
        _, l_a, _ = segment_length_derivatives(np.array([direction * b]), np.array([d1]),
                                               np.array([d2]), s)
    return direction * float(l_a[0])


def _direction(d1, d2):
    sigma = d1 + d2
    return -1.0 if sigma > 0 or (sigma == 0 and d1 >= 0) else 1.0


def _reference_angle(mu, d1, d2, end_angle, s=S):
    """The branch angle at tension/stiffness ``mu`` by brentq on 2 b + mu l'(b) = 0."""
    direction = _direction(d1, d2)
    if d1 + d2 == 0.0:
        # A mirror segment: l'(0) = 0, so divide the trivial root b = 0 out.
        f = lambda b: 2.0 + mu * _l_prime(b, direction, d1, d2, s) / b  # noqa: E731
        lo = 1e-9
    else:
        f = lambda b: 2.0 * b + mu * _l_prime(b, direction, d1, d2, s)  # noqa: E731
        lo = 1e-12
    if f(lo) >= 0.0:
        return 0.0                          # a mirror segment below buckling: straight
    if f(end_angle) <= 0.0:
        return direction * end_angle        # past the branch end: held there
    return direction * brentq(f, lo, end_angle, xtol=1e-16, rtol=1e-15, maxiter=500)


def _pairs(rng, n):
    holes = np.array([-10.0, -6.5, -3.0, 3.0, 6.5, 10.0])     # the authors' offsets
    d1 = np.concatenate([holes.repeat(6), rng.uniform(-12.5, 12.5, n)])
    d2 = np.concatenate([np.tile(holes, 6), rng.uniform(-12.5, 12.5, n)])
    return d1, d2


def test_branch_ends_against_dense_sampling():
    # With a contact angle of pi many branches end at the segment's shortest length
    # before contact: there l' = 0, which sampling l on a fine grid finds independently.
    # Contact ends are at the contact angle, their tension 2 b / -l' there; a mirror
    # segment buckles at 2 / |l''(0)| (l'' by central differences of l).
    rng = np.random.default_rng(3)
    d1, d2 = _pairs(rng, 60)
    with np.errstate(all='ignore'):
        br = segment_branch(d1, d2, S, max_angle_rad=math.pi)
    grid = np.linspace(0.0, math.pi, 200001)
    n_kind = {'contact': 0, 'shortest': 0}
    with np.errstate(all='ignore'):
        for i in range(len(d1)):
            direction = _direction(d1[i], d2[i])
            assert br.direction[i] == direction
            length, _, _ = segment_length_derivatives(direction * grid, np.full_like(grid, d1[i]),
                                                      np.full_like(grid, d2[i]), S)
            kind = str(br.end_kind[i])
            n_kind[kind] += 1
            if kind == 'shortest':
                shortest = grid[np.nanargmin(length)]
                assert br.end_angle_rad[i] == pytest.approx(shortest, abs=3e-5), (d1[i], d2[i])
                assert np.nanmin(length) < length[-1]
            else:
                assert kind == 'contact' and br.end_angle_rad[i] == math.pi
                lp = _l_prime(math.pi, direction, d1[i], d2[i])
                assert br.end_tension[i] == pytest.approx(2.0 * math.pi / -lp, rel=1e-9)
            h = 1e-4
            if d1[i] + d2[i] == 0.0:
                assert br.mirror[i]
                seg = [segment_length_derivatives(np.array([e]), np.array([d1[i]]),
                                                  np.array([d2[i]]), S)[0][0] for e in (-h, 0, h)]
                curv0 = (seg[0] - 2.0 * seg[1] + seg[2]) / (h * h)
                assert br.buckling_tension[i] == pytest.approx(2.0 / abs(curv0), rel=1e-5)
            else:
                assert not br.mirror[i] and br.buckling_tension[i] == 0.0
    assert n_kind['contact'] > 20 and n_kind['shortest'] > 20, n_kind
    # The authors' contact angle: every one of their pairs ends at contact.
    default = segment_branch(d1[:36], d2[:36], S)
    assert np.all(default.end_angle_rad == CONTACT) and not default.fold.any()


@pytest.mark.parametrize('max_angle', [None, math.pi])
def test_angle_at_tension_against_brentq(max_angle):
    # Tensions below buckling, along the branch and past its end; stiffness scales the
    # tension (only tension / stiffness matters).
    rng = np.random.default_rng(11)
    d1, d2 = _pairs(rng, 30)
    br = segment_branch(d1, d2, S, max_angle_rad=max_angle)
    n_checked = 0
    for i in range(len(d1)):
        mu_end, mu_c = float(br.end_tension[i]), float(br.buckling_tension[i])
        mus = [0.0, 0.5 * mu_c, mu_c * (1 + 1e-3) + 1e-9, 2.0 * mu_end + 1.0, math.inf]
        mus += list(mu_c + (mu_end - mu_c) * rng.uniform(0.0, 1.0, 4))
        k = rng.uniform(0.5, 2.0)
        for mu in mus:
            a = float(segment_angle_at_tension(mu * k, d1[i], d2[i], S, stiffness=k,
                                               max_angle_rad=max_angle))
            if math.isinf(mu):
                assert a == br.direction[i] * br.end_angle_rad[i]
                continue
            ref = _reference_angle(mu, d1[i], d2[i], float(br.end_angle_rad[i]))
            assert a == pytest.approx(ref, abs=1e-12), (d1[i], d2[i], mu)
            n_checked += 1
    assert n_checked > 500


def _cells(mu, d1, d2, max_angle=CONTACT):
    prof = _pair_profiles(d1, d2, S, max_angle)
    return prof, (prof['mu'], prof['b'], prof['direction'], d1, d2)


def test_the_in_cell_newton_converges_in_a_few_steps_and_per_entry():
    # Safeguarded Newton: six iterations reach brentq's root to 1e-13 rad where
    # bisection alone would still be 1e-4 of a cell off. Every entry ends where it
    # ends alone (it stops changing once settled; to an ulp: numpy's vector loops may
    # round a long array's elements differently from a one-element one), and a warm
    # start at the root is kept.
    rng = np.random.default_rng(5)
    d1, d2 = _pairs(rng, 20)
    prof, (tm, tb, direction, _, _) = _cells(None, d1, d2)
    frac = rng.uniform(0.0, 1.0, len(d1))
    mu = prof['mu_c'] + frac * (prof['mu_end'] - prof['mu_c'])
    b = _branch_solve(mu, tm, tb, direction, d1, d2, S, iters=6)
    ref = np.array([abs(_reference_angle(m, x, y, CONTACT)) for m, x, y in zip(mu, d1, d2)])
    assert np.max(np.abs(b - ref)) <= 1e-13
    for i in range(len(d1)):
        r = slice(i, i + 1)
        alone = _branch_solve(mu[r], tm[r], tb[r], direction[r], d1[r], d2[r], S, iters=6)
        assert alone[0] == pytest.approx(b[i], rel=1e-14, abs=1e-300)
    # A start at the root, inside its cell, is taken and kept after one iteration.
    m = tm.shape[-1]
    idx = np.clip(np.sum(tm < mu[:, None], axis=-1), 1, m - 1)
    take = lambda t, j: np.take_along_axis(t, j[:, None], -1)[:, 0]  # noqa: E731
    cell = (take(tb, idx - 1), take(tb, idx), take(tm, idx - 1), take(tm, idx), tm[:, 0],
            tm[:, -1], tb[:, 0], tb[:, -1])
    warm = _branch_refine(mu, cell, direction, d1, d2, S, 1, start=ref)
    cold = _branch_refine(mu, cell, direction, d1, d2, S, 1)
    assert np.max(np.abs(warm - ref)) <= 1e-15
    assert np.max(np.abs(cold - ref)) > 1e-12     # one step from the linear start is not


def test_path_table_cells_bracket_the_root_and_start_near_it():
    # _segment_cells (the path tables' build): per segment column, the cell found by
    # binary search brackets the root and its cubic start is within 1e-7 rad of it, in
    # the first cell (just past straight) and the last (next to contact) too.
    rng = np.random.default_rng(8)
    d1, d2 = _pairs(rng, 6)
    prof = _pair_profiles(d1, d2, S, CONTACT)
    tables = prof['tables']
    n = len(d1)
    mu_c, mu_end = prof['mu_c'], prof['mu_end']
    frac = np.vstack([np.full(n, 1e-9), np.full(n, 1e-4), rng.uniform(0, 1, (20, n)),
                      np.full(n, 1.0 - 1e-9)])
    mu = mu_c + frac * (mu_end - mu_c)
    with np.errstate(all='ignore'):
        start, (b_lo, b_hi, mu_lo, mu_hi, *_rest) = _segment_cells(mu, tables)
    for p in range(mu.shape[0]):
        for i in range(n):
            root = abs(_reference_angle(mu[p, i], d1[i], d2[i], CONTACT))
            assert b_lo[p, i] <= root <= b_hi[p, i], (p, i)
            assert mu_lo[p, i] <= mu[p, i] <= mu_hi[p, i]
            # (A mirror segment's first cells, at its pitchfork, start linear.)
            if not prof['mirror'][i] and frac[p, 0] >= 1e-4:
                assert abs(start[p, i] - root) <= 1e-7, (p, i, start[p, i] - root)


@pytest.mark.parametrize('kwargs, match', [
    (dict(tension=-1e-9), r'tension must be >= 0, got -1e-09$'),
    (dict(tension=math.nan), 'tension must not be NaN'),
    (dict(d1_mm=math.inf), r'd1_mm must be finite, got inf$'),
    (dict(d2_mm=math.nan), 'd2_mm must be finite'),
    (dict(stiffness=0.0), r'stiffness must be > 0, got 0\.0$'),
    (dict(stiffness=math.inf), 'stiffness must be finite'),
    (dict(spacing_mm=0.0), 'spacing_mm must be finite and > 0'),
    (dict(spacing_mm=math.inf), 'spacing_mm must be finite and > 0'),
    (dict(spacing_mm=math.nan), 'spacing_mm must be finite and > 0'),
    (dict(max_angle_rad=0.0), r'max_angle_rad must be in \(0, pi\]'),
    (dict(max_angle_rad=math.pi + 1e-12), r'max_angle_rad must be in \(0, pi\]'),
])
def test_segment_angle_at_tension_refuses_bad_input(kwargs, match):
    args = dict(tension=0.1, d1_mm=3.0, d2_mm=6.5, spacing_mm=S)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        segment_angle_at_tension(**args)


def test_the_contact_angle_bounds_are_inclusive_of_pi_and_default_to_the_rib():
    a_pi = segment_angle_at_tension(math.inf, 3.0, 6.5, S, max_angle_rad=math.pi)
    assert a_pi == -segment_branch(3.0, 6.5, S, max_angle_rad=math.pi).end_angle_rad
    assert segment_angle_at_tension(math.inf, 3.0, 6.5, S) == -CONTACT
    # A spacing long enough that 2 s / 25 mm exceeds pi: the default is capped at pi.
    assert segment_branch(3.0, 6.5, 50.0).end_angle_rad <= math.pi
    with pytest.raises(ValueError, match='max_angle_rad'):
        segment_branch(3.0, 6.5, S, max_angle_rad=-1.0)
