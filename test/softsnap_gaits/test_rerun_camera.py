"""The camera in the rerun recording: a real frame of sim_robot's camera, real messages,
a real .rrd read back. The tracker's rib centres and the prediction are drawn where the
renderer put the markers (found again by OpenCV in the rendered frame)."""
from __future__ import annotations

import array
import os

import numpy as np

os.environ.setdefault('MUJOCO_GL', 'egl')


def _msgs(sim, camera, image):
    from geometry_msgs.msg import Point, Pose, PoseStamped
    from sensor_msgs.msg import CameraInfo, Image
    from softsnap_interfaces.msg import MeasuredShape, ModuleShape, RobotShape
    stamp_ns = 1_500_000_000
    img = Image()
    img.header.stamp.sec, img.header.stamp.nanosec = 1, 500_000_000
    img.height, img.width = image.shape[:2]
    img.encoding, img.step = 'rgb8', image.shape[1] * 3
    img.data = array.array('B', image.tobytes())
    k = camera.view.intrinsics
    info = CameraInfo(width=k.width_px, height=k.height_px)
    info.k = [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0]
    pose = PoseStamped()
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = camera.view.position_m
    pose.pose.orientation.w, pose.pose.orientation.x = 0.0, 1.0
    simulated = RobotShape()
    predicted = RobotShape()
    measured = []
    for name in sim.module_names:
        position, wxyz = sim.module_base_pose(name)
        p = Pose()
        p.position.x, p.position.y, p.position.z = (float(v) for v in position)
        p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z = (float(v) for v in wxyz)
        simulated.modules.append(ModuleShape(module=name))
        simulated.base_poses.append(p)
        predicted.modules.append(ModuleShape(module=name,
                                             angles=[float(a) for a in sim.segment_angles(name)]))
        shape = MeasuredShape(module=name, source='camera')
        # On the markers' face (4.5 mm + the disc's 0.1 mm gap above the rib centre), so
        # the drawn points must fall on the rendered markers exactly.
        shape.rib_centers = [Point(x=float(x), y=float(y), z=float(z) + 0.0046)
                             for x, y, z in sim.rib_centers(name)]
        shape.visible = [True] * 12
        measured.append(shape)
    return stamp_ns, img, info, pose, simulated, predicted, measured


def test_frames_detections_and_prediction_are_recorded_over_the_markers(tmp_path, read_rrd):
    import cv2
    import mujoco
    import rerun as rr
    from softsnap_ros import cdr
    from softsnap_driver.sim_camera import PINK_RGB, CameraSettings, SimCamera, capture_frame_state
    from softsnap_driver.sim_robot import build_simulation
    from softsnap_gaits.rerun_camera import IMAGE_PATH, CameraRecorder
    from softsnap_model import recording
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    sim = build_simulation(scene, gravity=False, links_per_segment=2)
    sim.set_cable_length(sim.module_names[0], sim.straight_cable_length(sim.module_names[0]) - 0.025)
    sim.step(1.5)
    mujoco.mj_kinematics(sim.model, sim.data)
    camera = SimCamera(sim, CameraSettings())
    try:
        image = camera.render(capture_frame_state(sim))
    finally:
        camera.close()
    stamp_ns, img, info, pose, simulated, predicted, measured = _msgs(sim, camera, image)

    path = tmp_path / 'camera.rrd'
    rec = recording.open_recording(path, None, application_id='softsnap_test')
    recorder = CameraRecorder(rec, scene.skeleton.spacing_mm, rate_hz=5.0)
    recorder.camera_info(info)
    recorder.camera_pose(pose)
    recorder.simulated(cdr.from_message(simulated))
    recorder.predicted_shape(cdr.from_message(predicted))
    for shape in measured:
        recorder.measured_shape(shape)
    assert recorder.image(img)
    assert not recorder.image(img)           # the same stamp again: within the rate limit
    recording.close_recording(rec)

    rrd = read_rrd(path)
    assert rrd.times(IMAGE_PATH) == [stamp_ns]
    blob = rrd.values(IMAGE_PATH, 'EncodedImage:blob')[0]
    jpeg = np.asarray(blob[0] if isinstance(blob[0], list) else blob, dtype=np.uint8)
    decoded = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
    assert decoded.shape == image.shape
    assert 'Pinhole:image_from_camera' in rrd.static[IMAGE_PATH]
    # The pink markers of the rendered frame, found by OpenCV.
    mask = np.all(np.abs(image.astype(int) - PINK_RGB) <= 40, axis=2).astype(np.uint8)
    _n, _labels, stats, centroids = cv2.connectedComponentsWithStats(mask)
    pink = centroids[1:][stats[1:, cv2.CC_STAT_AREA] >= 4]
    assert len(pink) == 60
    for name in sim.module_names:
        points = np.array(rrd.values(f'{IMAGE_PATH}/measured/{name}', 'Points2D:positions')[0])
        assert points.shape == (12, 2)
        offset = np.min(np.linalg.norm(points[:, None, :] - pink[None], axis=2), axis=1)
        assert offset.max() < 0.4, (name, offset)
        # The prediction for the simulated angles, in the ribs' plane (4.6 mm lower: up
        # to ~2.5 px nearer the image centre at the image's edge), on the same ribs.
        line = np.array(rrd.values(f'{IMAGE_PATH}/predicted/{name}', 'LineStrips2D:strips')[0][0])
        assert line.shape == (12, 2)
        assert np.max(np.linalg.norm(line - points, axis=1)) < 3.5, name
    assert rr is not None
