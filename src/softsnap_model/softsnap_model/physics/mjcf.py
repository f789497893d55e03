"""MJCF (MuJoCo XML) of SoftSnap modules, generated from data; whole robots are
:mod:`.robot_mjcf`.

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

Every number comes from :class:`PhysicsParameters` (documented sources and estimates).
"""
from __future__ import annotations

import numbers
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace

import numpy as np

from ..skeleton import Skeleton
from .frames import _flat, _rot, _unit_quaternion, _vector
from .parameters import (DEFAULT_LINKS_PER_SEGMENT, MAX_LINKS_PER_SEGMENT, PhysicsParameters,
                         SKELETON_THICKNESS_MM)
from .rib_contact import hinge_armature_kgm2, hinge_limit_attributes
__all__ = ['ModuleLayout', 'RobotLayout', 'link_lengths', 'module_mjcf', 'module_mjcf_layout']

# Collision classes (MuJoCo: two geoms collide if contype1 & conaffinity2 or
# contype2 & conaffinity1): robot parts touch the ground and the payload, not each
# other (rib contact inside a module is the hinge range; modules of one robot do not
# reach each other in the scenes' gaits); the payload touches both.
_ROBOT_CLASS = (2, 0)

_GROUND_CLASS = (0, 2)

_PAYLOAD_CLASS = (2, 2)

_VISUAL_CLASS = (0, 0)


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
