"""Rib thickness: the contact angle from the geometry of two rigid rib slabs."""
import math

import numpy as np
import pytest

from softsnap_model import Skeleton, reachable_range, segment_length, solve_forward
from softsnap_model.reference import PAPER_THREADINGS
from softsnap_model.skeleton import DEFAULT_RIB_THICKNESS_MM, contact_angle


def inner_corners(a, s, rib_length, t):
    """Facing inner corners of rib 0 and rib 1 (slabs of thickness t) for a bend a > 0.

    Built from the FACTS.md rib-centre recursion, independently of the contact formula:
    rib k's centre line is normal to the spine at P_k, its face towards the other rib is
    the centre line moved t/2 along the spine, and the inner end is on the concave side.
    """
    p0 = np.zeros(2)
    chord = s * math.sin(a / 2) / (a / 2)
    p1 = chord * np.array([math.cos(a / 2), math.sin(a / 2)])
    tangent0, tangent1 = np.array([1.0, 0.0]), np.array([math.cos(a), math.sin(a)])
    left0, left1 = np.array([0.0, 1.0]), np.array([-math.sin(a), math.cos(a)])
    c0 = p0 + 0.5 * t * tangent0 + 0.5 * rib_length * left0
    c1 = p1 - 0.5 * t * tangent1 + 0.5 * rib_length * left1
    return c0, c1


def test_default_is_the_cad_thickness():
    sk = Skeleton()
    assert sk.rib_thickness_mm == DEFAULT_RIB_THICKNESS_MM == 3.0
    # 201 mm skeleton = 11 pitches of 18 mm + one rib thickness (FACTS.md).
    assert sk.n_segments * sk.spacing_mm + sk.rib_thickness_mm == 201.0


def test_thin_ribs_give_the_paper_contact_angle_exactly():
    assert Skeleton(rib_thickness_mm=0.0).contact_angle_rad == 2.0 * 18.0 / 25.0
    assert contact_angle(18.0, 25.0, 0.0) == 1.44
    assert contact_angle(100.0, 25.0, 0.0) == math.pi


@pytest.mark.parametrize('s, rib_length, t', [(18.0, 25.0, 3.0), (18.0, 25.0, 9.0),
                                               (12.0, 30.0, 1.5), (18.0, 25.0, 0.0)])
def test_inner_corners_meet_at_the_contact_angle(s, rib_length, t):
    a_c = contact_angle(s, rib_length, t)
    c0, c1 = inner_corners(a_c, s, rib_length, t)
    assert np.linalg.norm(c0 - c1) < 1e-9
    # Just before contact the corners are apart and the gap closes as the bend grows.
    gaps = [np.linalg.norm(np.subtract(*inner_corners(a, s, rib_length, t)))
            for a in (0.9 * a_c, 0.99 * a_c)]
    assert gaps[0] > gaps[1] > 0.0


def test_first_order_value_leaves_a_gap():
    # (s - t) / (l/2) = 1.20 rad is the first-order estimate: the drawn ribs still have
    # a 0.35 mm gap there; they touch at 1.2311 rad.
    a_c = Skeleton().contact_angle_rad
    assert a_c == pytest.approx(1.231107, abs=1e-6)
    c0, c1 = inner_corners(1.2, 18.0, 25.0, 3.0)
    assert np.linalg.norm(c0 - c1) == pytest.approx(0.347, abs=0.002)


def test_thick_ribs_shrink_the_reachable_range():
    t = PAPER_THREADINGS['yellow']
    thin, thick = Skeleton(rib_thickness_mm=0.0), Skeleton()
    lo0, hi0 = reachable_range(thin, t)
    lo3, hi3 = reachable_range(thick, t)
    assert hi0 == hi3
    assert hi0 - lo0 == pytest.approx(83.02, abs=0.01)
    # Every segment at contact (all bend clockwise: right-side holes).
    d = thick.threading_mm(t)
    full = float(np.sum(segment_length(-thick.contact_angle_rad, d[:-1], d[1:], 18.0)))
    assert lo3 == pytest.approx(full, abs=1e-9)
    assert hi3 - lo3 == pytest.approx(70.37, abs=0.01)
    # Lengths both skeletons reach give the same shape until a thick segment hits contact.
    # (to rounding: the start tables are sampled up to each skeleton's contact angle).
    assert np.allclose(solve_forward(thin, t, hi0 - 20.0).angles,
                       solve_forward(thick, t, hi0 - 20.0).angles, rtol=0, atol=1e-12)
    res = solve_forward(thick, t, lo3 + 0.5)
    assert res.converged and res.at_contact.any()
    assert np.max(np.abs(res.angles)) == thick.contact_angle_rad


def test_serialisation_and_validation():
    sk = Skeleton(rib_thickness_mm=2.5)
    data = sk.to_dict()
    assert data['rib_thickness_mm'] == 2.5
    assert Skeleton.from_dict(data) == sk
    assert Skeleton.from_dict({k: v for k, v in data.items() if k != 'rib_thickness_mm'}) \
        == Skeleton(rib_thickness_mm=DEFAULT_RIB_THICKNESS_MM)
    assert hash(sk) != hash(Skeleton()) and sk != Skeleton()
    for bad in (-0.1, 18.0, 20.0, math.nan, math.inf, True, '3'):
        with pytest.raises(ValueError, match='rib_thickness_mm'):
            Skeleton(rib_thickness_mm=bad)
