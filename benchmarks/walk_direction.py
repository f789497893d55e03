#!/usr/bin/env python3
"""Which way does a gait move the brittle star? Displacements in MuJoCo, per cycle.

Each gait runs on a fresh :class:`~softsnap_driver.sim_robot.SimRobot` (firmware,
loaded winches, the MuJoCo robot on the ground), driven with the gait's contraction
schedule as the drivers would send it (``ScriptedCommands``, no sockets), the same way as
``test_brittle_star_walk_and_walk_reverse_move_it_in_opposite_directions``. The robot
settles for 0.3 s first; the table gives the base's ground-plane displacement (mm, robot
frame at the start) after each cycle, and the angle between the first gait's
displacement and each other one's after the last cycle.

Not a timing benchmark (deterministic: the same numbers on every machine with the same
MuJoCo build). A few cycles take tens of seconds per gait on a loaded 2-core machine.

Usage: .venv/bin/python benchmarks/walk_direction.py [--gaits walk,walk_reverse]
       [--cycles 3] [--links-per-segment 2]

Links per segment: 2, the MuJoCo model's default, which keeps a settled module within
1 mm of the quasi-static shape over the whole reach (benchmarks/rib_contact_bench.py);
1 link is 5-15 mm off even below contact (issue 32).
"""
from __future__ import annotations

import argparse
import math

import numpy as np

from softsnap_driver.sim_robot import ScriptedCommands, SimRobot, build_simulation
from softsnap_gaits.gaits import make_gait
from softsnap_model.physics.parameters import DEFAULT_LINKS_PER_SEGMENT
from softsnap_model.scene import load_scene

SETTLE_S = 0.3


def travel_mm(scene, gait_name: str, cycles: int, links_per_segment: int) -> np.ndarray:
    """Ground-plane displacement of the robot base after each cycle, (cycles, 2) mm."""
    robot = SimRobot(scene, build_simulation(scene, links_per_segment=links_per_segment))
    robot.run_until(SETTLE_S)
    start = np.asarray(robot.simulation.robot_base_pose()[0])
    gait = make_gait(gait_name, scene)
    script = ScriptedCommands(gait.contraction_mm, start_s=robot.clock())
    out = []
    for c in range(1, cycles + 1):
        robot.run_until(SETTLE_S + c * gait.period_s, script)
        out.append((np.asarray(robot.simulation.robot_base_pose()[0]) - start)[:2] * 1e3)
    return np.array(out)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(a @ b) / (float(np.linalg.norm(a)) * float(np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='brittle_star')
    parser.add_argument('--gaits', default='walk,walk_reverse')
    parser.add_argument('--cycles', type=int, default=3)
    parser.add_argument('--links-per-segment', type=int, default=DEFAULT_LINKS_PER_SEGMENT)
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    names = [g for g in args.gaits.split(',') if g]
    results = {}
    for name in names:
        results[name] = travel_mm(scene, name, args.cycles, args.links_per_segment)
        rows = ', '.join(f'({x:+.1f}, {y:+.1f})' for x, y in results[name])
        print(f'{name:>14}: displacement after cycles 1..{args.cycles} (x, y) mm: {rows}',
              flush=True)
    first = results[names[0]][-1]
    for name in names[1:]:
        last = results[name][-1]
        print(f'{names[0]} vs {name}: dot {float(first @ last):+.1f} mm^2, '
              f'angle {angle_deg(first, last):.0f} deg')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
