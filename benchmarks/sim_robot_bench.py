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

The gait's contraction schedule is evaluated before the clock starts (the same values at
the same simulated times as :class:`ScriptedCommands` would compute them): the gait runs
in the gait node's process, not in ``sim_robot``; the firmware's handling of every
``set`` request is timed.

``--before REV``: each run of a scene is paired with a run of this script's
``run_once`` on the ``src/`` of git revision ``REV`` (from ``git archive``, in a child
process whose ``PYTHONPATH`` puts that source first), the two interleaved so both see
the same load; the table adds that CPU real-time factor and the ratio of the medians.
E.g. ``--before ab2bb8c``: the 2 ms step and the per-period Python work before issue 16's
speed-up.

``--timestep-ms``: the physics step of this run (default sim_robot's,
``DEFAULT_PHYSICS_TIMESTEP_S``).

``--stages``: after the table, one more run of each scene (this code) with MuJoCo's own
stage timers (``data.timer``, wall clock, so only meaningful on a quiet core): µs per
step and share of the step for the constraint solve, collision, constraint make,
kinematics and inertia; where ``mj_step`` spends its time (docs/sim_robot.md).

Usage: .venv/bin/python benchmarks/sim_robot_bench.py [--seconds 3] [--repeat 3]
       [--scenes brittle_star,snake] [--links-per-segment N] [--before REV]
       [--timestep-ms 3] [--stages]
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from softsnap_driver import sim_robot as _sim_robot
from softsnap_driver.sim_robot import (DEFAULT_LINKS_PER_SEGMENT, ScriptedCommands, SimRobot,
                                       build_simulation)
from softsnap_driver.sim_robot_runner import OPTIONS, build_payload
from softsnap_gaits.demo import PHYSICS_PAYLOADS
from softsnap_gaits.gaits import make_gait
from softsnap_model.scene import load_scene

SCENES = ('brittle_star', 'starfish', 'snake', 'gripper', 'ring')


#: sim_robot's physics step, s; None on a source before it had one (--before).
DEFAULT_PHYSICS_TIMESTEP_S = getattr(_sim_robot, 'DEFAULT_PHYSICS_TIMESTEP_S', None)
#: Physics step of the runs, s (set by --timestep-ms; None: build_simulation's own).
TIMESTEP_S = DEFAULT_PHYSICS_TIMESTEP_S
REPO = Path(__file__).resolve().parent.parent


def make_robot(name: str, links: int) -> SimRobot:
    scene = load_scene(name)
    options = argparse.Namespace(**{k: d for k, (_t, d, _h) in OPTIONS.items()})
    for key, value in PHYSICS_PAYLOADS.get(name, {}).items():
        setattr(options, key, value)
    kwargs = {} if TIMESTEP_S is None else {'timestep_s': TIMESTEP_S}
    simulation = build_simulation(scene, payload=build_payload(options), links_per_segment=links,
                                  **kwargs)
    return SimRobot(scene, simulation)


def precomputed(contraction_mm, robot: SimRobot, seconds: float, rate_hz: float = 50.0):
    """``contraction_mm`` looked up from a table of the values ScriptedCommands will ask
    for in a run of `seconds` (its firing rule on the robot's clock, bit for bit), so the
    gait's cost stays out of the timed loop; any other time is computed."""
    probe = ScriptedCommands(contraction_mm, rate_hz=rate_hz)
    table, dt, step = {}, robot.control_period_s, 0
    while step * dt < seconds - 1e-12:
        now = step * dt          # SimRobot's clock: the step count times the period
        if now + 1e-12 >= probe._next_s:
            probe._next_s += probe.period_s
            table[now] = contraction_mm(now)
        step += 1
    return lambda t: table[t] if t in table else contraction_mm(t)


def run_once(name: str, seconds: float, links: int) -> tuple[float, float, float]:
    """(wall s to build, wall s to simulate `seconds`, CPU s to simulate them)."""
    t0 = time.perf_counter()
    robot = make_robot(name, links)
    built = time.perf_counter() - t0
    gait = make_gait(robot.scene.default_gait, robot.scene)
    script = ScriptedCommands(precomputed(gait.contraction_mm, robot, seconds))
    wall0, cpu0 = time.perf_counter(), time.process_time()
    robot.run_until(seconds, script)
    return built, time.perf_counter() - wall0, time.process_time() - cpu0


#: MuJoCo stage timers printed by --stages: (label, mjtTimer name).
STAGES = (('step', 'mjTIMER_STEP'), ('constraint solve', 'mjTIMER_CONSTRAINT'),
          ('collision', 'mjTIMER_POS_COLLISION'), ('constraint make', 'mjTIMER_POS_MAKE'),
          ('kinematics', 'mjTIMER_POS_KINEMATICS'), ('inertia', 'mjTIMER_POS_INERTIA'))


def stages(name: str, seconds: float, links: int) -> str:
    """One run of `name`; MuJoCo's stage timers as µs per step (share of the step)."""
    import mujoco
    robot = make_robot(name, links)
    gait = make_gait(robot.scene.default_gait, robot.scene)
    robot.run_until(seconds, ScriptedCommands(precomputed(gait.contraction_mm, robot, seconds)))
    timer = robot.simulation.data.timer
    step = timer[int(mujoco.mjtTimer.mjTIMER_STEP)]
    per_step = step.duration / max(step.number, 1)
    parts = []
    for label, key in STAGES:
        t = timer[int(getattr(mujoco.mjtTimer, key))]
        us = t.duration / max(t.number, 1)
        share = '' if key == 'mjTIMER_STEP' else f' ({us / per_step:.0%})'
        parts.append(f'{label} {us * 1e6:.0f} us{share}')
    return f'{name:13s} nv {robot.simulation.model.nv}: ' + ', '.join(parts)


def run_before(root: Path, name: str, seconds: float, links: int) -> tuple[float, float, float]:
    """This script's run_once in a child process on the old revision's source."""
    paths = [str(root / 'src' / p) for p in ('softsnap_model', 'softsnap_driver', 'softsnap_gaits')]
    this = str(Path(__file__).resolve())
    code = ('import importlib.util, sys\n'
            f'spec = importlib.util.spec_from_file_location("before", {this!r})\n'
            'mod = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod)\n'
            f'print(*mod.run_once({name!r}, {seconds!r}, {links!r}))\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(paths + [os.environ.get('PYTHONPATH', '')]))
    out = subprocess.run([sys.executable, '-c', code], check=True, capture_output=True, text=True,
                         env=env, cwd=root).stdout
    built, wall, cpu = (float(v) for v in out.split()[-3:])
    return built, wall, cpu


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
    parser.add_argument('--before', metavar='REV',
                        help='also run the code of this git revision, interleaved (e.g. ab2bb8c)')
    parser.add_argument('--timestep-ms', type=float,
                        default=(DEFAULT_PHYSICS_TIMESTEP_S or 0.002) * 1e3,
                        help='physics timestep, ms (default sim_robot\'s, '
                             f'{DEFAULT_PHYSICS_TIMESTEP_S * 1e3:g})')
    parser.add_argument('--stages', action='store_true',
                        help="also print MuJoCo's stage timers per scene (one more run each)")
    args = parser.parse_args()
    global TIMESTEP_S
    TIMESTEP_S = args.timestep_ms * 1e-3
    from benchlib import checkout_src    # here: run_before's child loads this file from src/
    root = checkout_src(args.before) if args.before else None
    if hasattr(os, 'sched_setaffinity'):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())} '
          f'({os.cpu_count()} cores; this process pinned to one)')
    print(f'\nsim_robot real-time factor (simulated s per wall s), {args.seconds:g} s of the '
          f"default gait, {args.repeat} runs; links per segment: "
          f"{args.links_per_segment or 'physics model default'}; physics step "
          f'{TIMESTEP_S * 1e3:g} ms' + (f'; before: {args.before}' if args.before else ''))
    header = (f"{'scene':13s} {'modules':>7s} {'build s':>8s} {'RTF median':>11s} "
              f"{'RTF range':>15s} {'CPU RTF':>8s}"
              + (f" {'CPU RTF before':>14s} {'ratio':>6s}" if root else ''))
    print(header)
    print('-' * len(header))
    for name in args.scenes.split(','):
        runs, before = [], []
        for _ in range(args.repeat):
            if root:
                before.append(run_before(root, name, args.seconds, args.links_per_segment))
            runs.append(run_once(name, args.seconds, args.links_per_segment))
        factors = [args.seconds / wall for _, wall, _ in runs]
        cpu = statistics.median(args.seconds / c for _, _, c in runs)
        modules = len(load_scene(name).modules)
        extra = ''
        if root:
            cpu_before = statistics.median(args.seconds / c for _, _, c in before)
            extra = f' {cpu_before:14.2f} {cpu / cpu_before:6.2f}'
        print(f'{name:13s} {modules:7d} {statistics.median(b for b, _, _ in runs):8.2f} '
              f'{statistics.median(factors):11.2f} {min(factors):7.2f}-{max(factors):<7.2f} '
              f'{cpu:8.2f}' + extra, flush=True)
        if root:
            cpus = [args.seconds / c for _, _, c in runs]
            olds = [args.seconds / c for _, _, c in before]
            print(f'{"":13s} CPU RTF range now {min(cpus):.2f}-{max(cpus):.2f}, '
                  f'before {min(olds):.2f}-{max(olds):.2f}', flush=True)
    if args.stages:
        print('\nmj_step by stage (MuJoCo timers, wall clock, mean per physics step):')
        for name in args.scenes.split(','):
            print(stages(name, args.seconds, args.links_per_segment), flush=True)
    seconds = min(args.seconds, 2.0)
    first, second = trajectory(seconds, args.links_per_segment), trajectory(seconds, args.links_per_segment)
    same = first.shape == second.shape and np.array_equal(first, second)
    print(f'\ndeterminism: brittle star walk, {seconds:g} s twice: trajectories '
          f"{'identical bit for bit' if same else 'DIFFER'} "
          f'(largest difference {np.abs(first - second).max():.3g} m over {first.size} values)')
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    if root:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == '__main__':
    main()
