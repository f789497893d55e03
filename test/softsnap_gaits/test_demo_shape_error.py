"""The demo's simulated-versus-predicted shape error (--physics), on known shapes.

Regression for issue 16's demo figure: a simulated snapshot was compared with the latest
predicted shape received, whose cable length was another one while a winch moved.
"""
import numpy as np
import pytest

from softsnap_gaits.demo import SETTLED_SNAPSHOTS, ModuleStats, simulated_shape_errors_mm
from softsnap_model.forward import solve_forward
from softsnap_model.scene import load_scene

SCENE = load_scene('brittle_star')
YELLOW = SCENE.module('yellow')


def shape_m(length_mm: float, shift_mm=(0.0, 0.0)) -> np.ndarray:
    """solve_forward's rib centres for `length_mm`, as sim_robot sends them: (12, 3) m."""
    planar = np.asarray(solve_forward(SCENE.skeleton, YELLOW.threading_mm, length_mm).rib_centers)
    planar = planar + np.asarray(shift_mm)
    return np.column_stack((planar, np.zeros(len(planar)))) / 1000.0


def test_snapshot_is_compared_with_the_shape_of_its_own_cable_length():
    straight = YELLOW.straight_length_mm
    s = ModuleStats()
    # The latest predicted shape received is for 10 mm less cable than the snapshot has:
    # it must not be what the snapshot is compared with.
    s.predicted_tips = [(0, (straight - 20.0) / 1000.0, np.asarray(
        solve_forward(SCENE.skeleton, YELLOW.threading_mm, straight - 20.0).angles))]
    s.simulated_shapes = [(shape_m(straight - 10.0), (straight - 10.0) / 1000.0),
                          (shape_m(straight - 10.0, (0.0, 3.0)), (straight - 10.0) / 1000.0)]
    errors, settled = simulated_shape_errors_mm(s, SCENE.skeleton, YELLOW.threading_mm)
    # The same shape: 0; every rib 3 mm off: an RMS of 3 mm.
    assert errors == pytest.approx([0.0, 3.0], abs=1e-6)
    assert settled == [False, False]
    # Against the 20 mm shape the first snapshot would be far off (what the old pairing did).
    other = shape_m(straight - 20.0)
    assert np.sqrt(np.mean(np.sum((other - s.simulated_shapes[0][0]) ** 2, axis=1))) * 1e3 > 5.0


def test_settled_once_the_cable_length_held_for_the_settling_snapshots():
    straight = YELLOW.straight_length_mm
    held, moving = straight - 15.0, straight - 16.0
    lengths = [moving] + [held] * (SETTLED_SNAPSHOTS + 2) + [moving, moving]
    s = ModuleStats()
    s.simulated_shapes = [(shape_m(length), length / 1000.0) for length in lengths]
    errors, settled = simulated_shape_errors_mm(s, SCENE.skeleton, YELLOW.threading_mm)
    assert len(errors) == len(lengths) and max(errors) < 1e-6
    # The first held snapshot starts the count; SETTLED_SNAPSHOTS equal ones after it.
    expected = [False] * (SETTLED_SNAPSHOTS + 1) + [True, True] + [False, False]
    assert settled == expected


def test_a_length_the_model_refuses_is_skipped_not_fatal():
    straight = YELLOW.straight_length_mm
    s = ModuleStats()
    s.simulated_shapes = [(shape_m(straight - 5.0), (straight - 5.0) / 1000.0),
                          (shape_m(straight - 5.0), 0.001)]   # 1 mm of cable: unreachable
    errors, settled = simulated_shape_errors_mm(s, SCENE.skeleton, YELLOW.threading_mm)
    assert errors == pytest.approx([0.0], abs=1e-6) and settled == [False]
