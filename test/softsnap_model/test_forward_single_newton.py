"""The plain-float single solve's own machinery (forward/single.py), each part on its own:
its Newton iteration from poor starts (bisection, clamping, kicks), its iteration count
against the batch engine's, a warm start from angles alone (the derived tension), the
certification of an unpolished table start, and lengths exactly at the path table's
nodes. test_forward_single.py checks the answers; a fast path that reaches them slowly,
or only through its fallback to the batch engine, fails here."""

import bisect
import math

import numpy as np
import pytest

import softsnap_model.forward as fwd
from softsnap_model import Skeleton
from softsnap_model.forward import single
from softsnap_model.forward.newton import _CONSTRAINT_ULPS, _INNER_TOL_MM, _INNER_TOL_RAD, _guess_b

from test_forward_single import _lengths, _residuals_of, _threadings


def _cases(thickness=3.0, seed=23, n_random=12, n_lengths=8):
    """(threading, its problem data, lengths, batch result) over the edges of the range."""
    sk = Skeleton(rib_thickness_mm=thickness)
    rng = np.random.default_rng(seed)
    for t in _threadings(rng, n_random):
        lo, hi = fwd.reachable_range(sk, t)
        lengths = _lengths(rng, lo, hi, n_lengths)
        batch = fwd.solve_forward_batch(sk, t, lengths)
        _, S = fwd._single(sk, tuple(sk.threading_mm(t).tolist()))
        keep = ~batch.slack
        yield sk, t, S, lengths[keep], batch, np.flatnonzero(keep)


def _bracket(S, length):
    """The exact tension bracket of the path cell of ``length`` (as _solve_single finds it)."""
    S['path'].ensure(length)
    j = min(max(bisect.bisect_left(S['neg_path_len_list'], -length), 1), S['n_path'] - 1)
    return float(S['path_lam'][j - 1]), float(S['path_lam'][j])



def test_newton_from_poor_starts_converges_to_the_batch_answer():
    # Starts at both ends of the cell's tension bracket, its middle and far outside it
    # (angles from the tables at that tension): Newton steps that leave the bracket are
    # bisected, angles pushed past contact or below straight are clamped, mirror segments
    # past buckling are kicked onto their branch. Every start must end certified at the
    # batch engine's answer.
    n_runs = n_long = 0
    for sk, t, S, lengths, batch, index in _cases():
        sc = single._scalars(S)
        for length, i in zip(lengths, index):
            length = float(length)
            lam_lo, lam_hi = _bracket(S, length)
            tol_mm = max(_INNER_TOL_MM, _CONSTRAINT_ULPS * math.ulp(length))
            starts = [(lam0, False) for lam0 in (lam_lo, lam_hi, 0.5 * (lam_lo + lam_hi),
                                                  2.0 * lam_hi + 1.0)]
            if sc.has_mirror:
                starts.append((2.0 * lam_hi + 1.0, True))   # mirror segments straight
            for lam0, straight in starts:
                with np.errstate(all='ignore'):
                    b0 = _guess_b(S['P'], np.array([lam0]))[0]
                b0 = np.nan_to_num(b0, nan=0.0)
                if straight:
                    # On the trivial root, unstable past buckling: Newton must kick them.
                    b0[sc.mirror_idx] = 0.0
                b0 = b0.tolist()
                st = single._newton_single(S, sc, length, lam0, b0, lam_lo, lam_hi, 60,
                                           tol_mm, _INNER_TOL_RAD)
                n_runs += 1
                n_long += st['iters'] > 4
                assert abs(st['g']) <= tol_mm, (t, length, lam0, st)
                assert st['stat'] <= _INNER_TOL_RAD and st['curv_min'] > 0, (t, length, lam0)
                assert lam_lo <= st['lam'] <= lam_hi
                assert all(0.0 <= x <= end for x, end in zip(st['b'], sc.b_end))
                angles = np.array([d * x for d, x in zip(sc.direction, st['b'])])
                curv = min(float(batch.min_curvature[i]), 1.0)
                assert np.max(np.abs(angles - batch.angles[i])) <= 2e-14 / curv + 2e-15
                contact = (np.zeros(sc.n, bool) if st['contact'] is None
                           else np.array(st['contact']))
                assert np.array_equal(contact, batch.at_contact[i]), (t, length, lam0)
    # The far starts took many steps (the bisection ran), not only the easy ones.
    assert n_runs > 1000 and n_long > 50, (n_runs, n_long)


@pytest.mark.parametrize('thickness', [3.0, 0.0])
def test_cold_solves_take_the_batch_engines_newton_steps(thickness):
    # The same iteration as the batch engine's: a table start certified there is also
    # certified here, or polished by exactly one step (the single solve asks for the
    # residual within 1e-14 rad times the curvature, the batch for 1e-14 rad); otherwise
    # both take the same number of steps. A start prepared worse (a mirror segment not
    # kicked onto its branch) shows as extra steps.
    n_steps = 0
    for sk, t, S, lengths, batch, index in _cases(thickness):
        for length, i in zip(lengths, index):
            out = single._solve_single(S, float(length), fallback=False)
            it_batch = int(batch.iterations[i])
            assert out['converged'], (t, length)
            if it_batch > 0:
                assert out['iterations'] == it_batch, (t, length, out['iterations'], it_batch)
            else:
                assert out['iterations'] <= 1, (t, length, out['iterations'])
            n_steps += it_batch > 0
    assert n_steps > 10, n_steps


@pytest.mark.parametrize('thickness', [3.0, 0.0])
def test_a_warm_start_from_angles_alone_needs_no_newton_step(thickness):
    # Angles without a tension: the tension is derived from them (least squares over the
    # bent, free segments) and must certify them as they are, with no Newton step, at
    # any point whose curvature is not tiny (next to buckling the 1e-14 rad target is
    # tighter than a derived tension can meet, and Newton polishes).
    n_warm = 0
    for sk, t, S, lengths, batch, index in _cases(thickness):
        for length, i in zip(lengths, index):
            cold = single._solve_single(S, float(length), fallback=False)
            warm = single._solve_single(S, float(length), None, cold['angles'],
                                        fallback=False)
            assert warm['converged']
            if cold['min_curvature'] >= 0.05:
                n_warm += 1
                assert warm['iterations'] == 0, (t, length, cold['min_curvature'])
                assert warm['tension'] == pytest.approx(cold['tension'], rel=1e-12, abs=1e-12)
                assert np.max(np.abs(warm['angles'] - cold['angles'])) <= 1e-15
                # With its tension as well: taken as it is.
                given = single._solve_single(S, float(length), cold['tension'],
                                             cold['angles'], fallback=False)
                assert given['iterations'] == 0 and given['tension'] == cold['tension']
    assert n_warm > 300, n_warm


def test_an_unpolished_table_start_is_certified_only_when_it_is_an_answer():
    # max_iter = 0: the table's start as it is. Whatever the solve calls converged must
    # pass residuals recomputed by the geometry module; the few starts that are not close
    # enough must say so (not converged), and without the fallback nothing repairs them.
    n_yes = n_no = 0
    for sk, t, S, lengths, batch, index in _cases():
        for length in lengths:
            out = single._solve_single(S, float(length), max_iter=0, fallback=False)
            assert out['iterations'] == 0
            constraint, stat = _residuals_of(sk, t, out['angles'], out['tension'],
                                                      out['at_contact'], float(length))
            certified = (constraint <= fwd.CONSTRAINT_TOL_MM
                         and stat <= fwd.STATIONARITY_TOL_RAD and out['is_minimum'])
            if out['converged']:
                n_yes += 1
                assert certified, (t, length, constraint, stat)
            else:
                n_no += 1
                assert not (out['stationarity_residual'] <= fwd.STATIONARITY_TOL_RAD
                            and out['constraint_residual'] <= fwd.CONSTRAINT_TOL_MM
                            and out['min_curvature'] > 0)
            # With the fallback, the same request is always answered certified.
            full = single._solve_single(S, float(length), max_iter=0)
            assert full['converged']
    assert n_yes > 300, n_yes


def test_lengths_exactly_at_the_path_tables_nodes():
    # A node of the path table is an event (a segment reaching contact, a mirror segment
    # buckling, a cell end) where the answer's tension is the cell's bracket end. There
    # the plain path can fail to certify: from a start rejected by a hair its Newton
    # steps cycle across the kink. Then the batch engine must answer instead, and every
    # node (both skeletons, mirror threadings included) comes out certified and equal to
    # the batch engine's answer.
    n_nodes = n_alone = 0
    for thickness in (3.0, 0.0):
        for sk, t, S, lengths, batch, index in _cases(thickness, seed=5, n_random=4,
                                                      n_lengths=4):
            nodes = np.array(S['path_len_list'])
            lo, hi = fwd.reachable_range(sk, t)
            nodes = nodes[(nodes > lo) & (nodes < hi)]
            picks = nodes[np.linspace(0, len(nodes) - 1, min(len(nodes), 12)).astype(int)]
            ref = fwd.solve_forward_batch(sk, t, picks)
            for j, length in enumerate(picks):
                alone = single._solve_single(S, float(length), fallback=False)
                out = single._solve_single(S, float(length))
                n_nodes += 1
                n_alone += bool(alone['converged'])
                assert out['converged'] and ref.converged[j], (t, length)
                constraint, stat = _residuals_of(
                    sk, t, out['angles'], out['tension'], out['at_contact'], float(length))
                assert constraint <= fwd.CONSTRAINT_TOL_MM and stat <= fwd.STATIONARITY_TOL_RAD
                assert np.max(np.abs(out['angles'] - ref.angles[j])) <= 1e-12
    # Most nodes the plain path certifies alone; a few need the batch engine.
    assert n_nodes > 100 and n_nodes - 20 <= n_alone < n_nodes, (n_nodes, n_alone)


def test_uneven_stiffness_on_the_plain_path():
    # Uniform stiffness (k = 1) hides a k in the wrong place: with a stiffness of its own
    # per segment the plain path alone must give the batch engine's answer.
    rng = np.random.default_rng(31)
    sk = Skeleton(stiffness=tuple(rng.uniform(0.5, 2.0, 11).tolist()))
    n_solves = 0
    for t in _threadings(rng, 6):
        lo, hi = fwd.reachable_range(sk, t)
        lengths = _lengths(rng, lo, hi, 6)
        lengths = lengths[lengths < hi]
        batch = fwd.solve_forward_batch(sk, t, lengths)
        _, S = fwd._single(sk, tuple(sk.threading_mm(t).tolist()))
        for i, length in enumerate(lengths):
            out = single._solve_single(S, float(length), fallback=False)
            n_solves += 1
            assert out['converged'], (t, length)
            curv = min(float(batch.min_curvature[i]), 1.0)
            assert np.max(np.abs(out['angles'] - batch.angles[i])) <= 2e-14 / curv + 2e-15
            assert out['tension'] == pytest.approx(batch.tension[i], rel=1e-12 / curv)
            assert out['energy'] == pytest.approx(
                float(np.sum(np.asarray(sk.stiffness_array) * batch.angles[i] ** 2)), rel=1e-12)
    assert n_solves > 100, n_solves
