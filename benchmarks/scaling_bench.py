#!/usr/bin/env python3
"""Scaling benchmark: the whole demo graph and the MuJoCo robot against the module count.

For each module count (generated snakes, ``softsnap_gaits.scene_generator``), the demo
runs ``--seconds`` of gait with simulated modules (``--no-rerun --no-bag --json``), once
with one ``sim_module`` process per module (``--sim-modules separate``, the old graph) and
once with one shared process (``shared``), interleaved so both see the same load, each
``--repeats`` times. The table gives, per count and mode, the median and range of:

- start-up: first process launched -> every module seen end to end (s);
- CPU of the graph's processes over the run (% of one core; the demo's own observer
  process not counted) and their summed RSS (MiB);
- command -> commanded shape: the median over modules of each module's median (ms);
- commands lost (the nodes' own counts) and whether the robot started at all.

``--physics``: afterwards, the real-time factor of the MuJoCo robot per count on one
core (benchmarks/sim_robot_bench.py's run: simulated s per CPU s and per wall s).

The load average is printed at the start and the end: on a shared machine the figures
are only as good as the cores they ran on.

Usage: .venv/bin/python benchmarks/scaling_bench.py [--modules 5,10,20,50] [--seconds 8]
       [--repeats 1] [--modes separate,shared] [--physics]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_demo(scene: Path, mode: str, seconds: float, run_dir: Path) -> dict:
    """One demo run's figures (``started`` False and None figures when it did not start)."""
    argv = [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', str(scene),
            '--seconds', str(seconds), '--no-rerun', '--no-bag', '--json',
            '--sim-modules', mode, '--run-dir', str(run_dir)]
    out = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=600)
    text = out.stdout
    start = text.find('\n{')
    if start < 0:
        return {'started': False, 'returncode': out.returncode}
    summary = json.loads(text[start + 1:])
    if not summary.get('started') or 'modules' not in summary:
        return {'started': False, 'returncode': out.returncode}
    modules = summary['modules'].values()
    medians = [m['command_to_shape_ms']['median'] for m in modules
               if m.get('command_to_shape_ms') and m['command_to_shape_ms'].get('median') is not None]
    return {
        'started': bool(summary.get('started')),
        'startup_s': summary.get('startup_seconds'),
        'cpu_percent': sum(p['cpu_percent'] for p in summary['processes'].values()),
        'rss_mib': sum(p['rss_mib'] for p in summary['processes'].values()),
        'processes': len(summary['processes']),
        'command_to_shape_ms': statistics.median(medians) if medians else None,
        'lost': sum(m['commands_lost'] or 0 for m in modules),
        'returncode': out.returncode,
    }


def _cell(values, fmt: str) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return '-'
    med = statistics.median(values)
    return (f'{med:{fmt}}' if len(values) == 1
            else f'{med:{fmt}} [{min(values):{fmt}}-{max(values):{fmt}}]')


def physics_rtf(scene: Path, seconds: float) -> tuple[float, float]:
    """(simulated s per CPU s, per wall s) of the MuJoCo robot on one core."""
    sys.path.insert(0, str(ROOT / 'benchmarks'))
    import sim_robot_bench
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    _, wall, cpu = sim_robot_bench.run_once(str(scene), seconds,
                                            sim_robot_bench.DEFAULT_LINKS_PER_SEGMENT)
    return seconds / cpu, seconds / wall


def print_table(counts, modes, results, args) -> None:
    print(f'\nthe demo graph, {args.seconds:g} s of the concertina, {args.repeats} run(s) each; '
          'median [range]')
    header = (f'{"modules":>7}  {"sim modules":11}  {"started":7}  {"procs":>5}  {"start-up s":>14}  '
              f'{"CPU % of a core":>18}  {"RSS MiB":>16}  {"cmd->shape ms":>18}  {"lost":>5}')
    print(header)
    print('-' * len(header))
    for n in counts:
        for mode in modes:
            runs = results[(n, mode)]
            ok = [x for x in runs if x['started']]
            print(f'{n:>7}  {mode:11}  {len(ok)}/{len(runs):<5}  '
                  f'{_cell([x["processes"] for x in ok], ".0f"):>5}  '
                  f'{_cell([x["startup_s"] for x in ok], ".1f"):>14}  '
                  f'{_cell([x["cpu_percent"] for x in ok], ".0f"):>18}  '
                  f'{_cell([x["rss_mib"] for x in ok], ".0f"):>16}  '
                  f'{_cell([x["command_to_shape_ms"] for x in ok], ".0f"):>18}  '
                  f'{_cell([x["lost"] for x in ok], ".0f"):>5}')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--modules', default='5,10,20,50')
    parser.add_argument('--seconds', type=float, default=8.0)
    parser.add_argument('--repeats', type=int, default=1)
    parser.add_argument('--modes', default='separate,shared')
    parser.add_argument('--physics', action='store_true')
    parser.add_argument('--physics-seconds', type=float, default=2.0)
    args = parser.parse_args()
    counts = [int(n) for n in args.modules.split(',')]
    modes = [m for m in args.modes.split(',') if m and m != 'none']   # none: physics only
    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())} '
          f'({os.cpu_count()} cores)', flush=True)
    work = Path(tempfile.mkdtemp(prefix='scaling_bench_'))
    scenes = {}
    for n in counts:
        scenes[n] = work / f'snake_{n}.yaml'
        subprocess.run([sys.executable, '-m', 'softsnap_gaits.scene_generator', 'snake', str(n),
                        '-o', str(scenes[n])], check=True, capture_output=True, cwd=ROOT)
    results: dict[tuple[int, str], list[dict]] = {(n, m): [] for n in counts for m in modes}
    for r in range(args.repeats):
        for n in counts:
            for mode in modes:
                t0 = time.monotonic()
                res = run_demo(scenes[n], mode, args.seconds, work / f'run-{n}-{mode}-{r}')
                results[(n, mode)].append(res)
                print(f'  {n} modules, {mode}: {"started" if res["started"] else "did NOT start"} '
                      f'({time.monotonic() - t0:.0f} s)', flush=True)
    if modes:
        print_table(counts, modes, results, args)
    if args.physics:
        print(f'\nMuJoCo robot on one core, {args.physics_seconds:g} s of the concertina')
        print(f'{"modules":>7}  {"RTF (sim s / CPU s)":>20}  {"RTF (sim s / wall s)":>21}')
        for n in counts:
            cpu_rtf, wall_rtf = physics_rtf(scenes[n], args.physics_seconds)
            print(f'{n:>7}  {cpu_rtf:>20.2f}  {wall_rtf:>21.2f}', flush=True)
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
