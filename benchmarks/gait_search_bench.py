#!/usr/bin/env python3
"""Gait search throughput: rollouts per second on 1 worker, 2 processes and Ray; and the
best score against the budget of a finished search.

Part 1 runs the same batch of rollouts (the brittle star, the search's decoded gaits from
one seeded CMA-ES population, the coarse-jitter setting) on each backend in turn,
interleaved over ``--repeats`` rounds, and prints rollouts per wall second (median and
range) side by side with the load average; every backend must return the same results
(checked). Part 2 (``--result runs/.../result.json``) prints a search's best-so-far score
against the rollouts spent.

Usage: .venv/bin/python benchmarks/gait_search_bench.py [--rollouts 8] [--seconds 2]
       [--repeats 2] [--result runs/optimise-.../result.json]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from softsnap_gaits.gait_family import gait_family
from softsnap_gaits.gait_objective import DEFAULT_SETTINGS
from softsnap_gaits.gait_search import make_backend
from softsnap_model.scene import load_scene


def tasks(n: int, seconds: float) -> list:
    scene = load_scene('brittle_star')
    family = gait_family('walk', scene)
    rng = np.random.default_rng(0)
    setting = next(s for s in DEFAULT_SETTINGS if s.name == 'coarse-jitter')
    return [(str(scene.path), family.decode(x).spec, setting, seconds, 0.0, 0)
            for x in rng.uniform(0.2, 0.8, (n, family.dimension))]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--rollouts', type=int, default=8)
    p.add_argument('--seconds', type=float, default=2.0)
    p.add_argument('--repeats', type=int, default=2)
    p.add_argument('--result', default=None)
    args = p.parse_args(argv)
    batch = tasks(args.rollouts, args.seconds)
    backends = {'1 worker': make_backend('serial'),
                '2 processes': make_backend('process', workers=2),
                'Ray (local, 2 CPUs)': make_backend('ray', num_cpus=2, include_dashboard=False,
                                                    configure_logging=False,
                                                    object_store_memory=200 * 2**20)}
    try:
        # Warm-up: spawn the workers and import MuJoCo in each before timing.
        for b in backends.values():
            b.map(batch[:2])
        rates = {k: [] for k in backends}
        reference = None
        for _ in range(args.repeats):
            for name, b in backends.items():
                t0 = time.perf_counter()
                out = b.map(batch)
                rates[name].append(len(batch) / (time.perf_counter() - t0))
                reference = reference or out
                assert out == reference, f'{name} returned different rollouts'
    finally:
        for b in backends.values():
            b.close()
    print(f'{args.rollouts} rollouts of {args.seconds:g} s (brittle star, coarse-jitter), '
          f'{args.repeats} rounds, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs')
    base = statistics.median(rates['1 worker'])
    for name, r in rates.items():
        med = statistics.median(r)
        print(f'  {name:>20}: {med:.2f} rollouts/s (range {min(r):.2f}-{max(r):.2f}), '
              f'{med / base:.2f}x one worker')
    if args.result:
        res = json.loads(open(args.result).read())
        print(f"\nbest so far against budget ({res['scene']} / {res['name']}, "
              f"start {res['start_score_mm_s']:+.2f} mm/s):")
        for g in res['history']:
            print(f"  {g['rollouts']:5d} rollouts  {g['wall_s']:7.0f} s  best {g['best_so_far']:+.2f} mm/s")
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
