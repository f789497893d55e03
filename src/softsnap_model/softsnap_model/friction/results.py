"""Contracts of the friction solve, the branch directions and its frozen results."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: Length contract (mm): ``|sum L_i - L| <= CONSTRAINT_TOL_MM``; also stuck holes' ``S_k``.
CONSTRAINT_TOL_MM = 1e-9

#: Equilibrium contract (rad): every angle within this of its branch angle at its tension.
STATIONARITY_TOL_RAD = 1e-10

#: Slip contract (dimensionless): ``|log(T_k/T_{k-1}) -+ mu_k theta_k|`` on slipping holes.
SLIP_TOL = 1e-10

#: Branch check (rad): every angle within this of the followed branch's angle at its
#: tension (:func:`~softsnap_model.forward.segment_angle_at_tension`).
BRANCH_TOL_RAD = 1e-6

#: Newton iterations per active set before the fallback.
MAX_ITER = 60

#: Estimated friction coefficient of a PE/nylon line in printed TPU holes (not measured).
TYPICAL_FRICTION_RANGE = (0.1, 0.3)

#: Hole modes: slipping towards the winch (pulled), towards the tip (released), stuck.
PULL, RELEASE, STICK = -1, 1, 0

# Internal targets, tighter than the contracts.
_TOL_RAD = 1e-13

_TOL_MM = 1e-12

_TOL_SLIP = 1e-13

# A stuck hole's tension ratio may leave its cone by this much (log units) before it slips.
_CONE_TOL = 1e-9

# A slipping hole may move against its friction by this much (mm) before it sticks.
_MOVE_TOL_MM = 1e-9

# ----------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrictionResult:
    """Result of :func:`solve_friction` (and one step of :func:`friction_sweep`).

    Attributes
    ----------
    angles : ndarray (n_segments,)
        Bending angles (rad).
    rib_centers, cable_path : ndarray (n_ribs, 2)
        Rib centres and threaded hole positions (mm), base frame.
    segment_tensions : ndarray (n_segments,)
        Tension of each cable segment (rad^2/mm; times K for N); 0 when slack.
    winch_tension : float
        Tension on the winch side of the base hole (rad^2/mm).
    wrap_angles : ndarray (n_segments,)
        Wrap angle at the holes of ribs 0..n-2 (rad), :func:`wrap_angles`.
    total_wrap_rad : float
        ``sum wrap_angles``.
    tip_tension_ratio : float
        ``segment_tensions[-1] / winch_tension`` (1 without friction; nan when slack).
    hole_modes : ndarray of int (n_segments,)
        Per hole: ``PULL`` (-1), ``RELEASE`` (+1) or ``STICK`` (0); entry 0 is the winch
        motion.
    at_contact, held_straight : ndarray of bool (n_segments,)
        Segments held at rib contact, and mirror segments held straight.
    friction : ndarray (n_segments,)
        Friction coefficient per hole used.
    direction : str
        'pull', 'release' or 'hold'.
    converged : bool
        Every check of the accuracy contract passed (module docstring).
    constraint_residual : float
        ``|sum L_i - L|`` (mm).
    stationarity_residual : float
        ``max |a_i + T_i L_i'/(2 k_i)|`` over free segments, ``|a_i - a_branch|`` over
        held ones (rad).
    slip_residual : float
        Largest slip-relation residual (dimensionless), or stick-relation (mm) residual.
    iterations : int
        Newton iterations, all active sets together.
    slack : bool
        Length at or above the straight length: straight shape, no tension.
    cable_length_mm : float
    message : str
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    segment_tensions: np.ndarray
    winch_tension: float
    wrap_angles: np.ndarray
    total_wrap_rad: float
    tip_tension_ratio: float
    hole_modes: np.ndarray
    at_contact: np.ndarray
    held_straight: np.ndarray
    friction: np.ndarray
    direction: str
    converged: bool
    constraint_residual: float
    stationarity_residual: float
    slip_residual: float
    iterations: int
    slack: bool
    cable_length_mm: float
    message: str

    @property
    def success(self) -> bool:
        """Alias of ``converged`` (scipy naming)."""
        return self.converged


@dataclass(frozen=True)
class FrictionSweepResult:
    """Result of :func:`friction_sweep`: one :class:`FrictionResult` per length.

    Attributes
    ----------
    steps : tuple of FrictionResult
    cable_lengths_mm : ndarray (B,)
    angles : ndarray (B, n_segments)
    rib_centers : ndarray (B, n_ribs, 2)
    winch_tension : ndarray (B,)
    converged : bool
        Every step converged.
    """

    steps: tuple
    cable_lengths_mm: np.ndarray
    angles: np.ndarray
    rib_centers: np.ndarray
    winch_tension: np.ndarray
    converged: bool

    def __len__(self):
        return len(self.steps)
