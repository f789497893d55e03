"""Helpers shared by the benchmark scripts: median timing, repeats with their range,
the machine's load average, starting installed nodes as processes (stop them with
process_group.stop_process_group), and the source of an earlier revision for side-by-side
runs."""
from __future__ import annotations

import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from ament_index_python.packages import get_package_prefix


def start_node(package: str, executable: str, ros_args: list[str],
               log_path: str | None = None) -> subprocess.Popen:
    """Start ``<prefix>/lib/<package>/<executable> --ros-args ...`` in its own process group.

    Output goes to ``log_path`` (default: discarded); each node gets a fresh ROS_HOME.
    """
    exe = os.path.join(get_package_prefix(package), 'lib', package, executable)
    out = open(log_path or os.devnull, 'w')
    return subprocess.Popen([exe, '--ros-args', *ros_args], stdout=out, stderr=subprocess.STDOUT,
                            start_new_session=True,
                            env=dict(os.environ, ROS_HOME=tempfile.mkdtemp()))


def timed(fn, repeat: int, clock=time.perf_counter):
    """(median time of ``repeat`` calls of ``fn`` in s, the last call's result).

    ``clock`` is wall time by default; ``time.thread_time`` gives the CPU time of the
    calling thread, which on a shared machine does not count the time other processes
    hold the cores (it still includes their cache and memory-bus contention).
    """
    times = []
    out = None
    for _ in range(repeat):
        t0 = clock()
        out = fn()
        times.append(clock() - t0)
    return statistics.median(times), out


def load_line(when: str) -> str:
    """``'load average at <when>: 1m 5m 15m'`` (figures on a shared machine need it)."""
    one, five, fifteen = os.getloadavg()
    return f'load average at {when}: {one:.2f} {five:.2f} {fifteen:.2f} ({os.cpu_count()} cores)'


def spread(values) -> tuple[float, float, float]:
    """(median, min, max) of repeated measurements."""
    values = list(values)
    return statistics.median(values), min(values), max(values)


def fmt_spread(values, scale: float = 1.0, digits: int = 1) -> str:
    """``'median (min-max)'`` of ``values * scale``."""
    med, lo, hi = spread(values)
    return f'{med * scale:,.{digits}f} ({lo * scale:,.{digits}f}-{hi * scale:,.{digits}f})'


#: The repository's root (the benchmarks' parent directory).
REPO = Path(__file__).resolve().parent.parent


def checkout_src(rev: str) -> Path:
    """A new temporary directory holding ``src/`` of git revision ``rev`` (``git archive``),
    for running the old code side by side with the current one."""
    root = Path(tempfile.mkdtemp(prefix='bench_before_'))
    archive = subprocess.run(['git', '-C', str(REPO), 'archive', rev, 'src'],
                             check=True, capture_output=True).stdout
    subprocess.run(['tar', '-x', '-C', str(root)], input=archive, check=True)
    return root
