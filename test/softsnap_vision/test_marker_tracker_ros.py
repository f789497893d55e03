"""marker_tracker in its own process over real DDS: images and camera_info in, measured
shapes and /diagnostics out; bad images are refused without a crash."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from render import Camera, ModuleDrawing, centred_origin, render
from softsnap_model import Skeleton, solve_forward

pytestmark = pytest.mark.ros

NS = '/vision_under_test'
SK = Skeleton()
TRUE_SK = Skeleton(stiffness=[1.3] * 4 + [1.0] * 7)
YELLOW = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()
BLUE = 'R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2'.split()


def camera_info_msg(cam: Camera):
    from sensor_msgs.msg import CameraInfo
    msg = CameraInfo()
    msg.header.frame_id = 'camera_optical_frame'
    msg.width, msg.height = cam.width, cam.height
    msg.k = cam.K.ravel().tolist()
    msg.d = cam.D.tolist()
    msg.distortion_model = 'plumb_bob'
    msg.r = np.eye(3).ravel().tolist()
    p = np.zeros((3, 4))
    p[:, :3] = cam.K
    msg.p = p.ravel().tolist()
    return msg


def image_msg(image: np.ndarray, encoding='bgr8'):
    from sensor_msgs.msg import Image
    msg = Image()
    msg.header.frame_id = 'camera_optical_frame'
    msg.height, msg.width = image.shape[:2]
    msg.encoding = encoding
    msg.step = image.shape[1] * (image.shape[2] if image.ndim == 3 else 1)
    msg.data = image.tobytes()
    return msg


def test_tracker_node_measures_modules_and_survives_bad_images(start_node, ros_node):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image
    from softsnap_interfaces.msg import CableLength, MeasuredShape

    proc = start_node('softsnap_vision', 'marker_tracker', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', 'plane_distance:=0.5',
                      '-p', 'diagnostics_period:=0.5', '-p', 'warn_period:=0.0',
                      '-r', 'image_raw:=camera/image_raw', '-r', 'camera_info:=camera/camera_info')
    cam = Camera(width=800, height=600)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    length = SK.straight_length_mm(YELLOW) - 30.0
    yellow = solve_forward(TRUE_SK, YELLOW, length).rib_centers
    blue = solve_forward(SK, BLUE, SK.straight_length_mm(BLUE) - 15.0).rib_centers
    frame = render(cam, [
        ModuleDrawing(ribs_mm=yellow, yaw_rad=0.1, base_marker=False, tag_id=0, hidden=(5,),
                      origin_mm=centred_origin(yellow, 0.1, 48.0, at=(0.0, 70.0))),
        ModuleDrawing(ribs_mm=blue, yaw_rad=math.pi, base_marker=False, tag_id=1,
                      origin_mm=centred_origin(blue, math.pi, 48.0, at=(0.0, -75.0)))],
        seed=41, tag_dictionary=dictionary)

    shapes = {}
    diagnostics = []
    ros_node.create_subscription(MeasuredShape, f'{NS}/yellow/shape/measured',
                                 lambda m: shapes.__setitem__('yellow', m), 10)
    ros_node.create_subscription(MeasuredShape, f'{NS}/blue/shape/measured',
                                 lambda m: shapes.__setitem__('blue', m), 10)
    ros_node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 50)
    images = ros_node.create_publisher(Image, f'{NS}/camera/image_raw', qos_profile_sensor_data)
    infos = ros_node.create_publisher(CameraInfo, f'{NS}/camera/camera_info', qos_profile_sensor_data)
    lengths = ros_node.create_publisher(CableLength, f'{NS}/yellow/cable_length/measured', 10)
    assert ros_node.spin_until(lambda: images.get_subscription_count() > 0
                               and infos.get_subscription_count() > 0
                               and lengths.get_subscription_count() > 0, 60.0), proc.output()

    def camera_status():
        for array in reversed(diagnostics):
            for s in array.status:
                if s.name == f'softsnap/{NS.strip("/")}/marker_tracker/camera':
                    return s
        return None

    # 1. an image before any camera_info: skipped, STALE 'no camera_info yet'
    images.publish(image_msg(frame))
    assert ros_node.spin_until(lambda: camera_status() is not None
                               and 'no camera_info' in camera_status().message, 30.0), proc.output()
    assert camera_status().level == DiagnosticStatus.STALE

    # 2. camera_info, then a grey image and one of the wrong size: refused, WARN, alive
    info = camera_info_msg(cam)
    bad = [image_msg(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), 'mono8'),
           image_msg(frame[:300, :400].copy())]
    diagnostics.clear()

    def refused_count():
        s = camera_status()
        if s is None:
            return 0
        return int(dict((kv.key, kv.value) for kv in s.values)['images refused (count)'])

    def send_bad():
        infos.publish(info)
        for b in bad:
            images.publish(b)
        return refused_count() >= 3

    assert ros_node.spin_until(send_bad, 60.0), proc.output()
    assert proc.alive()
    # The diagnostic can arrive before the warning's line has been read from the pipe.
    assert ros_node.spin_until(lambda: 'encoding' in proc.output()
                               or 'camera_info is for' in proc.output(), 10.0), proc.output()

    # 3. good frames: both modules measured
    length_msg = CableLength(cable_length=length / 1000.0)

    def send_good():
        infos.publish(info)
        lengths.publish(length_msg)
        images.publish(image_msg(frame))
        m = shapes.get('yellow')
        return ('blue' in shapes and m is not None and math.isfinite(m.rmse_to_model))

    assert ros_node.spin_until(send_good, 60.0), proc.output()
    for name, truth, hidden in (('yellow', yellow, {5}), ('blue', blue, set())):
        m = shapes[name]
        assert m.source == 'camera' and m.module == name
        assert m.header.frame_id == f'brittle_star/{name}'
        assert [not v for v in m.visible] == [i in hidden for i in range(12)]
        got = np.array([[p.x, p.y] for p in m.rib_centers]) * 1000.0
        seen = np.array(m.visible)
        assert np.isnan(got[~seen]).all()
        assert np.hypot(*(got[seen] - truth[seen]).T).max() <= 0.4, name
        assert 0 <= m.residual < 0.3e-3
    model = solve_forward(SK, YELLOW, length).rib_centers
    seen = np.array(shapes['yellow'].visible)
    true_rmse = float(np.sqrt(np.mean(np.sum((yellow[seen] - model[seen]) ** 2, axis=1))))
    assert true_rmse > 0.5
    assert abs(shapes['yellow'].rmse_to_model * 1000.0 - true_rmse) <= 0.2
    assert abs(shapes['yellow'].cable_length - length / 1000.0) < 1e-12
    assert math.isnan(shapes['blue'].rmse_to_model)   # no measured length for blue

    # 4. per-module diagnostics: seen modules OK, the others STALE
    def module_levels():
        for array in reversed(diagnostics):
            levels = {s.name.split('/')[-2]: s.level for s in array.status
                      if s.name.endswith('/camera') and 'marker_tracker' not in s.name}
            if levels:
                return levels
        return {}

    diagnostics.clear()
    assert ros_node.spin_until(lambda: send_good() and module_levels().get('yellow')
                               == DiagnosticStatus.OK, 30.0), proc.output()
    levels = module_levels()
    assert levels['blue'] == DiagnosticStatus.OK and levels['red'] == DiagnosticStatus.STALE
    assert proc.alive()


def test_bad_marker_file_ends_the_node_with_one_line(start_node, tmp_path):
    import time
    (tmp_path / 'markers.yaml').write_text('rib_marker: {color_rgb: [128, 128, 128]}\n')
    proc = start_node('softsnap_vision', 'marker_tracker', '--ros-args',
                      '-p', f'markers:={tmp_path / "markers.yaml"}')
    deadline = time.monotonic() + 60.0
    while proc.alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert proc.proc.returncode == 2, proc.output()
    assert 'cannot start' in proc.output() and 'too grey' in proc.output()
