#!/usr/bin/env python3
"""sim_robot benchmark: real-time factor per scene on one core, and determinism.

For each scene, a :class:`~softsnap_driver.sim_robot.SimRobot` (firmware of every module,
winches loaded by the cable tensions, the MuJoCo robot; the demo's payloads for the
gripper and the ring) is driven by its default gait the way its drivers would drive it
(:class:`~softsnap_driver.sim_robot.ScriptedCommands`: ``set`` requests at 50 Hz), with
no sockets and no pacing: the real-time factor is simulated seconds per wall second of
the coupled loop, the cost ``sim_robot`` pays when serving drivers (the HTTP threads and
the ROS publishing add little: a few hundred requests per second). The process is pinned
to one core. Each scene runs ``--repeat`` times; the table gives the median and range.

Determinism: the brittle star walks ``--seconds`` twice from the same start with the same
commands; the trajectories (robot base and every rib centre, every 0.1 s) must be
identical bit for bit.

The load average is printed at the start and the end: on a shared machine the numbers
are only as good as the idle core they ran on.

``--ab``: each scene also runs, interleaved with the default runs, with MuJoCo's constraint
island discovery switched back on (the model before it was disabled), and the table adds
that CPU real-time factor and the ratio of the medians (same load for both).

Usage: .venv/bin/python benchmarks/sim_robot_bench.py [--seconds 3] [--repeat 3]
       [--scenes brittle_star,snake] [--links-per-segment N] [--ab]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import mujoco
import numpy as np

from softsnap_driver.sim_robot import (DEFAULT_LINKS_PER_SEGMENT, OPTIONS, ScriptedCommands, SimRobot,
                                       build_payload, build_simulation)
from softsnap_gaits.demo import PHYSICS_PAYLOADS
from softsnap_gaits.gaits import make_gait
from softsnap_model.scene import load_scene

SCENES = ('brittle_star', 'starfish', 'snake', 'gripper', 'ring')


def make_robot(name: str, links: int, islands: bool = False) -> SimRobot:
    scene = load_scene(name)
    options = argparse.Namespace(**{k: d for k, (_t, d, _h) in OPTIONS.items()})
    for key, value in PHYSICS_PAYLOADS.get(name, {}).items():
        setattr(options, key, value)
    simulation = build_simulation(scene, payload=build_payload(options), links_per_segment=links)
    if islands:      # the model as it was before island discovery was disabled
        simulation.model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
    return SimRobot(scene, simulation)


def run_once(name: str, seconds: float, links: int,
             islands: bool = False) -> tuple[float, float, float]:
    """(wall s to build, wall s to simulate `seconds`, CPU s to simulate them)."""
    t0 = time.perf_counter()
    robot = make_robot(name, links, islands)
    built = time.perf_counter() - t0
    gait = make_gait(robot.scene.default_gait, robot.scene)
    script = ScriptedCommands(gait.contraction_mm)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    robot.run_until(seconds, script)
    return built, time.perf_counter() - wall0, time.process_time() - cpu0


def trajectory(seconds: float, links: int) -> np.ndarray:
    robot = make_robot('brittle_star', links)
    script = ScriptedCommands(make_gait('walk', robot.scene).contraction_mm)
    rows, t = [], 0.0
    while t < seconds - 1e-9:
        t += 0.1
        robot.run_until(t, script)
        snap = robot.snapshot()
        rows.append(np.concatenate([snap.base_position_m]
                                   + [np.ravel(m.rib_centers_m) for m in snap.modules]))
    return np.array(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=3.0, help='simulated time per run, s')
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--scenes', default=','.join(SCENES))
    parser.add_argument('--links-per-segment', type=int, default=DEFAULT_LINKS_PER_SEGMENT,
                        help="links per segment of the MuJoCo model (default sim_robot's, "
                             f"{DEFAULT_LINKS_PER_SEGMENT}; 0: the physics model's default)")
    parser.add_argument('--ab', action='store_true',
                        help='also run with island discovery on (before), interleaved')
    args = parser.parse_args()
    if hasattr(os, 'sched_setaffinity'):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())} '
          f'({os.cpu_count()} cores; this process pinned to one)')
    print(f'\nsim_robot real-time factor (simulated s per wall s), {args.seconds:g} s of the '
          f"default gait, {args.repeat} runs; links per segment: "
          f"{args.links_per_segment or 'physics model default'}")
    header = (f"{'scene':13s} {'modules':>7s} {'build s':>8s} {'RTF median':>11s} "
              f"{'RTF range':>15s} {'CPU RTF':>8s}"
              + (f" {'CPU RTF before':>14s} {'ratio':>6s}" if args.ab else ''))
    print(header)
    print('-' * len(header))
    for name in args.scenes.split(','):
        runs, before = [], []
        for _ in range(args.repeat):
            if args.ab:
                before.append(run_once(name, args.seconds, args.links_per_segment, True))
            runs.append(run_once(name, args.seconds, args.links_per_segment))
        factors = [args.seconds / wall for _, wall, _ in runs]
        cpu = statistics.median(args.seconds / c for _, _, c in runs)
        modules = len(load_scene(name).modules)
        extra = ''
        if args.ab:
            cpu_before = statistics.median(args.seconds / c for _, _, c in before)
            extra = f' {cpu_before:14.2f} {cpu / cpu_before:6.2f}'
        print(f'{name:13s} {modules:7d} {statistics.median(b for b, _, _ in runs):8.2f} '
              f'{statistics.median(factors):11.2f} {min(factors):7.2f}-{max(factors):<7.2f} '
              f'{cpu:8.2f}' + extra, flush=True)
    seconds = min(args.seconds, 2.0)
    first, second = trajectory(seconds, args.links_per_segment), trajectory(seconds, args.links_per_segment)
    same = first.shape == second.shape and np.array_equal(first, second)
    print(f'\ndeterminism: brittle star walk, {seconds:g} s twice: trajectories '
          f"{'identical bit for bit' if same else 'DIFFER'} "
          f'(largest difference {np.abs(first - second).max():.3g} m over {first.size} values)')
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')


if __name__ == '__main__':
    main()
