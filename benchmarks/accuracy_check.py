"""Accuracy regression check of the forward solver; the first step of `make bench`.

Exits with status 1 if the solve loses accuracy, never because it is slow. On a fixed
set of problems (the paper's nine threadings at several lengths across their range, and
a 192-rib module), every answer of ``solve_forward`` and ``solve_forward_batch`` must

1. be certified (``converged``) and meet the contracts when re-checked here with an
   independent evaluation of the FACTS.md cable-length formula (``math``/``cmath``, the
   derivative by complex step, no code of the solver): cable length within
   ``CONSTRAINT_TOL_MM`` and stationarity within ``STATIONARITY_TOL_RAD``;
2. agree within ``ANGLE_TOL_RAD`` with a plain reference solver: the tension by
   bracketing (brentq) on the total length, each segment's angle by bracketing on its
   own stationarity condition; no tables, no Newton, no warm start.

The solver agrees with that reference to about 1e-15 rad (a few ulp), so
``ANGLE_TOL_RAD`` flags a loss of four orders of magnitude while leaving room for
rounding. test/softsnap_model/test_accuracy_check.py shows the check failing on wrong solvers.

Usage: .venv/bin/python benchmarks/accuracy_check.py [--quick]   (about 5-20 s)
"""
from __future__ import annotations

import argparse
import cmath
import math
import sys
import time

import numpy as np
from scipy.optimize import brentq

from softsnap_model import Skeleton
from softsnap_model.forward import (CONSTRAINT_TOL_MM, STATIONARITY_TOL_RAD,
                                    reachable_range, solve_forward, solve_forward_batch)
from softsnap_model.reference import PAPER_THREADINGS

#: Largest allowed angle difference (rad) to the reference solver.
ANGLE_TOL_RAD = 1e-11
#: Fractions of the reachable contraction range at which each threading is checked.
FRACTIONS = (0.02, 0.3, 0.6, 0.9)
_STEP = 1e-30   # complex step (exact first derivative to rounding)


def segment_length(a, d1, d2, s):
    """FACTS.md: sqrt((d1 - d2)^2 + c^2 (s + d1 a)(s + d2 a)), c = 2 sin(a/2) / a."""
    lib = cmath if isinstance(a, complex) else math
    c = 1.0 if a == 0 else 2.0 * lib.sin(a / 2.0) / a
    return lib.sqrt((d1 - d2) ** 2 + c * c * (s + d1 * a) * (s + d2 * a))


def segment_slope(a, d1, d2, s):
    """dL/da by complex step: Im L(a + i h) / h."""
    if a == 0.0:
        a = 1e-300     # the formula's removable point; the slope is continuous there
    return segment_length(complex(a, _STEP), d1, d2, s).imag / _STEP


def reference_solve(skeleton, threading, length_mm):
    """Angles (rad) and tension of the quasi-static path at ``length_mm`` (independent).

    Branch rule of the package docstring: direction -sign(d1 + d2) (mirror pairs bend
    clockwise when d1 >= 0), a segment stays at 0 below its buckling tension and at
    the rib-contact angle beyond the tension that brings it there.
    """
    d = [float(v) for v in skeleton.threading_mm(threading)]
    s, k = skeleton.spacing_mm, [float(v) for v in skeleton.stiffness_array]
    b_max = skeleton.contact_angle_rad
    pairs = list(zip(d[:-1], d[1:]))

    def direction(d1, d2):
        total = d1 + d2
        return -1.0 if total > 0 or (total == 0 and d1 >= 0) else 1.0

    def angle(mu, d1, d2):
        sign = direction(d1, d2)

        def phi(b):     # tension per stiffness that holds the segment at magnitude b
            return 2.0 * b / -(sign * segment_slope(sign * b, d1, d2, s))

        if mu == 0.0 or phi(1e-9) >= mu:
            return 0.0
        if phi(b_max) <= mu:
            return sign * b_max
        return sign * brentq(lambda b: phi(b) - mu, 1e-9, b_max, xtol=1e-16, rtol=8.9e-16)

    def angles_at(lam):
        return [angle(lam / ki, d1, d2) for ki, (d1, d2) in zip(k, pairs)]

    def total(lam):
        return sum(segment_length(a, d1, d2, s) for a, (d1, d2) in zip(angles_at(lam), pairs))

    hi = 1.0
    while total(hi) > length_mm:
        hi *= 2.0
    lam = brentq(lambda x: total(x) - length_mm, 0.0, hi, xtol=1e-300, rtol=8.9e-16)
    return np.array(angles_at(lam)), lam


def independent_residuals(skeleton, threading, length_mm, angles, tension):
    """(constraint mm, stationarity rad) of an answer, by this file's own formula."""
    d = [float(v) for v in skeleton.threading_mm(threading)]
    s, k = skeleton.spacing_mm, [float(v) for v in skeleton.stiffness_array]
    b_max = skeleton.contact_angle_rad
    lengths, stat = 0.0, 0.0
    for i, a in enumerate(angles):
        d1, d2 = d[i], d[i + 1]
        lengths += segment_length(float(a), d1, d2, s)
        held = a == 0.0 and d1 + d2 == 0.0        # a mirror segment below buckling
        at_contact = abs(abs(a) - b_max) <= 1e-12
        if not (held or at_contact):
            stat = max(stat, abs(a + tension * segment_slope(float(a), d1, d2, s) / (2 * k[i])))
    return abs(lengths - length_mm), stat


def problems(quick=False):
    """The fixed problem set: (label, skeleton, threading, length_mm)."""
    sk = Skeleton()
    out = []
    fractions = FRACTIONS[::2] if quick else FRACTIONS
    for name, threading in PAPER_THREADINGS.items():
        lo, hi = reachable_range(sk, threading)
        for frac in fractions:
            out.append((f'{name} {frac:.2f}', sk, threading, hi - frac * (hi - lo)))
    long = Skeleton(n_ribs=192)
    threading = (['R1', 'R2', 'R3', 'R2'] * 48)
    lo, hi = reachable_range(long, threading)
    out.append(('192 ribs 0.30', long, threading, hi - 0.3 * (hi - lo)))
    return out


def _single(skeleton, threading, length_mm):
    r = solve_forward(skeleton, threading, length_mm)
    return r.angles, r.tension, r.converged


def _batch(skeleton, threading, length_mm):
    # A batch of three copies of the same item: rows must agree with the reference too.
    r = solve_forward_batch(skeleton, [threading] * 3, [length_mm] * 3)
    return r.angles[2], float(r.tension[2]), bool(r.converged.all())


#: The solvers checked by default: (label, function(skeleton, threading, length_mm) ->
#: (angles, tension, converged)).
SOLVERS = (('solve_forward', _single), ('solve_forward_batch', _batch))


def check(solvers=SOLVERS, quick=False, out=sys.stdout) -> bool:
    """Run the check; print one line per problem and solver; True if all pass."""
    ok_all = True
    worst = 0.0
    for label, sk, threading, length in problems(quick):
        ref, _ = reference_solve(sk, threading, length)
        for name, solver in solvers:
            angles, tension, converged = solver(sk, threading, length)
            err = float(np.max(np.abs(np.asarray(angles) - ref)))
            g, stat = independent_residuals(sk, threading, length, angles, tension)
            ok = (bool(converged) and err <= ANGLE_TOL_RAD and g <= CONSTRAINT_TOL_MM
                  and stat <= STATIONARITY_TOL_RAD)
            worst = max(worst, err)
            ok_all &= ok
            if not ok or name == solvers[0][0]:
                print(f'{"ok  " if ok else "FAIL"} {label:16s} {name:20s} angle err '
                      f'{err:.1e} rad  constraint {g:.1e} mm  stationarity {stat:.1e} rad'
                      f'{"" if converged else "  (not converged)"}', file=out)
    print(f'largest angle difference to the reference: {worst:.2e} rad '
          f'(allowed {ANGLE_TOL_RAD:.0e})', file=out)
    return ok_all


def main(argv=None, solvers=SOLVERS) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='half the lengths')
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    ok = check(solvers, quick=args.quick)
    print(f'accuracy check {"passed" if ok else "FAILED"} in {time.perf_counter() - t0:.1f} s')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
