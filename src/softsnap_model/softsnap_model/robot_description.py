"""A scene's robot as a URDF kinematic tree, its joint values and its transforms (no ROS).

The tree (frame names are the TF frames; REP 105's ``base_link`` is the root):

- ``base_link`` -> ``<scene>`` (fixed, identity): the robot frame every RobotShape,
  ModuleShape base pose and marker is expressed in;
- ``<scene>`` -> ``<scene>/<module>`` (fixed, the scene's base pose), or for a chained
  module ``<scene>/<parent>/rib_<n-1>`` -> ``<scene>/<module>`` (fixed, the scene's
  parent offset): the module base frame of its ModuleShape (rib 0 at the origin);
- per segment k of a module, three joints from rib k to rib k+1 that reproduce the
  model's arc geometry exactly (FACTS.md: ``P_{k+1} = P_k + s sinc(a/2) (cos(t + a/2),
  sin(t + a/2))``, ``t_{k+1} = t_k + a``): ``.../segment_<k>/bend_in`` (revolute about
  z, a/2 rad), ``.../segment_<k>/chord`` (prismatic along x, the chord s sinc(a/2) in m)
  and ``.../segment_<k>/bend_out`` (revolute about z, mimics bend_in), so rib k+1 is
  turned by a and sits on the arc.

`joint_positions` turns a module's segment angles into those joint values (what
``/joint_states`` carries; robot_state_publisher computes the same transforms from them)
and `transforms` is the tree's forward kinematics (what ``/tf`` and ``/tf_static`` carry).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

__all__ = ['ROOT_FRAME', 'Joint', 'RobotDescription', 'describe_robot']

#: REP 105's robot base frame, the root of the tree.
ROOT_FRAME = 'base_link'
#: Bend joint limits (rad): half the rigid ribs' contact angle is 0.62 rad; a little more
#: so a solver's slightly-past-contact shape is never clamped by a URDF consumer.
BEND_LIMIT_RAD = math.pi / 2
#: Rib visual: thickness along the spine and height of the skeleton (m), FACTS.md.
RIB_THICKNESS_M = 0.003
SKELETON_HEIGHT_M = 0.009
#: Rib 0 carries a small box for the module's base/case, so the base is visible.
BASE_BOX_M = (0.02, 0.03, 0.02)


@dataclass(frozen=True)
class Joint:
    """One URDF joint: `origin` is the child's pose in the parent at zero motion."""

    name: str
    kind: str                 # 'fixed', 'revolute' or 'prismatic'
    parent: str
    child: str
    origin_xyz_m: tuple[float, float, float]
    origin_xyzw: tuple[float, float, float, float]
    mimic: str = ''           # name of the joint whose value this one copies


@dataclass(frozen=True)
class RobotDescription:
    """The tree of one scene: joints in parent-before-child order, the moving joints'
    names per module, and the URDF text."""

    scene: str
    joints: tuple[Joint, ...]
    module_joint_names: dict            # module -> names of its bend_in and chord joints
    rib_frames: dict                    # module -> its rib frames, rib 0 first
    urdf: str
    spacing_m: float

    @property
    def joint_names(self) -> list[str]:
        """Every independent moving joint (what /joint_states names), scene order."""
        return [n for names in self.module_joint_names.values() for n in names]

    def joint_positions(self, angles_rad) -> np.ndarray:
        """Joint values of one module, in ``module_joint_names`` order: per segment the
        half angle (rad) and the chord (m), from its segment angles (rad)."""
        a = np.asarray(angles_rad, dtype=float)
        chord = self.spacing_m * np.sinc(a / (2.0 * np.pi))   # numpy's sinc is sin(pi x)/(pi x)
        return np.column_stack([a / 2.0, chord]).ravel()

    def transforms(self, positions: dict[str, float], *, moving: bool = True):
        """(parent, child, xyz m, quaternion xyzw) of every joint of one kind.

        ``moving=True``: the revolute and prismatic joints at `positions` (a joint not in
        it, and the mimic of one, takes 0 or its master's value); ``moving=False``: the
        fixed joints (the ``/tf_static`` part).
        """
        out = []
        for joint in self.joints:
            if (joint.kind == 'fixed') == moving:
                continue
            q = positions.get(joint.mimic or joint.name, 0.0)
            xyz, quat = joint.origin_xyz_m, joint.origin_xyzw
            if joint.kind == 'revolute':
                quat = _quat_multiply(quat, (0.0, 0.0, math.sin(q / 2.0), math.cos(q / 2.0)))
            elif joint.kind == 'prismatic':
                xyz = tuple(np.add(xyz, _rotate(quat, (q, 0.0, 0.0))))
            out.append((joint.parent, joint.child, xyz, quat))
        return out


def describe_robot(scene) -> RobotDescription:
    """The tree and URDF of a loaded scene (softsnap_model.scene.Scene)."""
    skeleton = scene.skeleton
    n_ribs = int(skeleton.n_ribs)
    spacing_m = float(skeleton.spacing_mm) / 1000.0
    rib_length_m = float(skeleton.rib_length_mm) / 1000.0
    robot = scene.name
    identity = (0.0, 0.0, 0.0, 1.0)
    joints = [Joint(f'{robot}/base', 'fixed', ROOT_FRAME, robot, (0.0, 0.0, 0.0), identity)]
    module_joints: dict[str, list[str]] = {}
    rib_frames: dict[str, list[str]] = {}
    for module in _parents_first(scene.modules):
        base = f'{robot}/{module.name}'
        if module.parent:
            joints.append(Joint(f'{base}/mount', 'fixed', f'{robot}/{module.parent}/rib_{n_ribs - 1}',
                                base, tuple(module.parent_offset_position_m),
                                tuple(module.parent_offset_orientation_xyzw)))
        else:
            joints.append(Joint(f'{base}/mount', 'fixed', robot, base,
                                tuple(module.base_position_m), tuple(module.base_orientation_xyzw)))
        ribs = [base] + [f'{base}/rib_{k}' for k in range(1, n_ribs)]
        rib_frames[module.name] = ribs
        module_joints[module.name] = []
        for k in range(n_ribs - 1):
            seg = f'{base}/segment_{k}'
            joints += [Joint(f'{seg}/bend_in', 'revolute', ribs[k], f'{seg}/arc_in',
                             (0.0, 0.0, 0.0), identity),
                       Joint(f'{seg}/chord', 'prismatic', f'{seg}/arc_in', f'{seg}/arc_out',
                             (0.0, 0.0, 0.0), identity),
                       Joint(f'{seg}/bend_out', 'revolute', f'{seg}/arc_out', ribs[k + 1],
                             (0.0, 0.0, 0.0), identity, mimic=f'{seg}/bend_in')]
            module_joints[module.name] += [f'{seg}/bend_in', f'{seg}/chord']
    urdf = _urdf_text(robot, joints, rib_frames, spacing_m, rib_length_m,
                      {m.name: m.color for m in scene.modules})
    return RobotDescription(robot, tuple(joints), module_joints, rib_frames, urdf, spacing_m)


def _parents_first(modules):
    """Modules ordered so a chained module follows its parent (the snake lists head first)."""
    by_name = {m.name: m for m in modules}
    done: dict[str, object] = {}

    def visit(module):
        if module.name not in done:
            if module.parent:
                visit(by_name[module.parent])
            done[module.name] = module
    for module in modules:
        visit(module)
    return list(done.values())


#: Display colours of the scenes' module colour names (RGBA); grey otherwise.
_COLOURS = {'yellow': (1.0, 0.85, 0.1), 'blue': (0.2, 0.4, 1.0), 'red': (0.9, 0.15, 0.15),
            'green': (0.2, 0.8, 0.3), 'purple': (0.6, 0.3, 0.8), 'orange': (1.0, 0.55, 0.1),
            'pink': (1.0, 0.45, 0.7), 'white': (0.95, 0.95, 0.95), 'black': (0.15, 0.15, 0.15)}


def _urdf_text(robot, joints, rib_frames, spacing_m, rib_length_m, colours) -> str:
    links = [ROOT_FRAME, robot]
    for joint in joints:
        if joint.child not in links:
            links.append(joint.child)
    rib_colour = {}
    for module, ribs in rib_frames.items():
        rgb = _COLOURS.get((colours.get(module) or module).lower(), (0.7, 0.7, 0.7))
        for rib in ribs:
            rib_colour[rib] = (module, rgb)
    lines = ['<?xml version="1.0"?>',
             f'<!-- Generated by softsnap_model.robot_description from scene {robot}: '
             f'do not edit. Lengths in m, angles in rad. -->',
             f'<robot name={quoteattr(robot)}>']
    for module, ribs in rib_frames.items():
        rgb = rib_colour[ribs[0]][1]
        lines.append(f'  <material name={quoteattr(module)}><color rgba="{rgb[0]} {rgb[1]} '
                     f'{rgb[2]} 1"/></material>')
    rib_box = f'{RIB_THICKNESS_M} {rib_length_m} {SKELETON_HEIGHT_M}'
    for link in links:
        if link not in rib_colour:
            lines.append(f'  <link name={quoteattr(link)}/>')
            continue
        module = rib_colour[link][0]
        visuals = [f'<visual><geometry><box size="{rib_box}"/></geometry>'
                   f'<material name={quoteattr(module)}/></visual>',
                   # the spine rod from this rib halfway to the next (the arc is drawn by the
                   # two half rods meeting at the chord's middle only when straight)
                   f'<visual><origin xyz="{spacing_m / 2} 0 0"/><geometry><box size="{spacing_m} '
                   f'0.002 0.002"/></geometry><material name={quoteattr(module)}/></visual>']
        if link == rib_frames[module][0]:
            visuals.append(f'<visual><origin xyz="{-BASE_BOX_M[0] / 2} 0 0"/><geometry><box size='
                           f'"{" ".join(map(str, BASE_BOX_M))}"/></geometry>'
                           f'<material name={quoteattr(module)}/></visual>')
        if link == rib_frames[module][-1]:
            visuals = visuals[:1]
        lines.append(f'  <link name={quoteattr(link)}>' + ''.join(visuals) + '</link>')
    for joint in joints:
        rpy = ' '.join(repr(float(v)) for v in _rpy(joint.origin_xyzw))
        xyz = ' '.join(repr(float(v)) for v in joint.origin_xyz_m)
        body = [f'<parent link={quoteattr(joint.parent)}/>', f'<child link={quoteattr(joint.child)}/>',
                f'<origin xyz="{xyz}" rpy="{rpy}"/>']
        if joint.kind == 'revolute':
            body += ['<axis xyz="0 0 1"/>',
                     f'<limit lower="{-BEND_LIMIT_RAD!r}" upper="{BEND_LIMIT_RAD!r}" '
                     f'effort="1" velocity="10"/>']
        elif joint.kind == 'prismatic':
            body += ['<axis xyz="1 0 0"/>',
                     f'<limit lower="0" upper="{spacing_m!r}" effort="1" velocity="1"/>']
        if joint.mimic:
            body.append(f'<mimic joint={quoteattr(joint.mimic)}/>')
        lines.append(f'  <joint name={quoteattr(joint.name)} type="{joint.kind}">'
                     + ''.join(body) + '</joint>')
    lines.append('</robot>')
    return '\n'.join(lines) + '\n'


def _quat_multiply(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def _rotate(q, v):
    """Vector `v` rotated by unit quaternion `q` (xyzw)."""
    x, y, z, w = _quat_multiply(_quat_multiply(q, (*v, 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def _rpy(q):
    """URDF roll, pitch, yaw (rad; R = Rz(yaw) Ry(pitch) Rx(roll)) of a unit quaternion xyzw.

    From the rotation matrix, so a pitch of +-90 degrees (a gripper finger pointing
    down) keeps its exact rotation: there yaw is set to 0 and roll takes the rest."""
    x, y, z, w = q
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    r10, r11, r12 = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    r20, r21, r22 = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    pitch = math.asin(max(-1.0, min(1.0, -r20)))
    if math.hypot(r00, r10) > 1e-9:
        return math.atan2(r21, r22), pitch, math.atan2(r10, r00)
    return math.atan2(-r12, r11), pitch, 0.0
