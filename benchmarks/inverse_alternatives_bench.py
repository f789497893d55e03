"""Cost of inverse-design alternatives: time, peak memory and stop latency per k.

Run: .venv/bin/python benchmarks/inverse_alternatives_bench.py [--k 0 5 20 50 100 200]

Each k runs in a fresh Python process (so the peak resident memory is that design's),
after a warm-up design with k=0 that builds the per-process caches. The target is the
noisy one the node tests use (not reachable exactly, so the branch and bound works).
Reported per k: wall time, peak resident memory above the warmed-up process, the
longest gap between two cancel checks (the worst-case delay before a cancelled design
stops), and the measured delay from setting the stop flag half-way to DesignCancelled.
These are the numbers behind model_node's max_alternatives and design_timeout defaults
(docs/inverse.md).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, math, resource, sys, threading, time
from softsnap_model import Skeleton
from softsnap_model.inverse import DesignCancelled, design_threading

k = int(sys.argv[1])
sk = Skeleton()
target = [0.3 * math.sin(i) - 0.05 * i for i in range(11)]
design_threading(sk, target_angles=target, k=0)  # warm caches
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
checks = []

def watch():
    checks.append(time.perf_counter())
    return False

t0 = time.perf_counter()
design_threading(sk, target_angles=target, k=k, should_stop=watch)
wall = time.perf_counter() - t0
rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
gaps = [b - a for a, b in zip(checks, checks[1:])] or [0.0]
# Cancel half-way through a second run.
stop = threading.Event()
when = []
def fire():
    when.append(time.perf_counter())
    stop.set()
timer = threading.Timer(wall / 2, fire)
timer.start()
try:
    design_threading(sk, target_angles=target, k=k, should_stop=stop.is_set)
    latency = None
except DesignCancelled:
    latency = time.perf_counter() - when[0]
timer.cancel()
print(json.dumps(dict(k=k, wall=wall, rss_mib=(rss1 - rss0) / 1024, max_gap=max(gaps),
                      checks=len(checks), cancel_latency=latency)))
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--k', type=int, nargs='+', default=[0, 5, 20, 50, 100, 200])
    args = parser.parse_args()
    print(f'load average {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} cores')
    print('| k | design time (s) | peak memory above warm process (MiB) | checks | '
          'longest gap between checks (ms) | cancel half-way -> stopped (ms) |')
    print('| ---: | ---: | ---: | ---: | ---: | ---: |')
    for k in args.k:
        out = subprocess.run([sys.executable, '-c', CHILD, str(k)], check=True,
                             capture_output=True, text=True, timeout=3600)
        r = json.loads(out.stdout)
        latency = '-' if r['cancel_latency'] is None else f'{1e3 * r["cancel_latency"]:.1f}'
        print(f'| {k} | {r["wall"]:.2f} | {r["rss_mib"]:.0f} | {r["checks"]} | '
              f'{1e3 * r["max_gap"]:.1f} | {latency} |', flush=True)


if __name__ == '__main__':
    main()
