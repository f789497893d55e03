"""The generated URDF places every rib where the model's geometry puts it.

The reference is independent of softsnap_model.robot_description: the URDF text is parsed
with ElementTree and its chains composed here with 4x4 matrices from each joint's
``origin xyz rpy``, ``axis`` and value (the URDF rules robot_state_publisher applies), and
the result is compared with the model's rib centres (softsnap_model.geometry.rib_centers)
placed at the scene's base poses and, for chained modules, at the parent's tip composed
by the scene's own chain rule (softsnap_model.scene.compose_base_pose).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from softsnap_model import geometry
from softsnap_model.robot_description import ROOT_FRAME, describe_robot
from softsnap_model.scene import compose_base_pose, list_scenes, load_scene, quaternion_to_matrix


def _rpy_matrix(r, p, y):
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _axis_angle(axis, q):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(q) * k + (1 - math.cos(q)) * k @ k


def urdf_link_poses(urdf: str, positions: dict[str, float]) -> dict[str, np.ndarray]:
    """Every link's 4x4 pose in the root link, from the URDF text alone."""
    root = ET.fromstring(urdf)
    joints = {}
    for j in root.findall('joint'):
        origin = j.find('origin')
        axis = j.find('axis')
        mimic = j.find('mimic')
        joints[j.find('child').get('link')] = dict(
            name=j.get('name'), type=j.get('type'), parent=j.find('parent').get('link'),
            xyz=[float(v) for v in origin.get('xyz').split()],
            rpy=[float(v) for v in origin.get('rpy').split()],
            axis=[float(v) for v in axis.get('xyz').split()] if axis is not None else None,
            mimic=mimic.get('joint') if mimic is not None else None)
    poses = {}

    def pose(link):
        if link not in poses:
            if link not in joints:
                poses[link] = np.eye(4)
            else:
                j = joints[link]
                t = np.eye(4)
                t[:3, :3] = _rpy_matrix(*j['rpy'])
                t[:3, 3] = j['xyz']
                q = positions.get(j['mimic'] or j['name'], 0.0)
                motion = np.eye(4)
                if j['type'] == 'revolute':
                    motion[:3, :3] = _axis_angle(j['axis'], q)
                elif j['type'] == 'prismatic':
                    motion[:3, 3] = np.asarray(j['axis']) * q
                poses[link] = pose(j['parent']) @ t @ motion
        return poses[link]
    for link in [l.get('name') for l in root.findall('link')]:
        pose(link)
    return poses


def _angles(scene, seed):
    rng = np.random.default_rng(seed)
    n = scene.skeleton.n_ribs - 1
    return {m.name: rng.uniform(-0.5, 0.5, n) for m in scene.modules}


@pytest.mark.parametrize('scene_name', list_scenes())
def test_every_rib_frame_of_the_urdf_is_the_models_rib(scene_name):
    scene = load_scene(scene_name)
    desc = describe_robot(scene)
    angles = _angles(scene, 7)
    positions = {}
    for module in scene.modules:
        positions.update(zip(desc.module_joint_names[module.name],
                             desc.joint_positions(angles[module.name])))
    poses = urdf_link_poses(desc.urdf, positions)
    assert ROOT_FRAME in poses and np.allclose(poses[scene.name], np.eye(4))

    spacing = scene.skeleton.spacing_mm
    bases = {}

    def base_pose(module):   # the model's robot-frame base pose (4x4) of a module
        if module.name not in bases:
            if module.parent is None:
                pos, quat = module.base_position_m, module.base_orientation_xyzw
            else:
                parent = scene.module(module.parent)
                parent_base = base_pose(parent)
                tip_mm = geometry.rib_centers(angles[parent.name], spacing)[-1]
                heading = float(np.sum(angles[parent.name]))
                tip = parent_base[:3, :3] @ [tip_mm[0] / 1e3, tip_mm[1] / 1e3, 0.0] + parent_base[:3, 3]
                rot = parent_base[:3, :3] @ _axis_angle((0, 0, 1), heading)
                w = math.sqrt(max(0.0, 1 + np.trace(rot))) / 2
                tip_q = ((rot[2, 1] - rot[1, 2]) / (4 * w), (rot[0, 2] - rot[2, 0]) / (4 * w),
                         (rot[1, 0] - rot[0, 1]) / (4 * w), w)
                pos, quat = compose_base_pose(tip, tip_q, module)
            t = np.eye(4)
            t[:3, :3] = np.array(quaternion_to_matrix(tuple(quat)))
            t[:3, 3] = pos
            bases[module.name] = t
        return bases[module.name]

    for module in scene.modules:
        base = base_pose(module)
        centres_mm = geometry.rib_centers(angles[module.name], spacing)
        headings = np.concatenate([[0.0], np.cumsum(angles[module.name])])
        frames = desc.rib_frames[module.name]
        assert frames[0] == f'{scene.name}/{module.name}'       # the ModuleShape frame id
        assert len(frames) == scene.skeleton.n_ribs
        for k, frame in enumerate(frames):
            want = base[:3, :3] @ [centres_mm[k][0] / 1e3, centres_mm[k][1] / 1e3, 0.0] + base[:3, 3]
            assert np.allclose(poses[frame][:3, 3], want, atol=1e-9), (module.name, k)
            want_rot = base[:3, :3] @ _axis_angle((0, 0, 1), headings[k])
            assert np.allclose(poses[frame][:3, :3], want_rot, atol=1e-9), (module.name, k)


def test_the_transforms_are_the_urdfs_forward_kinematics():
    """What robot_state publishes on /tf and /tf_static composes to the URDF's link poses."""
    scene = load_scene('snake')
    desc = describe_robot(scene)
    angles = _angles(scene, 3)
    positions = {}
    for module in scene.modules:
        positions.update(zip(desc.module_joint_names[module.name],
                             desc.joint_positions(angles[module.name])))
    parent_of = {}
    for parent, child, xyz, quat in (desc.transforms(positions, moving=False)
                                     + desc.transforms(positions, moving=True)):
        t = np.eye(4)
        t[:3, :3] = np.array(quaternion_to_matrix(tuple(quat)))
        t[:3, 3] = xyz
        parent_of[child] = (parent, t)

    def compose(frame):
        if frame not in parent_of:
            return np.eye(4)
        parent, t = parent_of[frame]
        return compose(parent) @ t

    urdf = urdf_link_poses(desc.urdf, positions)
    for frames in desc.rib_frames.values():
        for frame in frames:
            assert np.allclose(compose(frame), urdf[frame], atol=1e-9)
    # every URDF link has exactly one transform to it; the root none
    links = {l.get('name') for l in ET.fromstring(desc.urdf).findall('link')}
    assert set(parent_of) == links - {ROOT_FRAME}


def test_joint_values_are_half_angles_and_chords_in_si_units():
    scene = load_scene('brittle_star')
    desc = describe_robot(scene)
    a = np.array([0.0, 0.2, -0.4] + [0.0] * 8)
    values = desc.joint_positions(a)
    assert values.shape == (22,)
    assert values[2] == pytest.approx(0.1) and values[4] == pytest.approx(-0.2)
    s = scene.skeleton.spacing_mm / 1000.0
    assert values[1] == pytest.approx(s)
    assert values[3] == pytest.approx(2 * (s / 0.2) * math.sin(0.1))   # chord of the arc
    assert len(desc.joint_names) == 22 * len(scene.modules)
