"""Quasi-static forward model of a SoftSnap module (pure numpy).

Model (paper, Algorithm 1; FACTS.md): the shape minimises the bending energy
``E = sum_i k_i a_i^2`` subject to ``sum_i L(a_i; d_i, d_{i+1}) = L_target``.

The problem is separable. With the multiplier ``lambda`` (the *tension*), stationarity
reads ``2 k_i a_i + lambda dL/da(a_i; d_i, d_{i+1}) = 0`` for every segment on its own,
so each segment's angle is a function of ``lambda`` and of its two holes only, and the
shape reached by shortening the cable quasi-statically from straight is the family
``a_i(lambda)``, ``lambda`` rising from 0. A forward solve is one scalar equation
``T(lambda) = sum_i L_i(a_i(lambda)) = L_target``, with ``T`` non-increasing, so the
answer is unique along the path and a cold solve equals path following. (The energy can
have other, higher local minima off the path, e.g. a segment held at rib contact on
the side against its holes' pull; docs/model.md.)

Units and conventions
---------------------
Angles in rad (counter-clockwise positive), lengths in mm, stiffness ``k_i`` is
dimensionless relative stiffness. ``tension`` is ``lambda`` in rad^2/mm: the physical
cable tension is ``lambda * K`` where ``K`` (N mm/rad^2) is the bending stiffness that
makes ``E = K sum k_i a_i^2`` an energy in N mm.

Branch rule (per segment, so segments stay independent)
-------------------------------------------------------
* Bend direction: ``-sign(d1 + d2)`` (right-side holes bend clockwise). A mirror
  segment (``d1 + d2 == 0``) has no first-order preference; it bends clockwise when
  ``d1 >= 0`` and counter-clockwise when ``d1 < 0``: the way a cable through only its
  proximal (base-side) hole would pull it. Both directions are exact, equally good
  answers (the segment length is even in the angle when ``d2 = -d1``): a result lists
  the bent mirror segments in ``tie_break_segments`` and ``solve_forward(...,
  mirror_flip=...)`` gives the other branch.
* A mirror segment stays straight until ``lambda`` reaches its buckling tension
  ``lambda_c = 2 k / |L''(0)|`` (pitchfork), then follows the branch in its direction.
  For the authors' hole set every mirror pitchfork is supercritical (verified in the
  tests), so the buckled state is a true minimum.
* A segment stops at the rib-contact angle ``Skeleton.contact_angle_rad`` (the ribs
  meet at the centre of curvature); beyond the tension where it gets there it stays
  at contact, like a hard stop, and the other segments take up further shortening.
* If a segment's branch turns back (a fold: ``d lambda / d a = 0`` before contact) the
  quasi-static path snaps there; lengths past the fold raise :class:`SnapThroughError`.
  No pair of the authors' holes folds before contact.

Layout of this subpackage
-------------------------
* :mod:`.results`: contracts (tolerances), errors and frozen result types;
* :mod:`.branch`: per-segment branches, their profile tables and the profile cache;
* :mod:`.path`: per-threading problem data, its caches and its batch layout;
* :mod:`.path_table`: the path table of a threading, built lazily;
* :mod:`.start_polynomials`: the path's derivatives and each cell's start polynomial;
* :mod:`.newton`: the batch Newton solve, certification and robust fallback;
* :mod:`.single`: one solve in plain Python floats (start, evaluation, second-order
  check, Newton), the engine of :func:`solve_forward`;
* :mod:`.api`: :func:`solve_forward`, :func:`reachable_range`;
* :mod:`.batch`: :func:`solve_forward_batch`, :func:`sweep` and :class:`PreparedBatch`
  (tables of a robot's threadings stacked once, for repeated small batches).

Caches (the only process-wide state; each is a pure function of its key, so it changes
the cost, never an answer): per hole-pair profiles (``branch._PROFILE_CACHE``) and
single-solve length coefficients (``path._Q_CACHE``), and per threading the problem
and path tables (``path._problem``, ``path._single``, ``path._single_named``; the
single solve keeps its per-threading lists in the ``path._single`` entry) and the hole
offsets of a threading given by name (``path._threading_cached``), least recently used
out beyond ``path._THREADINGS_CACHED`` (2560) threadings, about 0.3 MB each. A path
table is built lazily: a single solve builds the two or three samples of its own cell
(in plain floats, or numpy for an entry that needs the refinement; the 16-cell block
around it where the cell's guess misses) and the cell's start polynomial, a batch the
whole table; entries are computed one by one, so a partly built table answers exactly
like a full one.
:func:`clear_caches` empties them all (benchmarks use it to time a first solve).
"""
from __future__ import annotations

# The private names imported here are the package's internal face: the inverse design,
# the tests and the benchmarks reach them as ``forward._name``.
from .api import reachable_range, solve_forward
from .batch import PreparedBatch, solve_forward_batch, sweep
from .branch import (_PROFILE_CACHE, SegmentBranch, _branch_derivs, _branch_solve,
                     _pair_profile_array, segment_angle_at_tension, segment_branch)
from .path import _Q_CACHE, _problem, _single, _single_named, _threading_cached
from .results import (CONSTRAINT_TOL_MM, MAX_ITER, STATIONARITY_TOL_RAD, BatchResult,
                      ForwardResult, InfeasibleLengthError, PreparedBatchResult,
                      SnapThroughError, SweepResult)
from .single import WARM_START_RADIUS_RAD, _solve_single

__all__ = [
    'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD', 'MAX_ITER', 'WARM_START_RADIUS_RAD',
    'InfeasibleLengthError', 'SnapThroughError',
    'SegmentBranch', 'segment_branch', 'segment_angle_at_tension',
    'ForwardResult', 'BatchResult', 'SweepResult', 'PreparedBatchResult',
    'reachable_range', 'solve_forward', 'solve_forward_batch', 'sweep', 'PreparedBatch',
    'clear_caches',
]


def clear_caches() -> None:
    """Empty every forward-solver cache (pair profiles and per-threading tables).

    Only the cost of the next solves changes; answers are the same.
    """
    for cached in (_problem, _single, _single_named, _threading_cached):
        cached.cache_clear()
    _PROFILE_CACHE.clear()
    _Q_CACHE.clear()
