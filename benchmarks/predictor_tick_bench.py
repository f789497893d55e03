#!/usr/bin/env python3
"""CPU per prediction tick of the model node's core, in-process (no ROS).

What the model node's prediction thread does at 100 Hz in ``node_cost_bench.py``'s
``model5`` case, without DDS: every module of the scene gets a new commanded and a new
measured length (the same contraction pattern as that benchmark's length publisher),
then one :meth:`RobotPredictor.tick` solves them with rib centres (both RobotShape topics
subscribed). The figure is the tick's thread CPU time (``time.thread_time``), so other
processes on the machine change it less than wall time; it is still slower on a loaded
machine (caches), hence the comparison with ``--before REV`` (that revision's
``softsnap_model`` extracted with ``git archive``, run in a child process, rounds
interleaved with the current code).

Usage: .venv/bin/python benchmarks/predictor_tick_bench.py [--scene brittle_star|synthetic50]
       [--ticks 2000] [--rounds 5] [--before cf2cb37]
Prints, per code version, the median [range] over rounds of µs of CPU per tick and per
length, and the ratio after/before of the medians; the load average at start and end.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import checkout_src, load_line

ROOT = Path(__file__).resolve().parent.parent


def length_feeder(predictor, scene):
    """(feed, lengths per tick): ``feed(tick)`` submits a new commanded and measured length
    of every module of ``scene`` to ``predictor``, node_cost_bench's ``model5`` pattern."""
    topics = [(m.name, m.straight_length_mm, source, offset, 2 * index + t)
              for index, m in enumerate(scene.modules)
              for t, (source, offset) in enumerate((('commanded', 0.0), ('predicted', 0.7)))]

    def feed(tick: int) -> None:
        for name, straight, source, offset, i in topics:
            contraction = 30.0 + 20.0 * ((tick * 0.013 + 0.037 * i) % 1.0)
            predictor.submit(source, name, straight - contraction - offset)

    return feed, len(topics)


def measure(scene_name: str, ticks: int) -> tuple[float, int]:
    """(µs of thread CPU per tick, lengths per tick) over ``ticks`` ticks after a warm-up."""
    from softsnap_model.predictor import RobotPredictor
    from softsnap_model.scene import load_scene

    scene = load_scene(scene_name)
    predictor = RobotPredictor(scene)
    feed, lengths = length_feeder(predictor, scene)
    want = {'commanded': True, 'predicted': True}

    for tick in range(200):   # warm-up: caches, first solves
        feed(tick)
        predictor.tick(want)
    cpu = 0.0
    for tick in range(200, 200 + ticks):
        feed(tick)
        start = time.thread_time()
        predictor.tick(want)
        cpu += time.thread_time() - start
    return cpu / ticks * 1e6, lengths


def run_version(code_dir: Path | None, scene: str, ticks: int) -> tuple[float, int]:
    """One measurement in a fresh interpreter (``code_dir``: the old sources first)."""
    env = dict(os.environ)
    if code_dir is not None:
        env['PYTHONPATH'] = os.pathsep.join(
            [str(code_dir / 'src' / 'softsnap_model'), env.get('PYTHONPATH', '')]).rstrip(
            os.pathsep)
    out = subprocess.run([sys.executable, __file__, '--child', scene, str(ticks)], env=env,
                         check=True, capture_output=True, text=True).stdout.split()
    return float(out[0]), int(out[1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='brittle_star',
                        help="a scene name or file; 'synthetic50': node_cost_bench's "
                             'synthetic 50-module scene (its model50 case)')
    parser.add_argument('--ticks', type=int, default=2000)
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--before', default='', help='git revision to compare against')
    parser.add_argument('--child', nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        us, lengths = measure(args.child[0], int(args.child[1]))
        print(us, lengths)
        return 0
    print(load_line('start'), flush=True)
    if args.scene == 'synthetic50':
        from node_cost_bench import write_scene
        args.scene = str(write_scene(Path(tempfile.mkdtemp(prefix='tick_bench_')) /
                                     'synthetic_50.yaml', 50))
    versions: dict[str, Path | None] = {'after': None}
    if args.before:
        versions = {'before': checkout_src(args.before), 'after': None}
    results: dict[str, list[float]] = {label: [] for label in versions}
    lengths = 0
    for round_ in range(args.rounds):
        for label, code_dir in versions.items():
            us, lengths = run_version(code_dir, args.scene, args.ticks)
            results[label].append(us)
            print(f'  round {round_ + 1}: {label:6s} {us:7.0f} µs of CPU per tick', flush=True)
    print(f'\n{args.scene}: {lengths} new lengths per tick, rib centres on, '
          f'{args.ticks} ticks per round; thread CPU, median [range] of {args.rounds} rounds')
    for label, values in results.items():
        med = statistics.median(values)
        print(f'  {label:6s}: {med:6.0f} µs per tick [{min(values):.0f}-{max(values):.0f}], '
              f'{med / lengths:.0f} µs per length')
    if args.before:
        ratio = statistics.median(results['after']) / statistics.median(results['before'])
        print(f'  after/before: {ratio:.2f} (before = {args.before})')
    print(load_line('end'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
