"""The plain-float single solve (forward/single.py, issue 17) against the vectorised batch
engine and against residuals recomputed by the geometry module: random threadings and
lengths, slack cables, full contraction, segments at contact, mirror segments held
straight or just past buckling, warm starts, mirror flips, a 6-rib and a 192-rib
skeleton."""

import numpy as np
import pytest

import softsnap_model.forward as fwd
from softsnap_model import Skeleton, segment_length_derivatives
from softsnap_model.forward.single import _sum
from softsnap_model.reference import PAPER_THREADINGS

HOLES = ('R1', 'R2', 'R3', 'L1', 'L2', 'L3')
# Fractions of the reachable range (0 = straight, 1 = the unreachable minimum): the ends,
# the neighbourhood of buckling and of full contraction, and the middle.
EDGES = (1e-12, 1e-9, 1e-6, 1e-3, 0.5, 0.999, 1.0 - 1e-6, 1.0 - 1e-9)


def _threadings(rng, n_random):
    special = [['R1', 'L1'] * 6, ['R2', 'L2'] * 6, ['R3'] * 12, ['R1'] * 6 + ['L1'] * 6]
    return ([list(t) for t in PAPER_THREADINGS.values()] + special
            + [[HOLES[i] for i in rng.integers(0, 6, 12)] for _ in range(n_random)])


def _lengths(rng, lo, hi, n_random):
    frac = np.concatenate([EDGES, rng.uniform(0.0, 1.0, n_random)])
    lengths = hi - frac * (hi - lo)
    return lengths[lengths > lo]


def _independent_residuals(sk, t, res):
    """Constraint (mm) and stationarity (rad) of a result, from the geometry module."""
    return _residuals_of(sk, t, res.angles, res.tension, res.at_contact, res.cable_length_mm)


def _residuals_of(sk, t, angles, tension, at_contact, length_mm):
    """Constraint (mm) and stationarity (rad) of angles and a tension, from the geometry
    module (free segments: neither at contact nor straight)."""
    d = sk.threading_mm(t)
    k = np.asarray(sk.stiffness_array)
    seg, l_a, _ = segment_length_derivatives(angles, d[:-1], d[1:], sk.spacing_mm)
    free = ~at_contact & (angles != 0.0)
    stat = np.abs(angles + tension * l_a / (2.0 * k))[free]
    return abs(seg.sum() - length_mm), float(stat.max(initial=0.0))


@pytest.mark.parametrize('thickness', [3.0, 0.0])
def test_single_solve_matches_the_batch_engine(thickness):
    # Both certify to the same inner targets, so their angles differ at most by what the
    # stationarity target allows at the point's curvature (the batch accepts a start
    # with |residual| <= 1e-14 rad, the single solve only <= 1e-14 times the smallest
    # curvature; Newton steps stop at the same residual target), plus rounding.
    sk = Skeleton(rib_thickness_mm=thickness)
    rng = np.random.default_rng(17)
    n_solves = n_contact = n_held = 0
    for t in _threadings(rng, 25):
        lo, hi = fwd.reachable_range(sk, t)
        lengths = _lengths(rng, lo, hi, 12)
        batch = fwd.solve_forward_batch(sk, t, lengths)
        for i, length in enumerate(lengths):
            res = fwd.solve_forward(sk, t, length)
            n_solves += 1
            assert res.converged == batch.converged[i], (t, length)
            assert res.converged, (t, length, res.message)
            assert res.slack == batch.slack[i]
            assert np.array_equal(res.at_contact, batch.at_contact[i]), (t, length)
            gap = float(np.max(np.abs(res.angles - batch.angles[i])))
            curv = min(res.min_curvature, 1.0)
            assert gap <= 2e-14 / curv + 2e-15, (t, length, gap, curv)
            assert abs(res.tension - batch.tension[i]) <= 1e-12 * max(res.tension, 1.0) / curv
            assert res.is_minimum and batch.is_minimum[i]
            constraint, stat = _independent_residuals(sk, t, res)
            assert constraint <= fwd.CONSTRAINT_TOL_MM, (t, length, constraint)
            assert stat <= fwd.STATIONARITY_TOL_RAD, (t, length, stat)
            n_contact += bool(res.at_contact.any())
            n_held += bool(any(res.angles[j] == 0.0 for j in res.tie_break_segments)
                           or (not res.slack and np.any(res.angles == 0.0)))
    # The edge cases were reached, not only the easy middle of the range.
    assert n_solves > 500 and n_contact > 20 and n_held > 5, (n_solves, n_contact, n_held)


def test_single_solve_agrees_with_the_bracketing_reference():
    # Independent of tables and Newton: benchmarks/accuracy_check.py brackets the tension
    # and every segment's angle.
    from benchmark_scripts import load
    reference_solve = load('accuracy_check').reference_solve
    sk = Skeleton()
    for name in ('blue', 'gripper', 's'):
        t = list(PAPER_THREADINGS[name])
        lo, hi = fwd.reachable_range(sk, t)
        for frac in (0.02, 0.3, 0.6, 0.9):     # the domain of accuracy_check.py
            length = hi - frac * (hi - lo)
            res = fwd.solve_forward(sk, t, length)
            ref = np.asarray(reference_solve(sk, t, length)[0])
            assert np.max(np.abs(res.angles - ref)) <= 1e-13, (name, frac)


def test_slack_and_infeasible_lengths_are_handled_before_the_single_solve():
    sk = Skeleton()
    t = list(PAPER_THREADINGS['red'])
    lo, hi = fwd.reachable_range(sk, t)
    for length in (hi, hi + 1.0):
        res = fwd.solve_forward(sk, t, length)
        assert res.slack and res.converged and not res.angles.any() and res.tension == 0.0
    with pytest.raises(fwd.InfeasibleLengthError):
        fwd.solve_forward(sk, t, lo)


def test_warm_starts_and_mirror_flips_keep_the_cold_answer():
    sk = Skeleton()
    t = list(PAPER_THREADINGS['snake'])      # mirror segments (R3 L3, L3 R3)
    lo, hi = fwd.reachable_range(sk, t)
    for frac in (0.02, 0.6, 0.995):
        length = hi - frac * (hi - lo)
        cold = fwd.solve_forward(sk, t, length)
        # The mirror segments 3 and 7 (R3 L3, L3 R3) stay straight until the others are
        # at contact, then buckle.
        assert (cold.angles[3] == 0.0) == (frac < 0.99) == (not cold.tie_break_segments)
        for initial in (cold, cold.angles, cold.angles + 1e-9, cold.angles + 1e-3):
            warm = fwd.solve_forward(sk, t, length, initial=initial)
            assert np.max(np.abs(warm.angles - cold.angles)) <= 1e-14
            assert warm.converged
        assert fwd.solve_forward(sk, t, length, initial=cold).iterations == 0
        if not cold.tie_break_segments:
            continue
        flip = cold.tie_break_segments[:1]
        flipped = fwd.solve_forward(sk, t, length, mirror_flip=flip)
        assert flipped.angles[flip[0]] == -cold.angles[flip[0]]
        assert flipped.tension == cold.tension and flipped.converged
    with pytest.raises(ValueError, match='finite'):
        fwd.solve_forward(sk, t, hi - 10.0, initial=np.full(11, np.nan))


@pytest.mark.parametrize('n_ribs, pattern', [(6, ['R3', 'L3', 'R1']), (192, ['R1', 'R2', 'R3', 'R2'])])
def test_other_skeletons_match_the_batch_engine(n_ribs, pattern):
    # 6 ribs: short sums; 192 ribs: 191 segments, numpy's pairwise summation blocks.
    sk = Skeleton(n_ribs=n_ribs)
    t = (pattern * n_ribs)[:n_ribs]
    lo, hi = fwd.reachable_range(sk, t)
    lengths = hi - np.array([1e-6, 0.1, 0.5, 0.9, 0.999]) * (hi - lo)
    batch = fwd.solve_forward_batch(sk, t, lengths)
    for i, length in enumerate(lengths):
        res = fwd.solve_forward(sk, t, length)
        assert res.converged and batch.converged[i]
        curv = min(res.min_curvature, 1.0)
        assert np.max(np.abs(res.angles - batch.angles[i])) <= 2e-14 / curv + 1e-14


def test_constraint_sum_is_numpys_summation_order():
    # The single solve sums segment lengths in np.add.reduce's order, so its constraint
    # residual is bit-identical to the batch engine's (the certification decisions agree).
    rng = np.random.default_rng(5)
    for n in list(range(0, 40)) + [127, 128, 129, 191, 300, 1000]:
        values = rng.uniform(1.0, 20.0, n) * np.exp(rng.uniform(-20.0, 0.0, n))
        assert _sum(values.tolist()) == np.add.reduce(values), n
    # Signed values over 26 decades make every change of order show in the last bits:
    # long lists (numpy's blocks of 128 and its halving at multiples of 8), and slices
    # that start inside a list, as the batch layout hands them.
    for start in range(4):              # every short count, from inside a list too
        for count in range(0, 300):
            for _ in range(5):          # a changed order shows in about a third of draws
                values = rng.normal(size=start + count) * np.exp(
                    rng.uniform(-30.0, 30.0, start + count))
                assert _sum(values.tolist(), start, count) == np.add.reduce(values[start:]), \
                    (start, count)
    for _ in range(200):
        n = int(rng.integers(1, 3000))
        values = rng.normal(size=n) * np.exp(rng.uniform(-30.0, 30.0, n))
        assert _sum(values.tolist()) == np.add.reduce(values), n
        start = int(rng.integers(0, n))
        count = int(rng.integers(0, n - start + 1))
        part = values[start:start + count]
        assert _sum(values.tolist(), start, count) == np.add.reduce(part), (n, start, count)


@pytest.mark.parametrize('thickness', [3.0, 0.0])
def test_the_plain_float_path_stands_on_its_own(thickness):
    """The single solve without its fallback to the batch engine: over the same edges of
    the range (contact, buckling, mirror segments held straight, near straight) it must
    certify by itself and give the batch engine's answer, cold and from a warm start.
    (With the fallback a broken fast path would still answer right, only slower.)"""
    sk = Skeleton(rib_thickness_mm=thickness)
    rng = np.random.default_rng(23)
    n_solves = n_steps = 0
    for t in _threadings(rng, 12):
        lo, hi = fwd.reachable_range(sk, t)
        lengths = _lengths(rng, lo, hi, 8)
        batch = fwd.solve_forward_batch(sk, t, lengths)
        _, S = fwd._single(sk, tuple(sk.threading_mm(t).tolist()))
        for i, length in enumerate(lengths):
            if batch.slack[i]:
                continue        # slack lengths are answered before the single solve
            out = fwd._solve_single(S, float(length), fallback=False)
            n_solves += 1
            n_steps += out['iterations'] > 0
            assert out['converged'], (t, length)
            curv = min(float(batch.min_curvature[i]), 1.0)
            assert np.max(np.abs(out['angles'] - batch.angles[i])) <= 2e-14 / curv + 2e-15
            tol = 1e-12 * max(out['tension'], 1.0) / curv
            assert abs(out['tension'] - batch.tension[i]) <= tol
            assert np.array_equal(out['at_contact'], batch.at_contact[i]), (t, length)
            assert out['residual'] == max(out['constraint_residual'],
                                          out['stationarity_residual'])
            assert out['min_curvature'] == pytest.approx(float(batch.min_curvature[i]), rel=1e-6)
            # A warm start at the answer costs no more Newton steps and changes nothing.
            warm = fwd._solve_single(S, float(length), out['tension'], out['angles'],
                                     fallback=False)
            assert warm['converged'] and warm['iterations'] <= out['iterations']
            assert np.max(np.abs(warm['angles'] - out['angles'])) <= 2e-14 / curv + 2e-15
    assert n_solves > 150 and n_steps > 10, (n_solves, n_steps)
