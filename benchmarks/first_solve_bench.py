#!/usr/bin/env python3
"""CPU time of the first ``solve_forward`` of a threading, in two settings.

``forward_bench.py`` times each first solve right after building the full path tables
of the other benchmark threadings, so the CPU's caches are cold for it. This script
gives the two other views a user meets:

- ``loop``: first solves one after another over the benchmark's threadings (their
  per-threading tables forgotten before each, the per-hole-pair profiles kept), as a
  design script that tries threading after threading does;
- ``random``: the first solve of random 12-rib threadings never solved before in the
  process, 5-40 mm shorter than straight (a length the threading cannot reach is
  drawn again, untimed); pair profiles are kept once built, and the first ``--warmup``
  threadings, which still build some, are not counted.

Each figure is the median, 10th and 90th percentile of ``time.thread_time`` per solve,
repeated ``--rounds`` times (median and range of the round medians). ROS-free.

Usage: .venv/bin/python benchmarks/first_solve_bench.py [--rounds 3] [--random 1500]
"""
from __future__ import annotations

import argparse
import random
import statistics
import time

from benchlib import fmt_spread, load_line
from forward_bench import SK, THREADINGS
from softsnap_model import forward

#: The per-threading caches a first solve fills (pair profiles are kept).
THREADING_CACHES = ('_problem', '_single', '_single_named', '_threading_cached')


def forget_threadings() -> None:
    for name in THREADING_CACHES:
        getattr(forward, name).cache_clear()


def first_solve_s(threading, length_mm: float) -> float:
    forget_threadings()
    t0 = time.thread_time()
    forward.solve_forward(SK, threading, length_mm)
    return time.thread_time() - t0


def loop_round(passes: int) -> list[float]:
    threadings = [text.split() for text in THREADINGS.values()]
    return [first_solve_s(t, SK.straight_length_mm(t) - 30.0)
            for _ in range(passes) for t in threadings]


def random_round(count: int, warmup: int, seed: int) -> list[float]:
    rng = random.Random(seed)
    holes = list(SK.holes_mm)
    seen, times = set(), []
    while len(times) < count + warmup:
        t = [rng.choice(holes) for _ in range(SK.n_ribs)]
        if tuple(t) in seen:
            continue
        seen.add(tuple(t))
        try:
            times.append(first_solve_s(t, SK.straight_length_mm(t) - rng.uniform(5.0, 40.0)))
        except forward.InfeasibleLengthError:
            continue    # a contraction this threading cannot reach: drawn again, not timed
    return times[warmup:]


def summary(times: list[float]) -> tuple[float, float, float]:
    deciles = statistics.quantiles(times, n=10)
    return statistics.median(times), deciles[0], deciles[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--rounds', type=int, default=3)
    parser.add_argument('--passes', type=int, default=40,
                        help='passes over the benchmark threadings per loop round')
    parser.add_argument('--random', type=int, default=1200,
                        help='random new threadings timed per round')
    parser.add_argument('--warmup', type=int, default=300,
                        help='random threadings solved first, not timed (pair profiles)')
    args = parser.parse_args()
    print(load_line('start'))
    forward.clear_caches()
    loop_round(2)   # imports, pair profiles of the benchmark threadings
    rows = {'loop': [], 'random': []}
    for r in range(args.rounds):
        rows['loop'].append(summary(loop_round(args.passes)))
        rows['random'].append(summary(random_round(args.random, args.warmup, seed=r)))
    print('first solve of a threading, ms of CPU; median (range) over rounds of the '
          'per-round median, 10th and 90th percentile (target <= 1 ms):')
    for name, label in (('loop', f'loop over the {len(THREADINGS)} benchmark threadings'),
                        ('random', 'random new 12-rib threadings')):
        med, p10, p90 = zip(*rows[name])
        print(f'  {label}: median {fmt_spread(med, 1e3, 2)}, p10 {fmt_spread(p10, 1e3, 2)}, '
              f'p90 {fmt_spread(p90, 1e3, 2)}')
    print(load_line('end'))


if __name__ == '__main__':
    main()
