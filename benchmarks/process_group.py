"""Stopping a child process and everything it started, like Ctrl-C in a terminal.

Shared by the benchmark scripts (nodes started by benchlib.start_node) and the tests
(test/conftest.py's NodeProcess and the tests that start a helper process of their own;
conftest puts benchmarks/ on sys.path). No ROS imports. The process must have been
started with ``start_new_session=True``: the signals go to its whole process group, so
grandchildren (a launched node, rerun's server) stop with it.
"""
from __future__ import annotations

import os
import signal
import subprocess


def stop_process_group(proc: subprocess.Popen, timeout: float = 10.0) -> int:
    """SIGINT proc's process group, wait up to ``timeout`` s, then SIGKILL it.

    Returns the exit code; ``-signal.SIGKILL`` means SIGINT was not enough in time.
    A process that has already exited is only reaped.
    """
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode
