"""Inverse-design benchmark: time per design and error vs a capped random search.

Run: .venv/bin/python benchmarks/inverse_bench.py [--baseline 40] [--repeat 2]

For each hole set (the authors' 8 holes, and 16 holes per rib) and each target, prints
the wall time of design_threading (global, k=3 alternatives) and its angle error next to
the best error of a random subset of threadings, each evaluated with the forward solver
over its whole cable-length range (what the paper's tool does, capped at a few dozen
candidates). Then the first design in a fresh Python process (import included), where
every per-pair branch profile and per-threading path table is still to be built.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
from scipy import optimize

from softsnap_model import design_threading, forward
from softsnap_model.skeleton import Skeleton

HOLES_16 = {f'{side}{j}': sign * d for j, d in
            enumerate([0.5, 2.0, 3.0, 4.5, 6.5, 8.0, 10.0, 11.5])
            for side, sign in (('L', -1.0), ('R', 1.0))}


def targets(skeleton, rng):
    """Named targets: a forward-solved paper threading, a smooth S and a zigzag."""
    w = 'R3 R3 R3 R3 L2 L3 L2 R3 R3 R3 R3 R3'.split()
    names = list(skeleton.holes_mm)
    if not set(w) <= set(names):
        w = [names[-1] if h.startswith('R') else names[-2] for h in w]
    lo, hi = forward.reachable_range(skeleton, w)
    reach = forward.solve_forward(skeleton, w, 0.5 * (lo + hi)).angles
    x = np.linspace(0.0, 1.0, skeleton.n_segments)
    smooth = -0.35 * np.sin(2 * np.pi * x) + 0.05 * rng.normal(size=x.size)
    zigzag = np.array([0.3, -0.3] * 6)[:skeleton.n_segments]
    return {'forward-solved "w"': reach, 'smooth S + noise': smooth, 'zigzag': zigzag}


def random_search(skeleton, target, n_threadings, rng):
    """Best error over n random threadings, each optimised over its cable length."""
    names = list(skeleton.holes_mm)
    best = np.inf
    for _ in range(n_threadings):
        threading = list(rng.choice(names, skeleton.n_ribs))
        lo, hi = forward.reachable_range(skeleton, threading)

        def err(length):
            return float(np.linalg.norm(
                forward.solve_forward(skeleton, threading, length).angles - target))

        grid = lo + (hi - lo) * np.linspace(0.01, 1.0, 12)
        values = [err(L) for L in grid]
        j = int(np.argmin(values))
        fit = optimize.minimize_scalar(err, bounds=(grid[max(j - 1, 0)], grid[min(j + 1, 11)]),
                                       method='bounded', options={'xatol': 1e-6})
        best = min(best, values[j], fit.fun)
    return best


FRESH = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np
from softsnap_model import Skeleton, design_threading
t1 = time.perf_counter()
holes = json.loads(sys.argv[1])
sk = Skeleton(holes_mm=holes, rib_thickness_mm=0.0) if holes else Skeleton(rib_thickness_mm=0.0)
res = design_threading(sk, target_angles=np.array([0.3, -0.3] * 6)[:11], k=3)
t2 = time.perf_counter()
print(json.dumps([t1 - t0, t2 - t1]))
"""


def fresh_process_design(holes):
    """(import s, first design s) of the zigzag target in a new interpreter."""
    out = subprocess.run([sys.executable, '-c', FRESH, json.dumps(holes)], check=True,
                         capture_output=True, text=True, timeout=600)
    return json.loads(out.stdout)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--baseline', type=int, default=40, help='random threadings')
    parser.add_argument('--repeat', type=int, default=2, help='timed repeats per design')
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for label, skeleton in (('8 holes', Skeleton(rib_thickness_mm=0.0)),
                             ('16 holes', Skeleton(holes_mm=HOLES_16, rib_thickness_mm=0.0))):
        for name, target in targets(skeleton, rng).items():
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                res = design_threading(skeleton, target_angles=target, k=3)
                times.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            base = random_search(skeleton, target, args.baseline, rng)
            base_time = time.perf_counter() - t0
            rows.append((label, name, min(times), max(times), res.error, res.lower_bound,
                         res.converged, base, base_time, ' '.join(res.holes)))
    load = os.getloadavg()[0]
    fresh = {label: fresh_process_design(holes) for label, holes in
             (('8 holes', None), ('16 holes', HOLES_16))}
    print(f'load average {load:.2f} (1 min) on {os.cpu_count()} cores')
    for label, (t_import, t_design) in fresh.items():
        print(f'{label}: fresh process, zigzag: import {t_import:.2f} s, first design '
              f'{t_design:.2f} s')
    print(f'| hole set | target | design time min / max (s) | error (rad) | certified lower '
          f'bound (rad) | closed | random {args.baseline} error (rad) | random time (s) '
          f'| best threading |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for r in rows:
        print(f'| {r[0]} | {r[1]} | {r[2]:.2f} / {r[3]:.2f} | {r[4]:.3g} | {r[5]:.3g} | '
              f'{"yes" if r[6] else "no"} | {r[7]:.3g} | {r[8]:.1f} | {r[9]} |')


if __name__ == '__main__':
    main()
