"""Contracts, errors and result types of the forward solver.

Owns the public tolerances (:data:`CONSTRAINT_TOL_MM`, :data:`STATIONARITY_TOL_RAD`,
:data:`MAX_ITER`), the documented errors (:class:`InfeasibleLengthError`,
:class:`SnapThroughError`) and the frozen results (:class:`ForwardResult`,
:class:`BatchResult`, :class:`SweepResult`, :class:`PreparedBatchResult`). No solving
happens here.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


#: Constraint contract: ``|sum_i L_i - L_target| <= CONSTRAINT_TOL_MM`` (mm) on success.
CONSTRAINT_TOL_MM = 1e-9

#: Stationarity contract: ``max_i |a_i + lambda L_i'(a_i) / (2 k_i)| <= STATIONARITY_TOL_RAD``
#: (rad) over the segments that are not held straight or at contact.
STATIONARITY_TOL_RAD = 1e-10

#: Default cap on Newton iterations of one solve.
MAX_ITER = 40


class InfeasibleLengthError(ValueError):
    """Cable length below what the threading reaches along the quasi-static path.

    Attributes
    ----------
    reachable_range_mm : tuple of float
        ``(min_length_mm, straight_length_mm)``; the minimum itself is approached as
        the tension grows without bound and is not attained.
    """

    def __init__(self, message, reachable_range_mm):
        super().__init__(message)
        self.reachable_range_mm = tuple(float(v) for v in reachable_range_mm)


class SnapThroughError(InfeasibleLengthError):
    """The quasi-static path folds (snap-through) before reaching the requested length.

    ``reachable_range_mm[0]`` is the cable length at the fold.
    """


@dataclass(frozen=True)
class ForwardResult:
    """Result of :func:`solve_forward` (scipy.optimize style).

    Attributes
    ----------
    angles : ndarray, shape (n_segments,)
        Bending angles (rad, counter-clockwise positive).
    rib_centers : ndarray, shape (n_ribs, 2)
        Rib centres (mm) in the base frame.
    cable_path : ndarray, shape (n_ribs, 2)
        Threaded hole positions (mm); the cable runs straight between them.
    energy : float
        ``sum k_i a_i^2`` (rad^2).
    tension : float
        Multiplier ``lambda`` (rad^2/mm); 0 when slack. See the module docstring.
    iterations : int
        Newton iterations (0 for a slack cable).
    converged : bool
        Both residual contracts hold and the point is a constrained local minimum.
    residual : float
        ``max(constraint_residual, stationarity_residual)``.
    constraint_residual : float
        ``|sum L_i - L_target|`` (mm); contract ``CONSTRAINT_TOL_MM``.
    stationarity_residual : float
        ``max |a_i + lambda L_i' / (2 k_i)|`` (rad) over segments that are neither held
        straight nor at contact; contract ``STATIONARITY_TOL_RAD``.
    is_minimum : bool
        Second-order check: the Lagrangian Hessian ``diag(2 k_i + lambda L_i'')`` is
        positive on the tangent space of the constraint (segments at contact are on
        an active bound and excluded).
    min_curvature : float
        Smallest ``1 + lambda L_i'' / (2 k_i)`` over non-contact segments (> 0 for a
        strict minimum; near 0 next to a buckling or fold point).
    slack : bool
        The requested length is at or above the straight length.
    at_contact : ndarray of bool
        Segments held at the rib-contact angle.
    cable_length_mm : float
        Requested length.
    message : str
    tie_break_segments : tuple of int
        Mirror segments (``d2 = -d1``) that are bent: their direction was a tie-break
        (the rule in the module docstring), and bending them the other way is an equally
        good answer (same length, energy and tension; ``solve_forward(...,
        mirror_flip=...)``). Mirror segments still straight are not listed.
    mirror_flip : tuple of int
        Mirror segments bent against the tie-break rule on request (``mirror_flip``).
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    energy: float
    tension: float
    iterations: int
    converged: bool
    residual: float
    constraint_residual: float
    stationarity_residual: float
    is_minimum: bool
    min_curvature: float
    slack: bool
    at_contact: np.ndarray
    cable_length_mm: float
    message: str
    tie_break_segments: tuple = ()
    mirror_flip: tuple = ()

    @property
    def success(self) -> bool:
        """Alias of ``converged`` (scipy naming)."""
        return self.converged


def _forward_result(**fields) -> ForwardResult:
    """A :class:`ForwardResult` from every one of its fields, built without the frozen
    dataclass's ``__init__`` (one ``object.__setattr__`` per field, a measurable part of
    a single solve). The result is the same frozen, comparable object."""
    result = object.__new__(ForwardResult)
    result.__dict__.update(fields)
    return result


@dataclass(frozen=True)
class BatchResult:
    """Result of :func:`solve_forward_batch`: the ForwardResult fields as arrays.

    ``angles`` (B, n_segments), ``rib_centers`` and ``cable_path`` (B, n_ribs, 2), the
    scalar fields of :class:`ForwardResult` as (B,) arrays, ``at_contact`` (B, n),
    ``tie_break`` (B, n): bent mirror segments (``ForwardResult.tie_break_segments``).
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    energy: np.ndarray
    tension: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    residual: np.ndarray
    constraint_residual: np.ndarray
    stationarity_residual: np.ndarray
    is_minimum: np.ndarray
    min_curvature: np.ndarray
    slack: np.ndarray
    at_contact: np.ndarray
    cable_length_mm: np.ndarray
    tie_break: np.ndarray = None

    def __len__(self):
        return self.angles.shape[0]

    def item(self, i: int, message: str = '') -> ForwardResult:
        """The i-th solve as a :class:`ForwardResult`."""
        return ForwardResult(
            angles=self.angles[i], rib_centers=self.rib_centers[i],
            cable_path=self.cable_path[i], energy=float(self.energy[i]),
            tension=float(self.tension[i]), iterations=int(self.iterations[i]),
            converged=bool(self.converged[i]), residual=float(self.residual[i]),
            constraint_residual=float(self.constraint_residual[i]),
            stationarity_residual=float(self.stationarity_residual[i]),
            is_minimum=bool(self.is_minimum[i]), min_curvature=float(self.min_curvature[i]),
            slack=bool(self.slack[i]), at_contact=self.at_contact[i],
            cable_length_mm=float(self.cable_length_mm[i]), message=message,
            tie_break_segments=(() if self.tie_break is None else
                                tuple(int(j) for j in np.nonzero(self.tie_break[i])[0])))


@dataclass(frozen=True)
class SweepResult(BatchResult):
    """Result of :func:`sweep`; ``contractions_mm`` (B,) is the swept input."""

    contractions_mm: np.ndarray = field(default=None)


@dataclass(frozen=True)
class PreparedBatchResult(BatchResult):
    """Result of :meth:`PreparedBatch.solve`: a :class:`BatchResult` whose bad rows are
    refused one by one instead of failing the whole batch.

    ``refused`` (a tuple of B strings) is ``''`` for a row that was solved, else why it
    was not: the message of the error :func:`solve_forward` raises for that row (bad
    threading, NaN, a length at or below the reachable minimum...). A refused row has
    NaN angles, rib centres, cable path and real-valued fields, zero iterations and
    False flags; every other row is exactly as if solved alone.
    """

    refused: tuple = ()
