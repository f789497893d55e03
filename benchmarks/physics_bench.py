"""MuJoCo physics levels: error against the quasi-static model, run time, real-time factor
per scene, determinism (issue 16).

1. Fidelity (gravity off, slow winch, settled): largest rib-centre distance between the
   MuJoCo module and ``solve_forward`` for the paper's threadings at 20 and 40 mm
   contraction, per links-per-segment N; time to build, ramp and settle one module.
2. Levels: exact quasi-static (``solve_forward``), quasi-static with gravity
   (``solve_loaded``), MuJoCo static at several N, MuJoCo with gravity (hanging / on its
   side / on the ground), with their cost and their distance to the quasi-static answer.
3. Real-time factor of each scene's robot on one core: every winch follows a 1 Hz cosine
   between straight and 20 mm contraction (phases staggered per module) for
   ``--seconds`` of simulated time; simulated time over the process's CPU time (and over
   wall time: the machine may be shared).
4. Determinism: the same scene run twice gives bit-identical positions and velocities.

Usage: nice .venv/bin/python benchmarks/physics_bench.py [--quick] [--seconds 5]
       [--live-timestep-ms 3]
(about 3 minutes; --quick: fewer threadings and N, 2 s per scene). The real-time table
times each scene at the model's 2 ms step and, interleaved, at sim_robot's 3 ms.
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import numpy as np

from softsnap_model import Skeleton, solve_forward
from softsnap_model.loads import Loads, solve_loaded
from softsnap_model.physics.compare import PAPER_THREADINGS, load_case, static_fidelity
from softsnap_model.physics.parameters import DEFAULT_LINKS_PER_SEGMENT, PhysicsParameters
from softsnap_model.physics.simulation import RobotSimulation

SCENES = ('brittle_star', 'starfish', 'snake', 'ring', 'gripper')


def load() -> str:
    return ' / '.join(f'{v:.1f}' for v in os.getloadavg())


def fidelity_table(names, contractions, links):
    print('\n## Fidelity: MuJoCo (gravity off, settled) vs solve_forward\n')
    print('Largest rib-centre distance (mm); time = build + ramp (20 mm/s) + settle of one '
          'module, CPU seconds.\n')
    head = ' | '.join(f'N = {n}' for n in links)
    print(f'| threading | contraction | {head} |')
    print('| --- | ---: |' + ' ---: |' * len(links))
    per_n = {n: [] for n in links}
    times = {n: [] for n in links}
    for name in names:
        for c in contractions:
            cells = []
            for n in links:
                t0 = time.process_time()
                r = static_fidelity(name, c, links_per_segment=n)
                times[n].append(time.process_time() - t0)
                per_n[n].append(r.max_rib_error_mm)
                flag = '' if r.settled else ' (not settled)'
                cells.append(f'{r.max_rib_error_mm:.3f}{flag}')
            print(f'| {name} | {c:.0f} mm | ' + ' | '.join(cells) + ' |')
    print('| **max** | |' + ''.join(f' **{max(per_n[n]):.3f}** |' for n in links))
    print('| median CPU time (s) | |' + ''.join(
        f' {statistics.median(times[n]):.2f} |' for n in links))
    return per_n, times


def levels_table(links, fid_err, fid_time):
    print('\n## Levels: cost and distance to the quasi-static answer (yellow, 20 mm)\n')
    sk = Skeleton()
    holes = PAPER_THREADINGS['yellow'].split()
    length = sk.straight_length_mm(holes) - 20.0
    reps = 50
    t0 = time.process_time()
    for _ in range(reps):
        solve_forward(sk, holes, length)
    t_exact = (time.process_time() - t0) / reps
    loads = Loads(gravity_mps2=(9.80665, 0.0, 0.0))
    t0 = time.process_time()
    for _ in range(10):
        solve_loaded(sk, holes, length, loads)
    t_loaded = (time.process_time() - t0) / 10
    print('| level | what | CPU time per shape | rib-centre distance (mm) |')
    print('| --- | --- | ---: | --- |')
    print(f'| exact quasi-static | `solve_forward` | {t_exact * 1e3:.2f} ms | reference |')
    print(f'| quasi-static + gravity | `solve_loaded`, hanging | {t_loaded * 1e3:.1f} ms '
          f'| reference for MuJoCo + gravity |')
    for n in links:
        print(f'| MuJoCo static, N = {n} | gravity off, settled | '
              f'{statistics.median(fid_time[n]):.2f} s | max {max(fid_err[n]):.3f} over the '
              f'table above |')
    for case in ('hanging', 'side', 'flat'):
        t0 = time.process_time()
        r = load_case(case, 'yellow', 20.0)
        t = time.process_time() - t0
        print(f'| MuJoCo + gravity, N = {DEFAULT_LINKS_PER_SEGMENT} | {case} '
              f'(quasi-static sag {r.tip_sag_mm:.1f} mm) | {t:.2f} s | '
              f'{r.max_rib_error_mm:.2f} vs `solve_loaded`; tension {r.tension_n:.3f} vs '
              f'{r.reference_tension_n:.3f} N |')


def drive(sim: RobotSimulation, seconds: float, record: bool = False):
    """Every winch on a 1 Hz cosine, 0-20 mm, phases staggered; returns the trajectory."""
    dt = sim.timestep_s
    names = sim.module_names
    straight = [sim.straight_cable_length(m) for m in names]
    n = int(round(seconds / dt))
    traj = []
    for i in range(n):
        t = (i + 1) * dt
        for k, m in enumerate(names):
            phase = 2.0 * math.pi * (t - 0.2 * k)
            sim.set_cable_length(m, straight[k] - 0.010 * (1.0 - math.cos(phase)))
        sim.step(dt)
        if record and i % 10 == 0:
            traj.append(np.concatenate([sim.data.qpos, sim.data.qvel]))
    return np.array(traj)


def realtime_table(seconds: float, live_timestep_s: float | None = None):
    """RTF per scene at the model's default step, and side by side (interleaved, same
    load) at ``live_timestep_s`` (sim_robot's step) when given."""
    default_dt = PhysicsParameters().timestep_s
    steps = [default_dt] + ([live_timestep_s] if live_timestep_s else [])
    print(f'\n## Real-time factor per scene (one core, N = {DEFAULT_LINKS_PER_SEGMENT}, '
          + ' and '.join(f'{dt * 1e3:g} ms' for dt in steps) + ' step)\n')
    print(f'{seconds:g} s simulated, every winch on a 1 Hz cosine 0-20 mm. RTF = simulated '
          'time / CPU time of this process (wall time in brackets: the machine is shared).\n')
    cols = ' | '.join(f'RTF (CPU) {dt * 1e3:g} ms | RTF (wall) {dt * 1e3:g} ms' for dt in steps)
    print(f'| scene | DoF | contacts (end) | {cols} | deterministic |')
    print('| --- | ---: | ---: |' + ' ---: | ---: |' * len(steps) + ' --- |')
    out = {}
    for name in SCENES:
        cells, same = [], True
        for dt in steps:
            params = PhysicsParameters(timestep_s=dt)
            sim = RobotSimulation(name, parameters=params)
            sim.step(0.2)
            c0, w0 = time.process_time(), time.perf_counter()
            drive(sim, seconds)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            a = drive(RobotSimulation(name, parameters=params), 1.0, record=True)
            b = drive(RobotSimulation(name, parameters=params), 1.0, record=True)
            same = same and bool(np.array_equal(a, b))
            out[name, dt] = (seconds / cpu, seconds / wall)
            cells.append(f'{seconds / cpu:.1f} | ({seconds / wall:.1f})')
            if dt == default_dt:
                dof, ncon = sim.model.nv, sim.data.ncon
        print(f'| {name} | {dof} | {ncon} | ' + ' | '.join(cells)
              + f' | {"yes" if same else "NO"} |', flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true')
    parser.add_argument('--seconds', type=float, default=None,
                        help='simulated seconds per scene for the real-time factor')
    parser.add_argument('--live-timestep-ms', type=float, default=3.0,
                        help="also time each scene at this step, ms (sim_robot's default "
                             "physics_timestep_s; 0: only the model's default)")
    args = parser.parse_args(argv)
    print(f'# physics_bench (load average at start: {load()})')
    if args.quick:
        names, contractions, links = ('yellow', 'red'), (20.0,), (1, 2, 4)
        seconds = args.seconds or 2.0
    else:
        names = ('yellow', 'blue', 'green', 'red', 'gripper', 's', 'w')
        contractions, links = (20.0, 40.0), (1, 2, 3, 4, 8)
        seconds = args.seconds or 5.0
    err, times = fidelity_table(names, contractions, links)
    if args.live_timestep_ms > 0:
        live = PhysicsParameters(timestep_s=args.live_timestep_ms * 1e-3)
        worst = max(static_fidelity(n, c, parameters=live).max_rib_error_mm
                    for n in names for c in contractions)
        print(f'\nAt sim_robot\'s {args.live_timestep_ms:g} ms step, N = '
              f'{DEFAULT_LINKS_PER_SEGMENT}: largest rib-centre distance {worst:.3f} mm over '
              f'the same threadings and contractions (target at 20 mm: 0.5 mm).')
    levels_table(links, err, times)
    realtime_table(seconds, None if args.live_timestep_ms <= 0 else args.live_timestep_ms * 1e-3)
    print(f'\n(load average at end: {load()})')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
