"""The batch engine's Newton and its robust fallback (forward/newton.py), each on its own:
Newton from poor starts in a mixed batch against the same rows solved one at a time
(its shrinking to the unconverged rows changes nothing, bit for bit, and never exceeds
the iteration cap), the robust fallback alone from a cell's bracket and from the whole
path's, and the early exit against the full loop. test_forward.py checks the answers of
the public calls; an engine that reaches them only through its fallback fails here."""

import numpy as np
import pytest

import softsnap_model.forward as fwd
from softsnap_model import Skeleton, segment_length_derivatives
from softsnap_model.forward import newton
from softsnap_model.forward.path import _problem, _stack

from test_forward_single import _lengths, _threadings


def _batches(thickness=3.0, seed=29, n_random=8, n_lengths=10, uneven=False):
    """(skeleton, threading, batch problem, non-slack lengths, reference result); with
    ``uneven`` each segment has its own stiffness (uniform stiffness hides a k in the
    wrong place: k = 1)."""
    rng = np.random.default_rng(seed)
    stiffness = tuple(rng.uniform(0.6, 1.6, 11).tolist()) if uneven else None
    sk = Skeleton(rib_thickness_mm=thickness, stiffness=stiffness)
    for t in _threadings(rng, n_random):
        lo, hi = fwd.reachable_range(sk, t)
        lengths = _lengths(rng, lo, hi, n_lengths)
        lengths = lengths[lengths < hi]
        ref = fwd.solve_forward_batch(sk, t, lengths)
        P = _stack([_problem(sk, tuple(sk.threading_mm(t).tolist()))],
                   np.zeros(len(lengths), dtype=int))
        yield sk, t, P, lengths, ref


def _rows(P, rows):
    return {key: (val[rows] if key in newton._PER_ITEM else val) for key, val in P.items()}


def _poor_starts(P, lengths):
    """The table start, but every other row restarted far above its bracket (angles from
    the tables there), and every fourth of those with its mirror segments straight."""
    lam, b, lam_lo, lam_hi = newton._start_from_table(P, lengths)
    poor = np.arange(len(lengths)) % 2 == 1
    lam = np.where(poor, 2.0 * lam_hi + 1.0, lam)
    b[poor] = np.nan_to_num(newton._guess_b(P, lam[poor], np.flatnonzero(poor)), nan=0.0)
    straight = np.arange(len(lengths)) % 4 == 3
    if P['has_mirror']:
        b[straight] = np.where(P['mirror'][straight], 0.0, b[straight])
    return lam, b, lam_lo, lam_hi, poor


def _certified(st):
    return ((np.abs(st['g']) <= fwd.CONSTRAINT_TOL_MM)
            & (st['stat'] <= fwd.STATIONARITY_TOL_RAD)
            & (np.where(st['contact'], np.inf, st['curv']).min(axis=1) > 0))


@pytest.mark.parametrize('uneven', [False, True])
@pytest.mark.parametrize('max_iter', [fwd.MAX_ITER, 3])
def test_a_mixed_batch_iterates_each_row_as_if_alone(max_iter, uneven):
    # Rows that start at the answer stop at once, the poor ones iterate: once at most
    # half the rows are left, Newton continues on those alone (a sub-batch). Every row
    # must take exactly the steps it takes alone, end bit for bit where it ends alone,
    # and never more than max_iter steps.
    n_rows = n_shrunk = n_poor_certified = 0
    with np.errstate(all='ignore'):
        for sk, t, P, lengths, ref in _batches(uneven=uneven):
            lam, b, lam_lo, lam_hi, poor = _poor_starts(P, lengths)
            tol_mm = newton._constraint_targets(lengths, newton._INNER_TOL_MM)
            st = newton._newton(P, lengths, lam.copy(), b.copy(), lam_lo, lam_hi, max_iter,
                                tol_mm, newton._INNER_TOL_RAD)
            assert np.all(st['iters'] <= max_iter)
            # Well-conditioned rows (curvature >= 1e-3; next to buckling 1e-12 mm needs a
            # tension finer than its ulp) certify from their table start within a step.
            good = ref.min_curvature >= 1e-3
            assert np.all(st['iters'][~poor & good] <= 1), t
            n_shrunk += int(np.count_nonzero(st['iters'] > np.median(st['iters'])))
            for i in range(len(lengths)):
                r = np.array([i])
                alone = newton._newton(_rows(P, r), lengths[r], lam[r].copy(), b[r].copy(),
                                       lam_lo[r], lam_hi[r], max_iter, tol_mm[r],
                                       newton._INNER_TOL_RAD)
                n_rows += 1
                assert st['iters'][i] == alone['iters'][0], (t, lengths[i])
                assert np.array_equal(st['b'][i], alone['b'][0]), (t, lengths[i])
                assert st['lam'][i] == alone['lam'][0]
            if max_iter == fwd.MAX_ITER:
                # From far above its bracket a well-conditioned row is bisected back and
                # certified at the answer (the ill-conditioned ones go to the fallback).
                ok = _certified(st)
                assert ok[good].all(), (t, lengths[good & ~ok])
                curv = np.minimum(ref.min_curvature, 1.0)
                gap = np.max(np.abs(P['direction'] * st['b'] - ref.angles), axis=1)
                assert np.all(gap[ok] <= 2e-14 / curv[ok] + 2e-15), t
                assert np.array_equal(st['contact'][ok], ref.at_contact[ok]), t
                n_poor_certified += int(np.count_nonzero(ok & poor))
            else:
                assert np.any(st['iters'][poor] == max_iter)   # the cap was reached
    assert n_rows > 100 and n_shrunk > 10, (n_rows, n_shrunk)
    assert max_iter < fwd.MAX_ITER or n_poor_certified > 40, n_poor_certified


def _constraint(P, lengths, b):
    seg, _, _ = segment_length_derivatives(P['direction'] * b, P['d1'], P['d2'], P['s'])
    return seg.sum(axis=1) - lengths


@pytest.mark.parametrize('uneven', [False, True])
@pytest.mark.parametrize('bracket', ['cell', 'whole path'])
def test_the_robust_fallback_alone_finds_the_answer(bracket, uneven):
    # Exact per-segment solves and a safeguarded Newton on the tension: from the path
    # cell's bracket, or from the whole path's (tension 0 to the path's last sample), it
    # must close in on the answer without the bordered Newton; four polishing steps then
    # certify it, as the fallback does.
    n_rows = 0
    with np.errstate(all='ignore'):
        for sk, t, P, lengths, ref in _batches(n_random=4, n_lengths=6, uneven=uneven):
            _, _, lam_lo, lam_hi = newton._start_from_table(P, lengths)
            if bracket == 'whole path':
                path_lam = P['paths'][0][1]
                lam_lo = np.full(len(lengths), float(path_lam[0]))
                lam_hi = np.full(len(lengths), float(path_lam[-1]))
            # Its Newton steps on the tension converge in a few iterations where
            # bisection alone would still be far off (2^-12 of a cell, 2^-30 of the path).
            lam, b, lo, hi = newton._robust(P, lengths, lam_lo.copy(), lam_hi.copy(),
                                            max_iter=12 if bracket == 'cell' else 30)
            assert np.all((lam_lo <= lo) & (lo <= lam) & (lam <= hi) & (hi <= lam_hi)), t
            # Well-conditioned rows (next to buckling the length is too steep in the
            # tension for 1e-9 mm: there it stops at the tension's resolution).
            good = ref.min_curvature >= 1e-3
            assert np.allclose(lam[good], ref.tension[good], rtol=1e-9, atol=1e-12), t
            assert np.all(np.abs(_constraint(P, lengths, b))[good] <= 1e-9), t
            tol_mm = newton._constraint_targets(lengths, newton._INNER_TOL_MM)
            st = newton._newton(P, lengths, lam, b, lo, hi, 4, tol_mm, newton._INNER_TOL_RAD)
            assert _certified(st)[good].all(), t
            curv = np.minimum(ref.min_curvature, 1.0)
            gap = np.max(np.abs(P['direction'] * st['b'] - ref.angles), axis=1)
            assert np.all(gap[good] <= 1e-12 / curv[good]), (t, gap.max())
            n_rows += int(np.count_nonzero(good))
    assert n_rows > 50, n_rows


@pytest.mark.parametrize('thickness', [3.0, 0.0])
def test_the_early_exit_is_the_full_loop_bit_for_bit(thickness):
    # When the table start already meets the inner targets the loop is skipped: the
    # answers must be those of running it.
    n_exits = 0
    with np.errstate(all='ignore'):
        for sk, t, P, lengths, ref in _batches(thickness, n_random=6):
            fast = newton._solve_arrays(P, lengths)
            full = newton._solve_arrays(P, lengths, early_exit=False)
            for key in ('angles', 'tension', 'iterations', 'converged', 'at_contact',
                        'constraint_residual', 'stationarity_residual', 'min_curvature'):
                assert np.array_equal(fast[key], full[key]), (t, key)
            n_exits += bool(np.all(fast['iterations'] == 0))
    assert n_exits > 5, n_exits


@pytest.mark.parametrize('uneven', [False, True])
def test_curvatures_per_segment_against_finite_differences(uneven):
    # 1 + lambda l''/(2k) per segment from the geometry module's lengths by central
    # differences: for free segments (whatever form the engine uses), for mirror
    # segments held straight (the snake's), next to buckling and at contact aside.
    n_held = n_free = 0
    h = 1e-4
    with np.errstate(all='ignore'):
        for sk, t, P, lengths, ref in _batches(n_random=4, uneven=uneven):
            st = newton._solve_arrays(P, lengths)
            lam, b, lo, hi = newton._start_from_table(P, lengths)
            tol_mm = newton._constraint_targets(lengths, newton._INNER_TOL_MM)
            state = newton._newton(P, lengths, ref.tension.copy(),
                                   np.abs(ref.angles) * 1.0, lo, hi, 0, tol_mm,
                                   newton._INNER_TOL_RAD)
            d = sk.threading_mm(t)
            k = np.asarray(sk.stiffness_array)
            for i in range(len(lengths)):
                for j in range(sk.n_segments):
                    if ref.at_contact[i, j]:
                        continue
                    a = ref.angles[i, j]
                    seg = [segment_length_derivatives(np.array([a + e]), d[j:j + 1],
                                                      d[j + 1:j + 2], sk.spacing_mm)[0][0]
                           for e in (-h, 0.0, h)]
                    lpp = (seg[0] - 2.0 * seg[1] + seg[2]) / (h * h)
                    expect = 1.0 + ref.tension[i] * lpp / (2.0 * k[j])
                    if abs(expect) < 0.05:
                        continue    # next to buckling the difference quotient is too coarse
                    assert state['curv'][i, j] == pytest.approx(expect, rel=2e-3, abs=2e-3), \
                        (t, lengths[i], j)
                    held = bool(state['held'][i, j])
                    n_held += held
                    n_free += not held
            assert np.allclose(st['min_curvature'], ref.min_curvature)
    assert n_held > 10 and n_free > 500, (n_held, n_free)


def test_slack_rows_in_a_batch():
    # Slack rows are straight, untensioned and not iterated; their curvature is the
    # formula's at zero tension, 1, as for the taut rows beside them.
    sk = Skeleton()
    t = ['R1', 'L1'] * 6
    lo, hi = fwd.reachable_range(sk, t)
    lengths = np.array([hi, hi + 5.0, 0.5 * (lo + hi), hi - 1.0])
    out = fwd.solve_forward_batch(sk, t, lengths)
    assert out.slack.tolist() == [True, True, False, False]
    assert np.all(out.min_curvature[:2] == 1.0) and np.all(out.tension[:2] == 0.0)
    assert np.all(out.angles[:2] == 0.0) and np.all(out.iterations[:2] == 0)
    assert out.converged.all() and np.all(out.min_curvature[2:] < 1.0)
