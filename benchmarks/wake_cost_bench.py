#!/usr/bin/env python3
"""What a sleeping CPU costs a node that wakes 100 times a second, side by side.

On the development machine (a KVM guest, ``haltpoll`` cpuidle) a thread that sleeps
between short bursts of work pays for it: the burst after a sleep takes several times
the CPU of the same burst run back to back, unless something else kept that CPU busy
meanwhile. Every node of this stack sleeps between messages, so its CPU figure depends
on whether the machine's other cores were idle. This script measures that effect, with
the CPUs free to idle and with them kept busy by a spinner at the lowest priority
(``nice 19``, one per CPU, pinned), interleaved round by round:

- ``tick`` (ROS-free): the model node's prediction tick, :meth:`RobotPredictor.tick` of
  the brittle star with all ten lengths new (``predictor_tick_bench.py``'s pattern), in
  one process pinned to one CPU (the first this process may use), timed by thread
  CPU time (``time.thread_time_ns``): back to back; after a 10 ms sleep; after a 10 ms
  sleep with the spinner on that CPU; after 10 ms of busy waiting.
- ``nodes``: ``node_cost_bench.py``'s cases (default ``baseline model5 driver``; also
  ``container5`` and ``model50``, its synthetic 50-module scene), each
  run with the CPUs free and with a spinner on every CPU, alternating. The node's CPU
  is read from the kernel as there. A spinner at nice 19 takes about 1.5 % of a core
  from a nice-0 process it competes with, and a waking node preempts it.

The spinners are a measuring condition, not a product setting: they show how much of a
node's CPU is its own work and how much the idle CPU's wake-up adds. Which of the two a
user sees depends on their machine (bare metal, power states, other load).

Usage: .venv/bin/python benchmarks/wake_cost_bench.py [--rounds 5] [--ticks 300]
       [--nodes] [--cases baseline model5 model50 driver container5] [--repeats 3]
       [--seconds 8]
Prints median [range] over rounds, the ratio of each setting to the first one, and the
load average at start and end.
"""
from __future__ import annotations

import argparse
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from benchlib import load_line

SLEEP_S = 0.01   # the node's 100 Hz period
TICK_SETTINGS = ('back to back', 'after a 10 ms sleep', 'after a 10 ms sleep, its CPU kept busy',
                 'after 10 ms of busy waiting')


@contextmanager
def spinners(cpus):
    """A ``nice 19`` busy loop pinned to each CPU of ``cpus`` while the block runs."""
    procs = []

    def pinned(cpu):
        return lambda: (os.sched_setaffinity(0, {cpu}), os.nice(19))

    try:
        for cpu in cpus:
            procs.append(subprocess.Popen(['sh', '-c', 'while :; do :; done'],
                                          preexec_fn=pinned(cpu), start_new_session=True))
        time.sleep(0.3)
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


def tick_round(ticks: int, setting: str) -> float:
    """Median µs of thread CPU per prediction tick in one setting (this process is
    pinned to one CPU by the caller)."""
    from predictor_tick_bench import length_feeder
    from softsnap_model.predictor import RobotPredictor
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    predictor = RobotPredictor(scene)
    feed, _ = length_feeder(predictor, scene)
    for tick in range(100):          # tables built, caches filled
        feed(tick)
        predictor.tick()
    times = []
    for tick in range(100, 100 + ticks):
        if setting.startswith('after a'):
            time.sleep(SLEEP_S)
        elif setting.startswith('after 10 ms of busy'):
            end = time.perf_counter() + SLEEP_S
            while time.perf_counter() < end:
                pass
        t0 = time.thread_time_ns()
        feed(tick)
        predictor.tick()
        times.append(time.thread_time_ns() - t0)
    return statistics.median(times) / 1e3


def run_ticks(rounds: int, ticks: int) -> None:
    allowed = os.sched_getaffinity(0)
    cpu = min(allowed)
    os.sched_setaffinity(0, {cpu})
    results = {setting: [] for setting in TICK_SETTINGS}
    for _ in range(rounds):
        for setting in TICK_SETTINGS:
            busy = [cpu] if 'kept busy' in setting else []
            with spinners(busy):
                results[setting].append(tick_round(ticks, setting))
    first = statistics.median(results[TICK_SETTINGS[0]])
    print(f'\nprediction tick (brittle star, 10 new lengths), µs of thread CPU, pinned to CPU '
          f'{cpu}; '
          f'median [range] of {rounds} rounds of {ticks} ticks:')
    for setting, values in results.items():
        med = statistics.median(values)
        print(f'  {setting:40s} {med:8.0f} [{min(values):.0f}-{max(values):.0f}]'
              f'  {med / first:5.2f}x back to back')
    os.sched_setaffinity(0, allowed)


def run_nodes(cases: list[str], repeats: int, warmup: float, seconds: float) -> None:
    import node_cost_bench as ncb

    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(100, 200)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    work = Path(tempfile.mkdtemp(prefix='wake_cost_'))
    scene50 = ncb.write_scene(work / 'synthetic_50.yaml', 50) if 'model50' in cases else None
    conditions = {'CPUs free to idle': [], 'a nice-19 spinner on every CPU':
                  sorted(os.sched_getaffinity(0))}
    results: dict[tuple[str, str], list[float]] = {}
    events: dict[tuple[str, str], list[float]] = {}
    for repeat in range(repeats):
        for case in cases:
            for condition, cpus in conditions.items():
                run_dir = work / f'{case}-{len(cpus)}-{repeat}'
                run_dir.mkdir()
                os.environ['NODE_COST_WORK'] = str(run_dir)
                with spinners(cpus):
                    cpu, rates = ncb.run_case(case, None, run_dir, warmup, seconds,
                                              scene50=scene50)
                results.setdefault((case, condition), []).append(cpu)
                rate = rates.get('lengths', rates.get('commands', 0.0))
                events.setdefault((case, condition), []).append(rate)
                print(f'  repeat {repeat + 1}: {case:10s} {condition:32s} {cpu:6.2f}% of a core'
                      + ''.join(f', {k} {v:.0f}/s' for k, v in rates.items()), flush=True)
    idle, busy = conditions
    print(f'\nnode CPU, % of one core, median [range] of {repeats} runs of {seconds:g} s '
          '(per module in parentheses):')
    print(f'  {"case":12s} {idle:>28s} {busy:>34s} {"busy/free":>10s}')
    for case in cases:
        a, b = results[(case, idle)], results[(case, busy)]
        n = ncb.PER_MODULE[case]

        def cell(values):
            med = statistics.median(values)
            return f'{med:.2f} [{min(values):.2f}-{max(values):.2f}] ({med / n:.2f})'
        print(f'  {case:12s} {cell(a):>28s} {cell(b):>34s} '
              f'{statistics.median(b) / statistics.median(a):10.2f}')
        for condition in conditions:
            rate = statistics.median(events[(case, condition)])
            if rate > 0:
                cpu = statistics.median(results[(case, condition)])
                print(f'      {condition}: {rate:.0f} events/s, '
                      f'{cpu * 1e4 / rate:.0f} µs of CPU per event')
    print(f'(logs in {work})')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=5, help='tick rounds per setting')
    parser.add_argument('--ticks', type=int, default=300, help='ticks per round')
    parser.add_argument('--nodes', action='store_true', help="also node_cost_bench's cases")
    parser.add_argument('--cases', nargs='+', default=['baseline', 'model5', 'driver'],
                        choices=['baseline', 'model5', 'model50', 'driver', 'container5'])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--warmup', type=float, default=3.0)
    parser.add_argument('--seconds', type=float, default=8.0)
    args = parser.parse_args()
    print(load_line('start'), flush=True)
    try:
        idle_driver = Path('/sys/devices/system/cpu/cpuidle/current_driver').read_text().strip()
    except OSError:
        idle_driver = 'unknown'
    print(f'cpuidle driver: {idle_driver}', flush=True)
    run_ticks(args.rounds, args.ticks)
    if args.nodes:
        run_nodes(args.cases, args.repeats, args.warmup, args.seconds)
    print(load_line('end'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
