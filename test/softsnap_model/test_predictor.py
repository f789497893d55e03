"""RobotPredictor: the model node's core, tested directly with the real forward solver."""
import dataclasses
import math

import numpy as np
import pytest

from softsnap_model import geometry
from softsnap_model.forward import reachable_range, solve_forward
from softsnap_model.predictor import ModulePrediction, RobotPredictor
from softsnap_model.scene import load_scene


@pytest.fixture(scope='module')
def brittle_star():
    return load_scene('brittle_star')


@pytest.fixture(scope='module')
def snake():
    return load_scene('snake')


def straight(scene, name):
    return scene.module(name).straight_length_mm


def test_shapes_equal_direct_forward_solves(brittle_star):
    predictor = RobotPredictor(brittle_star)
    lengths = {m.name: m.straight_length_mm - 10.0 - 5.0 * i
               for i, m in enumerate(brittle_star.modules)}
    for name, length in lengths.items():
        predictor.submit('commanded', name, length, stamp_ns=42)
    updated = predictor.tick(rib_centers=True)
    assert [s.module for s in updated['commanded']] == list(brittle_star.module_names)
    assert updated['predicted'] == []
    for shape, module in zip(updated['commanded'], brittle_star.modules):
        direct = solve_forward(brittle_star.skeleton, module.threading_mm, lengths[module.name])
        np.testing.assert_allclose(shape.angles, direct.angles, atol=1e-9)
        np.testing.assert_allclose(shape.rib_centers_mm, direct.rib_centers, atol=1e-7)
        assert shape.cable_length_mm == lengths[module.name]
        assert shape.converged and shape.stamp_ns == 42
        assert shape.tension == pytest.approx(direct.tension, rel=1e-6)
    assert predictor.counters.solves == 5


def test_identical_modules_are_solved_once(snake):
    predictor = RobotPredictor(snake)
    length = straight(snake, 'head') - 30.0
    for name in snake.module_names:
        predictor.submit('commanded', name, length)
        predictor.submit('predicted', name, length)
    updated = predictor.tick()
    assert predictor.counters.solves == 1
    assert predictor.counters.skipped_duplicate == 9
    shapes = updated['commanded'] + updated['predicted']
    assert len(shapes) == 10
    for shape in shapes[1:]:
        np.testing.assert_array_equal(shape.angles, shapes[0].angles)
    assert sum(s.solve_time_s > 0 for s in shapes) == 1


def test_unchanged_length_is_not_solved_again(brittle_star):
    predictor = RobotPredictor(brittle_star, length_tol_mm=1e-3)
    length = straight(brittle_star, 'yellow') - 20.0
    predictor.submit('predicted', 'yellow', length)
    predictor.tick()
    predictor.submit('predicted', 'yellow', length + 5e-4)
    assert predictor.tick() == {'commanded': [], 'predicted': []}
    assert predictor.counters.solves == 1
    assert predictor.counters.skipped_unchanged == 1
    predictor.submit('predicted', 'yellow', length + 0.5)
    assert len(predictor.tick()['predicted']) == 1
    assert predictor.counters.solves == 2


def test_solves_are_warm_started_from_the_previous_shape(brittle_star):
    calls = []

    def recording_solver(skeleton, threading, length, initial=None):
        calls.append(None if initial is None else np.array(initial))
        return solve_forward(skeleton, threading, length, initial=initial)

    predictor = RobotPredictor(brittle_star, solver=recording_solver)
    for contraction in (10.0, 12.0):
        predictor.submit('commanded', 'green', straight(brittle_star, 'green') - contraction)
        predictor.tick()
    assert calls[0] is None
    first = solve_forward(brittle_star.skeleton, brittle_star.module('green').threading_mm,
                          straight(brittle_star, 'green') - 10.0)
    np.testing.assert_allclose(calls[1], first.angles, atol=1e-9)


def test_rib_centres_only_when_asked(brittle_star):
    predictor = RobotPredictor(brittle_star)
    predictor.submit('commanded', 'red', straight(brittle_star, 'red') - 15.0)
    predictor.submit('predicted', 'red', straight(brittle_star, 'red') - 16.0)
    updated = predictor.tick({'commanded': False, 'predicted': True})
    assert updated['commanded'][0].rib_centers_mm is None
    centers = updated['predicted'][0].rib_centers_mm
    assert centers.shape == (brittle_star.skeleton.n_ribs, 2)
    np.testing.assert_allclose(centers, geometry.rib_centers(updated['predicted'][0].angles,
                                                             brittle_star.skeleton.spacing_mm))
    assert predictor.counters.skipped_rib_points == 1


@pytest.mark.parametrize('module, length, reason', [
    ('nobody', 150.0, 'unknown module'),
    ('yellow', math.nan, 'finite'),
    ('yellow', math.inf, 'finite'),
    ('yellow', 1.0, 'reachable'),
])
def test_bad_lengths_are_refused_and_the_last_shape_kept(brittle_star, module, length, reason):
    predictor = RobotPredictor(brittle_star)
    good = straight(brittle_star, 'yellow') - 25.0
    predictor.submit('commanded', 'yellow', good)
    predictor.tick()
    before = predictor.shapes('commanded')[0]
    with pytest.raises(ValueError, match=reason):
        predictor.submit('commanded', module, length)
    assert predictor.counters.refused == 1
    assert predictor.tick() == {'commanded': [], 'predicted': []}
    assert predictor.shapes('commanded')[0] is before


def test_reachable_minimum_is_accepted_and_slack_is_straight(brittle_star):
    predictor = RobotPredictor(brittle_star)
    low, high = reachable_range(brittle_star.skeleton, brittle_star.module('blue').threading_mm)
    predictor.submit('commanded', 'blue', high + 3.0)
    shape = predictor.tick()['commanded'][0]
    np.testing.assert_allclose(shape.angles, 0.0, atol=1e-12)
    assert shape.tension == 0.0


def test_chained_modules_sit_on_their_parents_tips(snake):
    predictor = RobotPredictor(snake)
    # Straight: the scene's stated base poses.
    for (position, orientation), module in zip(predictor.base_poses('commanded'), snake.modules):
        np.testing.assert_allclose(position, module.base_position_m, atol=1e-9)
        np.testing.assert_allclose(np.abs(orientation), np.abs(module.base_orientation_xyzw),
                                   atol=1e-9)
    predictor.submit('commanded', 'tail', straight(snake, 'tail') - 40.0)
    predictor.tick(rib_centers=True)
    tail = predictor.shapes('commanded')[snake.module_names.index('tail')]
    poses = dict(zip(snake.module_names, predictor.base_poses('commanded')))
    # body4 is attached 50 mm beyond the tail's tip rib, along the tip's spine direction.
    heading = float(np.sum(tail.angles))
    tip_mm = tail.rib_centers_mm[-1]
    expected = (np.array([tip_mm[0], tip_mm[1], 0.0])
                + 50.0 * np.array([math.cos(heading), math.sin(heading), 0.0])) / 1000.0
    np.testing.assert_allclose(poses['body4'][0], expected, atol=1e-9)
    yaw = 2.0 * math.atan2(poses['body4'][1][2], poses['body4'][1][3])
    assert math.remainder(yaw - heading, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    # The head moved too (it rides on the chain), the tail did not.
    assert not np.allclose(poses['head'][0], snake.module('head').base_position_m)
    np.testing.assert_allclose(poses['tail'][0], snake.module('tail').base_position_m)


def test_without_skipping_every_length_is_solved_separately_with_rib_centres(snake):
    # Regression: the no-skip mode (the benchmark's reference) crashed on its group keys.
    predictor = RobotPredictor(snake, skip=False)
    length = straight(snake, 'head') - 30.0
    for _ in range(2):
        for name in snake.module_names:
            predictor.submit('commanded', name, length)
        updated = predictor.tick(rib_centers=False)
        assert len(updated['commanded']) == 5
        assert all(shape.rib_centers_mm is not None for shape in updated['commanded'])
    assert predictor.counters.solves == 10
    assert predictor.counters.skipped_duplicate == predictor.counters.skipped_unchanged == 0


def test_a_solver_refusal_at_tick_time_keeps_the_last_shape(brittle_star):
    def refusing_solver(skeleton, threading, length, initial=None):
        if length < 170.0:
            raise ValueError(f'refused {length}')
        return solve_forward(skeleton, threading, length, initial=initial)

    predictor = RobotPredictor(brittle_star, solver=refusing_solver)
    predictor.submit('predicted', 'yellow', 180.0)
    first = predictor.tick()['predicted'][0]
    predictor.submit('predicted', 'yellow', 160.0)
    assert predictor.tick() == {'commanded': [], 'predicted': []}
    assert predictor.shapes('predicted')[0] is first
    assert predictor.errors == [('yellow', 'predicted', 'refused 160.0')]
    assert predictor.counters.refused == 1


def test_one_batched_solve_per_tick_gives_the_shapes_of_single_solves(brittle_star):
    # Every module and source changes every tick: one solve_forward_batch call per tick
    # must give what one solve_forward per module gives (a slack length included).
    batched, single = RobotPredictor(brittle_star), RobotPredictor(brittle_star, batch=False)
    assert batched.batch and not single.batch
    for tick in range(3):
        for predictor in (batched, single):
            for i, m in enumerate(brittle_star.modules):
                contraction = -2.0 if (i == 3 and tick == 1) else 10.0 + 7.0 * i + 3.0 * tick
                predictor.submit('commanded', m.name, m.straight_length_mm - contraction)
                predictor.submit('predicted', m.name, m.straight_length_mm - contraction - 0.7)
        got, want = batched.tick(rib_centers=True), single.tick(rib_centers=True)
        for source in ('commanded', 'predicted'):
            assert [s.module for s in got[source]] == list(brittle_star.module_names)
            for a, b in zip(got[source], want[source]):
                np.testing.assert_allclose(a.angles, b.angles, atol=1e-9)
                np.testing.assert_allclose(a.rib_centers_mm, b.rib_centers_mm, atol=1e-7)
                assert a.cable_length_mm == b.cable_length_mm
                assert a.converged and b.converged
                assert a.tension == pytest.approx(b.tension, rel=1e-6, abs=1e-12)
                assert a.solve_time_s > 0.0
        if tick == 1:  # red's commanded length is slack: the straight shape
            assert got['commanded'][3].tension == 0.0
            np.testing.assert_array_equal(got['commanded'][3].angles, 0.0)
    assert batched.counters.solves == single.counters.solves == 30


def test_an_idle_tick_has_nothing_pending_and_returns_no_shapes(brittle_star):
    predictor = RobotPredictor(brittle_star)
    assert not predictor.has_pending
    predictor.submit('predicted', 'green', straight(brittle_star, 'green') - 12.0)
    assert predictor.has_pending
    assert len(predictor.tick()['predicted']) == 1
    assert not predictor.has_pending
    assert predictor.tick() == {'commanded': [], 'predicted': []}
    # The same length again is skipped at submit: still nothing pending.
    predictor.submit('predicted', 'green', straight(brittle_star, 'green') - 12.0)
    assert not predictor.has_pending and predictor.counters.skipped_unchanged == 1


def test_small_ticks_are_solved_one_by_one_and_large_ones_in_one_batch(brittle_star):
    # Issue 17, sixth pass: a batch call has a fixed cost of about four single solves,
    # so fewer than BATCH_MIN_PROBLEMS distinct problems go one by one. Both give the
    # certified shape (to rounding), and the same ticks give the same shapes every time.
    from softsnap_model.predictor import BATCH_MIN_PROBLEMS

    def feed(predictor, tick):
        # Tick t changes t modules' commanded lengths (1 to 5 problems).
        for i, m in enumerate(brittle_star.modules[:tick % 5 + 1]):
            predictor.submit('commanded', m.name, m.straight_length_mm - 10.0 - 3.0 * i - tick)
        return predictor.tick(rib_centers=True)['commanded']

    runs = []
    for _ in range(2):
        predictor = RobotPredictor(brittle_star)
        calls = []
        solve = predictor._batch_solver.solve
        predictor._batch_solver.solve = lambda *a, **k: calls.append(len(a[1])) or solve(*a, **k)
        shapes = [feed(predictor, tick) for tick in range(10)]
        assert calls == [5, 5], calls     # ticks 4 and 9 have five problems
        assert BATCH_MIN_PROBLEMS == 5
        runs.append(shapes)
        for tick_shapes in shapes:
            for shape in tick_shapes:
                want = solve_forward(brittle_star.skeleton,
                                     brittle_star.module(shape.module).threading_mm,
                                     shape.cable_length_mm)
                np.testing.assert_allclose(shape.angles, want.angles, rtol=0, atol=1e-12)
                np.testing.assert_allclose(shape.rib_centers_mm, want.rib_centers,
                                           rtol=0, atol=1e-9)
                assert shape.converged
    for first, second in zip(*runs):    # deterministic: bit-identical shapes
        for a, b in zip(first, second):
            assert a.module == b.module and np.array_equal(a.angles, b.angles)
            assert a.tension == b.tension


def test_tick_shapes_are_frozen_module_predictions_built_field_by_field(snake):
    # The tick builds its shapes without the dataclass's __init__ (its cost per shape):
    # they must still be whole, frozen ModulePredictions, equal to ones built by it.
    predictor = RobotPredictor(snake)
    names = list(snake.module_names)
    for i, name in enumerate(names):
        # The first two modules share a length (one solve, two shapes).
        contraction = 12.0 if i < 2 else 12.0 + 4.0 * i
        predictor.submit('commanded', name, straight(snake, name) - contraction, stamp_ns=7 + i)
    updated = predictor.tick(rib_centers={'commanded': True})
    field_names = [f.name for f in dataclasses.fields(ModulePrediction)]
    assert [s.module for s in updated['commanded']] == names
    for shape in updated['commanded']:
        assert type(shape) is ModulePrediction
        assert sorted(vars(shape)) == sorted(field_names)
        rebuilt = ModulePrediction(**{name: getattr(shape, name) for name in field_names})
        assert repr(rebuilt) == repr(shape)
        with pytest.raises(dataclasses.FrozenInstanceError):
            shape.cable_length_mm = 1.0
        assert shape.source == 'commanded' and shape.rib_centers_mm is not None
    stamps = [s.stamp_ns for s in updated['commanded']]
    assert stamps == [7 + i for i in range(len(names))]
    # The snake's first two modules share a threading: one solve, whose time goes with
    # one of its two shapes only.
    assert snake.module(names[0]).threading_mm == snake.module(names[1]).threading_mm
    first, second = updated['commanded'][:2]
    assert (first.solve_time_s > 0.0) != (second.solve_time_s > 0.0)
    assert predictor.counters.skipped_duplicate == 1
