"""MJCF of whole robots (scenes), built from the modules of :mod:`.mjcf`.

Robots (scenes, :mod:`softsnap_model.scene`): one root body ``robot`` at the robot frame
(free joint, or fixed for hanging robots such as the gripper, which an arm holds); a hub
connector (pentagon, cuboid) is a geom of that body; a module's base body (motor box,
battery, rib 0) is a child of the root at the scene's base pose, or of its parent's tip
rib for chains (the snake). The ring's modules are chained in file order and the loop is
closed by a weld equality. The ground is the plane ``z = 0`` with friction.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from typing import Mapping

import numpy as np

from .frames import _flat, _mat_to_wxyz, _rot
from .mjcf import (RobotLayout, _PAYLOAD_CLASS, _ROBOT_CLASS, _add_ground, _add_module,
                   _append_nonempty, _check_links, _f, _parameters, _quat_wxyz, _root, _to_xml)
from .parameters import (DEFAULT_LINKS_PER_SEGMENT, Payload, PhysicsParameters,
                         SKELETON_THICKNESS_MM, _check_real)

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
