"""Inverse design under printing tolerance: sensitivity figures and robust ranking."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from softsnap_model import forward, reference
from softsnap_model.inverse import (DesignSensitivity, design_sensitivity,
                                    design_threading, result_to_dict)
from softsnap_model.inverse.robustness import _perturbed_angles
from softsnap_model.skeleton import Skeleton

# Paper Figure S4 (c)/(d) targets (FACTS.md), 8 holes per rib; degrees, segment 0 first.
S4_C = np.radians([0, 0, 0, 10, 15, 0, 10, 30, 0, 0, 0])
S4_D = np.radians([0, 0, 0, -10, -30, 0, 10, 30, 0, 0, 0])
# Seeds: the design's own Monte Carlo uses the default; judging uses an independent one.
CHECK_SEED = 12345
CHECK_SAMPLES = 1000


def idealised_skeleton():
    """The authors' module with the paper's idealised ribs (no rib thickness): the
    numbers below were measured with the contact angle 1.44 rad."""
    extra = {f.name: 0.0 for f in dataclasses.fields(Skeleton) if 'thick' in f.name}
    sk = Skeleton(n_ribs=12, spacing_mm=18.0, rib_length_mm=25.0, **extra)
    assert sk.contact_angle_rad == pytest.approx(1.44, abs=1e-12)
    return sk


SK = idealised_skeleton()


def held_out(design, target, hole_mm=0.2, length_mm=0.0):
    """Error under tolerance on noise the design never saw (independent seed)."""
    return design_sensitivity(SK, design.threading, design.cable_length, target,
                              hole_tolerance_mm=hole_mm, length_tolerance_mm=length_mm,
                              n_samples=CHECK_SAMPLES, seed=CHECK_SEED)


# ------------------------------------------------------------------ the Monte Carlo


def test_perturbed_solves_agree_with_the_forward_solver():
    rng = np.random.default_rng(4)
    base = np.array(SK.threading_mm('R0 L0 R0 L0 L2 L1 R1 L3 L3 R3 L3 R3'.split()))
    lo, hi = forward.reachable_range(SK, base)
    offsets = base + rng.normal(0.0, 0.3, (24, base.size))
    lengths = rng.uniform(lo + 2.0, hi - 1.0, 24)
    lengths[0] = hi + 5.0                  # slack: straight
    offsets[1] = base                      # exact mirror pairs, buckled or not
    angles, at_limit = _perturbed_angles(SK, offsets, lengths)
    assert not at_limit.any()
    for i in range(24):
        ref = forward.solve_forward(SK, offsets[i], lengths[i])
        np.testing.assert_allclose(angles[i], ref.angles, atol=1e-8, rtol=0)
    # Below the reachable range: the branch-end shape, flagged.
    angles, at_limit = _perturbed_angles(SK, base[None], np.array([lo - 1.0]))
    assert at_limit.all()
    assert np.allclose(np.abs(angles), SK.contact_angle_rad)


def test_sensitivity_is_seeded_and_zero_tolerance_is_the_nominal_error():
    threading = 'R1 L1 R1 L1 R2 R1 L1 L0 L3 R3 L3 R3'.split()
    nominal = forward.solve_forward(SK, threading, 227.87)
    err = float(np.linalg.norm(nominal.angles - S4_D))
    zero = design_sensitivity(SK, threading, 227.87, S4_D, n_samples=8)
    assert zero.median_error == pytest.approx(err, abs=1e-8)
    assert zero.max_error == pytest.approx(err, abs=1e-8)
    assert zero.nominal_error == pytest.approx(err, abs=1e-12)
    one = design_sensitivity(SK, threading, 227.87, S4_D, hole_tolerance_mm=0.2, seed=3)
    two = design_sensitivity(SK, threading, 227.87, S4_D, hole_tolerance_mm=0.2, seed=3)
    other = design_sensitivity(SK, threading, 227.87, S4_D, hole_tolerance_mm=0.2, seed=4)
    assert one == two
    assert one.median_error != other.median_error
    assert one.mean_error > err and one.p90_error >= one.median_error
    assert isinstance(one, DesignSensitivity) and one.n_samples == 128


def test_length_tolerance_alone_is_measured():
    threading = 'R0 L0 R0 L0 L2 L1 R1 L3 L3 R3 L3 R3'.split()
    small = design_sensitivity(SK, threading, 223.49, S4_C, length_tolerance_mm=0.1)
    large = design_sensitivity(SK, threading, 223.49, S4_C, length_tolerance_mm=0.5)
    assert small.hole_tolerance_mm == 0.0
    assert large.median_error > small.median_error > small.nominal_error - 1e-9
    # The S4 (c) shape moves ~0.08 rad per mm of cable: 0.5 mm (1 sigma) is ~0.03 rad.
    assert 0.015 < large.median_error < 0.06


def test_s4_designs_lose_accuracy_under_hole_noise_as_issue_13_reports():
    # Issue 13: 0.014 / 0.032 rad nominal, median 0.038 / 0.075 rad with 0.2 mm noise.
    for target, nominal, median in ((S4_C, 0.0144, 0.038), (S4_D, 0.0321, 0.075)):
        res = design_threading(SK, target_angles=target, k=0)
        assert res.error == pytest.approx(nominal, abs=5e-4)
        sens = held_out(res, target)
        assert sens.median_error == pytest.approx(median, abs=0.006)
        assert sens.p90_error > 1.5 * sens.median_error > 2 * res.error


# ------------------------------------------------------------------ the design


@pytest.mark.parametrize('name, target', [
    ('s-shape', forward.solve_forward(
        SK, list(reference.PAPER_THREADINGS['s']),
        forward.reachable_range(SK, list(reference.PAPER_THREADINGS['s']))[1] - 0.6 * np.diff(
            forward.reachable_range(SK, list(reference.PAPER_THREADINGS['s'])))[0]).angles),
    ('kink', np.array([0, 0, 0, 0, 0.4, 0.4, 0.4, 0, 0, 0, 0.0])),
])
def test_robust_ranking_lowers_the_median_error_under_hole_noise(name, target):
    # Many threadings reach these shapes exactly; the nominal ranking picks one of the
    # tied designs, the robust ranking the one that survives 0.2 mm hole noise best.
    nominal = design_threading(SK, target_angles=target, k=0)
    robust = design_threading(SK, target_angles=target, k=0, hole_tolerance_mm=0.2)
    assert robust.error <= nominal.error + 1e-6          # no nominal accuracy given up
    assert nominal.sensitivity is None
    got, base = held_out(robust, target), held_out(nominal, target)
    assert got.median_error < 0.5 * base.median_error, (name, got, base)
    assert robust.sensitivity.median_error < 0.5 * base.median_error


@pytest.mark.parametrize('target', [S4_C, S4_D], ids=['S4c', 'S4d'])
def test_robust_ranking_on_the_s4_targets(target):
    res = design_threading(SK, target_angles=target, k=3, hole_tolerance_mm=0.2)
    designs = (res,) + res.alternatives
    assert len(designs) == 4
    for d in designs:
        assert d.sensitivity.hole_tolerance_mm == 0.2 and d.sensitivity.n_samples == 128
        assert d.sensitivity.nominal_error == pytest.approx(d.error, abs=1e-9)
    medians = [d.sensitivity.median_error for d in designs]
    assert medians == sorted(medians)
    assert 'ranked by median error under tolerance' in res.message
    # For these targets the nominal best is already the most robust of the exact
    # search's 12 best designs (docs/inverse.md): the ranking must not make it worse.
    nominal = design_threading(SK, target_angles=target, k=0)
    assert held_out(res, target).median_error <= held_out(nominal, target).median_error + 0.002
    assert res.lower_bound <= nominal.error + 1e-12


def test_report_only_keeps_the_nominal_order():
    res = design_threading(SK, target_angles=S4_C, k=1, hole_tolerance_mm=0.2,
                           length_tolerance_mm=0.1, robust_rank=False, robust_samples=32)
    nominal = design_threading(SK, target_angles=S4_C, k=1)
    assert res.holes == nominal.holes
    assert [a.holes for a in res.alternatives] == [a.holes for a in nominal.alternatives]
    assert res.sensitivity.length_tolerance_mm == 0.1 and res.sensitivity.n_samples == 32
    assert 'sensitivity under tolerance' in res.message
    plain = result_to_dict(res)
    assert plain['sensitivity']['median_error'] == res.sensitivity.median_error
    assert plain['alternatives'][0]['sensitivity']['p90_error'] > 0


def test_quantile_ranking_reports_the_quantile():
    res = design_threading(SK, target_angles=S4_D, k=1, hole_tolerance_mm=0.2,
                           robust_quantile=0.9, robust_candidates=4)
    designs = (res,) + res.alternatives
    q = [d.sensitivity.quantile_error for d in designs]
    assert q == sorted(q)
    assert res.sensitivity.quantile == 0.9
    assert res.sensitivity.quantile_error == pytest.approx(res.sensitivity.p90_error)


@pytest.mark.parametrize('kwargs, match', [
    (dict(hole_tolerance_mm=-0.1), 'hole_tolerance_mm'),
    (dict(hole_tolerance_mm=float('nan')), 'hole_tolerance_mm'),
    (dict(length_tolerance_mm=9.0), r'length_tolerance_mm must be a number in \[0, 5\]'),
    (dict(hole_tolerance_mm=0.1, robust_candidates=0), 'robust_candidates'),
    (dict(hole_tolerance_mm=0.1, robust_samples=0), 'robust_samples'),
    (dict(hole_tolerance_mm=0.1, robust_quantile=1.5), 'quantile'),
])
def test_bad_tolerance_input_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        design_threading(SK, target_angles=S4_C, k=0, **kwargs)


def test_command_line_reports_the_sensitivity(capsys):
    import json

    from softsnap_model.cli import main
    angles = ' '.join(f'{a:.6f}' for a in S4_C)
    code = main(['inverse', '--angles', angles, '--k', '0', '--hole-tolerance', '0.2',
                 '--length-tolerance', '0.1'])
    out = capsys.readouterr()
    assert code == 0, out.err
    data = json.loads(out.out)
    sens = data['sensitivity']
    assert sens['hole_tolerance_mm'] == 0.2 and sens['length_tolerance_mm'] == 0.1
    assert sens['p90_error'] >= sens['median_error'] > data['error_rad']
    code = main(['inverse', '--angles', angles, '--hole-tolerance', '-1'])
    assert code == 2 and 'hole_tolerance_mm' in capsys.readouterr().err
