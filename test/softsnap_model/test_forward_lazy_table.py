"""The lazily built path table (issue 17, first solve of a new threading): a table built
block by block, in any order, gives the same solutions bit for bit as one built in full,
and the caches stay bounded over many threadings."""
import itertools
import threading

import numpy as np
import pytest

import softsnap_model.forward as fwd
from softsnap_model import Skeleton
from softsnap_model.forward import path as fpath
from softsnap_model.forward import path_table as ptable
from softsnap_model.forward import start_polynomials
from softsnap_model.reference import PAPER_THREADINGS

SKELETONS = (Skeleton(), Skeleton(rib_thickness_mm=0.0))
# The paper's threadings, one with every segment a mirror segment (a plateau at the
# start of the path: nothing bends before the first buckling) and a few 7-rib ones.
THREADINGS = ([list(t) for t in PAPER_THREADINGS.values()] + [['R3', 'L3'] * 6]
              + [['R1'] * 5 + list(tail) for tail in
                 (('R3',) * 7, ('R1', 'R2', 'R3', 'L3', 'R3', 'L1', 'R2'), ('L2', 'R2') * 3
                  + ('L1',))])


def forget_tables():
    """Forget every per-threading table; the shared pair profiles stay (a full and a
    lazy table are then built from the same profiles)."""
    for cached in (fwd._problem, fwd._single, fwd._single_named, fwd._threading_cached):
        cached.cache_clear()


def key(sk, t):
    return tuple(sk.threading_mm(t).tolist())


def lengths_of(sk, t, n, seed):
    lo, hi = fwd.reachable_range(sk, t)
    rng = np.random.default_rng(seed)
    # Random order, and both ends of the range.
    return np.concatenate([[lo + 1e-9, hi - 1e-9], rng.uniform(lo, hi, n)])


@pytest.mark.parametrize('sk', SKELETONS, ids=('thick ribs', 'thin ribs'))
def test_partly_built_table_gives_the_full_tables_solutions_bit_for_bit(sk):
    n_solves = n_partial = 0
    for seed, t in enumerate(THREADINGS):
        lengths = lengths_of(sk, t, 25, seed)
        forget_tables()
        lazy = [fwd.solve_forward(sk, t, length) for length in lengths]
        table = fwd._problem(sk, key(sk, t)).path
        n_partial += not table.complete_
        built = table._sample_built.copy()
        cells = np.array(table._cell_built)
        exact, b, poly = table._exact.copy(), table.b.copy(), table.poly.copy()
        forget_tables()
        full = fwd._problem(sk, key(sk, t)).path.complete()
        # Every entry built lazily is the full build's entry, exactly.
        assert np.array_equal(exact[built], full._exact[built])
        assert np.array_equal(b[built], full.b[built])
        assert cells.any() and np.array_equal(poly[cells], full.poly[cells])
        assert built[:-1][cells].all() and built[1:][cells].all()
        for length, res in zip(lengths, lazy):
            ref = fwd.solve_forward(sk, t, length)
            assert res.converged and ref.converged
            assert np.array_equal(res.angles, ref.angles), (t, length)
            assert res.tension == ref.tension and res.iterations == ref.iterations
            n_solves += 1
    assert n_partial >= len(THREADINGS) - 2     # the lazy tables were partial indeed
    assert n_solves == 27 * len(THREADINGS)


def test_lazy_single_solves_agree_with_the_batch_solver():
    # Independent of the single-solve path: the batch engine, on the full table, with
    # its own start search and vectorised Newton.
    sk = SKELETONS[0]
    for seed, t in enumerate(THREADINGS[:9]):
        lengths = lengths_of(sk, t, 20, 100 + seed)
        forget_tables()
        single = np.array([fwd.solve_forward(sk, t, length).angles for length in lengths])
        assert not fwd._problem(sk, key(sk, t)).path.complete_
        batch = fwd.solve_forward_batch(sk, t, lengths)
        assert batch.converged.all()
        assert np.max(np.abs(batch.angles - single)) <= 1e-12, t
        # The batch built the rest of the table; single solves still agree.
        assert fwd._problem(sk, key(sk, t)).path.complete_
        again = np.array([fwd.solve_forward(sk, t, length).angles for length in lengths])
        assert np.array_equal(again, single)


def test_first_solve_builds_only_a_small_part_of_the_table():
    sk = SKELETONS[1]
    for name in ('yellow', 'blue', 'red', 'snake', 'w'):
        t = list(PAPER_THREADINGS[name])
        forget_tables()
        fwd.solve_forward(sk, t, sk.straight_length_mm(t) - 30.0)
        table = fwd._problem(sk, key(sk, t)).path
        n = table.lam.size
        assert n > 200, name                           # a table worth building lazily
        assert table._sample_built.sum() <= 0.1 * n, (name, table._sample_built.sum(), n)
        assert sum(table._cell_built) <= 2 * ptable._BLOCK
        # The searchable lengths stay non-increasing, built or not.
        assert np.all(table.len[1:] <= table.len[:-1])
        assert table.len_list == table.len.tolist()
        assert table.neg_len_list == (-table.len).tolist()


def test_concurrent_first_solves_of_one_threading_agree_with_sequential_ones():
    sk = SKELETONS[0]
    t = list(PAPER_THREADINGS['blue'])
    lengths = lengths_of(sk, t, 40, 7)
    forget_tables()
    expected = [fwd.solve_forward(sk, t, length).angles for length in lengths]
    forget_tables()
    got = [None] * len(lengths)

    def work(part):
        for i in part:
            got[i] = fwd.solve_forward(sk, t, lengths[i]).angles

    workers = [threading.Thread(target=work, args=(range(j, len(lengths), 3),))
               for j in range(3)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert all(np.array_equal(g, e) for g, e in zip(got, expected))


def test_loop_over_every_7_rib_threading_builds_each_table_once_and_stays_small():
    # 3^7 = 2187 threadings (the benchmark's loop): each table is built once, lazily,
    # kept by the cache (2560 threadings), and a second pass rebuilds nothing.
    sk = SKELETONS[1]
    ts = [['R1'] * 5 + list(tail) for tail in itertools.product(('R1', 'R2', 'R3'), repeat=7)]
    forget_tables()
    first = [fwd.solve_forward(sk, t, sk.straight_length_mm(t) - 20.0) for t in ts]
    info = fwd._problem.cache_info()
    assert info.currsize == len(ts) <= info.maxsize == fpath._THREADINGS_CACHED
    misses = (fwd._problem.cache_info().misses, fwd._single.cache_info().misses)
    second = [fwd.solve_forward(sk, t, sk.straight_length_mm(t) - 20.0) for t in ts]
    assert (fwd._problem.cache_info().misses, fwd._single.cache_info().misses) == misses
    assert all(np.array_equal(a.angles, b.angles) for a, b in zip(first, second))
    # Lazily built: a small part of each table's entries computed; the memory a table
    # holds is bounded (its arrays are allocated in full, about 0.3 MB at most).
    tables = [fwd._problem(sk, key(sk, t)).path for t in ts[::97]]
    assert max(tb._sample_built.mean() for tb in tables) <= 0.5
    nbytes = max(sum(a.nbytes for a in (tb.len, tb._exact, tb.b, tb._derivs, tb.poly))
                 for tb in tables)
    assert nbytes <= 0.35e6, nbytes


def test_a_cells_float_polynomial_is_the_numpy_tables_bit_for_bit():
    # A single solve builds its cell's start polynomial in plain floats
    # (start_polynomials._cell_polynomial), a batch the whole table's in numpy: every cell
    # of whole tables, built both ways, over random 12-rib threadings and the paper's.
    rng = np.random.default_rng(17)
    holes = list(SKELETONS[0].holes_mm)
    threadings = THREADINGS[:9] + [list(rng.choice(holes, 12)) for _ in range(12)]
    n_cells = n_numpy = 0
    for i, t in enumerate(threadings):
        sk = SKELETONS[i % 2]
        forget_tables()
        table = fwd._problem(sk, key(sk, t)).path.complete()
        for j in range(table.n_cells):
            at = slice(j, j + 2)
            try:
                rows = start_polynomials._cell_polynomial(
                    table.lam[at].tolist(), table._exact[at].tolist(), table.b[at].tolist(),
                    table._derivs[:, at].tolist(), *table._seg_lists)
            except ArithmeticError:     # built by numpy then (a zero denominator)
                n_numpy += 1
                continue
            assert np.array_equal(np.array(rows), table.poly[j], equal_nan=True), (t, j)
            # The sign of a zero too (the stored bits).
            assert np.array_equal(np.signbit(rows), np.signbit(table.poly[j])), (t, j)
            n_cells += 1
    assert n_cells > 9000 and n_numpy < 0.02 * n_cells


def test_a_single_solves_float_samples_are_the_numpy_tables_bit_for_bit():
    # A single first solve builds its cell's two or three samples in plain floats
    # (path_table._path_samples_float), a block or a whole table builds them in numpy
    # (path_table._path_samples): every sample of whole tables, built both ways. The cases:
    # the paper's threadings, every segment a mirror one (straight before buckling),
    # random 12-rib threadings on thick and thin ribs, uneven stiffness, and holes at
    # the rib's ends (coinciding holes: branches ending at their shortest length).
    rng = np.random.default_rng(6)
    uneven = Skeleton(stiffness=tuple(rng.uniform(0.5, 2.0, 11)))
    ends = Skeleton(rib_thickness_mm=0.0,
                    holes_mm={'E': 12.5, 'R2': 6.0, 'R1': 3.0, 'L1': -3.0, 'L2': -6.0})
    cases = [(SKELETONS[i % 2], t) for i, t in enumerate(THREADINGS)]
    for sk in SKELETONS + (uneven, ends):
        names = list(sk.holes_mm)
        cases += [(sk, list(rng.choice(names, 12))) for _ in range(6)]
    cases += [(ends, ['E'] * 4 + list(rng.choice(list(ends.holes_mm), 8))) for _ in range(4)]
    n_samples = n_numpy = n_outside = 0
    kinds = set()
    for sk, t in cases:
        forget_tables()
        with np.errstate(all='ignore'):     # coinciding holes: pair profiles divide 0 by 0
            prob = fwd._problem(sk, key(sk, t))
        kinds.update(prob.kind)
        table = prob.path.complete()
        rows = ptable._float_rows(table.seg)
        k, count = table._seg_lists[0], table._seg_lists[3]
        for j, lam in enumerate(table.lam.tolist()):
            try:
                (total, b, lp, lpp, l3), = ptable._path_samples_float(
                    [lam], rows, k, count, table.s, table.straight)
            except (ptable._HardEntry, ArithmeticError):   # built by numpy then (rare)
                n_numpy += 1
                continue
            got = np.array([b, lp, lpp, l3])
            ref = np.concatenate([table.b[j][None], table._derivs[:, j]])
            assert total == table._exact[j], (t, j)
            assert np.array_equal(got, ref), (t, j)
            assert np.array_equal(np.signbit(got), np.signbit(ref)), (t, j)
            mu = [lam / x for x in k]
            n_outside += sum(m <= row[3] or m >= row[4] for m, row in zip(mu, rows))
            n_samples += 1
    assert {'contact', 'shortest'} <= kinds
    assert n_samples > 15000 and n_numpy < 0.02 * n_samples
    assert n_outside > 0.1 * n_samples      # straight (before buckling) and at the ends


def test_a_float_built_cell_is_the_full_tables_cell():
    # The first solve of a length builds its cell's samples in floats: the same entries,
    # cell polynomial and solution as a table built in full, on random threadings.
    rng = np.random.default_rng(11)
    sk = SKELETONS[0]
    n_float = 0
    for _ in range(40):
        t = list(rng.choice(list(sk.holes_mm), 12))
        lo, hi = fwd.reachable_range(sk, t)
        length = rng.uniform(lo, hi)
        forget_tables()
        res = fwd.solve_forward(sk, t, length)
        table = fwd._problem(sk, key(sk, t)).path
        built = table._sample_built.copy()
        n_float += bool(table._run_lists) and built.sum() <= 2 * ptable._GUESS_CELLS
        exact, b, derivs = table._exact.copy(), table.b.copy(), table._derivs.copy()
        cells = np.array(table._cell_built)
        poly = table.poly[cells].copy()
        forget_tables()
        full = fwd._problem(sk, key(sk, t)).path.complete()
        assert np.array_equal(exact[built], full._exact[built])
        assert np.array_equal(b[built], full.b[built])
        assert np.array_equal(derivs[:, built], full._derivs[:, built])
        assert np.array_equal(poly, full.poly[cells])
        ref = fwd.solve_forward(sk, t, length)
        assert np.array_equal(res.angles, ref.angles) and res.tension == ref.tension
    assert n_float >= 30        # most first solves built only a few samples, in floats


def test_a_first_solve_builds_its_own_cell_and_hardly_more():
    sk = SKELETONS[0]
    # The guess of the cell from approximate lengths is verified, so a bad guess would
    # still answer right, only by building blocks of 16 samples or the whole table. The
    # guess is good: a new threading's first solve builds its cell's two samples (three
    # at most here), each time, at random lengths of every paper threading, and the
    # answer is the full table's.
    rng = np.random.default_rng(1)
    sizes = []
    for t in PAPER_THREADINGS.values():
        for _ in range(12):
            fwd.clear_caches()
            lo, hi = fwd.reachable_range(sk, list(t))
            length = hi - rng.uniform(0.001, 0.999) * (hi - lo)
            res = fwd.solve_forward(sk, list(t), length)
            _, S = fwd._single(sk, tuple(sk.threading_mm(list(t)).tolist()))
            sizes.append(int(S['path']._sample_built.sum()))
            assert res.converged and res.iterations <= 1
            full = fwd.solve_forward_batch(sk, list(t), [length])
            assert np.max(np.abs(res.angles - full.angles[0])) <= 2e-14 / min(
                float(full.min_curvature[0]), 1.0) + 2e-15
    assert max(sizes) <= ptable._GUESS_CELLS and min(sizes) == 2, sorted(set(sizes))


def test_a_cell_whose_quintic_leaves_its_hull_falls_back_alike_in_both_builders():
    # Real cells with an end slope corrupted (l' of the wrong sign at one end): the quintic
    # through them overshoots the cell, and both builders, the float one of a single
    # solve and numpy's of whole tables, must fall back to the same linear interpolant,
    # bit for bit.
    sk = SKELETONS[0]
    n_linear = n_cells = 0
    for t in THREADINGS[:6]:
        forget_tables()
        table = fwd._problem(sk, key(sk, t)).path.complete()
        seg = table.seg
        for j in range(0, table.n_cells, 7):
            at = slice(j, j + 2)
            derivs = table._derivs[:, at].copy()
            derivs[0, 1] *= -1.0                  # l' at the cell's end with the wrong sign
            lam, exact, b = table.lam[at], table._exact[at], table.b[at]
            with np.errstate(all='ignore'):
                reference = start_polynomials._path_polynomials(
                    lam, exact, b, derivs[0], derivs[1], derivs[2], seg['k'], seg['lam_c'],
                    seg['lam_end'], seg['count'])[0]
            try:
                rows = np.array(start_polynomials._cell_polynomial(
                    lam.tolist(), exact.tolist(), b.tolist(), derivs.tolist(),
                    *table._seg_lists))
            except ArithmeticError:
                continue
            n_cells += 1
            assert np.array_equal(rows, reference, equal_nan=True), (t, j)
            p0 = np.concatenate([b[0], lam[:1]])
            p1 = np.concatenate([b[1], lam[1:]])
            if not rows[2:].any():
                n_linear += 1
                assert np.array_equal(rows[0], p0) and np.array_equal(rows[1], p1 - p0)
    assert n_cells > 50 and n_linear > 20, (n_cells, n_linear)


def test_single_solves_at_the_edges_build_blocks_lazily_and_agree_with_the_full_table():
    # Next to straight and next to full contraction many cells lie within the guess's
    # margin, so a first solve there builds whole blocks (or, at a length the guess
    # cannot place, more); solves in any order on a fresh table, each against the
    # answer of the table completed afterwards.
    rng = np.random.default_rng(4)
    fracs = [1e-12, 1e-9, 1e-6, 1e-4, 0.5, 0.999, 1.0 - 1e-6, 1.0 - 1e-9]
    n_partial = 0
    for sk in SKELETONS:
        for t in THREADINGS:
            fwd.clear_caches()
            lo, hi = fwd.reachable_range(sk, t)
            order = rng.permutation(len(fracs))
            lengths = [hi - fracs[i] * (hi - lo) for i in order]
            lazy = [fwd.solve_forward(sk, t, length) for length in lengths]
            _, S = fwd._single(sk, tuple(sk.threading_mm(t).tolist()))
            n_partial += not S['path'].complete_
            full = fwd.solve_forward_batch(sk, t, lengths)     # completes the same table
            assert S['path'].complete_
            for i, res in enumerate(lazy):
                assert res.converged, (t, lengths[i])
                curv = min(float(full.min_curvature[i]), 1.0)
                assert np.max(np.abs(res.angles - full.angles[i])) <= 2e-14 / curv + 2e-15, \
                    (t, lengths[i])
    assert n_partial >= len(THREADINGS), n_partial      # most tables stayed partial


@pytest.mark.parametrize('guess', ['no cell guess', 'no guess at all'])
def test_the_block_builds_behind_a_failed_guess_give_the_full_tables_answers(monkeypatch, guess):
    # The cell guess almost always places a length (then a first solve builds two
    # samples). Where it cannot, whole blocks are built, chosen by a coarser guess, or
    # every block between the built samples: forced here by a guess margin below zero
    # (and, for the second case, approximate lengths that bracket nothing).
    monkeypatch.setattr(ptable, '_GUESS_MARGIN_MM', -1.0)
    if guess == 'no guess at all':
        monkeypatch.setattr(ptable._PathTable, '_approx_lengths',
                            lambda self, lam: np.full(np.shape(lam), np.nan))
    rng = np.random.default_rng(9)
    n_blocks = 0
    for t in THREADINGS:
        sk = SKELETONS[0]
        fwd.clear_caches()
        lo, hi = fwd.reachable_range(sk, t)
        lengths = list(hi - rng.uniform(0.0, 1.0, 6) * (hi - lo))
        lazy = [fwd.solve_forward(sk, t, length) for length in lengths]
        _, S = fwd._single(sk, tuple(sk.threading_mm(t).tolist()))
        built = int(S['path']._sample_built.sum())
        n_blocks += built > 6 * 3
        full = fwd.solve_forward_batch(sk, t, lengths)
        for i, res in enumerate(lazy):
            assert res.converged, (t, lengths[i])
            curv = min(float(full.min_curvature[i]), 1.0)
            assert np.max(np.abs(res.angles - full.angles[i])) <= 2e-14 / curv + 2e-15
    assert n_blocks == len(THREADINGS), n_blocks      # blocks were built, not cells
