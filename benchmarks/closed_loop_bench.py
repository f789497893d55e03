"""Closed-loop shape control on the MuJoCo robot through the ROS graph.

    .venv/bin/python benchmarks/closed_loop_bench.py [--json] [--cases a,b]

A shape_controller node (its own process, real DDS) drives one hanging gripper module
(front_left) simulated in MuJoCo in this process (softsnap_gaits.physics_plant), with
physical parameters the controller's model gets wrong. Per case the tip target is where
the physics module rests at 30 mm of contraction; the open loop commands the model's
feedforward length for it, the closed loop sends a ReachShape goal (closed_loop_run).

Cases: stiffness_minus_20pct (K 20 % below the model's 17.6 N mm/rad^2), payload_20g_tip
(20 g on the tip rib), latency_100ms_noise_0.5mm (the payload case with every
measurement 100 ms late and 0.5 mm of noise per coordinate). The simulated camera
(sim_robot camera:=true) renders images, but the marker tracker that turns them into
MeasuredShape is not on this branch: that case is not run (said on stderr).

--json prints exactly {"cases": [{"name", "open_loop_tip_error_mm",
"closed_loop_tip_error_mm", "settle_time_s", "stable"}]} on stdout.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from softsnap_gaits.isolation import claim_slot

SLOT, _warning = claim_slot()
os.environ.setdefault('ROS_DOMAIN_ID', str(SLOT.domain_id))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchlib import load_line, start_node  # noqa: E402
from softsnap_ros.processes import stop_process_group  # noqa: E402

MODULE = 'front_left'
CASES = {
    'stiffness_minus_20pct': dict(physics={'bending_stiffness_nmm': 17.6 * 0.8}),
    'payload_20g_tip': dict(physics={'tip_mass_kg': 0.020}),
    'latency_100ms_noise_0.5mm': dict(physics={'tip_mass_kg': 0.020}, latency_s=0.1,
                                      noise_m=0.0005),
}


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
    log('simulated_camera: not run (the marker tracker that measures its images is not on '
        'this branch)')

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from softsnap_ros.dds_profile import use_node_profile
    from softsnap_gaits.closed_loop_run import run_case
    from softsnap_model.scene import load_scene

    use_node_profile()
    controller = start_node('softsnap_gaits', 'shape_controller', [
        '-r', '__ns:=/bench', '-p', 'scene:=gripper', '-p', f'modules:=[{MODULE}]',
        '-p', 'measured_topic:=shape/ground_truth', '-p', "gait_node:=''"],
        log_path=os.environ.get('CLOSED_LOOP_BENCH_LOG'))
    rclpy.init()
    node = rclpy.create_node('closed_loop_bench', namespace='/bench')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    scene = load_scene('gripper')
    results = []
    try:
        for name in names:
            case = CASES[name]
            results.append(run_case(node, executor, scene, MODULE, name,
                                    contraction_m=opts.contraction_mm * 1e-3, log=log,
                                    **case))
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
        stop_process_group(controller)
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
