#!/usr/bin/env python3
"""Hand gait against optimised gait through the whole physics demo graph, side by side.

For each scene, runs ``python -m softsnap_gaits.demo --scene S --physics --gait G
--seconds N --json --no-bag --no-rerun`` (sim_robot in MuJoCo, the drivers, the model
node, the gait node, all on sim_robot's /clock) for the hand gait and its optimised gait
in turn, ``--repeats`` times interleaved, and prints the robot's straight-line travel per
simulated second (the demo summary's ``base_travel``: distance_mm / seconds), median and
range, and the ratio optimised / hand in the same run. Not a timing benchmark: the speeds
are in simulated time, so the load only changes how long it takes.

Usage: .venv/bin/python benchmarks/optimised_gaits_demo.py [--pairs brittle_star:walk:walk_optimised,snake:concertina:concertina_optimised]
       [--seconds 12] [--repeats 1]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

DEFAULT_PAIRS = 'brittle_star:walk:walk_optimised,snake:concertina:concertina_optimised'


def demo_speed(scene: str, gait: str, seconds: float) -> tuple[float, dict]:
    cmd = [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', scene, '--physics',
           '--gait', gait, '--seconds', str(seconds), '--json', '--no-bag', '--no-rerun']
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    text = out.stdout[out.stdout.index('{'):] if '{' in out.stdout else ''
    try:
        summary = json.loads(text)
        base = summary['physics']['base_travel']
    except (ValueError, KeyError, TypeError):
        raise SystemExit(f'demo {scene}/{gait} gave no physics summary (exit {out.returncode}):\n'
                         f'{out.stdout[-2000:]}\n{out.stderr[-2000:]}')
    return base['distance_mm'] / base['seconds'], base


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--pairs', default=DEFAULT_PAIRS)
    p.add_argument('--seconds', type=float, default=12.0)
    p.add_argument('--repeats', type=int, default=1)
    args = p.parse_args(argv)
    for pair in args.pairs.split(','):
        scene, hand, best = pair.split(':')
        speeds = {hand: [], best: []}
        for _ in range(args.repeats):
            for gait in (hand, best):
                speed, base = demo_speed(scene, gait, args.seconds)
                speeds[gait].append(speed)
                print(f'  {scene}/{gait}: {base["distance_mm"]:.1f} mm, heading '
                      f'{base["heading_deg"]:.0f} deg, in {base["seconds"]:.1f} s: '
                      f'{speed:.2f} mm/s', flush=True)
        h, b = statistics.median(speeds[hand]), statistics.median(speeds[best])
        print(f'{scene}: {hand} {h:.2f} mm/s ({min(speeds[hand]):.2f}-{max(speeds[hand]):.2f}), '
              f'{best} {b:.2f} mm/s ({min(speeds[best]):.2f}-{max(speeds[best]):.2f}): '
              f'{b / h:.2f}x  (load average {os.getloadavg()[0]:.1f})', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
