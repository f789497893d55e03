"""robot_state over real DDS: the URDF on /robot_description, TF and /joint_states.

model_node and robot_state run as their own processes; the test subscribes as RViz does
(/robot_description and /tf_static transient local, subscribed after the publisher
started) and checks the tip rib's transform chain against the core solver's shape of the
length it sent, placed at the scene's base pose.
"""
from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from softsnap_model.forward import solve_forward
from softsnap_model.robot_description import ROOT_FRAME, describe_robot
from softsnap_model.scene import load_scene, quaternion_to_matrix

pytestmark = pytest.mark.ros

NS = '/brittle_star'
SCENE = load_scene('brittle_star')


def _matrix(translation, rotation):
    t = np.eye(4)
    t[:3, :3] = quaternion_to_matrix((rotation.x, rotation.y, rotation.z, rotation.w))
    t[:3, 3] = (translation.x, translation.y, translation.z)
    return t


def test_robot_state_publishes_the_urdf_tf_and_joint_states_of_the_models_shapes(
        start_node, ros_node):
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage
    from softsnap_interfaces.msg import CableLength

    model = start_node('softsnap_model', 'model_node', '--ros-args', '-r', f'__ns:={NS}',
                       '-p', 'scene:=brittle_star')
    state = start_node('softsnap_model', 'robot_state', '--ros-args', '-r', f'__ns:={NS}',
                       '-p', 'scene:=brittle_star', '-p', 'rate:=20')
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    descriptions, statics, dynamics, joints = [], [], [], []
    publisher = ros_node.create_publisher(CableLength, f'{NS}/yellow/cable_length/measured', 10)
    # Subscribed only once robot_state's publishers exist: a late joiner, as RViz is.
    assert ros_node.spin_until(lambda: ros_node.count_publishers('/robot_description') > 0,
                               60.0), state.output()
    ros_node.create_subscription(String, '/robot_description', descriptions.append, latched)
    ros_node.create_subscription(TFMessage, '/tf_static', statics.append, latched)
    ros_node.create_subscription(TFMessage, '/tf', dynamics.append, 100)
    ros_node.create_subscription(JointState, '/joint_states', joints.append, 100)
    assert ros_node.spin_until(lambda: descriptions and statics and joints, 60.0), state.output()

    urdf = descriptions[-1].data
    assert urdf == describe_robot(SCENE).urdf
    root = ET.fromstring(urdf)
    links = {link.get('name') for link in root.findall('link')}
    assert ROOT_FRAME in links and {f'brittle_star/{m.name}' for m in SCENE.modules} <= links
    children = {j.find('child').get('link') for j in root.findall('joint')}
    assert links - children == {ROOT_FRAME}                       # one tree, rooted at base_link

    yellow = SCENE.module('yellow')
    length_m = (yellow.straight_length_mm - 30.0) / 1000.0
    reference = solve_forward(SCENE.skeleton, yellow.threading_mm, length_m * 1000.0)
    # The model solves it and robot_state moves the joints (the first lengths may arrive
    # before the model's subscriptions have matched: resend until the joints move).
    names = describe_robot(SCENE).module_joint_names['yellow']

    def bent():
        msg = CableLength(cable_length=length_m)
        msg.header.stamp = ros_node.get_clock().now().to_msg()
        publisher.publish(msg)
        if not joints:
            return False
        values = dict(zip(joints[-1].name, joints[-1].position))
        return abs(values[names[0]] - reference.angles[0] / 2.0) < 1e-6
    deadline = time.monotonic() + 90.0
    while not bent() and time.monotonic() < deadline:
        ros_node.spin_until(lambda: False, 0.2)
    assert bent(), model.output() + state.output()

    values = dict(zip(joints[-1].name, joints[-1].position))
    assert list(joints[-1].name) == describe_robot(SCENE).joint_names
    np.testing.assert_allclose([values[n] for n in names[0::2]], np.asarray(reference.angles) / 2.0,
                               atol=1e-7)

    # Compose base_link -> yellow rib 11 from what was published on /tf_static and /tf.
    count = len(dynamics)
    assert ros_node.spin_until(lambda: len(dynamics) > count, 30.0)
    edges = {}
    for msg in statics[-1:] + dynamics[-1:]:
        for t in msg.transforms:
            edges[t.child_frame_id] = (t.header.frame_id, _matrix(t.transform.translation,
                                                                  t.transform.rotation))
    frame, pose = f'brittle_star/yellow/rib_{SCENE.skeleton.n_ribs - 1}', np.eye(4)
    while frame != ROOT_FRAME:
        parent, t = edges[frame]
        pose = t @ pose
        frame = parent
    base = np.eye(4)
    base[:3, :3] = quaternion_to_matrix(yellow.base_orientation_xyzw)
    base[:3, 3] = yellow.base_position_m
    tip_mm = np.asarray(reference.rib_centers)[-1]
    want = base @ np.array([tip_mm[0] / 1000.0, tip_mm[1] / 1000.0, 0.0, 1.0])
    np.testing.assert_allclose(pose[:3, 3], want[:3], atol=1e-6)
    heading = float(np.sum(reference.angles))
    want_x = base[:3, :3] @ [math.cos(heading), math.sin(heading), 0.0]
    np.testing.assert_allclose(pose[:3, 0], want_x, atol=1e-6)
    # A physics run's base pose (sim_robot's sim/base_pose in world) puts base_link in world.
    from geometry_msgs.msg import PoseStamped
    base_pose = ros_node.create_publisher(PoseStamped, f'{NS}/sim/base_pose', 10)
    pose = PoseStamped()
    pose.header.frame_id = 'world'
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 0.25, -0.1, 0.0045
    pose.pose.orientation.z, pose.pose.orientation.w = math.sin(0.2), math.cos(0.2)

    def world_tf():
        base_pose.publish(pose)
        return [t for m in dynamics[-3:] for t in m.transforms
                if (t.header.frame_id, t.child_frame_id) == ('world', ROOT_FRAME)]
    assert ros_node.spin_until(world_tf, 30.0), state.output()
    t = world_tf()[-1].transform
    assert (t.translation.x, t.translation.y, t.rotation.z) == pytest.approx(
        (0.25, -0.1, math.sin(0.2)))
    # A module nobody moved is straight: its tip 11 spacings along its base x axis.
    blue = SCENE.module('blue')
    frame, pose = f'brittle_star/blue/rib_{SCENE.skeleton.n_ribs - 1}', np.eye(4)
    while frame != ROOT_FRAME:
        parent, t = edges[frame]
        pose = t @ pose
        frame = parent
    axis = np.array(quaternion_to_matrix(blue.base_orientation_xyzw))[:, 0]
    spine = (SCENE.skeleton.n_ribs - 1) * SCENE.skeleton.spacing_mm / 1000.0
    np.testing.assert_allclose(pose[:3, 3], np.asarray(blue.base_position_m) + spine * axis,
                               atol=1e-9)
