"""The numbers the README quotes, measured on this machine: run it, paste its table.

    .venv/bin/python benchmarks/readme_numbers.py            # size, tests, warm bootstrap, demo
    .venv/bin/python benchmarks/readme_numbers.py --cold     # also a cold bootstrap of a fresh clone

What it measures (wall time, with the load average at the start beside it, since the
machine may be shared):
- the size of `.venv` (du) and how many tests pytest collects;
- a warm bootstrap (nothing changed: every step skipped);
- `make demo` (brittle star, 10 s of gait), start to exit, and the bag recorder's CPU
  beside the other processes' (from the demo's own `--json` summary);
- with --cold: `git clone` of this checkout into a temporary directory and its
  bootstrap there (pip's cache as it is; PYTHON as given, python3 by default).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
VENV_PY = REPO / '.venv' / 'bin' / 'python'


def timed(argv, cwd=REPO, env=None, timeout=3600) -> tuple[float, subprocess.CompletedProcess]:
    start = time.monotonic()
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    return time.monotonic() - start, done


def load() -> str:
    return f'{os.getloadavg()[0]:.1f}'


def venv_size_gb(venv: Path) -> float:
    out = subprocess.run(['du', '-sb', str(venv)], capture_output=True, text=True).stdout
    return int(out.split()[0]) / 1e9


def collected_tests() -> int:
    _, done = timed([str(VENV_PY), '-m', 'pytest', '--collect-only', '-q', '-p', 'no:cacheprovider'])
    match = re.search(r'(\d+) tests? collected', done.stdout) or re.search(
        r'^(\d+) tests?', done.stdout.strip().splitlines()[-1] if done.stdout.strip() else '')
    if not match:
        raise SystemExit(f'pytest --collect-only said: {done.stdout[-500:]}{done.stderr[-500:]}')
    return int(match.group(1))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--cold', action='store_true', help='also bootstrap a fresh clone')
    parser.add_argument('--no-demo', action='store_true', help='skip the demo run')
    args = parser.parse_args()
    rows = []
    rows.append(('`.venv` size', f'{venv_size_gb(REPO / ".venv"):.2f} GB', '-'))
    rows.append(('tests collected (`pytest --collect-only`)', str(collected_tests()), '-'))
    for attempt in ('bring up to date', 'timed'):    # the second run is the warm one
        la = load()
        seconds, done = timed(['bash', 'scripts/bootstrap.sh'])
        if done.returncode:
            raise SystemExit(f'bootstrap failed:\n{done.stderr[-2000:]}')
    rows.append(('warm bootstrap (nothing changed)', f'{seconds:.1f} s', la))
    if not args.no_demo:
        la = load()
        with tempfile.TemporaryDirectory() as run_dir:
            seconds, done = timed([str(VENV_PY), '-m', 'softsnap_gaits.demo', '--scene',
                                   'brittle_star', '--seconds', '10', '--run-dir', run_dir,
                                   '--json'], timeout=900)
        if done.returncode:
            raise SystemExit(f'demo failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}')
        rows.append(('`make demo` (brittle star, 10 s of gait), start to exit', f'{seconds:.1f} s', la))
        summary = json.loads(done.stdout[done.stdout.index('{'):])
        usage = {name: u['cpu_percent'] for name, u in (summary.get('processes') or {}).items()}
        if usage:
            cells = ', '.join(f'{name} {value:.0f} %' for name, value in
                              sorted(usage.items(), key=lambda item: -item[1]))
            rows.append(('CPU per process in that demo (% of one core)', cells, la))
    if args.cold:
        with tempfile.TemporaryDirectory() as scratch:
            clone = Path(scratch) / 'softsnap'
            subprocess.run(['git', 'clone', '-q', str(REPO), str(clone)], check=True)
            la = load()
            seconds, done = timed(['bash', 'scripts/bootstrap.sh'], cwd=clone)
            if done.returncode:
                raise SystemExit(f'cold bootstrap failed:\n{done.stderr[-2000:]}')
            python = os.environ.get('PYTHON', 'python3')
            rows.append((f'cold bootstrap of a fresh clone ({python}, pip cache as it is)',
                         f'{seconds:.0f} s, `.venv` {venv_size_gb(clone / ".venv"):.2f} GB', la))
    print(f'Measured {time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())} on {os.cpu_count()} '
          f'CPUs ({shutil.which("python3")}):\n')
    print('| what | measured | load average at start |')
    print('| --- | --- | --- |')
    for row in rows:
        print('| ' + ' | '.join(row) + ' |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
