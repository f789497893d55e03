"""Helpers shared by the benchmark scripts: median timing, and starting and stopping
installed nodes as processes."""
from __future__ import annotations

import os
import signal
import statistics
import subprocess
import tempfile
import time

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


def stop(proc: subprocess.Popen) -> None:
    """SIGINT (like Ctrl-C) to the node's process group; SIGKILL after 10 s."""
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)


def timed(fn, repeat: int):
    """(median wall time of ``repeat`` calls of ``fn`` in s, the last call's result)."""
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out
