"""Physics levels of the forward model: run time, error against each level's own
independent reference, and how far apart the levels' shapes are (issue 13).

Levels (docs/model.md, "Physics levels"):
  idealised      the paper's model, thin ribs (Skeleton(rib_thickness_mm=0)), solve_forward
  + thickness    3.0 mm ribs (Skeleton()): contact at 1.2311 rad, solve_forward
  + gravity      Skeleton() lying on its right side (gravity (0, -9.81, 0) m/s^2 in the
                 base frame), default K and rib masses, solve_loaded
  + tip load     as + gravity, and 0.1 N on the tip along -y, solve_loaded
References: the unloaded levels against the 40-digit mpmath KKT Newton of
test/softsnap_model/mp_reference.py (refined from our answer, contact segments held); the
loaded levels against scipy SLSQP (ftol 1e-15, central-difference gradients) on the
energy written from geometry.rib_centers and segment_length, started from the unloaded
answer (the same reference as test/softsnap_model/test_loads.py; itself good to ~1e-6 mm).
Error = largest rib-centre distance (mm) to the reference.

Times: median per problem of repeated solves (caches warm), then median and range over
the problems; wall time and the process's CPU time (a busy machine preempts the longer
loaded solves, which inflates their wall time); ratios against the idealised level's
median from the same run; the load average at start and end says how busy it was.

Usage: .venv/bin/python benchmarks/fidelity_bench.py [--quick]    (about 1 minute)
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test' / 'softsnap_model'))
from mp_reference import kkt_reference, rib_centers_mp  # noqa: E402
from test_loads import reference_solve  # noqa: E402

from softsnap_model import Skeleton, reachable_range, rib_centers, solve_forward  # noqa: E402
from softsnap_model.loads import Loads, solve_loaded  # noqa: E402
from softsnap_model.reference import PAPER_THREADINGS  # noqa: E402

THIN = Skeleton(rib_thickness_mm=0.0)
THICK = Skeleton()
G = 9.80665
ON_SIDE = Loads(gravity_mps2=(0.0, -G, 0.0))
TIP = Loads(gravity_mps2=(0.0, -G, 0.0), load_n=(0.0, -0.1, 0.0))
NAMES = ('yellow', 'blue', 'green', 'red', 'gripper', 's', 'w')
CONTRACTIONS_MM = (20.0, 40.0, 60.0, 80.0)


def level_solvers():
    return [
        ('idealised (t = 0)', THIN, lambda t, L: solve_forward(THIN, t, L)),
        ('+ rib thickness 3 mm', THICK, lambda t, L: solve_forward(THICK, t, L)),
        ('+ gravity (on its side)', THICK, lambda t, L: solve_loaded(THICK, t, L, ON_SIDE)),
        ('+ gravity + 0.1 N tip load', THICK, lambda t, L: solve_loaded(THICK, t, L, TIP)),
    ]


def mp_error(sk, t, length, res):
    free = [i for i in range(sk.n_segments) if not res.at_contact[i]]
    a_ref, _ = kkt_reference(sk.threading_mm(t), list(sk.stiffness_array), sk.spacing_mm,
                             length, res.angles, res.tension, free=free)
    ref = np.array([(float(x), float(y)) for x, y in rib_centers_mp(a_ref, sk.spacing_mm)])
    return float(np.max(np.linalg.norm(res.rib_centers - ref, axis=1)))


def slsqp_error(sk, t, length, loads, res):
    start = solve_forward(sk, t, length).angles
    a_ref, _ = reference_solve(sk, t, length, loads, start)
    ref = rib_centers(a_ref, sk.spacing_mm)
    return float(np.max(np.linalg.norm(res.rib_centers - ref, axis=1)))


def timed(fn, repeat):
    """Median wall time and median CPU time of this process (s): on a busy machine the
    wall time of a longer solve includes time spent preempted, the CPU time does not."""
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--quick', action='store_true', help='fewer repeats')
    args = ap.parse_args()
    reps = 5 if args.quick else 20
    load_start = os.getloadavg()

    # Problems every level can solve: contractions within the thick skeleton's range.
    problems = []
    for name in NAMES:
        t = PAPER_THREADINGS[name]
        lo, hi = reachable_range(THICK, t)
        for c in (20.0, 40.0, 60.0):
            if hi - c > lo + 0.5:
                problems.append((name, t, hi - c))

    rows = []
    for label, sk, solve in level_solvers():
        times, cpus, errs, iters, ok = [], [], [], [], 0
        for name, t, length in problems:
            res = solve(t, length)
            ok += bool(res.converged)
            iters.append(res.iterations)
            wall, cpu = timed(lambda: solve(t, length), reps)
            times.append(wall)
            cpus.append(cpu)
            if label.startswith('+ gravity'):
                loads = TIP if 'tip' in label else ON_SIDE
                errs.append(slsqp_error(sk, t, length, loads, res))
            else:
                errs.append(mp_error(sk, t, length, res))
        rows.append((label, statistics.median(times), min(times), max(times),
                     statistics.median(cpus), statistics.median(errs), max(errs), ok,
                     len(problems), float(np.mean(iters))))
    load_end = os.getloadavg()

    base, base_cpu = rows[0][1], rows[0][4]
    print(f'load average (1 min) at start {load_start[0]:.2f}, at end {load_end[0]:.2f}; '
          f'{len(problems)} problems ({", ".join(NAMES)} at 20/40/60 mm where reachable), '
          f'{reps} repeats each')
    print()
    print('| level | median wall time | range over problems | x idealised | median CPU '
          'time | x idealised (CPU) | converged | Newton iterations (mean) | '
          'error vs reference: median / max (mm) |')
    print('| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |')
    for label, med, lo_t, hi_t, cpu, e_med, e_max, ok, n, it in rows:
        print(f'| {label} | {med * 1e3:.2f} ms | {lo_t * 1e3:.2f}-{hi_t * 1e3:.2f} ms | '
              f'{med / base:.1f} | {cpu * 1e3:.2f} ms | {cpu / base_cpu:.1f} | {ok}/{n} | '
              f'{it:.1f} | {e_med:.1e} / {e_max:.1e} |')

    # How far apart the levels are: largest rib-centre distance (mm) between consecutive
    # levels, per threading and contraction ("-": the level cannot reach that length).
    print()
    print('Largest rib-centre distance (mm) between levels, per paper threading and '
          'contraction:')
    print()
    head = ' | '.join(f'{c:.0f} mm' for c in CONTRACTIONS_MM)
    print(f'| threading | levels | {head} |')
    print('| --- | --- |' + ' ---: |' * len(CONTRACTIONS_MM))
    levels = level_solvers()
    pairs = [(0, 1, 'thickness - idealised'), (1, 2, 'gravity - thickness'),
             (2, 3, 'tip load - gravity')]
    for name in NAMES:
        t = PAPER_THREADINGS[name]
        hi = THIN.straight_length_mm(t)
        shapes = []
        for _, _, solve in levels:
            row = []
            for c in CONTRACTIONS_MM:
                try:
                    res = solve(t, hi - c)
                    row.append(res.rib_centers if res.converged else None)
                except ValueError:
                    row.append(None)
            shapes.append(row)
        for i, j, what in pairs:
            cells = []
            for k in range(len(CONTRACTIONS_MM)):
                a, b = shapes[i][k], shapes[j][k]
                cells.append('-' if a is None or b is None else
                             f'{np.max(np.linalg.norm(a - b, axis=1)):.1f}')
            print(f'| {name} | {what} | ' + ' | '.join(cells) + ' |')


if __name__ == '__main__':
    main()
