"""Geometry: closed-form cable length vs independent geometric and mpmath references."""
import math

import mpmath as mp
import numpy as np
import pytest

from softsnap_model import Skeleton, cable_path, rib_centers, segment_length, \
    segment_length_derivatives

HOLES = [-10.0, -6.5, -3.0, -0.5, 0.5, 3.0, 6.5, 10.0]
ANGLES = [0.0, 1e-12, 1e-8, 1e-5, 1e-3, 0.1, -0.5, 1.0, -1.44, 2.0, 3.0, -3.14159, 3.5, 5.0]


def mp_length(a, d1, d2, s=18.0):
    a = mp.mpf(a)
    c = mp.mpf(1) if a == 0 else 2 * mp.sin(a / 2) / a
    return mp.sqrt((d1 - d2) ** 2 + c * c * (s + d1 * a) * (s + d2 * a))


def test_straight_length_is_hypot():
    for d1 in HOLES:
        for d2 in HOLES:
            assert segment_length(0.0, d1, d2, 18.0) == pytest.approx(math.hypot(18, d1 - d2),
                                                                      rel=1e-15)


@pytest.mark.parametrize('a', ANGLES)
def test_length_and_derivatives_match_mpmath(a):
    mp.mp.dps = 40
    for d1, d2 in [(10, 10), (10, -10), (3, 6.5), (-0.5, 0.5), (-10, 3), (0.0, 0.0)]:
        L, dL, d2L = segment_length_derivatives(a, d1, d2, 18.0)
        f = lambda x: mp_length(x, d1, d2)  # noqa: E731
        ref = [float(f(a)), float(mp.diff(f, a)), float(mp.diff(f, a, 2))]
        assert abs(L - ref[0]) <= 4e-15 * ref[0]
        assert abs(dL - ref[1]) <= 4e-15 * max(1.0, abs(ref[1]))
        assert abs(d2L - ref[2]) <= 4e-15 * max(1.0, abs(ref[2]))


def test_finite_differences_near_zero_are_smooth():
    # Central differences of the returned derivative agree with the second derivative
    # at and near a = 0: a precision-losing branch there would show as a jump.
    h = 1e-6
    for a in [-1e-8, 0.0, 1e-8, 1e-7, 3e-4]:
        for d1, d2 in [(10, -10), (3, 6.5), (-6.5, -6.5)]:
            L_p, dL_p, _ = segment_length_derivatives(a + h, d1, d2, 18.0)
            L_m, dL_m, _ = segment_length_derivatives(a - h, d1, d2, 18.0)
            _, dL, d2L = segment_length_derivatives(a, d1, d2, 18.0)
            assert (L_p - L_m) / (2 * h) == pytest.approx(dL, abs=1e-8)
            assert (dL_p - dL_m) / (2 * h) == pytest.approx(d2L, abs=1e-8)


@pytest.mark.parametrize('size_limit', ['_POW_MAX_SIZE', '_HORNER_MIN_SIZE'])
def test_large_arrays_match_mpmath_and_small_arrays(size_limit):
    # Larger arrays evaluate the near-zero series otherwise (repeated products, then
    # Horner's scheme); every way must meet the same mpmath contract, at and near a = 0.
    from softsnap_model import geometry
    mp.mp.dps = 40
    pairs = [(10, 10), (10, -10), (3, 6.5), (-0.5, 0.5), (-10, 3), (0.0, 0.0)]
    limit = getattr(geometry, size_limit)
    a = np.tile(np.array(ANGLES), limit // len(ANGLES) + 1)
    assert limit < a.size <= limit + len(ANGLES)
    for d1, d2 in pairs:
        big = segment_length_derivatives(a, d1, d2, 18.0)
        for j, x in enumerate(ANGLES):
            small = segment_length_derivatives(x, d1, d2, 18.0)
            f = lambda y: mp_length(y, d1, d2)  # noqa: E731
            ref = [float(f(x)), float(mp.diff(f, x)), float(mp.diff(f, x, 2))]
            for k in range(3):
                scale = ref[0] if k == 0 else max(1.0, abs(ref[k]))
                assert abs(big[k][j] - ref[k]) <= 4e-15 * scale, (x, d1, d2, k)
                assert abs(big[k][j] - small[k]) <= 4e-15 * scale, (x, d1, d2, k)
    c_big = segment_length(a, 3.0, 6.5, 18.0)[:len(ANGLES)]
    c_small = [float(segment_length(x, 3.0, 6.5, 18.0)) for x in ANGLES]
    np.testing.assert_allclose(c_big, c_small, rtol=4e-15)


def test_switch_at_pi_has_no_jump():
    eps = 1e-12
    for d1, d2 in [(10, 10), (3, -6.5)]:
        below = np.array(segment_length_derivatives(math.pi - eps, d1, d2, 18.0))
        above = np.array(segment_length_derivatives(math.pi + eps, d1, d2, 18.0))
        assert np.allclose(below, above, rtol=1e-12, atol=1e-10)


def test_formula_equals_hole_distance_from_poses():
    # Independent check: distance between holes placed with rib_centers/cable_path.
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.uniform(-1.4, 1.4, 11)
        d = rng.choice(HOLES, 12)
        P = cable_path(a, d, 18.0)
        assert np.allclose(np.linalg.norm(np.diff(P, axis=0), axis=1),
                           segment_length(a, d[:-1], d[1:], 18.0), atol=1e-12)


def test_rib_centers_straight_and_arc():
    assert np.allclose(rib_centers(np.zeros(11), 18.0)[:, 0], 18.0 * np.arange(12))
    # A constant-curvature bend of total angle pi puts the tip at the diameter.
    n, s = 11, 18.0
    P = rib_centers(np.full(n, math.pi / n), s)
    radius = n * s / math.pi
    assert np.allclose(P[-1], [0.0, 2 * radius], atol=1e-12)


def test_positive_offset_is_minus_y_at_straight():
    P = cable_path(np.zeros(2), [10.0, -10.0, 0.0], 18.0)
    assert P[0].tolist() == [0.0, -10.0] and P[1].tolist() == [18.0, 10.0]


def test_batch_broadcasting():
    a = np.zeros((5, 11))
    assert rib_centers(a, 18.0).shape == (5, 12, 2)
    assert cable_path(a, np.zeros((5, 12)), 18.0).shape == (5, 12, 2)
    assert segment_length(np.zeros((3, 1)), np.zeros(4), 1.0, 18.0).shape == (3, 4)


def test_skeleton_validation_and_yaml(tmp_path):
    sk = Skeleton()
    assert sk.n_segments == 11 and sk.straight_length_mm(['R3'] * 12) == 198.0
    with pytest.raises(ValueError, match='expected 12 holes, got 11'):
        sk.threading_mm(['R3'] * 11)
    with pytest.raises(ValueError, match="unknown hole 'R9'"):
        sk.threading_mm(['R9'] + ['R3'] * 11)
    with pytest.raises(ValueError, match='finite'):
        sk.threading_mm([float('nan')] + [0.0] * 11)
    with pytest.raises(ValueError, match='off the rib'):
        sk.threading_mm([13.0] + [0.0] * 11)
    with pytest.raises(ValueError, match='stiffness'):
        Skeleton(stiffness=[1.0] * 10)
    with pytest.raises(ValueError, match='n_ribs'):
        Skeleton(n_ribs=1)
    assert sk.hole_names(sk.threading_mm(['R3', 'L0'] * 6))[:2] == ['R3', 'L0']
    assert sk.hole_names([2.0])[0] is None
    path = tmp_path / 'sk.yaml'
    path.write_text('skeleton:\n  n_ribs: 5\n  spacing_mm: 20\n  holes_mm: {A: 1.0, B: -2}\n'
                    '  stiffness: [1, 2, 3, 4]\n')
    loaded = Skeleton.from_yaml(path)
    assert loaded.n_segments == 4 and loaded.stiffness == (1.0, 2.0, 3.0, 4.0)
    assert Skeleton.from_dict(loaded.to_dict()) == loaded
    with pytest.raises(ValueError, match='unknown skeleton keys'):
        Skeleton.from_dict({'n_rib': 3})


# -- half-angle functions and poses against mpmath, every evaluation path (docs/testing.md)
def mp_half_angle(u):
    u = mp.mpf(u)
    if u == 0:
        return 1.0, 1.0 / 3.0, 1.0
    return (float(mp.sin(u) / u), float((mp.sin(u) - u * mp.cos(u)) / u ** 3), float(mp.cos(u)))


HALF_ANGLES = [0.0, 1e-9, -1e-4, 0.3, -1.0, 1.5, math.pi / 2, -(math.pi / 2 + 1e-9), 1.6, -2.0,
               2.5, 3.0, -4.0, 6.0, 10.0, -25.0]


@pytest.mark.parametrize('size', [1, 256, 257, 1024, 1025])
def test_half_angle_functions_match_mpmath_on_every_path(size):
    # The friction and load models use the second function beyond |u| = pi/2 too (the
    # closed form there); sizes straddle the three series evaluations.
    from softsnap_model.geometry import half_angle_functions
    mp.mp.dps = 40
    u = np.resize(np.array(HALF_ANGLES), size)
    f0, f1, cos_u = half_angle_functions(u)
    assert f0.shape == f1.shape == cos_u.shape == u.shape
    for j, x in enumerate(u[:len(HALF_ANGLES)]):
        ref = mp_half_angle(x)
        for k, got in enumerate((f0[j], f1[j], cos_u[j])):
            assert abs(got - ref[k]) <= 1e-15 * max(abs(ref[k]), 1e-3), (x, k, got, ref[k])
    scalar = half_angle_functions(2.0)
    assert np.ndim(scalar[0]) == 0 and scalar[1] == pytest.approx(mp_half_angle(2.0)[1], rel=1e-14)


def test_g_and_derivatives_match_mpmath_on_both_sides_of_the_switch():
    from softsnap_model.geometry import g_and_derivatives
    mp.mp.dps = 40

    def g(x):
        return mp.mpf(1) if x == 0 else (2 * mp.sin(x / 2) / x) ** 2

    for a in [0.0, 1e-6, -0.7, 3.0, math.pi, -(math.pi + 1e-9), 3.2, -4.5, 7.0, 20.0]:
        got = g_and_derivatives(np.array([a, a]))
        ref = [float(g(mp.mpf(a))), float(mp.diff(g, mp.mpf(a))), float(mp.diff(g, mp.mpf(a), 2))]
        for k in range(3):
            assert got[k].shape == (2,)
            assert abs(got[k][0] - ref[k]) <= 2e-15 * max(1.0, abs(ref[k])), (a, k)


def mp_poses(angles, d, s):
    """Rib centres and hole positions by walking the arcs in mpmath (FACTS.md)."""
    x = y = t = mp.mpf(0)
    centres, holes = [(0.0, 0.0)], [(float(d[0] * mp.sin(t)), float(-d[0] * mp.cos(t)))]
    for k, a in enumerate(angles):
        a = mp.mpf(a)
        chord = s * (mp.sin(a / 2) / (a / 2) if a != 0 else 1)
        x += chord * mp.cos(t + a / 2)
        y += chord * mp.sin(t + a / 2)
        t += a
        centres.append((float(x), float(y)))
        holes.append((float(x + d[k + 1] * mp.sin(t)), float(y - d[k + 1] * mp.cos(t))))
    return np.array(centres), np.array(holes)


def test_rib_centres_and_holes_match_an_mpmath_walk():
    mp.mp.dps = 30
    rng = np.random.default_rng(38)
    for spacing in (18.0, 12.5):
        a = np.concatenate([[0.0, 2.5, -3.5], rng.uniform(-1.5, 1.5, 8)])
        d = rng.choice(HOLES, 12)
        centres, holes = mp_poses(a, d, spacing)
        np.testing.assert_allclose(rib_centers(a, spacing), centres, atol=1e-12)
        np.testing.assert_allclose(cable_path(a, d, spacing), holes, atol=1e-12)
        batch = cable_path(np.stack([a, -a]), np.stack([d, -d]), spacing)
        np.testing.assert_allclose(batch[0], holes, atol=1e-12)
        np.testing.assert_allclose(batch[1], holes * [1, -1], atol=1e-12)   # mirror image


def test_segment_length_matches_mpmath_for_large_angles_and_arrays():
    mp.mp.dps = 40
    a = np.array([0.0, 1e-7, -0.4, 1.2, -2.9, 3.3, 4.0, -6.0])
    for d1, d2 in [(10.0, -6.5), (-3.0, -3.0), (0.5, 10.0)]:
        got = segment_length(a, d1, d2, 18.0)
        ref = [float(mp_length(x, d1, d2)) for x in a]
        # (absolute slack: a short cable near a hole's centre of curvature loses digits)
        np.testing.assert_allclose(got, ref, rtol=4e-15, atol=3e-14)
        spaced = segment_length(a, d1, d2, np.full(a.shape, 12.0))
        np.testing.assert_allclose(spaced, [float(mp_length(x, d1, d2, 12.0)) for x in a],
                                   rtol=4e-15, atol=3e-14)
