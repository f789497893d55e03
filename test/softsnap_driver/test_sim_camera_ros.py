"""sim_robot's camera over real DDS: images, camera_info, the camera pose, and frames that
share their stamps with the ground truth (same rate: the same /clock ticks)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from softsnap_driver.sim_camera import ORANGE_RGB, PINK_RGB

pytestmark = pytest.mark.ros

NS = '/cam'
TIMEOUT_S = 150.0    # a model build, an OpenGL context and frames on a busy machine


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_the_camera_publishes_frames_with_honest_camera_info_and_ground_truth_stamps(
        start_node, ros_node, slot_port):
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import CameraInfo, Image
    from softsnap_interfaces.msg import MeasuredShape

    proc = start_node('softsnap_driver', 'sim_robot', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', f'port_base:={slot_port(5)}',
                      '-p', 'camera:=true', '-p', 'camera_rate_hz:=10.0',
                      '-p', 'ground_truth_rate_hz:=10.0', '-p', 'links_per_segment:=2')
    images, infos, poses, truth = [], [], [], []
    ros_node.create_subscription(Image, f'{NS}/camera/image_raw', images.append, 5)
    ros_node.create_subscription(CameraInfo, f'{NS}/camera/camera_info', infos.append, 50)
    ros_node.create_subscription(PoseStamped, f'{NS}/camera/pose', poses.append,
                                 QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    ros_node.create_subscription(MeasuredShape, f'{NS}/yellow/shape/ground_truth',
                                 truth.append, 100)
    assert ros_node.spin_until(lambda: len(images) >= 3 and poses and truth, TIMEOUT_S), \
        proc.output()[-3000:]
    image = images[-1]
    assert (image.width, image.height, image.encoding, image.step) == (1280, 960, 'rgb8', 3840)
    assert len(image.data) == 1280 * 960 * 3
    # camera_info follows its image (same stamp), on its own topic.
    assert ros_node.spin_until(lambda: any(_stamp_ns(i) == _stamp_ns(image) for i in infos), 30.0)
    info = next(i for i in infos if _stamp_ns(i) == _stamp_ns(image))
    f = 480.0 / math.tan(math.radians(22.5))       # fovy 45 degrees over 960 rows
    assert np.allclose(info.k, [f, 0, 639.5, 0, f, 479.5, 0, 0, 1])
    assert (info.width, info.height, info.distortion_model) == (1280, 960, 'plumb_bob')
    assert list(info.d) == [0.0] * 5 and info.header.frame_id == image.header.frame_id
    # Every frame shows an instant the ground truth was sampled at (same stamp).
    assert ros_node.spin_until(lambda: _stamp_ns(truth[-1]) >= _stamp_ns(images[-1]), 30.0)
    truth_stamps = {_stamp_ns(t) for t in truth}
    assert all(_stamp_ns(i) in truth_stamps for i in images[1:]), \
        ([_stamp_ns(i) for i in images], sorted(truth_stamps))
    pose = poses[-1]
    assert pose.header.frame_id == 'world' and pose.pose.position.z > 0.3
    q = pose.pose.orientation
    assert (q.w, q.x, q.y, q.z) == (0.0, 1.0, 0.0, 0.0)     # looking straight down
    # The picture has the 60 pink rib markers and 5 orange ones of the brittle star.
    import cv2
    pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(960, 1280, 3).astype(int)
    for rgb, expected in ((PINK_RGB, 60), (ORANGE_RGB, 5)):
        mask = np.all(np.abs(pixels - rgb) <= 40, axis=2).astype(np.uint8)
        count, _labels, stats, _c = cv2.connectedComponentsWithStats(mask)
        assert int(np.sum(stats[1:, cv2.CC_STAT_AREA] >= 4)) == expected, rgb
    assert 'camera: 1280x960 px at 10 Hz' in proc.output()
    assert proc.alive(), proc.output()[-3000:]
    assert proc.stop() == 0, proc.output()[-3000:]


def test_a_camera_that_cannot_render_ends_the_node_with_one_clear_line(start_node):
    start_node.env['MUJOCO_GL'] = 'glfw'        # a window backend, and no display
    start_node.env.pop('DISPLAY', None)
    proc = start_node('softsnap_driver', 'sim_robot', '--ros-args', '-p', 'scene:=gripper',
                      '-p', 'camera:=true')
    assert proc.proc.wait(120) == 2, proc.output()
    out = proc.output()
    assert 'cannot start: camera: the camera renders offscreen with MUJOCO_GL=egl or osmesa' \
        in out and 'Traceback' not in out, out


def test_the_module_view_films_a_hanging_finger_from_its_side(start_node, ros_node, slot_port):
    """camera_view:=module on the gripper: the camera looks sideways at front_left's
    marked face (its pose says so), and the picture holds that finger's 12 rib markers."""
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import Image

    proc = start_node('softsnap_driver', 'sim_robot', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=gripper', '-p', f'port_base:={slot_port(4)}',
                      '-p', 'camera:=true', '-p', 'camera_view:=module',
                      '-p', 'camera_width_px:=640', '-p', 'camera_height_px:=480')
    images, poses = [], []
    ros_node.create_subscription(Image, f'{NS}/camera/image_raw', images.append, 5)
    ros_node.create_subscription(PoseStamped, f'{NS}/camera/pose', poses.append,
                                 QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    assert ros_node.spin_until(lambda: images and poses, TIMEOUT_S), proc.output()[-3000:]
    q = poses[-1].pose.orientation
    w, x, y, z = q.w, q.x, q.y, q.z
    forward = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    down = np.array([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)])
    assert abs(forward[2]) < 0.1 and down[2] < -0.99    # sideways, image up = world up
    import cv2
    image = images[-1]
    pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(480, 640, 3).astype(int)
    mask = np.all(np.abs(pixels - PINK_RGB) <= 40, axis=2).astype(np.uint8)
    _count, _labels, stats, _c = cv2.connectedComponentsWithStats(mask)
    assert int(np.sum(stats[1:, cv2.CC_STAT_AREA] >= 4)) >= 12
    assert "facing the first module's markers" in proc.output()
    assert proc.stop() == 0, proc.output()[-3000:]


def test_an_unknown_camera_view_ends_the_node_with_one_clear_line(start_node):
    proc = start_node('softsnap_driver', 'sim_robot', '--ros-args', '-p', 'scene:=gripper',
                      '-p', 'camera:=true', '-p', 'camera_view:=sideways')
    assert proc.proc.wait(120) == 2, proc.output()
    out = proc.output()
    assert "camera view must be one of ('down', 'module'), got 'sideways'" in out \
        and 'Traceback' not in out, out
