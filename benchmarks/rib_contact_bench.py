"""Hard rib contact in MuJoCo (issue 32): the 1 mm table and the real-time factors,
``hard_contact_parameters()`` side by side with the default soft set (``legacy_parameters``).

1. Fidelity: one module, gravity off, the winch shortened at 20 mm/s to 30, 65 and 95 %
   of the reachable contraction (``reachable_range``) of the yellow, blue, green and red
   threadings, then settled (every joint speed < 1e-5 rad/s for 0.2 s, at most
   ``--max-time`` s); largest rib-centre distance to ``solve_forward`` (mm), the two
   tensions (N), whether and when (simulated s after the ramp) it settled.
2. Real-time factor of each five-module scene (and the gripper) on one core: every winch
   on a 1 Hz cosine between straight and ``--amplitude`` mm (phases staggered),
   ``--seconds`` simulated; simulated time over this process's CPU time, the new and the
   old parameters interleaved per scene (same load), and their ratio.

Usage: nice .venv/bin/python benchmarks/rib_contact_bench.py [--links 2] [--quick]
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import time

from softsnap_model import Skeleton
from softsnap_model.forward import reachable_range
from softsnap_model.physics.compare import QUASI_STATIC_DAMPING_TIME_S, static_fidelity
from softsnap_model.physics.parameters import PhysicsParameters
from softsnap_model.physics.rib_contact import hard_contact_parameters, legacy_parameters
from softsnap_model.physics.simulation import RobotSimulation
from softsnap_model.reference import PAPER_THREADINGS

THREADINGS = ('yellow', 'blue', 'green', 'red')
FRACTIONS = (0.30, 0.65, 0.95)
SCENES = ('brittle_star', 'starfish', 'snake', 'ring', 'gripper')


def load() -> str:
    return ' / '.join(f'{v:.1f}' for v in os.getloadavg())


def settings():
    new = hard_contact_parameters(damping_time_s=QUASI_STATIC_DAMPING_TIME_S)
    return (('hard contact', new), ('default (soft)', legacy_parameters(new)))


def contraction_mm(name: str, fraction: float) -> float:
    lo, hi = reachable_range(Skeleton(), PAPER_THREADINGS[name])
    return fraction * (hi - lo)


def fidelity_table(links: int, max_time_s: float, names=THREADINGS, fractions=FRACTIONS):
    print(f'\n## Fidelity: MuJoCo (N = {links}, gravity off, settled) vs solve_forward\n')
    print('Error = largest rib-centre distance (mm); tension MuJoCo / quasi-static (N); '
          'settle = simulated s after the ramp ("no": not within the limit).\n')
    print('| threading | % reach | contraction (mm) | ' + ' | '.join(
        f'{label}: error, tension, settle' for label, _ in settings()) + ' |')
    print('| --- | ---: | ---: |' + ' --- |' * len(settings()))
    worst = {label: 0.0 for label, _ in settings()}
    out = []
    for name in names:
        for f in fractions:
            c = contraction_mm(name, f)
            cells = []
            for label, params in settings():
                r = static_fidelity(name, c, links_per_segment=links, parameters=params,
                                    max_time_s=max_time_s)
                worst[label] = max(worst[label], r.max_rib_error_mm)
                settle = f'{r.settle_time_s:.2f} s' if r.settled else 'no'
                cells.append(f'{r.max_rib_error_mm:.3f} mm, {r.tension_n:.2f} / '
                             f'{r.reference_tension_n:.2f} N, {settle}')
                out.append((label, name, f, r))
            print(f'| {name} | {100 * f:.0f} | {c:.1f} | ' + ' | '.join(cells) + ' |',
                  flush=True)
    print('| **max** | | |' + ''.join(f' **{worst[label]:.3f} mm** |'
                                    for label, _ in settings()))
    return out


def drive(sim: RobotSimulation, seconds: float, amplitude_m: float) -> None:
    dt = sim.timestep_s
    names = sim.module_names
    straight = [sim.straight_cable_length(m) for m in names]
    for i in range(int(round(seconds / dt))):
        t = (i + 1) * dt
        for k, m in enumerate(names):
            phase = 2.0 * math.pi * (t - 0.2 * k)
            sim.set_cable_length(m, straight[k] - 0.5 * amplitude_m * (1.0 - math.cos(phase)))
        sim.step(dt)


def realtime_table(seconds: float, amplitude_mm: float, repeats: int, links: int):
    print(f'\n## Real-time factor (one core, N = {links}, 2 ms step, {seconds:g} s simulated, '
          f'winches on a 1 Hz cosine 0-{amplitude_mm:g} mm)\n')
    print('RTF = simulated time / CPU time of this process; median (range) of '
          f'{repeats} runs, new and old interleaved; largest joint speed at the end '
          '(rad/s or m/s) says whether the run stayed sane.\n')
    print('| scene | hard contact | default (soft) | ratio hard / soft | '
          'max speed new / old |')
    print('| --- | ---: | ---: | ---: | ---: |')
    base = PhysicsParameters()
    pairs = (('new', hard_contact_parameters(base)), ('old', legacy_parameters(base)))
    for scene in SCENES:
        rtf = {k: [] for k, _ in pairs}
        speed = {}
        for _ in range(repeats):
            for key, params in pairs:
                sim = RobotSimulation(scene, parameters=params, links_per_segment=links)
                sim.step(0.2)
                c0 = time.process_time()
                drive(sim, seconds, amplitude_mm * 1e-3)
                rtf[key].append(seconds / (time.process_time() - c0))
                speed[key] = sim.max_speed()
        med = {k: statistics.median(v) for k, v in rtf.items()}
        cell = {k: f'{med[k]:.1f} ({min(rtf[k]):.1f}-{max(rtf[k]):.1f})' for k in rtf}
        print(f'| {scene} | {cell["new"]} | {cell["old"]} | {med["new"] / med["old"]:.2f} | '
              f'{speed["new"]:.2g} / {speed["old"]:.2g} |', flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--links', type=int, default=2, help='links per segment')
    p.add_argument('--max-time', type=float, default=10.0, help='settling limit (s)')
    p.add_argument('--seconds', type=float, default=3.0)
    p.add_argument('--amplitude', type=float, default=20.0, help='winch amplitude (mm)')
    p.add_argument('--repeats', type=int, default=3)
    p.add_argument('--quick', action='store_true', help='only the fidelity table')
    p.add_argument('--skip-fidelity', action='store_true')
    args = p.parse_args(argv)
    print(f'# rib_contact_bench (load average at start: {load()})')
    if not args.skip_fidelity:
        fidelity_table(args.links, args.max_time)
    if not args.quick:
        realtime_table(args.seconds, args.amplitude, args.repeats, args.links)
    print(f'\n(load average at end: {load()})')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
