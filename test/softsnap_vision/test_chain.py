"""Rib order by walking the spine: exact answers on hand-made point sets."""
from __future__ import annotations

import math

import numpy as np
import pytest

from softsnap_model import Skeleton, solve_forward
from softsnap_vision.chain import FrameError, base_frame, order_ribs

SK = Skeleton()


def walk(points, first=0):
    return order_ribs(points, first, 12, SK.spacing_mm, SK.contact_angle_rad, math.radians(50.0),
                      2, 1.5)


def bent():
    holes = ['R3'] * 12
    return solve_forward(SK, holes, SK.straight_length_mm(holes) - 40.0).rib_centers


def test_shuffled_points_come_back_in_rib_order():
    ribs = bent()
    perm = np.random.default_rng(0).permutation(12)
    result = walk(ribs[perm], first=int(np.flatnonzero(perm == 0)[0]))
    assert [int(perm[j]) for j in result.point_index] == list(range(12))
    assert result.stopped == ''


def test_gaps_of_one_and_two_are_stepped_over_three_stop():
    ribs = bent()
    keep = [i for i in range(12) if i not in (3, 7, 8)]
    result = walk(ribs[keep])
    got = [None if j is None else keep[j] for j in result.point_index]
    assert got == [i if i in keep else None for i in range(12)]
    keep = [i for i in range(12) if i not in (4, 5, 6)]
    result = walk(ribs[keep])
    assert [None if j is None else keep[j] for j in result.point_index] == \
        [0, 1, 2, 3] + [None] * 8
    assert 'no rib marker after rib 3' in result.stopped


def test_a_decoy_at_the_next_ribs_distance_makes_it_ambiguous_not_guessed():
    ribs = bent()
    d = ribs[3] - ribs[2]
    turn = np.array([[math.cos(0.3), -math.sin(0.3)], [math.sin(0.3), math.cos(0.3)]])
    decoy = ribs[2] + turn @ d
    result = walk(np.vstack([ribs, decoy]))
    assert result.point_index[:3] == (0, 1, 2)
    assert all(j is None for j in result.point_index[3:])
    assert 'ambiguous' in result.stopped


def test_base_frame_refuses_a_hidden_rib_0():
    ribs = np.array([[18.0 * i, 0.0] for i in range(1, 12)])
    with pytest.raises(FrameError, match='rib 0 marker not found'):
        base_frame((-30.0, 0.0), ribs, 30.0, 2.5)
    frame = base_frame((-30.0, 0.0), np.vstack([[0.0, 0.0], ribs]), 30.0, 2.5)
    assert frame.first_rib_index == 0 and np.allclose(frame.x_axis, [1.0, 0.0])
