#!/usr/bin/env python3
"""Cost of the standard outputs per timer tick, in-process (no graph).

Builds what the model node's marker timer builds when every shape changed since the last
tick (the worst case: a moving gait; unchanged shapes reuse their cached markers), the
JointState messages of one prediction tick, and one driver's DiagnosticStatus and
BatteryState. Prints the median and p99 wall time per call.

Usage: nice .venv/bin/python benchmarks/standard_messages_bench.py [--repeats 2000] [--scene brittle_star]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from rclpy.serialization import serialize_message
from visualization_msgs.msg import MarkerArray

from softsnap_driver.diagnostics import DriverHealth, battery_state
from softsnap_driver.link_report import Counters, LinkReport
from softsnap_driver.protocol import ModuleStatus
from softsnap_model import standard_messages as standard
from softsnap_model.predictor import SOURCES, RobotPredictor
from softsnap_model.scene import load_scene


def timed(function, repeats: int) -> tuple[float, float]:
    """Median and p99 CPU time of this thread per call (s): on a loaded machine wall time
    mostly measures the other processes."""
    times = []
    for _ in range(repeats):
        start = time.thread_time()
        function()
        times.append(time.thread_time() - start)
    times.sort()
    return statistics.median(times), times[int(0.99 * (len(times) - 1))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=2000)
    parser.add_argument('--scene', default='brittle_star')
    args = parser.parse_args()
    scene = load_scene(args.scene)
    predictor = RobotPredictor(scene)
    for source in SOURCES:
        for i, module in enumerate(scene.modules):
            predictor.submit(source, module.name, module.straight_length_mm - 20.0 - i, 1)
    updated = predictor.tick(False)
    skeleton = scene.skeleton

    def markers(reuse=None):
        out = []
        for source in SOURCES:
            for index, (module, shape, pose) in enumerate(zip(
                    scene.modules, predictor.shapes(source), predictor.base_poses(source))):
                out += standard.prediction_markers(
                    shape, module_index=index, threading_mm=module.threading_mm,
                    base_pose_m=pose, frame_id=scene.name, spacing_mm=skeleton.spacing_mm,
                    rib_length_mm=skeleton.rib_length_mm,
                    reuse=reuse[(module.name, source)] if reuse else ())
        return MarkerArray(markers=out)

    # What the node keeps: the markers of each (module, source), updated in place.
    kept = {}
    for marker in markers().markers:
        module, source, _ = marker.ns.split('/')
        kept.setdefault((module, source), []).append(marker)

    array = markers()
    report = LinkReport(stamp=time.monotonic(), fresh=True, online=True, calibrated=True,
                        status=ModuleStatus(encoder_count=10, motor_power=200, encoder_errors=0,
                                            battery_voltage=3.9, paused=False),
                        measured_length_m=0.19, target_length_m=0.19, encoder_target=10,
                        pwm_power=200, counters=Counters(), last_error='')
    health = DriverHealth('softsnap/bench/m1/driver', '127.0.0.1:80')
    rows = [
        (f'MarkerArray, all {len(array.markers)} markers built new', markers),
        ('  the same, markers updated in place (the node)', lambda: markers(kept)),
        ('  serialising it (what publish adds)', lambda: serialize_message(array)),
        ('JointState of one tick, one source', lambda: standard.joint_states(updated['commanded'])),
        ('driver DiagnosticStatus', lambda: health.status(report, time.monotonic())),
        ('driver BatteryState', lambda: battery_state(report, 'm1')),
    ]
    print(f'scene {scene.name}: {len(scene.modules)} modules x {len(SOURCES)} sources, '
          f'{args.repeats} repeats, {len(serialize_message(array))} bytes per MarkerArray')
    print(f'| {"what":45s} | median CPU (ms) | p99 CPU (ms) |')
    print(f'| {"-" * 45} | ---: | ---: |')
    for name, function in rows:
        median, p99 = timed(function, args.repeats)
        print(f'| {name:45s} | {median * 1e3:.3f} | {p99 * 1e3:.3f} |')


if __name__ == '__main__':
    np.seterr(all='raise')
    main()
