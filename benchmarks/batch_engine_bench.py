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

With ``--before REV`` that revision's ``softsnap_model`` (``git archive``) runs in a child
process taking turns with the current code, round by round (which goes first
alternates); the ratio after/before of the round medians is printed per case, with the
load average at start and end.
ROS-free.

Usage: .venv/bin/python benchmarks/batch_engine_bench.py [--rounds 5] [--before REV]
       [--cases prepared10 single ...]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchlib import checkout_src, load_line

CASES = ('prepared10', 'prepared10_slack', 'batch1000', 'mixed100', 'sweep200', 'single')
#: Timed calls per case and round (after a warm-up of a tenth of it).
CALLS = {'prepared10': 2000, 'prepared10_slack': 2000, 'batch1000': 100, 'mixed100': 400,
         'sweep200': 200, 'single': 3000}


def _workloads():
    """name -> a function of the call index that makes one call."""
    import numpy as np

    from softsnap_model import Skeleton, solve_forward, solve_forward_batch, sweep
    from softsnap_model.forward import PreparedBatch, reachable_range
    from softsnap_model.reference import PAPER_THREADINGS
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    rows = [tuple(m.threading_mm) for m in scene.modules for _ in range(2)]
    straight = [m.straight_length_mm for m in scene.modules for _ in range(2)]
    prepared = PreparedBatch(scene.skeleton, rows)

    def tick_lengths(tick, slack=False):
        out = [s - (30.0 + 20.0 * ((tick * 0.013 + 0.037 * i) % 1.0)) - 0.7 * (i % 2)
               for i, s in enumerate(straight)]
        if slack:
            out[0] = straight[0]
        return np.array(out)

    ticks = [tick_lengths(t) for t in range(500)]
    slack_ticks = [tick_lengths(t, slack=True) for t in range(500)]
    sk = Skeleton()
    paper = [list(t) for t in PAPER_THREADINGS.values()]
    ranges = [reachable_range(sk, t) for t in paper]
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
        'batch1000': lambda i: solve_forward_batch(sk, red, batch_lengths[i % 20]),
        'mixed100': lambda i: solve_forward_batch(sk, *mixed[i % 20]),
        'sweep200': lambda i: sweep(sk, red, contractions),
        'single': lambda i: solve_forward(sk, *singles[i % len(singles)]),
    }


def measure(cases: list[str]) -> dict[str, float]:
    """µs of thread CPU per call of each case (one pass, after a warm-up)."""
    work = _workloads()
    out = {}
    for name in cases:
        call, calls = work[name], CALLS[name]
        for i in range(calls // 10):
            call(i)
        start = time.thread_time()
        for i in range(calls):
            call(i)
        out[name] = (time.thread_time() - start) / calls * 1e6
    return out


def run_version(code_dir: Path | None, cases: list[str]) -> dict[str, float]:
    """One measurement in a fresh interpreter (``code_dir``: the old sources first)."""
    env = dict(os.environ)
    if code_dir is not None:
        env['PYTHONPATH'] = os.pathsep.join(
            [str(code_dir / 'src' / 'softsnap_model'), env.get('PYTHONPATH', '')]).rstrip(
            os.pathsep)
    out = subprocess.run([sys.executable, __file__, '--child', *cases], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--before', default='', help='git revision to compare against')
    parser.add_argument('--cases', nargs='+', default=list(CASES), choices=CASES)
    parser.add_argument('--child', nargs='+', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.child)))
        return 0
    print(load_line('start'), flush=True)
    versions: dict[str, Path | None] = {'after': None}
    if args.before:
        versions = {'before': checkout_src(args.before), 'after': None}
    results = {label: {name: [] for name in args.cases} for label in versions}
    for round_ in range(args.rounds):
        # Alternate which version goes first, so that a trend in the load favours neither.
        for label, code_dir in list(versions.items())[::1 if round_ % 2 == 0 else -1]:
            figures = run_version(code_dir, args.cases)
            for name, us in figures.items():
                results[label][name].append(us)
            print(f'  round {round_ + 1}: {label:6s} ' + ', '.join(
                f'{name} {us:.0f}' for name, us in figures.items()), flush=True)
    print(f'\nµs of thread CPU per call, median [range] of {args.rounds} rounds')
    for name in args.cases:
        line = f'  {name:17s}'
        for label in versions:
            values = results[label][name]
            line += (f' {label} {statistics.median(values):8.1f} '
                     f'[{min(values):.1f}-{max(values):.1f}]')
        if args.before:
            ratio = (statistics.median(results['after'][name])
                     / statistics.median(results['before'][name]))
            line += f'  after/before {ratio:.3f}'
        print(line)
    if args.before:
        print(f'  (before = {args.before})')
    print(load_line('end'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
