"""Loads along their loading path (issue 32) against an independent path-following
reference written here: the cable shortened from straight in 0.25 mm steps with the load
on, each step a fresh SLSQP minimisation (test_loads.reference_solve: its own energy and
cable length from geometry, central-difference gradients) warm-started from the last;
a different minimiser and half the step of ``solve_loaded_path``.
"""
from __future__ import annotations

import numpy as np
import pytest

from softsnap_model import Skeleton, rib_centers
from softsnap_model.loading_path import CONTINUED, LOAD_BEFORE_CABLE, solve_loaded_path
from softsnap_model.loads import Loads, solve_loaded
from softsnap_model.reference import PAPER_THREADINGS
from test_loads import reference_solve

SK = Skeleton()
G = 9.80665
#: Shapes agree within this (mm): SLSQP is good to ~1e-6 mm per step; 80 warm starts.
TOL_MM = 0.01


def reference_path(threading, contraction_mm, loads, step_mm=0.25):
    straight = SK.straight_length_mm(threading)
    a = np.zeros(SK.n_segments)
    n = int(round(contraction_mm / step_mm))
    for k in range(n + 1):
        a, energy = reference_solve(SK, threading, straight - contraction_mm * k / n, loads, a)
    return rib_centers(a, SK.spacing_mm), energy


# (threading, contraction mm, loads): a module on its side (one equilibrium), and one
# where the fixed-length answer of solve_loaded is a different state, 183 mm away, of
# higher energy (-4.3 against -11.6 N mm): the path finds the lower one.
CASES = {
    'yellow on its side': ('yellow', 40.0, Loads(gravity_mps2=(0.0, -G, 0.0))),
    'blue, sideways gravity and tip load': (
        'blue', 7.0, Loads(gravity_mps2=(9.52, -2.34, 0.0), load_n=(-0.378, -0.035, 0.0))),
}


@pytest.mark.parametrize('case', list(CASES))
def test_load_before_the_cable_moves_matches_the_reference_path(case):
    name, c, loads = CASES[case]
    t = list(PAPER_THREADINGS[name])
    length = SK.straight_length_mm(t) - c
    res = solve_loaded_path(SK, t, length, loads)
    assert res.path == LOAD_BEFORE_CABLE and res.result.converged, res.result.message
    ref_centers, ref_energy = reference_path(t, c, loads)
    err = np.max(np.linalg.norm(res.result.rib_centers - ref_centers, axis=1))
    assert err < TOL_MM, (case, err)
    fixed = solve_loaded(SK, t, length, loads)
    gap = np.max(np.linalg.norm(fixed.rib_centers - ref_centers, axis=1))
    if case == 'yellow on its side':
        assert gap < TOL_MM and not res.lower_energy_exists
    else:
        # The old fixed-length semantics lands elsewhere; the flag reports the lower one.
        assert gap > 10.0, gap
        lower = fixed.energy_nmm < res.result.energy_nmm - 1e-6
        assert res.lower_energy_exists == lower
        if lower:
            assert res.alternative is not None and res.alternative_distance_mm > 10.0


def test_continuing_from_a_previous_state_follows_the_stream():
    """A stream of requests, each continuing from the last, ends where one path does."""
    name, c, loads = CASES['blue, sideways gravity and tip load']
    t = list(PAPER_THREADINGS[name])
    straight = SK.straight_length_mm(t)
    prev = solve_loaded_path(SK, t, straight - 2.0, loads).result
    for target in (4.0, 5.5, 7.0):
        out = solve_loaded_path(SK, t, straight - target, loads, previous=prev)
        assert out.path == CONTINUED and out.result.converged
        prev = out.result
    whole = solve_loaded_path(SK, t, straight - c, loads).result
    assert np.max(np.linalg.norm(prev.rib_centers - whole.rib_centers, axis=1)) < TOL_MM


def test_a_lost_path_is_reported_not_returned_as_an_answer():
    # A 0.26 N tip load across the 'w' module: the path passes a fold (the module snaps).
    t = list(PAPER_THREADINGS['w'])
    loads = Loads(gravity_mps2=(0.02, -9.81, 0.0), load_n=(-0.055, 0.259, 0.0))
    res = solve_loaded_path(SK, t, SK.straight_length_mm(t) - 84.4 + 0.0, loads)
    assert not res.result.converged and 'fold' in res.result.message


def test_bad_input_is_refused():
    t = list(PAPER_THREADINGS['yellow'])
    loads = Loads(gravity_mps2=(0.0, -G, 0.0))
    with pytest.raises(ValueError, match='step_mm'):
        solve_loaded_path(SK, t, 180.0, loads, step_mm=0.0)
    with pytest.raises(ValueError, match='previous'):
        solve_loaded_path(SK, t, 180.0, loads, previous='state')
    with pytest.raises(ValueError, match='loads'):
        solve_loaded_path(SK, t, 180.0, None)
