#!/usr/bin/env python3
"""CPU per call of the forward batch engine's entry points, old code against new.

Every batch solve goes through ``forward.newton._solve_arrays``; this times its callers
on the problems they meet, as thread CPU (``time.thread_time``) per call:

- ``prepared10``: ``PreparedBatch.solve`` of the brittle star's ten rows (five modules,
  a commanded and a predicted length each, the contraction pattern of
  ``predictor_tick_bench.py``): the model node's tick;
- ``prepared10_slack``: the same with one module's commanded length at its straight
  length (a module at rest: a slack row);
- ``batch1000``: ``solve_forward_batch`` of one paper threading, 1000 lengths;
- ``mixed100``: ``solve_forward_batch`` of 100 rows over the nine paper threadings;
- ``sweep200``: ``sweep`` over 200 contractions;
- ``single``: cold ``solve_forward`` (no warm start; tables already built) over the paper
  threadings at six contractions each.

With ``--before REV`` that revision's ``softsnap_model`` (``git archive``) is imported in
the same process under another name, and the two take turns in blocks of calls
(``--rounds`` blocks each, which goes first alternating), so that a change in the
machine's load hits both alike. Printed per case: µs per call (median [range] over the
blocks) and the ratio after/before (median [range] of the ratios of paired blocks, and
the ratio of the fastest blocks, the least disturbed), with the load average at start
and end. ROS-free.

Usage: .venv/bin/python benchmarks/batch_engine_bench.py [--rounds 60] [--before REV]
       [--cases prepared10 single ...]
"""
from __future__ import annotations

import argparse
import importlib
import shutil
import statistics
import sys
import time

from benchlib import checkout_src, load_line

CASES = ('prepared10', 'prepared10_slack', 'batch1000', 'mixed100', 'sweep200', 'single')
#: Calls per block of each case (one warm-up block runs first, untimed).
CALLS = {'prepared10': 50, 'prepared10_slack': 50, 'batch1000': 4, 'mixed100': 10,
         'sweep200': 8, 'single': 200}


def _workloads(pkg):
    """name -> a function of the call index that makes one call, with package ``pkg``
    (``softsnap_model`` or an earlier revision of it imported under another name)."""
    import numpy as np

    from softsnap_model.scene import load_scene

    forward = importlib.import_module(pkg.__name__ + '.forward')
    paper_threadings = importlib.import_module(pkg.__name__ + '.reference').PAPER_THREADINGS
    sk = pkg.Skeleton()     # the brittle star's skeleton (the scene's is built by the
    scene = load_scene('brittle_star')      # current package: only its threadings are used)
    rows = [tuple(m.threading_mm) for m in scene.modules for _ in range(2)]
    straight = [sk.straight_length_mm(t) for t in rows]
    prepared = forward.PreparedBatch(sk, rows)

    def tick_lengths(tick, slack=False):
        out = [s - (30.0 + 20.0 * ((tick * 0.013 + 0.037 * i) % 1.0)) - 0.7 * (i % 2)
               for i, s in enumerate(straight)]
        if slack:
            out[0] = straight[0]
        return np.array(out)

    ticks = [tick_lengths(t) for t in range(500)]
    slack_ticks = [tick_lengths(t, slack=True) for t in range(500)]
    paper = [list(t) for t in paper_threadings.values()]
    ranges = [forward.reachable_range(sk, t) for t in paper]
    rng = np.random.default_rng(7)
    red, (red_lo, red_hi) = paper[0], ranges[0]
    batch_lengths = red_hi - rng.uniform(0.02, 0.98, (20, 1000)) * (red_hi - red_lo)
    picks = rng.integers(0, len(paper), (20, 100))
    mixed = [([paper[j] for j in p], [ranges[j][1] - f * (ranges[j][1] - ranges[j][0])
                                      for j, f in zip(p, rng.uniform(0.02, 0.98, 100))])
             for p in picks]
    contractions = np.linspace(0.0, 0.95 * (red_hi - red_lo), 200)
    singles = [(t, hi - f * (hi - lo)) for t, (lo, hi) in zip(paper, ranges)
               for f in (0.05, 0.2, 0.4, 0.6, 0.8, 0.95)]
    return {
        'prepared10': lambda i: prepared.solve(rows, ticks[i % 500]),
        'prepared10_slack': lambda i: prepared.solve(rows, slack_ticks[i % 500]),
        'batch1000': lambda i: forward.solve_forward_batch(sk, red, batch_lengths[i % 20]),
        'mixed100': lambda i: forward.solve_forward_batch(sk, *mixed[i % 20]),
        'sweep200': lambda i: forward.sweep(sk, red, contractions),
        'single': lambda i: forward.solve_forward(sk, *singles[i % len(singles)]),
    }


def _block(call, calls: int, first: int) -> float:
    """µs of thread CPU per call over ``calls`` calls."""
    start = time.thread_time()
    for i in range(first, first + calls):
        call(i)
    return (time.thread_time() - start) / calls * 1e6


def _import_before(rev: str):
    """``softsnap_model`` of git revision ``rev``, imported as ``softsnap_model_before``."""
    root = checkout_src(rev)
    shutil.copytree(root / 'src' / 'softsnap_model' / 'softsnap_model',
                    root / 'softsnap_model_before')
    sys.path.insert(0, str(root))
    return importlib.import_module('softsnap_model_before')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=60, help='timed blocks per version')
    parser.add_argument('--before', default='', help='git revision to compare against')
    parser.add_argument('--cases', nargs='+', default=list(CASES), choices=CASES)
    args = parser.parse_args()
    print(load_line('start'), flush=True)
    import softsnap_model
    versions = {'after': softsnap_model}
    if args.before:
        versions = {'before': _import_before(args.before), 'after': softsnap_model}
    work = {label: _workloads(pkg) for label, pkg in versions.items()}
    print(f'µs of thread CPU per call, median [range] of {args.rounds} blocks per version')
    for name in args.cases:
        calls = CALLS[name]
        times = {label: [] for label in versions}
        for label in versions:
            _block(work[label][name], calls, 0)      # warm-up
        for round_ in range(args.rounds):
            order = list(versions)[::1 if round_ % 2 == 0 else -1]
            for label in order:
                times[label].append(_block(work[label][name], calls, (round_ + 1) * calls))
        line = f'  {name:17s}'
        for label, values in times.items():
            line += (f' {label} {statistics.median(values):8.1f} '
                     f'[{min(values):.1f}-{max(values):.1f}]')
        if args.before:
            ratios = [a / b for a, b in zip(times['after'], times['before'])]
            line += (f'  after/before {statistics.median(ratios):.3f} '
                     f'[{min(ratios):.2f}-{max(ratios):.2f}], of the fastest blocks '
                     f'{min(times["after"]) / min(times["before"]):.3f}')
        print(line, flush=True)
    if args.before:
        print(f'  (before = {args.before})')
    print(load_line('end'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
