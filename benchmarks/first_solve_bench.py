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
repeated ``--rounds`` times (median and range of the round medians). With ``--before
REV`` the solver of that git revision (forward_bench's ``load_before``) takes turns
with this one solve by solve, on the same threadings and lengths, and the ratio
before/now of the round medians is printed. ROS-free.

Usage: .venv/bin/python benchmarks/first_solve_bench.py [--rounds 3] [--random 1200]
       [--before REV]
"""
from __future__ import annotations

import argparse
import random
import statistics
import time

from benchlib import fmt_spread, load_line
from forward_bench import SK, THREADINGS, load_before
from softsnap_model import forward

#: The per-threading caches a first solve fills (pair profiles are kept).
THREADING_CACHES = ('_problem', '_single', '_single_named', '_threading_cached')


def missing_caches(mod) -> list[str]:
    """The caches of THREADING_CACHES that ``mod`` lacks (an older revision): its
    loop-round solves are then partly warm, and its times too low."""
    return [name for name in THREADING_CACHES if getattr(mod, name, None) is None]


def first_solve_s(mod, threading, length_mm: float) -> float:
    """CPU time (s) of a first solve by the solver module ``mod``, its per-threading
    caches emptied first."""
    for name in THREADING_CACHES:
        cached = getattr(mod, name, None)     # older revisions lack some of them
        if cached is not None:
            cached.cache_clear()
    t0 = time.thread_time()
    mod.solve_forward(SK, threading, length_mm)
    return time.thread_time() - t0


def loop_round(mods, passes: int) -> list[list[float]]:
    """Per module of ``mods``, the times of a loop of first solves (taking turns)."""
    threadings = [text.split() for text in THREADINGS.values()]
    out = [[] for _ in mods]
    for _ in range(passes):
        for t in threadings:
            for mod, times in zip(mods, out):
                times.append(first_solve_s(mod, t, SK.straight_length_mm(t) - 30.0))
    return out


def random_round(mods, count: int, warmup: int, seed: int) -> list[list[float]]:
    """Per module of ``mods``, the times of first solves of random new threadings (the
    modules take turns on each)."""
    rng = random.Random(seed)
    holes = list(SK.holes_mm)
    seen, out = set(), [[] for _ in mods]
    while len(out[0]) < count + warmup:
        t = [rng.choice(holes) for _ in range(SK.n_ribs)]
        if tuple(t) in seen:
            continue
        seen.add(tuple(t))
        length = SK.straight_length_mm(t) - rng.uniform(5.0, 40.0)
        try:
            times = [first_solve_s(mod, t, length) for mod in mods]
        except tuple(mod.InfeasibleLengthError for mod in mods):
            continue    # a contraction this threading cannot reach: drawn again, not timed
        for kept, dt in zip(out, times):
            kept.append(dt)
    return [times[warmup:] for times in out]


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
    parser.add_argument('--before', metavar='REV',
                        help='also time the solver of this git revision, solve by solve')
    args = parser.parse_args()
    print(load_line('start'))
    mods = [forward] + ([load_before(args.before)] if args.before else [])
    for mod in mods:
        if hasattr(mod, 'clear_caches'):
            mod.clear_caches()
    if args.before and (missing := missing_caches(mods[1])):
        print(f'note: {args.before} lacks {", ".join(missing)}: those are not emptied, '
              'so its loop-round times are partly warm (too low)')
    loop_round(mods, 2)   # imports, pair profiles of the benchmark threadings
    rows = {(kind, m): [] for kind in ('loop', 'random') for m in range(len(mods))}
    for r in range(args.rounds):
        for kind, times in (('loop', loop_round(mods, args.passes)),
                            ('random', random_round(mods, args.random, args.warmup, seed=r))):
            for m, values in enumerate(times):
                rows[kind, m].append(summary(values))
    print('first solve of a threading, ms of CPU; median (range) over rounds of the '
          'per-round median, 10th and 90th percentile (target <= 1 ms):')
    for kind, label in (('loop', f'loop over the {len(THREADINGS)} benchmark threadings'),
                        ('random', 'random new 12-rib threadings')):
        for m, who in enumerate(['now'] + [args.before] * (len(mods) - 1)):
            med, p10, p90 = zip(*rows[kind, m])
            print(f'  {label} ({who}): median {fmt_spread(med, 1e3, 2)}, '
                  f'p10 {fmt_spread(p10, 1e3, 2)}, p90 {fmt_spread(p90, 1e3, 2)}')
        if args.before:
            ratio = [b[0] / n[0] for b, n in zip(rows[kind, 1], rows[kind, 0])]
            print(f'    ratio of the medians, {args.before}/now: {fmt_spread(ratio, 1, 2)}x')
    print(load_line('end'))


if __name__ == '__main__':
    main()
