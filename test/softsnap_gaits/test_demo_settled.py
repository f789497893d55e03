"""The demo's settled tip error: sampled at the end of every hold, on known streams."""
import math

import numpy as np
import pytest

from softsnap_gaits.demo import ModuleStats, running_tip_errors_mm, settled_tip_errors_mm

MS = 1_000_000  # ns


def stats_with(lengths_m, commanded, predicted, tick_ms=20):
    """Commands every `tick_ms` from t = 0; shapes as (stamp ms, length m, tip mm)."""
    s = ModuleStats()
    s.command_stamps_ns = [k * tick_ms * MS for k in range(len(lengths_m))]
    s.command_lengths_m = list(lengths_m)
    s.commanded_tips = [(t * MS, length, np.asarray(tip, float)) for t, length, tip in commanded]
    s.predicted_tips = [(t * MS, length, np.asarray(tip, float)) for t, length, tip in predicted]
    return s


# A step: straight (0.2 m) for 5 ticks, a ramp of 3 ticks, 0.17 m for 6 ticks, a ramp of
# 3 ticks back, straight for 4 ticks. Holds end at ticks 4 (0 ms + 80) and 13 (260 ms).
LENGTHS = [0.2] * 5 + [0.19, 0.18, 0.175] + [0.17] * 6 + [0.175, 0.18, 0.19] + [0.2] * 4
END_OF_STRAIGHT_MS, END_OF_CONTRACTED_MS = 80, 260


def test_settled_error_is_taken_at_the_last_command_of_each_hold():
    commanded = [(0, 0.2, [200, 0, 0]), (100, 0.175, [190, 20, 0]), (180, 0.17, [180, 40, 0]),
                 (300, 0.18, [195, 10, 0])]
    # Predicted: the winch lags, then settles 3 mm from the commanded tip by 240 ms; a
    # later prediction (stamped after the hold ended) must not be used.
    predicted = [(0, 0.2, [201, 0, 0]), (150, 0.18, [190, 15, 0]), (240, 0.1701, [180, 43, 0]),
                 (270, 0.1701, [100, 0, 0])]
    s = stats_with(LENGTHS, commanded, predicted)
    errors = settled_tip_errors_mm(s, (0, 10**12))
    # End of the straight hold (80 ms): commanded [200, 0], predicted [201, 0] -> 1 mm.
    # End of the contracted hold (260 ms): commanded [180, 40], predicted [180, 43] -> 3 mm.
    assert errors == pytest.approx([1.0, 3.0])
    # The final straight hold is cut off by the end of the stream: no edge, no sample.
    assert len(errors) == 2


def test_only_step_ends_inside_the_window_count():
    commanded = [(0, 0.2, [200, 0, 0]), (180, 0.17, [180, 40, 0])]
    predicted = [(0, 0.2, [204, 0, 0]), (240, 0.17, [180, 42, 0])]
    s = stats_with(LENGTHS, commanded, predicted)
    assert settled_tip_errors_mm(s, (100 * MS, 10**12)) == pytest.approx([2.0])
    assert settled_tip_errors_mm(s, (0, 100 * MS)) == pytest.approx([4.0])
    assert settled_tip_errors_mm(s, (300 * MS, 10**12)) == []


def test_a_hold_without_its_own_commanded_shape_gives_no_sample():
    # The model node never solved 0.17 m (starved): the commanded shape in force is the
    # ramp's, which is not the held shape, so the contracted hold is skipped, not misjudged.
    commanded = [(0, 0.2, [200, 0, 0]), (120, 0.175, [190, 20, 0])]
    predicted = [(0, 0.2, [200, 0, 0]), (240, 0.17, [180, 40, 0])]
    s = stats_with(LENGTHS, commanded, predicted)
    assert settled_tip_errors_mm(s, (0, 10**12)) == pytest.approx([0.0])
    # No predicted shape before the first hold ends: no sample either.
    s = stats_with(LENGTHS, commanded, [(500, 0.2, [0, 0, 0])])
    assert settled_tip_errors_mm(s, (0, 10**12)) == []


def test_a_continuous_ease_has_no_hold_and_arrival_order_does_not_matter():
    t = np.arange(0, 50)
    ease = list(0.2 - 0.03 * (0.5 - 0.5 * np.cos(math.pi * t / 49)))   # never two equal
    s = stats_with(ease, [(0, 0.2, [0, 0, 0])], [(0, 0.2, [0, 0, 0])])
    assert settled_tip_errors_mm(s, (0, 10**12)) == []
    # Commands taken out of order (two topics, one executor) are sorted by stamp first.
    commanded = [(180, 0.17, [180, 40, 0]), (0, 0.2, [200, 0, 0])]
    predicted = [(240, 0.17, [180, 45, 0]), (0, 0.2, [200, 0, 0])]
    s = stats_with(LENGTHS, commanded, predicted)
    order = np.random.default_rng(1).permutation(len(LENGTHS))
    s.command_stamps_ns = [s.command_stamps_ns[i] for i in order]
    s.command_lengths_m = [s.command_lengths_m[i] for i in order]
    assert settled_tip_errors_mm(s, (0, 10**12)) == pytest.approx([0.0, 5.0])


def test_running_error_pairs_each_prediction_with_the_command_in_force():
    s = ModuleStats()
    s.commanded_tips = [(0, 0.2, np.array([0.0, 0.0, 0.0])), (10, 0.19, np.array([10.0, 0.0, 0.0]))]
    s.predicted_tips = [(5, 0.2, np.array([0.0, 3.0, 0.0])), (12, 0.195, np.array([10.0, 4.0, 0.0]))]
    s.tip_error_pairs = [(0, 0), (1, 1)]
    assert running_tip_errors_mm(s) == pytest.approx([3.0, 4.0])


def test_shapes_stored_as_angles_are_measured_at_their_tips():
    from softsnap_model.geometry import rib_centers
    straight, bent = np.zeros(11), np.full(11, -0.05)

    def tip(angles):
        return rib_centers(angles, 18.0)[-1]

    s = stats_with(LENGTHS, [(0, 0.2, straight), (180, 0.17, bent)],
                   [(0, 0.2, straight), (240, 0.17, bent)])
    assert settled_tip_errors_mm(s, (0, 10**12), tip) == pytest.approx([0.0, 0.0])
    s = stats_with(LENGTHS, [(0, 0.2, straight), (180, 0.17, bent)],
                   [(0, 0.2, bent), (240, 0.17, bent)])
    gap = float(np.linalg.norm(tip(straight) - tip(bent)))
    assert gap > 10.0
    assert settled_tip_errors_mm(s, (0, 10**12), tip) == pytest.approx([gap, 0.0])
