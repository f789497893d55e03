"""MJCF (MuJoCo XML) of SoftSnap modules and whole robots, generated from data.

No ``mujoco`` import here: the model is plain XML built with :mod:`xml.etree`, so it can
be written, inspected and tested without the simulator.

Model of one module (conventions of :mod:`softsnap_model.geometry`, FACTS.md)
-----------------------------------------------------------------------------
* Rib ``k`` is a rigid body whose frame sits where its centre line crosses the spine:
  x along the spine tangent (toward the tip), y along the rib toward the left ("L")
  side, z the bending axis. Rib 0 is clamped to the motor box (the module's base body).
* Each segment (spine arc ``s`` between two ribs) is ``N`` short straight links joined
  by ``N`` hinges about z, placed at the midpoints of ``N`` equal sub-arcs: a half link
  ``s/(2N)``, ``N - 1`` links ``s/N``, a half link. With equal hinge angles ``a/N`` this
  is the trapezoidal rule for the constant-curvature arc: rib ``i+1`` lands within
  ``s a^2 / (12 N^2)`` of the exact position (0.13 mm at ``a`` = 0.3 rad, N = 1).
* Stiffness: the quasi-static energy of segment ``i`` is ``K k_i a_i^2`` (N mm,
  :mod:`softsnap_model.loads`), a torque ``2 K k_i a_i``. ``N`` hinges in series, each
  ``k_h (a/N)^2 / 2``, store the same energy when ``k_h = 2 N K k_i`` (x 1e-3 for N m).
* ``coupled=True`` (default) adds joint equalities that keep the ``N`` hinges of a
  segment equal: the segment bends with constant curvature, as in the paper's model.
  ``coupled=False`` lets each hinge take its own angle (a beam whose curvature follows
  the local bending moment), which the constant-curvature model leaves out.
* Damping per hinge ``c_h = k_h * damping_time_s``: each segment relaxes with that time
  constant (viscoelastic TPU; an estimate, see :class:`PhysicsParameters`). MuJoCo's
  implicit damping also keeps the light links stable at the 2 ms step.
* Rib contact: every hinge is limited to ``|q| <= a_c / N`` (``a_c`` =
  ``Skeleton.contact_angle_rad``), MuJoCo's soft default limit; with
  ``rib_contact.hard_contact_parameters()`` only a segment's first hinge, a hard limit
  with its own solver reference (:mod:`~softsnap_model.physics.rib_contact`).
* The cable is a spatial tendon through one site per rib at the threaded hole
  (``y = -d``): its length is the polyline through the holes, exactly the model's
  ``sum_i L(a_i; d_i, d_{i+1})``. The winch is the tendon's upper length limit: a
  unilateral constraint, so the cable pulls when the path would be longer than the
  winch allows and is slack (no force) otherwise. Change it at run time through
  ``model.tendon_range`` (:class:`~softsnap_model.physics.simulation.RobotSimulation`).

Robots (scenes, :mod:`softsnap_model.scene`): one root body ``robot`` at the robot frame
(free joint, or fixed for hanging robots such as the gripper, which an arm holds); a hub
connector (pentagon, cuboid) is a geom of that body; a module's base body (motor box,
battery, rib 0) is a child of the root at the scene's base pose, or of its parent's tip
rib for chains (the snake). The ring's modules are chained in file order and the loop is
closed by a weld equality. The ground is the plane ``z = 0`` with friction.

Every number comes from :class:`PhysicsParameters` (documented sources and estimates).
"""
from __future__ import annotations

import math
import numbers
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from ..loads import (DEFAULT_BENDING_STIFFNESS_NMM, DEFAULT_END_RIB_MASS_KG,
                     DEFAULT_RIB_MASS_KG, MOTOR_BOX_MASS_KG_ESTIMATE, STANDARD_GRAVITY_MPS2)
from ..skeleton import Skeleton
from .rib_contact import RIB_CONTACT_MODES, hinge_armature_kgm2, hinge_limit_attributes
from .frames import _mat_to_wxyz, _rot, _unit_quaternion, _vector

__all__ = ['DEFAULT_LINKS_PER_SEGMENT', 'SKELETON_THICKNESS_MM', 'PhysicsParameters',
           'Payload', 'RobotLayout', 'ModuleLayout', 'module_mjcf', 'robot_mjcf',
           'robot_mjcf_layout', 'module_mjcf_layout']

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

# Collision classes (MuJoCo: two geoms collide if contype1 & conaffinity2 or
# contype2 & conaffinity1): robot parts touch the ground and the payload, not each
# other (rib contact inside a module is the hinge range; modules of one robot do not
# reach each other in the scenes' gaits); the payload touches both.
_ROBOT_CLASS = (2, 0)
_GROUND_CLASS = (0, 2)
_PAYLOAD_CLASS = (2, 2)
_VISUAL_CLASS = (0, 0)


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


@dataclass(frozen=True)
class ModuleLayout:
    """Names of one module's MJCF elements (for lookups by name after compiling)."""

    name: str
    base_body: str
    rib_bodies: tuple
    hole_sites: tuple
    hinge_joints: tuple          # (n_segments, N) names
    tendon: str
    threading_mm: tuple
    straight_length_m: float


@dataclass(frozen=True)
class RobotLayout:
    """What :func:`robot_mjcf_layout` built: element names and placement facts (SI)."""

    robot: str
    root_body: str
    free_base: bool
    modules: tuple               # ModuleLayout, scene order
    links_per_segment: int
    coupled: bool
    payload_body: str | None = None
    payload_hold: str | None = None      # weld holding the payload until released
    parameters: PhysicsParameters = field(default_factory=PhysicsParameters)

    def module(self, name: str) -> ModuleLayout:
        for m in self.modules:
            if m.name == name:
                return m
        raise ValueError(f'no module {name!r}; modules are '
                         f'{", ".join(m.name for m in self.modules)}')


# ------------------------------------------------------------------------------ helpers

def _f(*values) -> str:
    return ' '.join(f'{float(v):.10g}' for v in values)


def _quat_wxyz(xyzw) -> tuple:
    x, y, z, w = xyzw
    return (w, x, y, z)


def _box_inertia_geom(parent, name, half_m, pos_m, mass_kg, cls, rgba, friction=None):
    g = ET.SubElement(parent, 'geom', name=name, type='box', size=_f(*half_m),
                      pos=_f(*pos_m), mass=_f(mass_kg), contype=str(cls[0]),
                      conaffinity=str(cls[1]), rgba=rgba)
    if friction is not None:
        g.set('friction', _f(friction, 0.005, 0.0001))
    return g


def link_lengths(spacing, n_links: int) -> tuple[float, float]:
    """End and interior link lengths ``(c, h)`` of a segment of arc ``spacing`` cut into
    ``n_links`` hinges (``2 c + (n_links - 1) h = spacing``, same unit as ``spacing``).

    With all hinges at ``a / N`` the chord from rib to rib is, by symmetry, along the
    exact arc's chord; ``c`` is chosen so that its length matches the arc's chord
    ``s sinc(a/2)`` to second order in ``a`` (the equal split ``c = h/2``, the
    trapezoidal rule, is short by ``s a^2 / (12 N^2)``, which the cable's 3-10 mm lever
    turns into angle errors of ~1e-3 rad at N = 4). Expanding the chord,
    ``2c (1 - a^2/8) + h sum_j (1 - (j - N/2)^2 a^2 / (2 N^2))`` over the interior hinges
    ``j = 1..N-1``, equal to ``s (1 - a^2/24)`` gives ``c`` below. ``N = 1`` has no
    freedom: ``c = s/2``.

    Examples
    --------
    >>> link_lengths(18.0, 1), link_lengths(18.0, 2)
    ((9.0, 0.0), (3.0, 12.0))
    """
    n = int(n_links)
    if n == 1:
        return 0.5 * spacing, 0.0
    s2 = n * (n + 1) * (n + 2) / 12.0 - 0.5 * n * n       # sum of (j - N/2)^2, j = 1..N-1
    q = s2 / (n * n * (n - 1))
    c = spacing * (1.0 / 24.0 - 0.5 * q) / (0.25 - q)
    return c, (spacing - 2.0 * c) / (n - 1)


def _parameters(parameters, bending_stiffness_nmm) -> PhysicsParameters:
    """The parameter table, with ``bending_stiffness_nmm`` (N mm/rad^2) overriding its K."""
    params = PhysicsParameters() if parameters is None else parameters
    if not isinstance(params, PhysicsParameters):
        raise ValueError(f'parameters must be PhysicsParameters, got {type(params).__name__}')
    if bending_stiffness_nmm is not None:
        params = replace(params, bending_stiffness_nmm=bending_stiffness_nmm)   # validated
    return params


def _check_links(links_per_segment) -> int:
    n = links_per_segment
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) \
            or not 1 <= n <= MAX_LINKS_PER_SEGMENT:
        raise ValueError(f'links_per_segment must be an integer in [1, '
                         f'{MAX_LINKS_PER_SEGMENT}], got {n!r}')
    return int(n)


def _root(model_name: str, params: PhysicsParameters, gravity: bool):
    root = ET.Element('mujoco', model=model_name)
    ET.SubElement(root, 'compiler', angle='radian', autolimits='true')
    g = params.gravity_mps2 if gravity else 0.0
    # Pyramidal friction cones (MuJoCo's default): ~25 % cheaper than elliptic ones for
    # robots resting on one contact per rib (physics_bench.py), isotropic Coulomb either way.
    # Island discovery off: every contact row of a robot reaches its free base, so the
    # constraints form one island anyway and the search only costs (10-25 % of a step
    # of the brittle star, same trajectory bit for bit; benchmarks/physics_bench.py).
    option = ET.SubElement(root, 'option', timestep=_f(params.timestep_s),
                           integrator='implicitfast', gravity=_f(0.0, 0.0, -g),
                           cone='pyramidal')
    ET.SubElement(option, 'flag', island='disable')
    # Light bodies and stiff springs: MuJoCo's default contact softness would let the
    # 1 g ribs sink into the ground; a 2-step time constant keeps them on it.
    default = ET.SubElement(root, 'default')
    ET.SubElement(default, 'geom', solref=_f(max(2.0 * params.timestep_s, 0.002), 1.0))
    visual = ET.SubElement(root, 'visual')
    ET.SubElement(visual, 'global', offwidth='1280', offheight='960')
    return root


def _add_ground(world, params: PhysicsParameters):
    ET.SubElement(world, 'geom', name='ground', type='plane', size='5 5 0.1',
                  contype=str(_GROUND_CLASS[0]), conaffinity=str(_GROUND_CLASS[1]),
                  friction=_f(params.rib_friction, 0.005, 0.0001), rgba='0.8 0.8 0.75 1')
    ET.SubElement(world, 'light', name='sun', pos='0 0 3', dir='0 0 -1', directional='true')


def _add_module(parent, equality, tendons, *, name: str, skeleton: Skeleton,
                threading_mm: np.ndarray, pos_m, quat_wxyz, mount_m: float,
                params: PhysicsParameters, n_links: int, coupled: bool,
                rgba: str, flat: bool,
                rib_capsules: bool = False) -> tuple[ModuleLayout, ET.Element]:
    """Add one module under ``parent``; return its layout and its tip rib element.

    ``flat``: the ribs lie along the ground (module y horizontal in the robot frame).
    ``rib_capsules``: every rib touches through a capsule along its length (payloads).
    """
    s = skeleton.spacing_mm * 1e-3
    t_half = max(0.5 * skeleton.rib_thickness_mm, 0.25) * 1e-3
    l_half = 0.5 * skeleton.rib_length_mm * 1e-3
    z_half = 0.5 * SKELETON_THICKNESS_MM * 1e-3
    a_c = skeleton.contact_angle_rad
    k = skeleton.stiffness_array
    n_ribs = skeleton.n_ribs
    masses = np.full(n_ribs, params.rib_mass_kg)
    masses[0] = masses[-1] = params.end_rib_mass_kg

    base = ET.SubElement(parent, 'body', name=f'{name}/base', pos=_f(*pos_m),
                         quat=_f(*quat_wxyz))
    # Motor box (with the battery inside) behind rib 0, then the mount (connector link)
    # reaching back to whatever the module is attached to: mass in the box, none in the
    # mount's geom (its plastic is counted in the connector or the box estimate).
    bl, bw, bh = (v * 1e-3 for v in params.motor_box_size_mm)
    box_x = -t_half - 0.5 * bl
    # Lying flat, the box and mount touch the ground through one capsule along the
    # spine (two contacts instead of a box's four each); standing, through the boxes.
    box_class = _VISUAL_CLASS if flat else _ROBOT_CLASS
    _box_inertia_geom(base, f'{name}/motor_box', (0.5 * bl, 0.5 * bw, 0.5 * bh),
                      (box_x, 0, 0), params.motor_box_mass_kg, box_class,
                      '0.25 0.25 0.3 1', params.rib_friction)
    _box_inertia_geom(base, f'{name}/battery', (0.4 * bl, 0.4 * bw, 0.2 * bh),
                      (box_x, 0, 0), params.battery_mass_kg, _VISUAL_CLASS, '0.6 0.5 0.1 1')
    mount_len = mount_m - bl - t_half
    if mount_len > 1e-4:
        _box_inertia_geom(base, f'{name}/mount', (0.5 * mount_len, 0.3 * bw, 0.5 * bh),
                          (-t_half - bl - 0.5 * mount_len, 0, 0), 0.0, box_class,
                          '0.4 0.4 0.45 1', params.rib_friction)
    if flat:
        back = -t_half - bl - max(mount_len, 0.0) + 0.5 * bh
        ET.SubElement(base, 'geom', name=f'{name}/base/contact', type='capsule',
                      fromto=_f(back, 0, 0, -t_half - 0.5 * bh, 0, 0), size=_f(0.5 * bh),
                      mass='0', contype=str(_ROBOT_CLASS[0]), conaffinity=str(_ROBOT_CLASS[1]),
                      group='3', friction=_f(params.rib_friction, 0.005, 0.0001))

    rib_bodies, sites, hinges = [f'{name}/base'], [], []

    def add_rib(body, k_rib):
        # The box carries the mass and the picture; contact uses one sphere (ribs lying
        # flat on the ground and nothing else to touch: their whole underside is at one
        # height) or a capsule along the rib (ribs standing up, or a payload that the
        # rib ends must hold): one or two contacts per rib instead of a box's four,
        # which is most of the cost of a robot lying on the ground.
        _box_inertia_geom(body, f'{name}/rib{k_rib}', (t_half, l_half, z_half), (0, 0, 0),
                          masses[k_rib], _VISUAL_CLASS, rgba)
        if k_rib == 0 or (n_ribs - 1 - k_rib) % params.contact_rib_stride:
            pass                       # rib 0: the motor box touches for it
        elif flat and not rib_capsules:
            ET.SubElement(body, 'geom', name=f'{name}/rib{k_rib}/contact', type='sphere',
                          size=_f(z_half), mass='0', contype=str(_ROBOT_CLASS[0]),
                          conaffinity=str(_ROBOT_CLASS[1]), group='3',
                          friction=_f(params.rib_friction, 0.005, 0.0001))
        else:
            ET.SubElement(body, 'geom', name=f'{name}/rib{k_rib}/contact', type='capsule',
                          fromto=_f(0, -(l_half - z_half), 0, 0, l_half - z_half, 0),
                          size=_f(z_half), mass='0', contype=str(_ROBOT_CLASS[0]),
                          conaffinity=str(_ROBOT_CLASS[1]), group='3',
                          friction=_f(params.rib_friction, 0.005, 0.0001))
        site = f'{name}/hole{k_rib}'
        ET.SubElement(body, 'site', name=site, pos=_f(0.0, -threading_mm[k_rib] * 1e-3, 0.0),
                      size='0.0008', rgba='0.9 0.1 0.1 1')
        sites.append(site)

    add_rib(base, 0)
    c, h = link_lengths(s, n_links)
    rod_half = (0.5 * h if n_links > 1 else 0.5 * c, 0.0015, z_half)
    body = base
    for i in range(skeleton.n_segments):
        k_h = 2.0 * n_links * params.bending_stiffness_nmm * k[i] * 1e-3     # N m/rad
        seg = []
        for j in range(n_links):
            link = ET.SubElement(body, 'body', name=f'{name}/seg{i}/link{j}',
                                 pos=_f(c if j == 0 else h, 0, 0))
            jname = f'{name}/seg{i}/hinge{j}'
            ET.SubElement(link, 'joint', name=jname, type='hinge', axis='0 0 1',
                          stiffness=_f(k_h), damping=_f(k_h * params.damping_time_s),
                          armature=_f(hinge_armature_kgm2(params, n_links)),
                          **hinge_limit_attributes(params, a_c / n_links, j, coupled))
            # The link's rod from this hinge to the next (visual; mass numerical).
            ET.SubElement(link, 'geom', name=f'{name}/seg{i}/rod{j}', type='box',
                          size=_f(*rod_half), pos=_f(rod_half[0], 0, 0),
                          mass=_f(params.link_mass_kg), contype='0', conaffinity='0',
                          rgba='0.2 0.2 0.2 0.6')
            seg.append(jname)
            if coupled and j > 0:
                ET.SubElement(equality, 'joint', name=f'{name}/seg{i}/couple{j}',
                              joint1=jname, joint2=seg[0], polycoef='0 1 0 0 0',
                              solref=_f(*params.constraint_solref),
                              solimp=_f(*params.constraint_solimp))
            body = link
        rib = ET.SubElement(body, 'body', name=f'{name}/rib{i + 1}', pos=_f(c, 0, 0))
        add_rib(rib, i + 1)
        rib_bodies.append(f'{name}/rib{i + 1}')
        hinges.append(tuple(seg))
        body = rib

    straight_m = skeleton.straight_length_mm(threading_mm) * 1e-3
    tendon = ET.SubElement(tendons, 'spatial', name=f'{name}/cable', limited='true',
                           range=_f(0.0, straight_m + 1e-3), width='0.0003',
                           rgba='0.9 0.2 0.2 1',
                           solreflimit=_f(*params.constraint_solref),
                           solimplimit=_f(*params.constraint_solimp))
    for site in sites:
        ET.SubElement(tendon, 'site', site=site)
    layout = ModuleLayout(name=name, base_body=f'{name}/base', rib_bodies=tuple(rib_bodies),
                          hole_sites=tuple(sites), hinge_joints=tuple(hinges),
                          tendon=f'{name}/cable',
                          threading_mm=tuple(float(v) for v in threading_mm),
                          straight_length_m=straight_m)
    return layout, body


def _to_xml(root) -> str:
    ET.indent(root)
    return ET.tostring(root, encoding='unicode')


# ------------------------------------------------------------------------- one module

def module_mjcf_layout(skeleton: Skeleton | None = None, threading=None, *,
                       links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
                       parameters: PhysicsParameters | None = None, gravity: bool = True,
                       ground: bool = False, base_position_m=(0.0, 0.0, 0.0),
                       base_orientation_wxyz=(1.0, 0.0, 0.0, 0.0), coupled: bool = True,
                       name: str = 'module', bending_stiffness_nmm: float | None = None
                       ) -> tuple[str, RobotLayout]:
    """MJCF of one module clamped at its base (motor box fixed in the world).

    Parameters
    ----------
    skeleton : Skeleton, optional
        Module geometry (default: the authors' module).
    threading : sequence of str or float
        One hole per rib (names or offsets in mm), rib 0 first.
    links_per_segment : int
        ``N`` links per segment, 1 .. 64.
    parameters : PhysicsParameters, optional
    gravity : bool
        World gravity ``(0, 0, -g)`` on, or off (the quasi-static model's setting).
    ground : bool
        Add the ground plane ``z = 0``.
    base_position_m, base_orientation_wxyz : sequence
        Pose of the module base frame (rib 0) in the world (m, unit quaternion w, x, y, z).
        E.g. hanging tip down: ``(0.7071068, 0, 0.7071068, 0)`` (x to -z).
    coupled : bool
        Keep each segment's hinges equal (constant curvature).
    name : str
        Prefix of the element names.
    bending_stiffness_nmm : float, optional
        ``K`` (N mm/rad^2), overriding ``parameters.bending_stiffness_nmm``.

    Returns
    -------
    (xml, layout)
    """
    skeleton = Skeleton() if skeleton is None else skeleton
    if not isinstance(skeleton, Skeleton):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')
    if threading is None:
        raise ValueError('a threading is needed: one hole per rib, rib 0 first')
    d = skeleton.threading_mm(threading)
    n = _check_links(links_per_segment)
    params = _parameters(parameters, bending_stiffness_nmm)
    pos = _vector('base_position_m', base_position_m, 3)
    quat = _unit_quaternion('base_orientation_wxyz', base_orientation_wxyz)
    root = _root(name, params, gravity)
    world = ET.SubElement(root, 'worldbody')
    if ground:
        _add_ground(world, params)
    equality = ET.Element('equality')
    tendons = ET.Element('tendon')
    layout, _ = _add_module(world, equality, tendons, name=name, skeleton=skeleton,
                            threading_mm=d, pos_m=pos, quat_wxyz=quat, mount_m=0.0,
                            params=params, n_links=n, coupled=coupled,
                            rgba='0.95 0.75 0.1 1', flat=_flat(_rot(quat[1:] + quat[:1])))
    _append_nonempty(root, equality)
    _append_nonempty(root, tendons)
    return _to_xml(root), RobotLayout(robot=name, root_body=layout.base_body,
                                      free_base=False, modules=(layout,),
                                      links_per_segment=n, coupled=coupled,
                                      parameters=params)


def module_mjcf(skeleton: Skeleton | None = None, threading=None, **kwargs) -> str:
    """MJCF text of one clamped module; arguments of :func:`module_mjcf_layout`."""
    return module_mjcf_layout(skeleton, threading, **kwargs)[0]


def _append_nonempty(root, element):
    if len(element):
        root.append(element)


# ------------------------------------------------------------------------------ robots

#: Height of the gripper's connector centre above the ground (m) when its base is fixed
#: (an arm holds it): the straight fingers (rib 0 at -60 mm, 198 mm spine) end 0.14 m
#: above the ground.
HANGING_BASE_HEIGHT_M = 0.40
# A module hangs if its spine points within ~25 deg of straight down.
_HANGING_COS = -0.9


def _mount_m(scene) -> float:
    c = scene.connector
    for key in ('module_mount_mm', 'link_length_mm'):
        if key in c:
            return float(c[key]) * 1e-3
    return 0.045


def _ring_order(scene) -> list:
    """Modules of a closed ring in file order, each base at its predecessor's tip + link."""
    link = float(scene.connector.get('link_length_mm', 50.0)) * 1e-3
    spine = scene.skeleton.n_segments * scene.skeleton.spacing_mm * 1e-3
    mods = list(scene.modules)
    for i, m in enumerate(mods):
        nxt = mods[(i + 1) % len(mods)]
        tip = np.array(m.base_position_m) + _rot(m.base_orientation_xyzw) @ [spine + link, 0, 0]
        if np.linalg.norm(tip - np.array(nxt.base_position_m)) > 1e-3:
            raise ValueError(f'ring scene {scene.name!r}: module {nxt.name!r} does not start '
                             f'at the tip of {m.name!r} plus the {link * 1e3:g} mm link '
                             f'(off by {np.linalg.norm(tip - nxt.base_position_m) * 1e3:.1f} mm)')
    return mods


def _connector_geom(body, scene, params: PhysicsParameters, asset):
    """Collision shape and mass of a hub connector (pentagon, cuboid) in the root body."""
    c = scene.connector
    kind = c.get('type', '')
    # Thickness: the scene's, but no taller than the modules' extent across the ground
    # plane, so legs and connector rest on the ground together (no out-of-plane bending).
    extent = 0.0
    for m in scene.modules:
        r = _rot(m.base_orientation_xyzw)
        extent = max(extent, abs(r[2, 1]) * scene.skeleton.rib_length_mm
                     + abs(r[2, 2]) * SKELETON_THICKNESS_MM)
    if kind in ('pentagon', 'pentagon_3d'):
        apothem = float(c.get('apothem_mm', 27.5)) * 1e-3
        side = float(c.get('side_mm', 40.0)) * 1e-3
        thick = min(float(c.get('thickness_mm', 15.0)), extent) * 1e-3
        volume = 2.5 * side * apothem * thick          # pentagon area 5 s a / 2
        # A pentagonal prism (convex mesh), sides facing the modules. Not a cylinder:
        # MuJoCo's cylinder-plane test misfires when the axis is exactly vertical and
        # the robot turns about it (a -27 mm "penetration" that launched a free robot
        # with gravity off at 3.5 m/s; tests/model/test_physics.py).
        first = scene.modules[0].base_position_m
        theta0 = math.atan2(first[1], first[0]) if math.hypot(first[0], first[1]) > 1e-9 \
            else 0.0
        radius = apothem / math.cos(math.pi / 5)
        verts = []
        for zs in (-0.5 * thick, 0.5 * thick):
            for k in range(5):
                a = theta0 + math.pi / 5 + 2 * math.pi * k / 5
                verts += [radius * math.cos(a), radius * math.sin(a), zs]
        ET.SubElement(asset, 'mesh', name='connector', vertex=_f(*verts))
        ET.SubElement(body, 'geom', name='connector', type='mesh', mesh='connector',
                      mass=_f(volume * params.connector_density_kg_m3),
                      contype=str(_ROBOT_CLASS[0]), conaffinity=str(_ROBOT_CLASS[1]),
                      friction=_f(params.rib_friction, 0.005, 0.0001), rgba='0.3 0.45 0.8 1')
    elif kind == 'cuboid':
        half = [0.5e-3 * float(c.get(k, 40.0)) for k in ('length_mm', 'width_mm', 'height_mm')]
        volume = 8 * half[0] * half[1] * half[2]
        ET.SubElement(body, 'geom', name='connector', type='box', size=_f(*half),
                      mass=_f(volume * params.connector_density_kg_m3),
                      contype=str(_ROBOT_CLASS[0]), conaffinity=str(_ROBOT_CLASS[1]),
                      friction=_f(params.rib_friction, 0.005, 0.0001), rgba='0.3 0.45 0.8 1')
    else:
        raise ValueError(f'scene {scene.name!r}: connector type {kind!r} has no physics '
                         f'model; known: pentagon, pentagon_3d, cuboid, chain, ring')


def _default_payload_position(scene, payload: Payload) -> tuple:
    """Robot-frame payload centre (m) when the Payload gives none."""
    # Half its height: a ball's radius, else the last size (box z, cylinder half height).
    r = payload.size_m if payload.shape == 'ball' else payload.size_m[-1]
    kind = scene.connector.get('type', '')
    if kind == 'ring':
        # On the ground at the ring's centre; the ground is at the modules' underside.
        return (0.0, 0.0, -0.5 * SKELETON_THICKNESS_MM * 1e-3 + r)
    if _hanging(scene):
        return _grasp_place(scene)
    raise ValueError(f'scene {scene.name!r} has no default payload place: give '
                     f'Payload(position_m=...) in the robot frame (m)')


#: Contraction (mm) the gripper's payload place is computed for when the scene's
#: default gait states no ``amplitude_mm`` (the gripper scene's grasp uses 45 mm).
GRASP_CONTRACTION_MM = 45.0


def _grasp_place(scene) -> tuple:
    """Robot-frame centre (m) of a payload for the gripper to hold.

    The centroid of the fingertips (rib centres of the tip ribs) in the fingers' closed
    quasi-static shape at the default gait's amplitude, without the payload: the open
    fingers clear it, and closing they press on it where they would otherwise meet, as
    when the gripper closes on an object between its fingers.
    """
    from ..forward import solve_forward
    gait = scene.gaits.get(scene.default_gait, {})
    amp = float(gait.get('amplitude_mm', GRASP_CONTRACTION_MM))
    tips = []
    for m in scene.modules:
        length = scene.skeleton.straight_length_mm(m.threading_mm) - amp
        tip = solve_forward(scene.skeleton, m.threading_mm, length).rib_centers[-1] * 1e-3
        tips.append(np.array(m.base_position_m)
                    + _rot(m.base_orientation_xyzw) @ [tip[0], tip[1], 0.0])
    centre = np.mean(tips, axis=0)
    return (float(centre[0]), float(centre[1]), float(centre[2]))


def _flat(rot: np.ndarray) -> bool:
    """Ribs (module y) within 30 deg of horizontal for this orientation."""
    return abs(rot[2, 1]) < 0.5


def _hanging(scene) -> bool:
    return all(_rot(m.base_orientation_xyzw)[2, 0] < _HANGING_COS for m in scene.modules)


def robot_mjcf_layout(scene, *, links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
                      parameters: PhysicsParameters | None = None, gravity: bool = True,
                      ground: bool = True, payload: Payload | None = None,
                      base: str = 'auto', coupled: bool = True,
                      base_height_m: float | None = None,
                      chain: str = 'weld', bending_stiffness_nmm: float | None = None
                      ) -> tuple[str, RobotLayout]:
    """MJCF of a whole robot from a scene, and the names of its parts.

    Parameters
    ----------
    scene : Scene or str
        A loaded scene or a scene name/path for :func:`softsnap_model.scene.load_scene`.
    links_per_segment : int
        ``N`` links per segment (1 .. 64).
    parameters : PhysicsParameters, optional
    gravity, ground : bool
        World gravity (``-z``) and the ground plane ``z = 0``.
    payload : Payload, optional
        An object to hold (gripper) or cage (ring).
    base : str
        ``'free'`` (free joint: the robot moves on the ground), ``'fixed'`` (held in the
        world) or ``'auto'``: fixed when every module hangs (the gripper, which an arm
        holds, at ``HANGING_BASE_HEIGHT_M``), free otherwise.
    coupled : bool
        Constant curvature per segment (see the module docstring).
    base_height_m : float, optional
        Height of the robot frame's origin above the ground (m). None: the hanging
        height for a fixed base, else 0 (``RobotSimulation`` lowers a free robot onto the
        ground after compiling).
    chain : str
        How chained modules (snake, ring) are joined: ``'weld'`` (default: each module
        its own tree, held to its parent's tip by a weld equality; cheaper, the links
        slightly compliant) or ``'tree'`` (nested bodies, rigid links; the ring's loop
        is still closed by a weld).
    bending_stiffness_nmm : float, optional
        ``K`` (N mm/rad^2), overriding ``parameters.bending_stiffness_nmm``.

    Raises
    ------
    ValueError
        Unknown scene or connector type, bad parameters or payload (the message quotes
        the value and the allowed range).
    """
    from ..scene import load_scene, Scene
    if not isinstance(scene, Scene):
        if not isinstance(scene, str):
            raise ValueError(f'scene must be a Scene or a scene name, got {scene!r}')
        scene = load_scene(scene)
    n = _check_links(links_per_segment)
    params = _parameters(parameters, bending_stiffness_nmm)
    if payload is not None and not isinstance(payload, Payload):
        raise ValueError(f'payload must be a Payload or None, got {type(payload).__name__}')
    if chain not in ('weld', 'tree'):
        raise ValueError(f"chain must be 'weld' or 'tree', got {chain!r}")
    if base not in ('auto', 'free', 'fixed'):
        raise ValueError(f"base must be 'auto', 'free' or 'fixed', got {base!r}")
    free = (not _hanging(scene)) if base == 'auto' else base == 'free'
    if base_height_m is None:
        base_height_m = 0.0 if free else HANGING_BASE_HEIGHT_M
    base_height_m = _check_real('base_height_m', base_height_m, low=-1.0, high=10.0)

    root = _root(scene.name, params, gravity)
    world = ET.SubElement(root, 'worldbody')
    if ground:
        _add_ground(world, params)
    equality = ET.Element('equality')
    tendons = ET.Element('tendon')
    robot = ET.SubElement(world, 'body', name='robot', pos=_f(0, 0, base_height_m))
    if free:
        ET.SubElement(robot, 'freejoint', name='robot/base')
    # A tiny inertia of its own keeps the root valid whatever hangs below it.
    ET.SubElement(robot, 'inertial', pos='0 0 0', mass='1e-4', diaginertia='1e-9 1e-9 1e-9')

    kind = scene.connector.get('type', '')
    mount = _mount_m(scene)
    colors = _module_rgba(scene)
    layouts: dict = {}
    tips: dict = {}

    def add(m, parent_elem, pos, quat):
        lay, tip = _add_module(parent_elem, equality, tendons, name=m.name,
                               skeleton=scene.skeleton, threading_mm=np.array(m.threading_mm),
                               pos_m=pos, quat_wxyz=quat, mount_m=mount, params=params,
                               n_links=n, coupled=coupled, rgba=colors[m.name],
                               flat=_flat(_rot(m.base_orientation_xyzw)),
                               rib_capsules=payload is not None)
        layouts[m.name] = lay
        tips[m.name] = tip

    def weld(body1, body2, name):
        # Modules of chains are separate trees joined by welds at their straight
        # relative pose (relpose unset: the model's reference pose): a tree as deep as
        # the whole chain makes every contact row touch every joint (the mass matrix
        # and the constraint Jacobian turn dense), several times slower.
        ET.SubElement(equality, 'weld', name=name, body1=body1, body2=body2,
                      solref=_f(*params.weld_solref), solimp=_f(*params.weld_solimp))

    def add_free(m):
        # A module of its own tree, at its straight base pose in the world.
        holder = ET.SubElement(world, 'body', name=f'{m.name}/holder',
                               pos=_f(m.base_position_m[0], m.base_position_m[1],
                                      m.base_position_m[2] + base_height_m))
        ET.SubElement(holder, 'freejoint', name=f'{m.name}/free')
        add(m, holder, (0.0, 0.0, 0.0), _quat_wxyz(m.base_orientation_xyzw))

    tip_rib = f'rib{scene.skeleton.n_ribs - 1}'
    spine = scene.skeleton.n_segments * scene.skeleton.spacing_mm * 1e-3

    def add_child(m, prev):
        # Nested under the parent's tip rib at the straight relative pose.
        r_prev = _rot(prev.base_orientation_xyzw)
        tip_pos = np.array(prev.base_position_m) + r_prev @ [spine, 0, 0]
        rel_pos = r_prev.T @ (np.array(m.base_position_m) - tip_pos)
        rel_rot = r_prev.T @ _rot(m.base_orientation_xyzw)
        add(m, tips[prev.name], rel_pos, _mat_to_wxyz(rel_rot))

    if kind != 'ring' and kind != 'chain':
        asset = ET.Element('asset')
        _connector_geom(robot, scene, params, asset)
        root.insert(1, asset)
    if kind == 'ring':
        order = _ring_order(scene)
        links = list(zip(order, order[1:] + order[:1]))
        roots = [order[0]]
    else:
        by_name = {m.name: m for m in scene.modules}
        links = [(by_name[m.parent], m) for m in scene.modules if m.parent is not None]
        roots = [m for m in scene.modules if m.parent is None]
    for m in roots:
        add(m, robot, m.base_position_m, _quat_wxyz(m.base_orientation_xyzw))
    if chain == 'weld':
        for _, m in links:
            if m not in roots:
                add_free(m)
        for prev, m in links:
            weld(f'{prev.name}/{tip_rib}', f'{m.name}/base', f'{m.name}/link')
    else:
        pending = [link for link in links if link[1] not in roots]
        while pending:
            ready = [link for link in pending if link[0].name in tips]
            if not ready:      # load_scene rejects cycles; guard anyway
                raise ValueError(f'scene {scene.name!r}: cannot attach '
                                 f'{[m.name for _, m in pending]} to their parents')
            for prev, m in ready:
                add_child(m, prev)
                pending.remove((prev, m))
        if kind == 'ring':
            prev, m = links[-1]
            weld(f'{prev.name}/{tip_rib}', f'{m.name}/base', 'ring/closure')

    payload_body = payload_hold = None
    if payload is not None:
        pos = payload.position_m or _default_payload_position(scene, payload)
        world_pos = (pos[0], pos[1], pos[2] + base_height_m)
        pb = ET.SubElement(world, 'body', name='payload', pos=_f(*world_pos))
        ET.SubElement(pb, 'freejoint', name='payload/free')
        # MuJoCo's sphere size is the radius, a box's its half extents, a cylinder's
        # (radius, half height).
        ball = payload.shape == 'ball'
        ET.SubElement(pb, 'geom', name='payload', type='sphere' if ball else payload.shape,
                      size=_f(*((payload.size_m,) if ball else payload.size_m)),
                      mass=_f(payload.mass_kg), contype=str(_PAYLOAD_CLASS[0]),
                      conaffinity=str(_PAYLOAD_CLASS[1]),
                      friction=_f(params.payload_friction, 0.005, 0.0001),
                      rgba='0.9 0.3 0.6 1')
        payload_body = 'payload'
        if not free:
            # A hand holds the payload between the open fingers until released.
            payload_hold = 'payload/hold'
            ET.SubElement(equality, 'weld', name=payload_hold, body1='payload')
    _append_nonempty(root, equality)
    _append_nonempty(root, tendons)
    layout = RobotLayout(robot=scene.name, root_body='robot', free_base=free,
                         modules=tuple(layouts[m.name] for m in scene.modules),
                         links_per_segment=n, coupled=coupled, payload_body=payload_body,
                         payload_hold=payload_hold, parameters=params)
    return _to_xml(root), layout


def robot_mjcf(scene, **kwargs) -> str:
    """MJCF text of a whole robot; arguments of :func:`robot_mjcf_layout`."""
    return robot_mjcf_layout(scene, **kwargs)[0]


_COLORS = {'yellow': '0.95 0.8 0.1 1', 'blue': '0.2 0.4 0.9 1', 'green': '0.2 0.7 0.3 1',
           'red': '0.85 0.2 0.2 1', 'orange': '0.95 0.55 0.1 1'}


def _module_rgba(scene) -> Mapping[str, str]:
    return {m.name: _COLORS.get(m.color, '0.8 0.8 0.8 1') for m in scene.modules}
