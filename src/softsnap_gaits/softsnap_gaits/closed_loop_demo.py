"""``make demo ARGS="--physics --closed-loop"``: a gripper finger reaching a tip target.

One hanging gripper module (front_left) in MuJoCo (in this process,
:mod:`softsnap_gaits.physics_plant`) carries a 20 g load on its tip that the controller's
model does not know; a ``shape_controller`` node (its own process, real DDS) takes it to
where the loaded finger rests at 30 mm of contraction. Open loop first (the model's
feedforward), then a ReachShape goal; the summary gives both tip errors and the settle
time. The run folder holds the controller's log, its rerun recording (target, measured,
predicted shape and the error over time) and its steady-correction log.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

MODULE = 'front_left'
CASES = {
    'payload_20g_tip': dict(physics={'tip_mass_kg': 0.020}),
    'stiffness_minus_20pct': dict(physics={'bending_stiffness_nmm': 17.6 * 0.8}),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='demo --closed-loop', description=__doc__.split('\n')[0])
    parser.add_argument('--run-dir', default=None, help='folder for logs and the recording')
    parser.add_argument('--json', action='store_true', help='print the summary as JSON')
    args, _ignored = parser.parse_known_args(argv)   # demo.py's other options do not apply
    from softsnap_gaits.isolation import claim_slot
    slot, warning = claim_slot()
    if warning:
        print(f'demo: warning: {warning}', file=sys.stderr)
    os.environ.setdefault('ROS_DOMAIN_ID', str(slot.domain_id))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    log = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    run_dir = Path(args.run_dir or f'runs/closed_loop-{time.strftime("%Y%m%d-%H%M%S")}')
    run_dir.mkdir(parents=True, exist_ok=True)

    import subprocess

    import rclpy
    from ament_index_python.packages import get_package_prefix
    from rclpy.executors import SingleThreadedExecutor

    from softsnap_ros.dds_profile import use_node_profile
    from softsnap_gaits.closed_loop_run import run_case
    from softsnap_model.scene import load_scene

    use_node_profile()
    exe = Path(get_package_prefix('softsnap_gaits')) / 'lib' / 'softsnap_gaits' / 'shape_controller'
    log_file = open(run_dir / 'shape_controller.log', 'w')
    controller = subprocess.Popen(
        [str(exe), '--ros-args', '-r', '__ns:=/gripper', '-p', 'scene:=gripper',
         '-p', f'modules:=[{MODULE}]', '-p', 'measured_topic:=shape/ground_truth',
         '-p', "gait_node:=''", '-p', f'rerun_recording:={run_dir / "control.rrd"}',
         '-p', f'correction_log:={run_dir / "corrections.jsonl"}'],
        stdout=log_file, stderr=subprocess.STDOUT, start_new_session=True)
    rclpy.init()
    node = rclpy.create_node('closed_loop_demo', namespace='/gripper')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    scene = load_scene('gripper')
    results = []
    try:
        for name, case in CASES.items():
            results.append(run_case(node, executor, scene, MODULE, name, contraction_m=0.03,
                                    log=log, **case))
            from softsnap_interfaces.srv import SetShapeTarget
            client = node.create_client(SetShapeTarget, 'shape_controller/set_target')
            if client.wait_for_service(timeout_sec=10.0):
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
        controller.send_signal(2)
        try:
            controller.wait(timeout=15)
        except subprocess.TimeoutExpired:
            controller.kill()
        log_file.close()
    summary = {'task': f'gripper {MODULE}: tip target at 30 mm contraction',
               'cases': [r.as_json() | {'stop_reason': r.stop_reason} for r in results],
               'run_dir': str(run_dir)}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f'closed loop ({summary["task"]}); run folder {run_dir}')
        for r in summary['cases']:
            print(f'  {r["name"]:24s} open loop {r["open_loop_tip_error_mm"]:7.2f} mm   closed '
                  f'loop {r["closed_loop_tip_error_mm"]:6.3f} mm   settled in '
                  f'{r["settle_time_s"]} s   stable {r["stable"]}   goal {r["stop_reason"]}')
    ok = all(r['stable'] for r in summary['cases'])
    return 0 if ok else 1
