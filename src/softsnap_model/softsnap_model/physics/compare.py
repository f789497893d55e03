"""MuJoCo shapes against the quasi-static model: fidelity and load checks (needs ``mujoco``).

* :func:`static_fidelity`: gravity off, the winch shortened slowly, the settled MuJoCo
  shape against :func:`softsnap_model.forward.solve_forward` (the discretisation's error:
  it falls as the links per segment grow).
* :func:`load_case`: a module under gravity (lying on the ground, hanging down,
  horizontal) against :func:`softsnap_model.loads.solve_loaded`.

Distances are reported in millimetres (names ending in ``_mm``), like the quasi-static
core; the simulation itself is SI.
"""
from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..forward import solve_forward
from ..loads import Loads, solve_loaded
from ..skeleton import Skeleton
from .mjcf import DEFAULT_LINKS_PER_SEGMENT, PhysicsParameters
from .simulation import RobotSimulation

__all__ = ['PAPER_THREADINGS', 'QUASI_STATIC_DAMPING_TIME_S', 'WINCH_TEST_SPEED_M_S',
           'FidelityResult', 'static_fidelity', 'LoadCaseResult', 'load_case', 'LOAD_CASES']

#: The paper's threadings (FACTS.md), by name.
PAPER_THREADINGS = {
    'yellow': 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3',
    'blue': 'R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2',
    'green': 'R1 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3',
    'red': 'R3 R3 R3 R3 R3 R2 R1 L3 L3 L3 L3 L3',
    'orange': 'R3 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3',
    'gripper': 'R1 R2 R2 L1 L3 L3 L3 L3 L3 L3 L3 L3',
    'snake': 'R2 R3 R3 R3 L3 L3 L3 L3 R3 R3 R3 R3',
    's': 'R3 R3 R3 R3 R3 R3 L3 L3 L3 L3 L3 L3',
    'w': 'R3 R3 R3 R3 L2 L3 L2 R3 R3 R3 R3 R3',
}
#: Damping time (s) used for static comparisons: the settled shape does not depend on
#: damping, and a heavier one settles the first bending mode sooner.
QUASI_STATIC_DAMPING_TIME_S = 0.05
#: Winch speed (m/s) of the "slow actuation" in the comparisons: 20 mm in 1 s, slow
#: against the module's first bending mode (~8 rad/s).
WINCH_TEST_SPEED_M_S = 0.02
#: Settling criterion of the comparisons (rad/s), held for SETTLE_HOLD_S.
COMPARE_SPEED_TOL = 1e-5


@dataclass(frozen=True)
class FidelityResult:
    """One static comparison (mm, N, s).

    Attributes
    ----------
    threading : str
    contraction_mm : float
    links_per_segment : int
    max_rib_error_mm : float
        Largest distance between a MuJoCo rib centre and the quasi-static one.
    tip_error_mm : float
        Distance between the tip rib centres.
    max_angle_error_rad : float
    tension_n, reference_tension_n : float
        MuJoCo's cable tension and the model's ``lambda K``.
    settled : bool
    sim_time_s, wall_time_s : float
        Simulated time (ramp and settling) and the wall-clock time it took.
    """

    threading: str
    contraction_mm: float
    links_per_segment: int
    max_rib_error_mm: float
    tip_error_mm: float
    max_angle_error_rad: float
    tension_n: float
    reference_tension_n: float
    settled: bool
    sim_time_s: float
    wall_time_s: float


def _closest_branch(skeleton, threading, length_mm, centers_mm):
    """solve_forward's answer, on the mirror branch nearest the simulated shape."""
    ref = solve_forward(skeleton, threading, length_mm)
    best, best_err = ref, np.max(np.linalg.norm(centers_mm - ref.rib_centers, axis=1))
    ties = tuple(ref.tie_break_segments)
    for r in range(1, len(ties) + 1):
        for flip in itertools.combinations(ties, r):
            alt = solve_forward(skeleton, threading, length_mm, mirror_flip=flip)
            err = np.max(np.linalg.norm(centers_mm - alt.rib_centers, axis=1))
            if err < best_err:
                best, best_err = alt, err
    return best


def static_fidelity(threading, contraction_mm: float = 20.0, *,
                    links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
                    skeleton: Skeleton | None = None,
                    parameters: PhysicsParameters | None = None,
                    max_time_s: float = 10.0) -> FidelityResult:
    """Settled MuJoCo shape (gravity off, slow winch) against ``solve_forward``.

    Parameters
    ----------
    threading : str or sequence
        One hole per rib (``'R3 R3 ...'`` or a list), or a key of ``PAPER_THREADINGS``.
    contraction_mm : float
        Cable shortening from straight (mm), > 0.
    links_per_segment : int
    skeleton : Skeleton, optional
    parameters : PhysicsParameters, optional
        Default: the defaults with ``damping_time_s = QUASI_STATIC_DAMPING_TIME_S``.
    max_time_s : float
        Longest settling time (simulated s).
    """
    skeleton = Skeleton() if skeleton is None else skeleton
    text = PAPER_THREADINGS.get(threading, threading) if isinstance(threading, str) \
        else ' '.join(map(str, threading))
    holes = text.split()
    c = float(contraction_mm)
    if not math.isfinite(c) or c <= 0.0:
        raise ValueError(f'contraction_mm must be finite and > 0, got {contraction_mm!r}')
    params = parameters or PhysicsParameters(damping_time_s=QUASI_STATIC_DAMPING_TIME_S)
    start = time.perf_counter()
    sim = RobotSimulation.single_module(holes, skeleton, links_per_segment=links_per_segment,
                                        parameters=params)
    length_m = sim.straight_cable_length('module') - c * 1e-3
    sim.ramp_cable_length('module', length_m, WINCH_TEST_SPEED_M_S)
    res = sim.settle(max_time_s, speed_tol=COMPARE_SPEED_TOL)
    wall = time.perf_counter() - start
    centers = sim.rib_centers('module')[:, :2] * 1e3
    ref = _closest_branch(skeleton, holes, length_m * 1e3, centers)
    err = np.linalg.norm(centers - ref.rib_centers, axis=1)
    k = params.bending_stiffness_nmm
    return FidelityResult(
        threading=text, contraction_mm=c, links_per_segment=sim.layout.links_per_segment,
        max_rib_error_mm=float(err.max()), tip_error_mm=float(err[-1]),
        max_angle_error_rad=float(np.abs(sim.segment_angles('module') - ref.angles).max()),
        tension_n=sim.cable_tension('module'), reference_tension_n=float(ref.tension * k),
        settled=res.settled, sim_time_s=sim.time_s, wall_time_s=wall)


# --------------------------------------------------------------------------- load cases

#: Module-base orientations (w, x, y, z) and the gravity they give in the module frame.
#: ``flat``: lying on the ground (gravity across the bending plane: no in-plane load);
#: ``hanging``: tip down; ``side``: spine horizontal, bending in the vertical plane, the
#: right ("R") side down, so gravity pulls toward -y like ``Loads(gravity=(0,-g,0))``.
LOAD_CASES = {
    'flat': ((1.0, 0.0, 0.0, 0.0), True),
    'hanging': ((math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0), False),
    'side': ((math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0), False),
}


@dataclass(frozen=True)
class LoadCaseResult:
    """A module under gravity: MuJoCo against ``solve_loaded`` (mm, N).

    Attributes
    ----------
    case : str
        Key of ``LOAD_CASES``.
    threading : str
    contraction_mm : float
    max_rib_error_mm, tip_error_mm : float
        MuJoCo against the quasi-static loaded prediction.
    tip_sag_mm : float
        Quasi-static tip displacement caused by the loads (loaded minus unloaded), for
        scale.
    tension_n, reference_tension_n : float
    quasi_static_converged, settled : bool
    rib_centers_mm, reference_rib_centers_mm : ndarray (n_ribs, 2)
        Module base frame.
    """

    case: str
    threading: str
    contraction_mm: float
    max_rib_error_mm: float
    tip_error_mm: float
    tip_sag_mm: float
    tension_n: float
    reference_tension_n: float
    quasi_static_converged: bool
    settled: bool
    rib_centers_mm: np.ndarray
    reference_rib_centers_mm: np.ndarray


def load_case(case: str, threading='yellow', contraction_mm: float = 20.0, *,
              links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
              skeleton: Skeleton | None = None,
              parameters: PhysicsParameters | None = None,
              max_time_s: float = 15.0) -> LoadCaseResult:
    """Settle a module clamped at its base under gravity and compare with ``solve_loaded``.

    ``case`` is a key of :data:`LOAD_CASES`. ``flat`` lies on the ground (friction acts
    while the winch pulls, so MuJoCo may stop short of the frictionless prediction).
    """
    if case not in LOAD_CASES:
        raise ValueError(f'unknown load case {case!r}; known: {", ".join(LOAD_CASES)}')
    skeleton = Skeleton() if skeleton is None else skeleton
    text = PAPER_THREADINGS.get(threading, threading) if isinstance(threading, str) \
        else ' '.join(map(str, threading))
    holes = text.split()
    quat, on_ground = LOAD_CASES[case]
    params = parameters or PhysicsParameters(damping_time_s=QUASI_STATIC_DAMPING_TIME_S)
    # On the ground the skeleton's underside touches z = 0: its mid-plane is half the
    # skeleton thickness up; otherwise clamp it well above any ground.
    height = 0.5 * 9.0e-3 + 1e-4 if on_ground else 0.5
    sim = RobotSimulation.single_module(holes, skeleton, links_per_segment=links_per_segment,
                                        parameters=params, gravity=True, ground=on_ground,
                                        base_position_m=(0.0, 0.0, height),
                                        base_orientation_wxyz=quat)
    sim.settle(max_time_s, speed_tol=COMPARE_SPEED_TOL)    # sag under its own weight
    length_m = sim.straight_cable_length('module') - float(contraction_mm) * 1e-3
    sim.ramp_cable_length('module', length_m, WINCH_TEST_SPEED_M_S)
    res = sim.settle(max_time_s, speed_tol=COMPARE_SPEED_TOL)
    centers = sim.rib_centers('module')[:, :2] * 1e3
    # Gravity in the module base frame: world -z rotated into the base.
    _, q = sim.module_base_pose('module')
    rot = _quat_matrix(q)
    g_module = rot.T @ np.array([0.0, 0.0, -params.gravity_mps2])
    masses = np.full(skeleton.n_ribs, params.rib_mass_kg)
    masses[0] = masses[-1] = params.end_rib_mass_kg
    loads = Loads(gravity_mps2=tuple(g_module), bending_stiffness_nmm=params.bending_stiffness_nmm,
                  rib_masses_kg=tuple(masses))
    ref = solve_loaded(skeleton, holes, length_m * 1e3, loads)
    free = solve_forward(skeleton, holes, length_m * 1e3)
    err = np.linalg.norm(centers - ref.rib_centers, axis=1)
    return LoadCaseResult(
        case=case, threading=text, contraction_mm=float(contraction_mm),
        max_rib_error_mm=float(err.max()), tip_error_mm=float(err[-1]),
        tip_sag_mm=float(np.linalg.norm(ref.rib_centers[-1] - free.rib_centers[-1])),
        tension_n=sim.cable_tension('module'), reference_tension_n=float(ref.tension_n),
        quasi_static_converged=bool(ref.converged), settled=res.settled,
        rib_centers_mm=centers, reference_rib_centers_mm=np.array(ref.rib_centers))


def _quat_matrix(q) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
