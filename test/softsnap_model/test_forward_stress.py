"""Hypothesis stress tests: random threadings, lengths, mirrored holes, stiffness."""
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from softsnap_model import (CONSTRAINT_TOL_MM, STATIONARITY_TOL_RAD, InfeasibleLengthError,
                            Skeleton, reachable_range, segment_length,
                            segment_length_derivatives, solve_forward, solve_forward_batch)

SK = Skeleton(rib_thickness_mm=0.0)   # the paper's idealised model (thin ribs)
NAMES = list(SK.holes_mm)
SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

threadings = st.lists(st.sampled_from(NAMES), min_size=12, max_size=12)
# Mirror-heavy threadings: pairs of opposite holes, so most segments are mirror ones.
mirrored = st.lists(st.sampled_from(['0', '1', '2', '3']), min_size=6, max_size=6).map(
    lambda ix: [f'{side}{i}' for i in ix for side in 'RL'])
# Fraction of the reachable range, hugging both ends.
fractions = st.one_of(st.floats(0.0, 1.0), st.sampled_from([1e-15, 1e-12, 1e-9, 1e-6,
                                                            1 - 1e-9, 1 - 1e-6]))
stiffness = st.lists(st.floats(0.2, 5.0), min_size=11, max_size=11)


def check(skeleton, threading, frac):
    lo, hi = reachable_range(skeleton, threading)
    length = hi - frac * (hi - lo)
    if length <= lo:
        return
    res = solve_forward(skeleton, threading, length)
    assert np.all(np.isfinite(res.angles)) and np.isfinite(res.tension)
    assert res.converged, res.message
    assert res.is_minimum and res.min_curvature > 0
    assert res.constraint_residual <= CONSTRAINT_TOL_MM
    assert res.stationarity_residual <= STATIONARITY_TOL_RAD
    d = skeleton.threading_mm(threading)
    k = skeleton.stiffness_array
    total = float(np.sum(segment_length(res.angles, d[:-1], d[1:], skeleton.spacing_mm)))
    if not res.slack:
        # Independent residuals recomputed from the public geometry functions.
        assert abs(total - length) <= CONSTRAINT_TOL_MM
        _, dl, d2l = segment_length_derivatives(res.angles, d[:-1], d[1:],
                                                skeleton.spacing_mm)
        free = ~res.at_contact
        stat = np.abs(res.angles + res.tension * dl / (2 * k))[free]
        # Held-straight mirror segments have dl = 0 and angle 0: also stationary.
        assert np.all(stat <= 1e-10)
        assert np.all(np.abs(res.angles) <= skeleton.contact_angle_rad + 1e-12)
        assert np.all(np.abs(res.angles[res.at_contact]) == skeleton.contact_angle_rad)
    return res


@SETTINGS
@given(threadings, fractions)
def test_random_threadings(threading, frac):
    check(SK, threading, frac)


@SETTINGS
@given(mirrored, fractions)
def test_mirrored_threadings(threading, frac):
    check(SK, threading, frac)


@SETTINGS
@given(threadings, fractions, stiffness)
def test_random_stiffness(threading, frac, k):
    check(Skeleton(stiffness=k, rib_thickness_mm=0.0), threading, frac)


@SETTINGS
@given(threadings, st.floats(allow_nan=True, allow_infinity=True))
def test_any_length_only_documented_errors(threading, length):
    try:
        res = solve_forward(SK, threading, length)
    except InfeasibleLengthError as exc:
        assert exc.reachable_range_mm[0] >= length or not np.isfinite(length)
        return
    except ValueError as exc:
        assert not np.isfinite(length) or length <= 0, exc
        return
    assert res.converged and np.all(np.isfinite(res.angles))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(threadings, st.floats(1e-9, 1.0)), min_size=1, max_size=30))
def test_batch_equals_single(items):
    ts, lengths = [], []
    for t, frac in items:
        lo, hi = reachable_range(SK, t)
        length = hi - frac * (hi - lo)
        if length > lo:
            ts.append(t)
            lengths.append(length)
    if not ts:
        return
    batch = solve_forward_batch(SK, ts, lengths)
    assert batch.converged.all()
    for i in range(len(ts)):
        single = solve_forward(SK, ts[i], lengths[i])
        assert np.allclose(batch.angles[i], single.angles, atol=1e-11)
