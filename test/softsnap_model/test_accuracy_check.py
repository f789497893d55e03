"""The accuracy regression check of `make bench` (benchmarks/accuracy_check.py) is honest:
it passes for the solver and fails, with a non-zero exit status, for wrong ones."""
import io

import numpy as np
import pytest

from benchmark_scripts import load
from softsnap_model import Skeleton, solve_forward

accuracy_check = load('accuracy_check')


def test_reference_solver_agrees_with_the_solver_on_a_paper_threading():
    sk = Skeleton()
    t = ['R1'] * 8 + ['R2', 'R2', 'R3', 'R3']
    ref, lam = accuracy_check.reference_solve(sk, t, 170.0)
    res = solve_forward(sk, t, 170.0)
    assert np.max(np.abs(ref - res.angles)) <= 1e-12
    assert lam == pytest.approx(res.tension, rel=1e-9)


def test_check_passes_for_the_solver():
    out = io.StringIO()
    assert accuracy_check.check(quick=True, out=out)
    assert 'FAIL' not in out.getvalue()


def _perturbed(skeleton, threading, length_mm):
    # A solver that lost accuracy but still claims convergence: 1e-9 rad on one angle.
    r = solve_forward(skeleton, threading, length_mm)
    angles = r.angles.copy()
    angles[len(angles) // 2] += 1e-9
    return angles, r.tension, r.converged


def _uncertified(skeleton, threading, length_mm):
    # Right answers that the solver does not certify.
    r = solve_forward(skeleton, threading, length_mm)
    return r.angles, r.tension, False


def _wrong_tension(skeleton, threading, length_mm):
    # Right angles, wrong multiplier: only the independent stationarity check sees it.
    r = solve_forward(skeleton, threading, length_mm)
    return r.angles, r.tension * (1.0 + 1e-6), r.converged


@pytest.mark.parametrize('solver', [_perturbed, _uncertified, _wrong_tension])
def test_check_fails_for_a_wrong_solver(solver):
    out = io.StringIO()
    assert not accuracy_check.check([('wrong', solver)], quick=True, out=out)
    assert 'FAIL' in out.getvalue()


def test_main_exits_non_zero_when_accuracy_is_lost(capsys):
    assert accuracy_check.main(['--quick'], solvers=[('wrong', _perturbed)]) == 1
    assert 'accuracy check FAILED' in capsys.readouterr().out
