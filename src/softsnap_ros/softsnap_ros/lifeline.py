"""A node never outlives its supervisor: parent-death signal, lifeline pipe, SIGHUP.

A SoftSnap module has no watchdog: a driver that keeps running after whoever started it
died (SIGKILL, an out-of-memory kill, a closed terminal) keeps a robot moving that nobody
controls. Every node's start-up (:func:`softsnap_ros.spinning.init_ros`) calls
:func:`supervise` before ROS starts, which arranges three things, each ending in the
node's ordinary SIGTERM shutdown (so a driver's last act is still its confirmed stop):

- **Parent-death signal.** The kernel sends ``SIGTERM`` when the parent dies, by any
  signal (``prctl(PR_SET_PDEATHSIG)``, Linux). The parent may have died before the call:
  the parent pid is compared before and after it (and the supervisor that passed its
  pid in ``SOFTSNAP_SUPERVISOR_PID`` must still exist), and a change is the same death.
- **Lifeline pipe.** A supervisor that passes the read end of a pipe (its number in
  ``SOFTSNAP_LIFELINE_FD``) keeps the write end; when it dies the kernel closes that end
  and a thread here reads end-of-file. This holds where a parent-death signal does not
  (a wrapper process between the supervisor and the node, a supervisor's thread that
  exits).
- **SIGHUP like SIGTERM** (a closed terminal, a dropped SSH session): Python's default
  for SIGHUP ends the process at once, motors moving. The same thread re-sends it as
  SIGTERM, through Python's wakeup file descriptor, so it is handled even while the main
  thread waits in C (an executor with nothing to do) where a Python handler would not
  run.

A deadline behind all three: once the supervisor is gone (the lifeline ended), the
process has :data:`ORPHAN_EXIT_DEADLINE_S` for its orderly shutdown; if it still runs
then (a shutdown stuck in a teardown, a signal handler that never returns) it ends at
once, saying so. A driver's confirmed stop takes at most ``SHUTDOWN_BUDGET_S`` (1.2 s)
of that, so the deadline cuts nothing but a stuck exit, and no process of a robot whose
supervisor died is alive 5 s later.

No ROS imports: the plain simulators use it too.
"""
from __future__ import annotations

import ctypes
import os
import select
import signal
import sys
import threading

#: Environment variable: the file descriptor of the lifeline pipe's read end.
LIFELINE_FD_VARIABLE = 'SOFTSNAP_LIFELINE_FD'
#: Environment variable: the pid of the supervisor that started this process.
SUPERVISOR_PID_VARIABLE = 'SOFTSNAP_SUPERVISOR_PID'
#: The signal a lost parent or lifeline, and SIGHUP, become: every node handles it.
SHUTDOWN_SIGNAL = signal.SIGTERM
_PR_SET_PDEATHSIG = 1
#: Seconds an orphan (its lifeline ended) has for its orderly shutdown before it ends
#: itself: a normal stop takes 1.5-4 s on the loaded 2-core machine, the confirmed stop of
#: a driver at most 1.2 s of it.
ORPHAN_EXIT_DEADLINE_S = 4.5
#: Exit status of an orphan ended by the deadline.
ORPHAN_EXIT_STATUS = 70

_state = {'supervised': False}


def set_parent_death_signal(sig: int = SHUTDOWN_SIGNAL) -> bool:
    """Ask the kernel for `sig` when the parent dies; True if the call succeeded.

    If the parent died before the call took effect (the parent pid changed, or is not
    the supervisor named in the environment), `sig` is sent now.
    """
    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        ok = libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):   # not Linux: the lifeline pipe still holds
        ok = False
    supervisor = os.environ.pop(SUPERVISOR_PID_VARIABLE, '')
    if os.getppid() != parent or (supervisor.isdigit() and not _exists(int(supervisor))):
        os.kill(os.getpid(), sig)
    return ok


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _take_lifeline_fd() -> int | None:
    """The lifeline's fd from the environment (then removed: our own children do not
    have that fd), or None."""
    text = os.environ.pop(LIFELINE_FD_VARIABLE, '')
    if not text.isdigit():
        return None
    fd = int(text)
    try:
        os.fstat(fd)
    except OSError:
        return None
    os.set_inheritable(fd, False)
    return fd


def _install_sighup() -> int | None:
    """A Python SIGHUP handler (none replaced) and a wakeup fd; the fd to read, or None.

    Only from the main thread and only if SIGHUP still has its default action (a
    program with a handler of its own, like the demo runner, keeps it) and no wakeup fd
    is set (an asyncio loop's is kept).
    """
    if threading.current_thread() is not threading.main_thread():
        return None
    if signal.getsignal(signal.SIGHUP) is not signal.SIG_DFL:
        return None
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    try:
        previous = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    except ValueError:
        os.close(read_fd)
        os.close(write_fd)
        return None
    if previous != -1:   # someone else's: put it back, SIGHUP keeps its default
        signal.set_wakeup_fd(previous)
        os.close(read_fd)
        os.close(write_fd)
        return None
    signal.signal(signal.SIGHUP, lambda signum, frame: None)  # the watcher acts on it
    return read_fd


def _watch(lifeline_fd: int | None, wakeup_fd: int | None) -> None:
    """Thread: SIGTERM to this process when the lifeline ends or SIGHUP comes."""
    fds = [fd for fd in (lifeline_fd, wakeup_fd) if fd is not None]
    while fds:
        readable, _, _ = select.select(fds, [], [])
        for fd in readable:
            try:
                data = os.read(fd, 512)
            except OSError:
                data = b''
            if fd == lifeline_fd and not data:
                print('[lifeline] the supervisor is gone: shutting down', file=sys.stderr,
                      flush=True)
                fds.remove(fd)
                _arm_orphan_deadline()
                os.kill(os.getpid(), SHUTDOWN_SIGNAL)
            elif fd == wakeup_fd and signal.SIGHUP in data:
                print('[lifeline] SIGHUP: shutting down as on SIGTERM', file=sys.stderr,
                      flush=True)
                os.kill(os.getpid(), SHUTDOWN_SIGNAL)
            elif fd == wakeup_fd and not data:
                fds.remove(fd)


def _arm_orphan_deadline(deadline_s: float = ORPHAN_EXIT_DEADLINE_S) -> None:
    """End this process `deadline_s` from now unless it has ended by then."""
    def expire():
        print(f'[lifeline] still running {deadline_s:g} s after the supervisor died: '
              f'exiting now (status {ORPHAN_EXIT_STATUS})', file=sys.stderr, flush=True)
        os._exit(ORPHAN_EXIT_STATUS)
    timer = threading.Timer(deadline_s, expire)
    timer.daemon = True
    timer.name = 'lifeline-deadline'
    timer.start()


def supervise() -> None:
    """Parent-death signal, lifeline watcher and SIGHUP-as-SIGTERM for this process (once)."""
    if _state['supervised']:
        return
    _state['supervised'] = True
    set_parent_death_signal()
    lifeline = _take_lifeline_fd()
    wakeup = _install_sighup()
    if lifeline is not None or wakeup is not None:
        threading.Thread(target=_watch, args=(lifeline, wakeup), name='lifeline',
                         daemon=True).start()


class Lifeline:
    """The supervisor's side: a pipe whose read end every child gets.

    ``env(base)`` is the environment of a child (fd number and our pid), ``pass_fds``
    what to hand to ``subprocess.Popen``. The write end stays here, never inherited:
    when this process dies, however, every child reads end-of-file.
    """

    def __init__(self):
        self.read_fd, self._write_fd = os.pipe()
        os.set_inheritable(self._write_fd, False)

    @property
    def pass_fds(self) -> tuple[int, ...]:
        return (self.read_fd,)

    def env(self, base: dict[str, str]) -> dict[str, str]:
        return dict(base, **{LIFELINE_FD_VARIABLE: str(self.read_fd),
                             SUPERVISOR_PID_VARIABLE: str(os.getpid())})

    def cut(self) -> None:
        """Close the write end: every child still running starts its shutdown."""
        if self._write_fd is not None:
            os.close(self._write_fd)
            self._write_fd = None

    def close(self) -> None:
        self.cut()
        if self.read_fd is not None:
            os.close(self.read_fd)
            self.read_fd = None
