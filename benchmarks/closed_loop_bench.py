"""Closed-loop shape control on the MuJoCo robot through the ROS graph.

    .venv/bin/python benchmarks/closed_loop_bench.py [--json] [--cases a,b]

A shape_controller node (its own process, real DDS) drives one hanging gripper module
(front_left) simulated in MuJoCo in this process (softsnap_gaits.physics_plant), with
physical parameters the controller's model gets wrong. Per case the tip target is where
the physics module rests at 30 mm of contraction; the open loop commands the model's
feedforward length for it, the closed loop sends a ReachShape goal (closed_loop_run).

Cases: stiffness_minus_20pct (K 20 % below the model's 17.6 N mm/rad^2), payload_20g_tip
(20 g on the tip rib), latency_100ms_noise_0.5mm (the payload case with every
measurement 100 ms late and 0.5 mm of noise per coordinate), simulated_camera (the
payload case measured by a camera: MuJoCo renders the finger from its marked side at
640x480 and 15 Hz with an ArUco tag on its case, and a marker_tracker process, real
images over DDS and real OpenCV, publishes the measured shape the controller follows).

--json prints exactly {"cases": [{"name", "open_loop_tip_error_mm",
"closed_loop_tip_error_mm", "settle_time_s", "stable"}]} on stdout.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from softsnap_gaits.isolation import claim_slot

SLOT, _warning = claim_slot()
os.environ.setdefault('ROS_DOMAIN_ID', str(SLOT.domain_id))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
# The camera case renders offscreen: MuJoCo reads MUJOCO_GL once, at its first import.
os.environ.setdefault('MUJOCO_GL', 'egl')
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchlib import load_line, start_node  # noqa: E402
from softsnap_ros.processes import stop_process_group  # noqa: E402

MODULE = 'front_left'
CASES = {
    'stiffness_minus_20pct': dict(physics={'bending_stiffness_nmm': 17.6 * 0.8}),
    'payload_20g_tip': dict(physics={'tip_mass_kg': 0.020}),
    'latency_100ms_noise_0.5mm': dict(physics={'tip_mass_kg': 0.020}, latency_s=0.1,
                                      noise_m=0.0005),
    'simulated_camera': dict(physics={'tip_mass_kg': 0.020}, camera_rate_hz=15.0),
}
#: The shape topic the controller follows per case: the plant's ground truth, or the
#: tracker's measurement of the camera's images.
MEASURED_TOPIC = {name: 'shape/measured' if case.get('camera_rate_hz') else 'shape/ground_truth'
                  for name, case in CASES.items()}
#: The camera's tag on the finger's case (the tracker's scene gets the same id).
CAMERA_TAG_ID = 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--json', action='store_true', help='print the JSON summary only')
    parser.add_argument('--cases', default=','.join(CASES), help='comma-separated cases')
    parser.add_argument('--contraction-mm', type=float, default=30.0)
    opts = parser.parse_args(argv)
    log = (lambda *a: print(*a, file=sys.stderr)) if opts.json else print
    names = [c for c in opts.cases.split(',') if c]
    unknown = [c for c in names if c not in CASES]
    if unknown:
        parser.error(f'unknown case(s) {unknown}; cases are {", ".join(CASES)}')
    log(load_line('start'))

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from softsnap_ros.dds_profile import use_node_profile
    from softsnap_gaits.closed_loop_run import camera_tracker_args, run_case, tagged_scene_file
    from softsnap_model.scene import load_scene

    use_node_profile()
    log_path = os.environ.get('CLOSED_LOOP_BENCH_LOG')
    work = Path(tempfile.mkdtemp(prefix='closed_loop_bench_'))
    processes = {}

    def start_controller(topic):
        return start_node('softsnap_gaits', 'shape_controller', [
            '-r', '__ns:=/bench', '-p', 'scene:=gripper', '-p', f'modules:=[{MODULE}]',
            '-p', f'measured_topic:={topic}', '-p', "gait_node:=''"],
            log_path=log_path and f'{log_path}.controller-{topic.replace("/", "_")}')

    def start_tracker(plant):
        distance = plant.camera_plane_distance_m()
        log(f'simulated_camera: {plant.camera.describe()}; marker_tracker with '
            f'plane_distance {distance:.4f} m')
        scene_file = tagged_scene_file('gripper', MODULE, CAMERA_TAG_ID, work)
        processes['tracker'] = start_node(
            'softsnap_vision', 'marker_tracker',
            camera_tracker_args('/bench', scene_file, distance),
            log_path=log_path and f'{log_path}.tracker')
    rclpy.init()
    node = rclpy.create_node('closed_loop_bench', namespace='/bench')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    scene = load_scene('gripper')
    results = []
    controller_topic = None
    try:
        for name in names:
            case = CASES[name]
            if MEASURED_TOPIC[name] != controller_topic:   # one controller per input
                if 'controller' in processes:
                    stop_process_group(processes.pop('controller'))
                controller_topic = MEASURED_TOPIC[name]
                processes['controller'] = start_controller(controller_topic)
            on_plant = start_tracker if case.get('camera_rate_hz') else None
            try:
                results.append(run_case(node, executor, scene, MODULE, name,
                                        contraction_m=opts.contraction_mm * 1e-3, log=log,
                                        on_plant=on_plant, **case))
            finally:
                if 'tracker' in processes:
                    stop_process_group(processes.pop('tracker'))
            # Clear the target before the next case's open loop.
            from softsnap_interfaces.srv import SetShapeTarget
            client = node.create_client(SetShapeTarget, 'shape_controller/set_target')
            client.wait_for_service(timeout_sec=10.0)
            future = client.call_async(SetShapeTarget.Request(modules=[MODULE],
                                                              target_kind='clear'))
            deadline = time.monotonic() + 10.0
            while not future.done() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
            node.destroy_client(client)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        for proc in processes.values():
            stop_process_group(proc)
    log(load_line('end'))
    summary = {'cases': [r.as_json() for r in results]}
    if opts.json:
        print(json.dumps(summary))
    else:
        print(f'{"case":28s} {"open loop mm":>13s} {"closed loop mm":>15s} {"settle s":>9s} '
              f'{"stable":>7s}')
        for r in summary['cases']:
            print(f'{r["name"]:28s} {r["open_loop_tip_error_mm"]:13.3f} '
                  f'{r["closed_loop_tip_error_mm"]:15.3f} {str(r["settle_time_s"]):>9s} '
                  f'{str(r["stable"]):>7s}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
