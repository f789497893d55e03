#!/usr/bin/env python3
"""Supervisor death: how many of a running demo's processes are alive 5 s after the demo
runner gets SIGKILL (or SIGHUP, SIGTERM), and whether every driver's stop was confirmed.

Each run starts ``python -m softsnap_gaits.demo --scene brittle_star`` (10 processes:
five sim_module, driver_container, model_node, gait_node, rerun_logger, the bag
recorder), waits until the robot runs (the bag has taken its first 50 kB), signals the
runner, then counts the robot's processes (found by a tag in their environment,
softsnap_ros.processes) every 0.1 s: the time until none is left, and how many were
alive 5 s after the signal (the issue's "Done when"). From the drivers' log: each
driver's last stop (the shutdown's, or the watchdog's), confirmed or not.

Usage: .venv/bin/python benchmarks/supervisor_death.py [--runs 3] [--signals KILL HUP TERM]
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import fmt_spread, load_line
from softsnap_ros.processes import is_alive, stop_process_tree, tagged_env, tagged_processes
from softsnap_gaits.supervision import last_stop_outcomes

ALIVE_AT_S = 5.0


def one_run(sig: int) -> tuple[int, float, int, int, int]:
    """(robot processes before, seconds until none alive, alive at ALIVE_AT_S,
    drivers whose last stop was confirmed, drivers whose last stop was NOT)."""
    run_dir = Path(tempfile.mkdtemp(prefix='supervisor_death_'))
    env, tag = tagged_env(dict(os.environ))
    env.pop('ROS_DOMAIN_ID', None)
    proc = subprocess.Popen([sys.executable, '-m', 'softsnap_gaits.demo', '--scene', 'brittle_star',
                             '--seconds', '600', '--run-dir', str(run_dir)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            stdin=subprocess.DEVNULL, env=env, start_new_session=True)
    try:
        bag = run_dir / 'bag' / 'bag.mcap'
        deadline = time.monotonic() + 300
        while not (bag.exists() and bag.stat().st_size > 50_000):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f'demo did not start (exit {proc.poll()}), logs in {run_dir}')
            time.sleep(0.2)
        robot = [p for p in tagged_processes(tag) if p.pid != proc.pid]
        os.kill(proc.pid, sig)
        start = time.monotonic()
        alive_at = None
        gone_after = None
        while time.monotonic() - start < 60.0:
            alive = sum(is_alive(p) for p in robot)
            elapsed = time.monotonic() - start
            if gone_after is None and alive == 0:
                gone_after = elapsed
            if alive_at is None and elapsed >= ALIVE_AT_S:
                alive_at = alive
            if gone_after is not None and alive_at is not None:
                break
            time.sleep(0.1)
        proc.wait(60)
        last = last_stop_outcomes((run_dir / 'driver_container.log').read_text(errors='replace'))
        return (len(robot), gone_after if gone_after is not None else float('inf'),
                alive_at if alive_at is not None else len(robot),
                sum(ok for ok, _ in last.values()), sum(not ok for ok, _ in last.values()))
    finally:
        stop_process_tree(proc, tag, 15.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--signals', nargs='+', default=['KILL', 'HUP', 'TERM'])
    args = parser.parse_args()
    print(load_line('before'))
    print(f'{"signal":8s} {"runs":>4s} {"processes":>9s} {"alive at 5 s":>12s} '
          f'{"gone after (s), median (min-max)":>32s} {"last stop confirmed":>20s} {"NOT":>5s}')
    for name in args.signals:
        sig = getattr(signal, f'SIG{name}')
        runs = [one_run(sig) for _ in range(args.runs)]
        print(f'SIG{name:5s} {len(runs):4d} {runs[0][0]:9d} {max(r[2] for r in runs):12d} '
              f'{fmt_spread([r[1] for r in runs], digits=2):>32s} '
              f'{sum(r[3] for r in runs):>14d} of {sum(r[3] + r[4] for r in runs):<3d} '
              f'{sum(r[4] for r in runs):>5d}', flush=True)
    print(load_line('after'))


if __name__ == '__main__':
    main()
