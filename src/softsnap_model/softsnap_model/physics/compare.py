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
from dataclasses import dataclass

import numpy as np

from ..forward import solve_forward
from ..loads import Loads, solve_loaded
from ..reference import PAPER_THREADINGS as _PAPER
from ..skeleton import Skeleton
from .parameters import DEFAULT_LINKS_PER_SEGMENT, PhysicsParameters
from .simulation import RobotSimulation

__all__ = ['PAPER_THREADINGS', 'QUASI_STATIC_DAMPING_TIME_S', 'WINCH_TEST_SPEED_M_S',
           'FidelityResult', 'static_fidelity', 'LoadCaseResult', 'load_case', 'LOAD_CASES',
           'PayloadResult', 'payload_case', 'HOLD_DROP_TOL_M']

#: The paper's threadings (FACTS.md), by name, as space-separated hole names.
PAPER_THREADINGS = {name: ' '.join(holes) for name, holes in _PAPER.items()}
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
    settle_time_s : float
        Simulated time from the end of the ramp until settled (or ``max_time_s``).
    rib_centers_mm, reference_rib_centers_mm : ndarray (n_ribs, 2)
        The two shapes (module base frame).
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
    rib_centers_mm: np.ndarray = None
    reference_rib_centers_mm: np.ndarray = None
    settle_time_s: float = float('nan')


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
        settled=res.settled, sim_time_s=sim.time_s, wall_time_s=wall,
        rib_centers_mm=centers, reference_rib_centers_mm=np.array(ref.rib_centers),
        settle_time_s=res.time_s)


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


# ----------------------------------------------------------------------------- payloads

#: A payload "is held" when it sank less than this (m) in the time after it was let go.
HOLD_DROP_TOL_M = 0.01
#: Contact forces of a held payload are averaged over this last part of the hold (s).
AVERAGE_S = 0.5


@dataclass(frozen=True)
class PayloadResult:
    """The gripper closing on a payload and letting go of it (SI and mm).

    Attributes
    ----------
    scene : str
    contraction_mm : float
        Cable shortening of every finger.
    held : bool
        The payload sank less than ``HOLD_DROP_TOL_M`` in ``hold_time_s`` after release.
    drop_m : float
        How far it sank (m).
    hold_time_s : float
    finger_force_n : dict
        Module -> magnitude of the payload's contact force on that finger (N), averaged
        over the last ``AVERAGE_S`` of the hold.
    contact_rib : dict
        Module -> rib that carries most of it (-1: no contact).
    max_rib_error_mm : dict
        Module -> largest rib-centre distance between MuJoCo and ``solve_loaded`` with the
        finger's weight and the measured contact force as a point load on that rib
        (NaN where the quasi-static solve does not converge).
    tension_n : dict
        Module -> cable tension (N).
    """

    scene: str
    contraction_mm: float
    held: bool
    drop_m: float
    hold_time_s: float
    finger_force_n: dict
    contact_rib: dict
    max_rib_error_mm: dict
    tension_n: dict


def payload_case(scene='gripper', payload=None, contraction_mm: float | None = None, *,
                 links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
                 parameters: PhysicsParameters | None = None, close_time_s: float = 1.5,
                 hold_time_s: float = 2.0) -> PayloadResult:
    """Close a hanging gripper on its payload, let go of it, and compare the fingers.

    The fingers close over ``close_time_s`` to ``contraction_mm`` (default: the scene's
    default gait's amplitude) with the payload held in place (a hand), then the payload
    is released and the simulation runs ``hold_time_s``. Each finger is compared with
    :func:`softsnap_model.loads.solve_loaded` under its weight and the payload's contact
    force on it (world forces rotated into the module frame; the out-of-plane part is
    dropped, as that model does).
    """
    import mujoco
    from .parameters import Payload
    payload = Payload() if payload is None else payload
    sim = RobotSimulation(scene, links_per_segment=links_per_segment, parameters=parameters,
                          payload=payload)
    if not sim.layout.payload_hold:
        raise ValueError(f'payload_case needs a robot held in the world (the gripper); '
                         f'{sim.layout.robot!r} has a free base')
    sc = _scene(scene)
    if contraction_mm is None:
        gait = sc.gaits.get(sc.default_gait, {})
        contraction_mm = float(gait.get('amplitude_mm', 45.0))
    c = float(contraction_mm)
    dt = sim.timestep_s
    n = max(1, int(round(close_time_s / dt)))
    for i in range(n):
        for m in sim.module_names:
            sim.set_cable_length(m, sim.straight_cable_length(m) - c * 1e-3 * (i + 1) / n)
        sim.step(dt)
    sim.step(0.3)
    z0 = sim.payload_pose()[0][2]
    sim.release_payload()
    # Contact forces of the payload on each rib (world frame, N), averaged over the last
    # AVERAGE_S of the hold: a payload resting on springy fingers bounces, so one step's
    # contacts come and go.
    average_s = min(AVERAGE_S, hold_time_s)
    sim.step(hold_time_s - average_s)
    m_, d_ = sim.model, sim.data
    pid = sim._payload_id
    rib_owner = {}
    for name in sim.module_names:
        for k, b in enumerate(sim._rib_ids[name]):
            rib_owner[int(b)] = (name, k)
    forces = {name: {} for name in sim.module_names}
    f6 = np.zeros(6)
    n_avg = max(1, int(round(average_s / dt)))
    for _ in range(n_avg):
        sim.step(dt)
        for i in range(d_.ncon):
            con = d_.contact[i]
            b1, b2 = m_.geom_bodyid[con.geom1], m_.geom_bodyid[con.geom2]
            if pid not in (b1, b2):
                continue
            other = int(b2 if b1 == pid else b1)
            if other not in rib_owner:
                continue
            mujoco.mj_contactForce(m_, d_, i, f6)
            # mj_contactForce: the force geom1 exerts on geom2, in the contact frame
            # (rows of ``frame``: normal from geom1 to geom2, then two tangents).
            f_world = con.frame.reshape(3, 3).T @ f6[:3]
            on_rib = f_world if other == b2 else -f_world
            name, k = rib_owner[other]
            forces[name][k] = forces[name].get(k, np.zeros(3)) + on_rib / n_avg
    drop = float(z0 - sim.payload_pose()[0][2])
    p = parameters or PhysicsParameters()
    skeleton = sc.skeleton
    masses = np.full(skeleton.n_ribs, p.rib_mass_kg)
    masses[0] = masses[-1] = p.end_rib_mass_kg
    finger_force, contact_rib, errors, tensions = {}, {}, {}, {}
    for name in sim.module_names:
        per_rib = forces[name]
        total = sum(per_rib.values(), np.zeros(3))
        finger_force[name] = float(np.linalg.norm(total))
        rib = max(per_rib, key=lambda k: np.linalg.norm(per_rib[k])) if per_rib else -1
        contact_rib[name] = int(rib)
        tensions[name] = sim.cable_tension(name)
        _, q = sim.module_base_pose(name)
        rot = _quat_matrix(q)
        g_module = rot.T @ np.array([0.0, 0.0, -p.gravity_mps2])
        load = rot.T @ total if rib > 0 else np.zeros(3)
        loads = Loads(gravity_mps2=tuple(g_module), bending_stiffness_nmm=p.bending_stiffness_nmm,
                      rib_masses_kg=tuple(masses), load_n=tuple(load),
                      load_rib=rib if rib > 0 else -1)
        module = sc.module(name)
        length_mm = sim.cable_length(name) * 1e3
        try:
            ref = solve_loaded(skeleton, module.threading_mm, length_mm, loads)
            ok = ref.converged
        except ValueError:
            ok = False
        if ok:
            centers = sim.rib_centers(name)[:, :2] * 1e3
            errors[name] = float(np.max(np.linalg.norm(centers - ref.rib_centers, axis=1)))
        else:
            errors[name] = float('nan')
    return PayloadResult(scene=sim.layout.robot, contraction_mm=c,
                         held=bool(drop < HOLD_DROP_TOL_M), drop_m=drop,
                         hold_time_s=float(hold_time_s), finger_force_n=finger_force,
                         contact_rib=contact_rib, max_rib_error_mm=errors, tension_n=tensions)


def _scene(scene):
    from ..scene import Scene, load_scene
    return scene if isinstance(scene, Scene) else load_scene(scene)
