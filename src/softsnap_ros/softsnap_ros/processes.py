"""The one process supervisor: child processes with their logs, stopped like Ctrl-C.

Shared by the demo (each node a :class:`ChildProcess`), the benchmark scripts and the
tests (test/conftest.py's ``start_node``, the demo runner of test/e2e). No ROS imports.
A child runs in a session of its own (``start_new_session=True``): the signals go to its
whole process group, so grandchildren (a launched node, rerun's server) stop with it.

A process that puts its own children in sessions of their own (the demo runner does, one
per node) hands them out of reach of its group, and once it dies they are reparented and
out of reach of its process tree too. What they all keep is their environment: start the
process with :func:`tagged_env` and :func:`stop_process_tree` stops every process that
inherited the tag, whatever its session, group or parent.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
import uuid
from pathlib import Path
from typing import Sequence

#: Environment variable whose value names one process tree (see tagged_env).
TAG_VARIABLE = 'SOFTSNAP_PROCESS_TAG'
#: How often stop_tagged looks whether the processes it signalled are gone (s).
POLL_S = 0.05
#: SIGKILL rounds stop_tagged makes (a round catches what forked during the one before)
#: before it gives up and says which processes survived.
KILL_ROUNDS = 5


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


def tagged_env(env: dict[str, str]) -> tuple[dict[str, str], str]:
    """(``env`` with a new tag of its own, that tag) for a process to start."""
    tag = f'{os.getpid()}-{uuid.uuid4().hex}'
    return dict(env, **{TAG_VARIABLE: tag}), tag


def is_alive(proc) -> bool:
    """True while the psutil.Process runs (a zombie has exited; pid reuse is checked)."""
    import psutil
    try:
        return proc.is_running() and proc.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def tagged_processes(tag: str) -> list:
    """Live processes (psutil.Process) whose environment carries ``TAG_VARIABLE=tag``."""
    import psutil
    found = []
    for proc in psutil.process_iter():
        try:
            if proc.pid != os.getpid() and proc.environ().get(TAG_VARIABLE) == tag:
                found.append(proc)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue  # gone, someone else's, or exited
    return found


def _wait_gone(procs: list, timeout: float) -> list:
    """Wait up to ``timeout`` s for ``procs`` to exit; those still alive."""
    deadline = time.monotonic() + timeout
    alive = [p for p in procs if is_alive(p)]
    while alive and time.monotonic() < deadline:
        time.sleep(POLL_S)
        alive = [p for p in alive if is_alive(p)]
    return alive


def _signal_all(procs: list, sig: int) -> None:
    import psutil
    for proc in procs:
        try:
            proc.send_signal(sig)  # psutil checks the pid still names this process
        except psutil.NoSuchProcess:
            pass


def stop_tagged(tag: str, timeout: float = 10.0) -> list:
    """Stop every process carrying ``tag``: SIGINT, up to ``timeout`` s, then SIGKILL
    until none is left. Returns the processes found at first (psutil.Process).

    RuntimeError if some survive KILL_ROUNDS rounds of SIGKILL (a process stuck in the
    kernel), naming them.
    """
    found = tagged_processes(tag)
    _signal_all(found, signal.SIGINT)
    _wait_gone(found, timeout)
    for _ in range(KILL_ROUNDS):
        # Looked up again: what was started meanwhile (a fork just before its parent
        # took the signal) carries the tag too.
        left = tagged_processes(tag)
        if not left:
            return found
        _signal_all(left, signal.SIGKILL)
        _wait_gone(left, timeout)
    left = tagged_processes(tag)
    if left:
        raise RuntimeError(f'processes tagged {tag} survived SIGKILL: '
                           f'{sorted(p.pid for p in left)}')
    return found


def stop_process_tree(proc: subprocess.Popen, tag: str, timeout: float = 10.0) -> int:
    """Stop ``proc`` (started with ``tagged_env``'s env and ``start_new_session=True``)
    and every process that inherited its tag: proc's group first (stop_process_group),
    so it starts no more and may stop its children itself, then whatever still carries
    the tag. Returns proc's exit code."""
    returncode = stop_process_group(proc, timeout)
    stop_tagged(tag, timeout)
    return returncode


class ChildProcess:
    """A program started in its own session, its output (stdout and stderr) in a log file.

    Parameters
    ----------
    argv : sequence of str
        The program and its arguments.
    log_path : Path
        Where its output goes (kept after :meth:`stop`).
    env : dict
        Its environment.
    tagged : bool
        Give it a tag of its own (:func:`tagged_env`) so that :meth:`stop` also stops every
        process that inherited it, in whatever session (a demo's nodes, say).
    pass_fds : sequence of int
        File descriptors it inherits (a slot's lock, a lifeline).
    """

    def __init__(self, argv: Sequence[str], log_path: Path, env: dict[str, str], *,
                 tagged: bool = True, pass_fds: Sequence[int] = ()):
        self.argv = [str(a) for a in argv]
        self.log_path = Path(log_path)
        self._log = open(self.log_path, 'wb')
        self.tag = None
        if tagged:
            env, self.tag = tagged_env(env)
        self.popen = subprocess.Popen(self.argv, stdout=self._log, stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL, env=env,
                                      start_new_session=True, pass_fds=tuple(pass_fds))

    @property
    def proc(self) -> subprocess.Popen:
        return self.popen

    def alive(self) -> bool:
        return self.popen.poll() is None

    def signal(self, sig: int) -> None:
        """Send ``sig`` to its process group (nothing if it has exited)."""
        if self.popen.poll() is None:
            try:
                os.killpg(self.popen.pid, sig)
            except ProcessLookupError:
                pass

    def usage(self):
        """(cpu seconds, rss bytes) of the process now; None once it has exited."""
        import psutil
        try:
            proc = psutil.Process(self.popen.pid)
            times = proc.cpu_times()
            return times.user + times.system, proc.memory_info().rss
        except psutil.Error:
            return None

    def output(self) -> str:
        """Everything it wrote so far."""
        if not self._log.closed:   # stop() closes it; the file stays readable
            self._log.flush()
        return self.log_path.read_text(errors='replace')

    def tail(self, lines: int = 15) -> str:
        """Its last ``lines`` lines of output."""
        return '\n'.join(self.output().splitlines()[-lines:])

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT its group, SIGKILL after ``timeout`` s, then whatever carries its tag;
        its exit code (``-SIGKILL``: SIGINT was not enough in time)."""
        if self.tag is not None:
            returncode = stop_process_tree(self.popen, self.tag, timeout)
        else:
            returncode = stop_process_group(self.popen, timeout)
        self.close()
        return returncode

    def close(self) -> None:
        """Close the log file (the process is not touched)."""
        self._log.close()
