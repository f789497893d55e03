"""Inverse design: the globally best threading and cable length for a desired module shape.

Problem. A skeleton has ``n`` ribs and ``m`` holes per rib; a threading picks one hole per
rib and the cable length sets the shape through the quasi-static model (minimum bending
energy ``sum_i k_i a_i^2`` at the given total cable length). Given target bending angles
``t`` (one per segment, rad), find the threading ``T`` and cable length ``L`` whose
forward-solved angles ``a(T, L)`` minimise ``||a(T, L) - t||_2`` over every threading of
the hole set and every cable length.

Structure used. The cable tension ``lam`` (the Lagrange multiplier of the length
constraint) is shared by all segments, and at a fixed tension each segment's equilibrium
angle depends only on its own two holes and stiffness:
``a_i = forward.segment_angle_at_tension(lam, d_i, d_{i+1}, s, k_i)``. Hence designs are
parametrised by ``(T, lam)`` instead of ``(T, L)``; at fixed ``lam`` the best threading is
a min-sum dynamic programme over the rib chain (``O(n m^2)``), and the cable length of a
design is ``sum_i L(a_i)``, which decreases monotonically with the tension.

Globality over the tension. Along each branch of the per-segment equilibrium, ``|a|``
grows monotonically with the tension (stationarity ``2 k a = -lam L'(a)`` and stability
give ``da/dlam`` the sign of ``a``). So on a tension interval ``[lo, hi]`` every angle lies
between its values at the two ends (or, should its side change inside the interval,
within ``[-max|a|, max|a|]``). The distance of the target to these angle intervals gives
a lower bound of the cost of every threading on the interval; a k-best dynamic programme
over these lower bounds bounds the k-th best cost on the interval. Branch and bound over
the tension then splits every interval whose bound could still beat the incumbent, and
each threading the bounds point at is refined by a 1-D search over the tension. On exit
no threading of the allowed hole set, at any cable length, has an error below the
returned one minus ``GLOBAL_TOL_RAD`` (``lower_bound`` reports the certified bound).

The forward solver is the truth: every returned design is re-solved with
``forward.solve_forward`` at its cable length and the reported angles, points and errors
are those of that solve.

Bounded work. A design can be stopped from outside: ``should_stop`` (a callable, e.g.
``threading.Event().is_set``) and ``time_limit_s`` are checked between the steps of the
search (each step of the dynamic programme, each tension node, each refinement round and
each forward solve), so a stopped design ends within one step (milliseconds to tens of
milliseconds at the node's alternative cap) by raising :class:`DesignCancelled` or
:class:`DesignTimedOut`. ``progress(fraction, stage)`` reports how far the design got.

Where each part lives: :mod:`.targets` (target angles or points, hole set, length range),
:mod:`.search` (the tension-parametrised problem and the branch and bound), :mod:`.kbest`
(the k-best dynamic programme over the rib chain), :mod:`.design` (``design_threading``),
:mod:`.robustness` (tolerance sensitivity), :mod:`.results` (results and stops) and
:mod:`.cli` (``softsnap-model inverse``).
"""
from __future__ import annotations

from .cli import add_cli
from .design import design_threading
from .results import (DESIGN_STAGES, DesignCancelled, DesignResult, DesignSensitivity,
                      DesignStopped, DesignTimedOut, result_to_dict)
from .robustness import design_sensitivity
from .search import GLOBAL_TOL_RAD
from .targets import fit_angles_to_points

__all__ = [
    'DESIGN_STAGES',
    'DesignResult',
    'DesignStopped',
    'DesignCancelled',
    'DesignTimedOut',
    'DesignSensitivity',
    'design_threading',
    'design_sensitivity',
    'fit_angles_to_points',
    'GLOBAL_TOL_RAD',
    'result_to_dict',
    'add_cli',
]
