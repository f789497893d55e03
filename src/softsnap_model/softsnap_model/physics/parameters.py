"""The numbers of the MuJoCo model: :class:`PhysicsParameters` (each with its source or
estimate), :class:`Payload` and the limits they are checked against."""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

from ..loads import (DEFAULT_BENDING_STIFFNESS_NMM, DEFAULT_END_RIB_MASS_KG,
                     DEFAULT_RIB_MASS_KG, MOTOR_BOX_MASS_KG_ESTIMATE, STANDARD_GRAVITY_MPS2)
from .rib_contact import RIB_CONTACT_MODES

#: Links per segment when none is given: with the chord-matched link lengths
#: (:func:`link_lengths`) the rib centres are within 0.1 mm of the exact
#: constant-curvature model at 20 mm contraction from N = 2 (tests and
#: benchmarks/physics_bench.py); N = 1 is ~14 mm off, and every extra link costs run time.
DEFAULT_LINKS_PER_SEGMENT = 2

#: Largest links per segment accepted (cost grows linearly; error is ~1/N^2).
MAX_LINKS_PER_SEGMENT = 64

#: Skeleton thickness across the bending plane (mm), FACTS.md (201 x 25 x 9 mm).
SKELETON_THICKNESS_MM = 9.0

#: Largest payload mass (kg) and size (m) accepted: a module pulls ~10 N at most.
MAX_PAYLOAD_MASS_KG = 1.0

MAX_PAYLOAD_SIZE_M = 0.2

#: Payload shapes the model builds (:class:`Payload`).
PAYLOAD_SHAPES = ('ball', 'box', 'cylinder')


def _check_real(name, value, *, low=None, high=None, low_open=False, allow_zero=True):
    if isinstance(value, bool) or not isinstance(value, numbers.Real) \
            or not math.isfinite(value):
        raise ValueError(f'{name} must be a finite number, got {value!r}')
    value = float(value)
    if low is not None and (value < low or (low_open and value == low)):
        bound = f'> {low}' if low_open else f'>= {low}'
        raise ValueError(f'{name} must be {bound}' + (f' and <= {high}' if high is not None
                                                      else '') + f', got {value!r}')
    if high is not None and value > high:
        raise ValueError(f'{name} must be <= {high}, got {value!r}')
    return value


@dataclass(frozen=True)
class PhysicsParameters:
    """Every physical and numerical number of the MuJoCo model (SI unless named).

    Attributes
    ----------
    bending_stiffness_nmm : float
        ``K`` (N mm/rad^2): segment energy ``K k_i a_i^2``. Default
        :data:`softsnap_model.loads.DEFAULT_BENDING_STIFFNESS_NMM` (17.6, estimated from
        TPU 95A's modulus and the 3 x 9 mm spine; uncertain by a factor 2-3). Measure it
        by hanging a known weight from the tip of a straight module held horizontally
        (cable slack) and fitting the tip deflection with
        :func:`softsnap_model.loads.solve_loaded` (docs/physics.md).
    damping_time_s : float
        Ratio of hinge damping to hinge stiffness (s). Estimate: TPU's loss factor ~0.15
        (damping ratio ~0.08) at the first bending mode of a module held at its base
        (~8 rad/s with the default masses): ``2 * 0.08 / 8`` = 0.02 s.
    rib_mass_kg, end_rib_mass_kg : float
        Mass of an interior / end rib including half of each adjacent spine rod (kg),
        :data:`softsnap_model.loads.DEFAULT_RIB_MASS_KG` (1.19 g) and
        ``DEFAULT_END_RIB_MASS_KG`` (0.97 g), from the CAD volume at TPU's density. The
        same lumping as the quasi-static load model, so the two compare like for like.
    link_mass_kg : float
        Mass of each intermediate spine link (kg). Numerical: the rods' mass is already
        in the ribs; 10 mg keeps the link bodies well defined (0.8 % of a rib each).
    motor_box_mass_kg, battery_mass_kg : float
        Motor box with motor, PCB and PLA shell (20 g) and its 200 mAh Li-ion cell (5 g):
        :data:`softsnap_model.loads.MOTOR_BOX_MASS_KG_ESTIMATE` (25 g) split by the
        typical mass of an 80130 cell (~5 g).
    motor_box_size_mm : tuple of 3 float
        Motor box length along the spine, width along the ribs, height (mm). Estimate:
        30 x 25 mm; its height equals the skeleton's 9 mm so a module lies flat on the
        ground on its ribs and its box (the model has no out-of-plane bending that would
        let a thicker box's module sag onto the ground).
    connector_density_kg_m3 : float
        Effective density of the printed connectors (kg/m^3): PLA (1240) at ~40 %
        effective fill (walls plus infill), estimate.
    rib_friction : float
        Sliding friction coefficient of ribs, boxes and connectors on the ground.
        Estimate for TPU/PLA on a table (0.3-0.8); the gaits' travel depends on it.
    payload_friction : float
        Sliding friction of the payload on ribs and ground (estimate, PLA ball).
    constraint_stiffness_dt2, constraint_damping_dt : float
        Reference stiffness ``k`` (1/s^2) and damping ``b`` (1/s) of the cable's length
        limit and of the hinge-coupling equalities, given as the dimensionless
        ``k dt^2`` and ``b dt`` so that they follow the timestep (MuJoCo's negative
        ``solref = (-k, -b)``), with impedance ``constraint_impedance``. These are
        acceleration-space values: the ribs weigh a gram, so a time-constant ``solref``
        stiff enough to hold the cable (0.1 mm stretch needs ~2 ms) chatters between
        taut and slack; a heavily overdamped reference (``k dt^2 = 1``, ``b dt = 10``)
        holds the cable within 0.001 mm below contact and settles with the 3e-8
        armature (hard contact uses the deadbeat ``0.25, 1`` with 1e-5 instead).
    constraint_impedance : float
        ``solimp`` impedance of those constraints, in (0, 1): closer to 1 is harder.
    contact_rib_stride : int
        Every how many ribs one has a ground contact, counted from the tip (1: every
        rib). The spine is rigid out of its plane, so fewer contacts still carry a
        flat module; they cost less but concentrate the friction.
    hinge_armature_kgm2 : float
        Armature added to every hinge (kg m^2), numerical: 3e-8 (half a rib's own
        moment of inertia) slows the light links' fastest local modes so that a 2 ms
        step settles below contact up to N = 8. Hard rib contact needs 1e-5
        (:func:`~softsnap_model.physics.rib_contact.hard_contact_parameters`).
    scale_armature : bool
        Scale the armature with the step and N (:func:`~softsnap_model.physics.
        rib_contact.hinge_armature_kgm2`); False: every hinge gets the value as given.
    rib_contact : str
        ``'soft'`` (default: MuJoCo's default limit on every hinge) or ``'hard'``
        (issue 32; use the whole set of ``rib_contact.hard_contact_parameters()``).
    rib_contact_stiffness_dt2, rib_contact_damping_dt, rib_contact_impedance : float
        The hard limit's ``k dt^2``, ``b dt`` and ``solimp`` impedance (deadbeat 0.25, 1,
        at 0.99: the cable's 0.9999 with these chatters on the links at full contact).
    timestep_s : float
        Fixed integration step (s) with the ``implicitfast`` integrator. 2 ms is stable
        for the five scenes and the fidelity checks (implicit hinge damping; constraint
        references scaled with the step); 4 ms is not for robots on the ground.
    gravity_mps2 : float
        Magnitude of gravity (m/s^2), along world -z.
    """

    bending_stiffness_nmm: float = DEFAULT_BENDING_STIFFNESS_NMM
    damping_time_s: float = 0.02
    rib_mass_kg: float = DEFAULT_RIB_MASS_KG
    end_rib_mass_kg: float = DEFAULT_END_RIB_MASS_KG
    link_mass_kg: float = 1e-5
    motor_box_mass_kg: float = MOTOR_BOX_MASS_KG_ESTIMATE - 5e-3
    battery_mass_kg: float = 5e-3
    motor_box_size_mm: tuple = (30.0, 25.0, SKELETON_THICKNESS_MM)
    connector_density_kg_m3: float = 1240.0 * 0.4
    rib_friction: float = 0.6
    payload_friction: float = 0.8
    constraint_stiffness_dt2: float = 1.0
    constraint_damping_dt: float = 10.0
    constraint_impedance: float = 0.9999
    hinge_armature_kgm2: float = 3e-8
    scale_armature: bool = False
    rib_contact: str = 'soft'
    rib_contact_stiffness_dt2: float = 0.25
    rib_contact_damping_dt: float = 1.0
    rib_contact_impedance: float = 0.99
    contact_rib_stride: int = 1
    timestep_s: float = 0.002
    gravity_mps2: float = STANDARD_GRAVITY_MPS2

    def __post_init__(self):
        for name in ('bending_stiffness_nmm', 'damping_time_s', 'rib_mass_kg',
                     'end_rib_mass_kg', 'link_mass_kg', 'motor_box_mass_kg',
                     'battery_mass_kg', 'connector_density_kg_m3', 'rib_friction',
                     'payload_friction', 'constraint_stiffness_dt2', 'constraint_damping_dt',
                     'rib_contact_stiffness_dt2', 'rib_contact_damping_dt'):
            object.__setattr__(self, name, _check_real(name, getattr(self, name), low=0.0,
                                                       low_open=True))
        object.__setattr__(self, 'timestep_s', _check_real(
            'timestep_s', self.timestep_s, low=0.0, low_open=True, high=0.01))
        object.__setattr__(self, 'gravity_mps2', _check_real(
            'gravity_mps2', self.gravity_mps2, low=0.0, high=100.0))
        size = self.motor_box_size_mm
        try:
            size = tuple(_check_real('motor_box_size_mm', v, low=0.0, low_open=True)
                         for v in size)
        except TypeError:
            raise ValueError(f'motor_box_size_mm must be 3 numbers (mm), got {size!r}') \
                from None
        if len(size) != 3:
            raise ValueError(f'motor_box_size_mm must be 3 numbers (mm), got {size!r}')
        object.__setattr__(self, 'motor_box_size_mm', size)
        object.__setattr__(self, 'constraint_impedance', _check_real(
            'constraint_impedance', self.constraint_impedance, low=0.0, low_open=True,
            high=0.9999))
        st = self.contact_rib_stride
        if isinstance(st, bool) or not isinstance(st, numbers.Integral) or not 1 <= st <= 11:
            raise ValueError(f'contact_rib_stride must be an integer in [1, 11], got {st!r}')
        if self.rib_contact not in RIB_CONTACT_MODES:
            raise ValueError(f'rib_contact must be one of {RIB_CONTACT_MODES}, got '
                             f'{self.rib_contact!r}')
        object.__setattr__(self, 'rib_contact_impedance', _check_real(
            'rib_contact_impedance', self.rib_contact_impedance, low=0.0, low_open=True,
            high=0.9999))
        object.__setattr__(self, 'hinge_armature_kgm2', _check_real(
            'hinge_armature_kgm2', self.hinge_armature_kgm2, low=0.0, high=1.0))

    @property
    def constraint_solref(self) -> tuple:
        """``solref`` of the cable limit and couplings: (-stiffness, -damping)."""
        dt = self.timestep_s
        return (-self.constraint_stiffness_dt2 / dt ** 2, -self.constraint_damping_dt / dt)

    @property
    def weld_solref(self) -> tuple:
        """``solref`` of the welds joining chained modules: a 4-step time constant,
        damping ratio 2 (the cable's overdamped reference is unstable on these heavier
        bodies, and ratio 1 lets the snake's links chatter on the ground)."""
        return (4.0 * self.timestep_s, 2.0)

    @property
    def weld_solimp(self) -> tuple:
        """``solimp`` of the chain welds."""
        return (0.99, 0.999, 0.001, 0.5, 2.0)

    @property
    def constraint_solimp(self) -> tuple:
        """``solimp`` of the cable limit and couplings (constant impedance)."""
        return (self.constraint_impedance, self.constraint_impedance, 0.001, 0.5, 2.0)


@dataclass(frozen=True)
class Payload:
    """An object for the gripper or ring to hold (SI units).

    Parameters
    ----------
    shape : str
        ``'ball'``, ``'box'`` or ``'cylinder'`` (a puck standing on its end face: the
        flat ring's ribs, 9 mm tall, reach its wall, where they reach a ball only at
        its bottom; docs/sim_robot.md).
    mass_kg : float
        Mass (kg), in (0, 1].
    size_m : float or sequence of 2 or 3 float
        Ball radius; the box's 3 half extents; or the cylinder's (radius, half height)
        (m), each in (0, 0.2].
    position_m : sequence of 3 float, optional
        Centre in the robot frame (m). None: the scene's default place: the ring's centre
        on the ground; for the gripper, on the fingertips as the quasi-static model
        closes them at the default gait's amplitude, held there by a weld until
        ``RobotSimulation.release_payload`` (a hand placing it in the open gripper).
    """

    shape: str = 'ball'
    mass_kg: float = 0.02
    size_m: Any = 0.02
    position_m: Any = None

    def __post_init__(self):
        if self.shape not in PAYLOAD_SHAPES:
            raise ValueError(f"payload shape must be one of {', '.join(PAYLOAD_SHAPES)}, "
                             f"got {self.shape!r}")
        object.__setattr__(self, 'mass_kg', _check_real(
            'payload mass_kg', self.mass_kg, low=0.0, low_open=True, high=MAX_PAYLOAD_MASS_KG))
        if self.shape == 'ball':
            object.__setattr__(self, 'size_m', _check_real(
                'payload radius size_m', self.size_m, low=0.0, low_open=True,
                high=MAX_PAYLOAD_SIZE_M))
        else:
            size = self.size_m
            n, what = (3, '3 half extents') if self.shape == 'box' else (2, '(radius, half height)')
            if isinstance(size, numbers.Real) or not hasattr(size, '__len__') or len(size) != n:
                raise ValueError(f'a {self.shape} payload needs size_m = {what} (m), '
                                 f'got {size!r}')
            object.__setattr__(self, 'size_m', tuple(_check_real(
                f'payload {self.shape} size_m', v, low=0.0, low_open=True,
                high=MAX_PAYLOAD_SIZE_M) for v in size))
        if self.position_m is not None:
            p = self.position_m
            if not hasattr(p, '__len__') or len(p) != 3:
                raise ValueError(f'payload position_m must be 3 numbers (m, robot frame), '
                                 f'got {p!r}')
            object.__setattr__(self, 'position_m', tuple(_check_real(
                'payload position_m', v, low=-5.0, high=5.0) for v in p))
