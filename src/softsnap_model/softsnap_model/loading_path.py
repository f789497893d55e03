"""Loads along their loading path (issue 32): a loaded shape depends on how it got there.

:func:`softsnap_model.loads.solve_loaded` answers "the unloaded shape at this cable
length, then the load applied at that fixed length". A robot does something else: its
payload or gravity is on while the winch turns. Under a load the energy can have several
strict local minima at one cable length (a module on its side sags one way or snaps the
other), and which one the robot is in depends on the path. :func:`solve_loaded_path`
follows the path:

* with ``previous`` (a :class:`~softsnap_model.loads.LoadedResult`, e.g. the last answer
  of a stream of predictions), it continues from that state: the same active-set Newton
  as ``solve_loaded``, from ``previous``'s angles at ``previous``'s cable length, the
  length then stepped to the target (at most ``step_mm`` per step);
* without it, the default for a one-off request: "load on before the cable moves": the
  loaded shape at the straight (unshortened) cable length, then the cable shortened in
  steps to the target.

The answer says which path it followed and compares itself with the other equilibria it
knows at that length (the fixed-length answer of ``solve_loaded`` and, given
``previous``, the path from the straight length): ``lower_energy_exists`` flags a
converged strict minimum with lower energy, ``alternative`` is that state. This is a
check among known candidates, not a global search.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import cable_path, rib_centers
from .loads import MAX_ITER, LoadedResult, Loads, _newton, _Problem, solve_loaded
from .skeleton import Skeleton

__all__ = ['PathLoadedResult', 'solve_loaded_path', 'LOAD_BEFORE_CABLE', 'CONTINUED',
           'DEFAULT_PATH_STEP_MM']

#: Largest cable-length step (mm) between two solves along the path.
DEFAULT_PATH_STEP_MM = 0.5
#: Smallest step (mm) before the path is declared lost (a fold: the module snaps).
MIN_PATH_STEP_MM = 1e-3
#: Equilibria closer than this (mm, largest rib-centre distance) are the same state.
SAME_STATE_MM = 0.01
#: Energy margin (N mm) below which another equilibrium counts as lower.
ENERGY_MARGIN_NMM = 1e-6
LOAD_BEFORE_CABLE = 'load on before the cable moves'
CONTINUED = 'continued from the previous state'


@dataclass(frozen=True)
class PathLoadedResult:
    """Answer of :func:`solve_loaded_path` (mm, N, N mm).

    Attributes
    ----------
    result : LoadedResult
        The equilibrium reached along the path (``converged`` False with a message if
        the path was lost).
    path : str
        ``LOAD_BEFORE_CABLE`` or ``CONTINUED``.
    start_length_mm : float
        Cable length the path started from.
    length_steps : int
        Accepted cable-length steps.
    lower_energy_exists : bool
        A known other equilibrium at this length is a converged strict minimum with
        lower energy (the robot may snap into it if disturbed).
    alternative : LoadedResult or None
        That equilibrium (the lowest one known), or None.
    alternative_distance_mm : float
        Largest rib-centre distance to it (NaN without one).
    """

    result: LoadedResult
    path: str
    start_length_mm: float
    length_steps: int
    lower_energy_exists: bool
    alternative: LoadedResult | None
    alternative_distance_mm: float


def _result(prob, skeleton, d, a, lam, active, taut, K, forces, converged, iters, steps,
            message) -> LoadedResult:
    from .loads import _reduced_hessian_min_eig
    grad, H, L, Lp, Lpp = prob.evaluate(a, 1.0)
    free = active == 0
    lam_eff = lam if taut else 0.0
    r = grad + lam_eff * Lp
    stat = float(np.max(np.abs(r[free]) / prob.k2[free], initial=0.0))
    mc = _reduced_hessian_min_eig(H + lam_eff * np.diag(Lpp), free, Lp, taut)
    cres = L - prob.target
    centers = rib_centers(a, skeleton.spacing_mm)
    energy = K * float(skeleton.stiffness_array @ (a * a)) - float(np.sum(forces * centers))
    return LoadedResult(
        angles=a.copy(), rib_centers=centers, cable_path=cable_path(a, d, skeleton.spacing_mm),
        tension_n=float(lam) if taut else 0.0, slack=not taut, at_contact=active != 0,
        energy_nmm=energy, cable_length_mm=float(L), converged=bool(converged),
        constraint_residual_mm=float(abs(cres) if taut else max(cres, 0.0)),
        stationarity_residual_rad=stat, min_curvature=float(mc), is_minimum=bool(mc > 0.0),
        iterations=int(iters), load_steps=int(steps), message=message)


def _follow(skeleton, d, forces, K, state, start_mm, target_mm, step_mm):
    """Step the cable from ``start_mm`` to ``target_mm`` from ``state`` (full load)."""
    a, lam, active, taut = state
    prob = _Problem(skeleton, d, forces, K, float(start_mm))
    length, step, iters, steps = float(start_mm), float(step_mm), 0, 0
    message = 'ok'
    # Settle at the start length first (continuing from a state given at that length).
    out = _newton(prob, a, lam, active, taut, 1.0, MAX_ITER)
    iters += out[4]
    if out[5] != 'ok':
        return _result(prob, skeleton, d, a, lam, active, taut, K, forces, False, iters,
                       steps, f'no equilibrium at the start length ({out[5]})'), steps
    a, lam, active, taut = out[0], out[1], out[2], out[3]
    while abs(target_mm - length) > 1e-12:
        trial = length + math.copysign(min(step, abs(target_mm - length)), target_mm - length)
        prob.target = trial
        out = _newton(prob, a, lam, active, taut, 1.0, MAX_ITER)
        iters += out[4]
        if out[5] == 'ok' and out[6][2] > 0.0:
            a, lam, active, taut = out[0], out[1], out[2], out[3]
            length = trial
            steps += 1
            step = min(float(step_mm), 2.0 * step)
        else:
            step *= 0.5
            if step < MIN_PATH_STEP_MM:
                prob.target = length
                message = (f'the path is lost at {length:.4f} mm (a fold: the module would '
                           f'snap to another shape)')
                return _result(prob, skeleton, d, a, lam, active, taut, K, forces, False,
                               iters, steps, message), steps
    return _result(prob, skeleton, d, a, lam, active, taut, K, forces, True, iters, steps,
                   message), steps


def _state(res: LoadedResult, K):
    a = np.array(res.angles, dtype=float)
    active = np.where(res.at_contact, np.sign(a), 0).astype(int)
    return a, float(res.tension_n), active, not res.slack


def solve_loaded_path(skeleton: Skeleton, threading, length_mm: float, loads: Loads,
                      previous: LoadedResult | None = None,
                      step_mm: float = DEFAULT_PATH_STEP_MM,
                      check_alternatives: bool = True) -> PathLoadedResult:
    """Loaded shape at ``length_mm`` reached along the loading path (module docstring).

    Raises ValueError for bad input (as ``solve_loaded``) or a bad ``step_mm`` /
    ``previous``; an infeasible length raises ``InfeasibleLengthError``.
    """
    if not isinstance(loads, Loads):
        raise ValueError(f'loads must be a Loads, got {type(loads).__name__}')
    step = float(step_mm)
    if not math.isfinite(step) or not MIN_PATH_STEP_MM <= step <= 50.0:
        raise ValueError(f'step_mm must be in [{MIN_PATH_STEP_MM}, 50] mm, got {step_mm!r}')
    d = skeleton.threading_mm(threading)
    K = loads.bending_stiffness_nmm
    forces = loads.rib_forces_n(skeleton.n_ribs)
    straight = skeleton.straight_length_mm(d)
    fixed = solve_loaded(skeleton, d, length_mm, loads)     # validates the length
    if previous is not None:
        if not isinstance(previous, LoadedResult) \
                or np.shape(previous.angles) != (skeleton.n_segments,):
            raise ValueError('previous must be a LoadedResult of this skeleton')
        start = float(previous.cable_length_mm)
        state, path = _state(previous, K), CONTINUED
    else:
        first = solve_loaded(skeleton, d, straight, loads)
        if not first.converged:
            return PathLoadedResult(first, LOAD_BEFORE_CABLE, straight, 0, False, None,
                                    float('nan'))
        start, state, path = straight, _state(first, K), LOAD_BEFORE_CABLE
    res, steps = _follow(skeleton, d, forces, K, state, start, float(length_mm), step)
    alternative, lower, dist = None, False, float('nan')
    if check_alternatives and res.converged:
        candidates = [fixed]
        if previous is not None:
            candidates.append(solve_loaded_path(skeleton, d, length_mm, loads, None, step,
                                                False).result)
        for cand in candidates:
            if not (cand.converged and cand.is_minimum):
                continue
            gap = float(np.max(np.linalg.norm(cand.rib_centers - res.rib_centers, axis=1)))
            if gap > SAME_STATE_MM and cand.energy_nmm < res.energy_nmm - ENERGY_MARGIN_NMM \
                    and (alternative is None or cand.energy_nmm < alternative.energy_nmm):
                alternative, lower, dist = cand, True, gap
    return PathLoadedResult(res, path, start, steps, lower, alternative, dist)
