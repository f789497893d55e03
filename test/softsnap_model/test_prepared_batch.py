"""PreparedBatch: the model node's per-tick batch solve, tables stacked once (issue 17).

Every row must be what solve_forward gives for it alone, whatever else is stacked or
solved in the same call, and a bad row is refused with solve_forward's reason while the
other rows are solved.
"""
import functools

import numpy as np
import pytest

from softsnap_model import (Skeleton, InfeasibleLengthError, solve_forward, solve_forward_batch,
                            sweep)
from softsnap_model.forward import PreparedBatch, PreparedBatchResult, reachable_range
from softsnap_model.forward import batch as batch_module
from softsnap_model.forward import newton as newton_module
from softsnap_model.predictor import RobotPredictor
from softsnap_model.reference import PAPER_THREADINGS
from softsnap_model.scene import load_scene

SK = Skeleton()
PAPER = {name: list(PAPER_THREADINGS[name]) for name in ('yellow', 'blue', 'red', 's', 'w')}
ALTERNATING = ['R3', 'L3'] * 6      # mirror segments: straight until they buckle


def assert_rows_match_single_solves(result, threadings, lengths):
    assert isinstance(result, PreparedBatchResult)
    for i, (t, length) in enumerate(zip(threadings, lengths)):
        single = solve_forward(SK, t, length)
        np.testing.assert_allclose(result.angles[i], single.angles, rtol=0, atol=1e-12)
        np.testing.assert_allclose(result.rib_centers[i], single.rib_centers, rtol=0,
                                   atol=1e-9)
        np.testing.assert_allclose(result.cable_path[i], single.cable_path, rtol=0, atol=1e-9)
        assert result.tension[i] == pytest.approx(single.tension, rel=1e-9, abs=1e-15)
        assert result.converged[i] == single.converged
        assert result.slack[i] == single.slack
        assert result.is_minimum[i] == single.is_minimum
        assert np.array_equal(result.at_contact[i], single.at_contact)
        assert result.cable_length_mm[i] == length
        assert result.refused[i] == ''


def test_rows_equal_single_solves_over_many_random_ticks():
    names = list(PAPER) + ['alternating']
    table = {**PAPER, 'alternating': ALTERNATING}
    prepared = PreparedBatch(SK, [tuple(t) for t in table.values()])
    assert prepared.restacks == 1 and len(prepared.threadings) == 6
    rng = np.random.default_rng(17)
    for _ in range(15):
        picked = [table[names[k]] for k in rng.integers(0, len(names), 10)]
        low = np.array([reachable_range(SK, t)[0] for t in picked])
        straight = np.array([SK.straight_length_mm(t) for t in picked])
        # From slack (above straight) down to 0.5 mm above the reachable minimum.
        lengths = low + 0.5 + rng.uniform(0.0, 1.02) * (straight - low)
        result = prepared.solve([tuple(t) for t in picked], lengths)
        assert_rows_match_single_solves(result, picked, lengths)
        batch = solve_forward_batch(SK, picked, lengths)
        np.testing.assert_allclose(result.angles, batch.angles, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(result.tie_break, batch.tie_break)
    assert prepared.restacks == 1    # nothing new was seen: never restacked


def test_a_threading_change_between_ticks_restacks_once_and_keeps_answers():
    prepared = PreparedBatch(SK, [tuple(PAPER['yellow']), tuple(PAPER['red'])])
    tick = [tuple(PAPER['yellow']), tuple(PAPER['red'])]
    first = prepared.solve(tick, [180.0, 175.0])
    assert_rows_match_single_solves(first, tick, [180.0, 175.0])
    # A module re-threaded: a new threading in the next tick (given by names, as a
    # list), the old ones still there.
    changed = [tuple(PAPER['yellow']), PAPER['s'], tuple(PAPER['red'])]
    result = prepared.solve(changed, [181.0, 170.0, 176.0])
    assert prepared.restacks == 2
    assert_rows_match_single_solves(result, changed, [181.0, 170.0, 176.0])
    # The same threading as offsets is the same stacked entry: no restack.
    offsets = SK.threading_mm(PAPER['s'])
    again = prepared.solve([offsets, tuple(offsets.tolist())], [171.0, 172.0])
    assert prepared.restacks == 2 and len(prepared.threadings) == 3
    assert_rows_match_single_solves(again, [PAPER['s']] * 2, [171.0, 172.0])
    # Back to the first tick: the first answers exactly.
    back = prepared.solve(tick, [180.0, 175.0])
    np.testing.assert_array_equal(back.angles, first.angles)


def test_bad_rows_are_refused_with_the_single_solve_reason_and_do_not_poison_others():
    low, straight = reachable_range(SK, PAPER['red'])
    threadings = [PAPER['yellow'], PAPER['red'], PAPER['red'], ['R9'] * 12, PAPER['blue'],
                  PAPER['blue'], PAPER['w'], PAPER['red'], ALTERNATING]
    lengths = [175.0, low, low - 5.0, 170.0, np.nan, np.inf, 178.0, -1.0, 280.0]
    prepared = PreparedBatch(SK)
    result = prepared.solve(threadings, lengths)
    refused = [i for i, reason in enumerate(result.refused) if reason]
    assert refused == [1, 2, 3, 4, 5, 7]
    for i in refused:
        with pytest.raises(ValueError) as error:
            solve_forward(SK, threadings[i], lengths[i])
        assert result.refused[i].endswith(str(error.value)), (i, result.refused[i])
        assert np.isnan(result.angles[i]).all() and np.isnan(result.rib_centers[i]).all()
        assert not result.converged[i] and np.isnan(result.tension[i])
    with pytest.raises(InfeasibleLengthError):
        solve_forward(SK, PAPER['red'], low)
    assert 'reachable range' in result.refused[1] and 'unknown hole' in result.refused[3]
    good = [0, 6, 8]
    sub = PreparedBatch(SK).solve([threadings[i] for i in good], [lengths[i] for i in good])
    for i, j in zip(good, range(3)):
        assert result.refused[i] == ''
        np.testing.assert_array_equal(result.angles[i], sub.angles[j])
        single = solve_forward(SK, threadings[i], lengths[i])
        np.testing.assert_allclose(result.angles[i], single.angles, rtol=0, atol=1e-12)
        assert result.converged[i]
    # Every row bad, or nothing known at all: still an answer, never an exception.
    none = PreparedBatch(SK).solve([['R9'] * 12, ['X'] * 12], [170.0, 170.0])
    assert all(none.refused) and not none.converged.any() and none.angles.shape == (2, 11)
    assert len(PreparedBatch(SK).solve([], [])) == 0


def test_malformed_calls_raise_value_error_quoting_the_value():
    prepared = PreparedBatch(SK, [PAPER['red']])
    with pytest.raises(ValueError, match='expected 2 threadings'):
        prepared.solve([PAPER['red']], [170.0, 171.0])
    with pytest.raises(ValueError, match='must be 1-D'):
        prepared.solve([PAPER['red']], [[170.0]])
    with pytest.raises(ValueError, match='max_iter must be an integer >= 0, got -1'):
        prepared.solve([PAPER['red']], [170.0], max_iter=-1)
    with pytest.raises(ValueError, match='unknown hole'):
        PreparedBatch(SK, [['R9'] * 12])
    with pytest.raises(ValueError, match='skeleton must be a Skeleton'):
        PreparedBatch('not a skeleton')


def test_more_threadings_than_kept_restack_from_the_call_alone(monkeypatch):
    monkeypatch.setattr(batch_module, 'PREPARED_THREADINGS', 2)
    prepared = PreparedBatch(SK, [PAPER['yellow'], PAPER['red']])
    threadings = [PAPER['s'], PAPER['w'], PAPER['s']]
    result = prepared.solve(threadings, [170.0, 172.0, 174.0])
    assert len(prepared.threadings) == 2 and prepared.restacks == 2
    assert_rows_match_single_solves(result, threadings, [170.0, 172.0, 174.0])
    result = prepared.solve([PAPER['yellow']], [176.0])
    assert_rows_match_single_solves(result, [PAPER['yellow']], [176.0])
    # Regression: one call with more distinct threadings than kept recursed forever.
    many = [PAPER['yellow'], PAPER['red'], PAPER['s'], PAPER['w']]
    result = prepared.solve(many, [175.0, 172.0, 170.0, 168.0])
    assert len(prepared.threadings) == 4
    assert_rows_match_single_solves(result, many, [175.0, 172.0, 170.0, 168.0])


def test_predictor_refuses_a_bad_group_at_tick_time_and_solves_the_others():
    # Regression: the batched predictor used to re-solve a whole tick one by one when one
    # length was refused. A length exactly at the reachable minimum passes submit (it
    # refuses only lengths below it) but the solver refuses it: that group alone fails.
    scene = load_scene('brittle_star')
    predictor = RobotPredictor(scene)
    blue_low = predictor.reachable_mm['blue'][0]
    for m in scene.modules:
        predictor.submit('commanded', m.name, m.straight_length_mm - 20.0)
        predictor.submit('predicted', m.name, blue_low if m.name == 'blue'
                         else m.straight_length_mm - 25.0)
    updated = predictor.tick(rib_centers=True)
    assert len(updated['commanded']) == 5 and len(updated['predicted']) == 4
    assert [(module, source) for module, source, _ in predictor.errors] == [('blue', 'predicted')]
    assert 'reachable range' in predictor.errors[0][2]
    assert predictor.counters.refused == 1
    for shape in updated['predicted']:
        single = solve_forward(scene.skeleton, scene.module(shape.module).threading_mm,
                               shape.cable_length_mm)
        np.testing.assert_allclose(shape.angles, single.angles, rtol=0, atol=1e-12)
    assert predictor.shapes('predicted')[scene.module_names.index('blue')] is None


class _NewtonCalls:
    """Counts calls of newton._newton: none in a solve means it took the early exit."""

    def __init__(self, monkeypatch):
        self.calls = 0
        newton = newton_module._newton

        def counted(*args, **kwargs):
            self.calls += 1
            return newton(*args, **kwargs)
        monkeypatch.setattr(newton_module, '_newton', counted)

    def exited_early(self, solve):
        """(solve(), whether it took the early exit)."""
        before = self.calls
        result = solve()
        return result, self.calls == before


def _with_the_full_loop(monkeypatch, solve):
    """solve() with the early exit turned off in every batch entry point."""
    with monkeypatch.context() as patch:
        patch.setattr(batch_module, '_solve_arrays',
                      functools.partial(newton_module._solve_arrays, early_exit=False))
        return solve()


def assert_bit_identical(result, full):
    assert type(result) is type(full)
    for name, value in vars(full).items():
        got = getattr(result, name)
        if isinstance(value, np.ndarray):
            assert got.dtype == value.dtype and got.shape == value.shape, name
            assert got.tobytes() == value.tobytes(), name    # bits, incl. the sign of 0
        else:
            assert got == value, name


def test_a_certified_table_start_exits_before_newton_and_is_the_full_loop_bit_for_bit(
        monkeypatch):
    # Issue 17, seventh pass: most ticks' table starts are the answer already; the solver
    # core then certifies Newton's first evaluation without entering its loop, and every
    # field must be what the loop gives, in every batch entry point. Starts that need a
    # Newton step take the loop.
    table = {**PAPER, 'alternating': ALTERNATING}
    names = list(table)
    prepared = PreparedBatch(SK, [tuple(t) for t in table.values()])
    newton = _NewtonCalls(monkeypatch)
    rng = np.random.default_rng(6)
    taken = declined = 0
    for _ in range(60):
        picked = [table[names[k]] for k in rng.integers(0, len(names), 10)]
        low = np.array([reachable_range(SK, t)[0] for t in picked])
        straight = np.array([SK.straight_length_mm(t) for t in picked])
        # Down to 1e-6 mm above the minimum (contact), up to just below straight; one
        # tick in six has a slack row.
        lengths = low + np.exp(rng.uniform(np.log(1e-6), 0.0, 10)) * (straight - low) * 0.999
        if rng.uniform() < 1 / 6:
            lengths[rng.integers(0, 10)] = straight[0] + 1.0
        rows = [tuple(t) for t in picked]
        for solve in (lambda: prepared.solve(rows, lengths),
                      lambda: solve_forward_batch(SK, picked, lengths)):
            result, early = newton.exited_early(solve)
            assert_bit_identical(result, _with_the_full_loop(monkeypatch, solve))
            if early:
                taken += 1
                assert not result.iterations.any() and result.converged.all()
            else:
                declined += 1
                assert result.iterations.any()
    assert taken >= 40 and declined >= 10, (taken, declined)
    # A sweep of a threading without mirror segments, short of contact: one early exit.
    low, top = reachable_range(SK, PAPER['red'])
    contractions = np.linspace(1.0, 0.9 * (top - low), 50)
    result, early = newton.exited_early(lambda: sweep(SK, PAPER['red'], contractions))
    assert early and not result.iterations.any()
    assert_bit_identical(result, _with_the_full_loop(
        monkeypatch, lambda: sweep(SK, PAPER['red'], contractions)))


def test_the_early_exit_takes_slack_rows_and_declines_mirror_buckling_rows(monkeypatch):
    newton = _NewtonCalls(monkeypatch)
    prepared = PreparedBatch(SK, [tuple(PAPER['yellow']), tuple(ALTERNATING)])
    straight = SK.straight_length_mm(PAPER['yellow'])
    rows = [tuple(PAPER['yellow'])] * 2
    taut, early = newton.exited_early(lambda: prepared.solve(rows, [straight - 20.0] * 2))
    assert early
    # A slack row is straight at zero tension, not iterated: it does not stop the exit.
    for lengths in ([straight - 20.0, straight + 1.0], [straight - 20.0, straight]):
        result, early = newton.exited_early(lambda: prepared.solve(rows, lengths))
        assert early and result.slack.tolist() == [False, True]
        assert result.converged.all() and result.tension[1] == 0.0
        assert not result.angles[1].any()
        assert_bit_identical(result, _with_the_full_loop(
            monkeypatch, lambda: prepared.solve(rows, lengths)))
        np.testing.assert_array_equal(result.angles[0], taut.angles[0])
    # Alternating threading: its mirror segments are straight until they buckle, then
    # restart on their own branch, where the start is poor and Newton steps; lengths
    # over the range cross that.
    low, top = reachable_range(SK, ALTERNATING)
    outcomes = []
    for length in np.linspace(low + 1e-3, top - 1e-3, 200):
        result, early = newton.exited_early(
            lambda: prepared.solve([tuple(ALTERNATING)], [length]))
        outcomes.append(early)
        assert_bit_identical(result, _with_the_full_loop(
            monkeypatch, lambda: prepared.solve([tuple(ALTERNATING)], [length])))
        assert result.converged[0] and (result.iterations[0] == 0) == early
    assert not all(outcomes) and any(outcomes)


def test_empty_and_malformed_batches_of_both_entry_points():
    # An empty call answers with empty arrays of the right shapes (n segments, n + 1
    # ribs, x and y); lengths that are not 1-D and a 2-D sweep are refused; max_iter 0
    # is a valid cap.
    n = SK.n_segments
    for result in (solve_forward_batch(SK, PAPER['red'], []), PreparedBatch(SK).solve([], [])):
        assert result.angles.shape == (0, n) and result.rib_centers.shape == (0, n + 1, 2)
        assert result.cable_path.shape == (0, n + 1, 2) and result.at_contact.shape == (0, n)
        assert result.iterations.dtype.kind == 'i' and result.converged.dtype == bool
    with pytest.raises(ValueError, match=r'cable_lengths_mm must be 1-D, got shape \(1, 1\)'):
        solve_forward_batch(SK, PAPER['red'], [[170.0]])
    with pytest.raises(ValueError, match=r'contractions_mm must be 1-D, got shape \(1, 2\)'):
        batch_module.sweep(SK, PAPER['red'], [[1.0, 2.0]])
    low, straight = reachable_range(SK, PAPER['red'])
    capped = PreparedBatch(SK).solve([PAPER['red']], [straight - 10.0], max_iter=0)
    assert capped.iterations[0] == 0 and capped.refused == ('',)


def test_prepared_rows_at_the_edges_of_the_range_equal_the_batch_solver():
    # Next to straight (the path's first cell), next to full contraction (its last) and
    # in between, for every paper threading and mirror-heavy ones: the prepared start
    # (one search over the joined path tables) finds the same cells.
    threadings = [list(t) for t in PAPER_THREADINGS.values()] + [['R3', 'L3'] * 6, ALTERNATING]
    prepared = PreparedBatch(SK, threadings)
    fracs = np.array([1e-12, 1e-9, 1e-6, 1e-3, 0.3, 0.7, 0.999, 1.0 - 1e-6, 1.0 - 1e-9])
    rows, lengths = [], []
    for t in threadings:
        low, straight = reachable_range(SK, t)
        rows += [t] * len(fracs)
        lengths += list(straight - fracs * (straight - low))
    result = prepared.solve(rows, lengths)
    assert not any(result.refused) and result.converged.all()
    for t in threadings:
        sel = [i for i, r in enumerate(rows) if r is t]
        ref = solve_forward_batch(SK, t, [lengths[i] for i in sel])
        curv = np.minimum(ref.min_curvature, 1.0)
        gap = np.max(np.abs(result.angles[sel] - ref.angles), axis=1)
        assert np.all(gap <= 2e-14 / curv + 2e-15), (t, gap.max())
        assert np.array_equal(result.iterations[sel], ref.iterations), t


def test_threadings_given_one_per_row_in_every_accepted_form():
    # A list of one threading, an empty list, and a list mixing an array of offsets with
    # names: each row as if solved alone.
    low, straight = reachable_range(SK, PAPER['red'])
    one = solve_forward_batch(SK, [PAPER['red']], [straight - 20.0])
    single = solve_forward(SK, PAPER['red'], straight - 20.0)
    np.testing.assert_allclose(one.angles[0], single.angles, rtol=0, atol=1e-12)
    assert len(solve_forward_batch(SK, [], [])) == 0
    offsets = SK.threading_mm(PAPER['blue'])
    mixed = solve_forward_batch(SK, [offsets, PAPER['red'], offsets], [175.0, 180.0, 176.0])
    for i, (t, length) in enumerate(((PAPER['blue'], 175.0), (PAPER['red'], 180.0),
                                     (PAPER['blue'], 176.0))):
        np.testing.assert_allclose(mixed.angles[i], solve_forward(SK, t, length).angles,
                                   rtol=0, atol=1e-12)
