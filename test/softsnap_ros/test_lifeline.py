"""A process tied to its supervisor (softsnap_ros.lifeline) stops when the supervisor
dies by any signal, SIGKILL included, and takes SIGHUP like SIGTERM.

Real processes, real signals: a supervisor process starts a child that calls
``supervise()`` (as every node's ``init_ros`` does), then the supervisor is killed. The
child's SIGTERM handler writes a line and exits 0, so the test sees that the child ended
by its own orderly shutdown, not by a signal's default action.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

#: The child: a SIGTERM handler that reports, then waits (in C, like an idle executor).
CHILD = r'''
import os, signal, sys, threading, time
from softsnap_ros.lifeline import supervise
stop = threading.Event()
def on_term(signum, frame):
    print('child: SIGTERM, stopping', flush=True)
    stop.set()
signal.signal(signal.SIGTERM, on_term)
supervise()
print('child: ready', os.getpid(), flush=True)
while not stop.wait(0.5):
    pass
print('child: stopped cleanly', flush=True)
'''

#: The supervisor: starts the child (optionally through a shell that stays its parent,
#: so that only the lifeline pipe can tell it), prints the child's pid, then waits.
SUPERVISOR = r'''
import os, subprocess, sys, time
from softsnap_ros.lifeline import Lifeline
lifeline = Lifeline() if sys.argv[2] == 'lifeline' else None
env = lifeline.env(dict(os.environ)) if lifeline else dict(os.environ)
argv = [sys.executable, '-c', sys.argv[3]]
if sys.argv[1] == 'shell':   # a wrapper between supervisor and child: no parent-death signal
    argv = ['/bin/sh', '-c', '"$0" "$@"; true', *argv]
child = subprocess.Popen(argv, stdout=open(sys.argv[4], 'w'), stderr=subprocess.STDOUT, env=env,
                         start_new_session=True, pass_fds=lifeline.pass_fds if lifeline else ())
print(child.pid, flush=True)
time.sleep(600)
'''


def _wait_for(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def _child_pid(log, timeout=60.0) -> int:
    assert _wait_for(lambda: 'child: ready' in log.read_text(), timeout), log.read_text()
    return int(log.read_text().split('child: ready', 1)[1].split()[0])


def _alive(pid: int) -> bool:
    import psutil
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _run_supervisor(tmp_path, how: str, tie: str):
    log = tmp_path / 'child.log'
    log.write_text('')
    sup = subprocess.Popen([sys.executable, '-c', SUPERVISOR, how, tie, CHILD, str(log)],
                           stdout=subprocess.PIPE, text=True, start_new_session=True)
    sup.stdout.readline()
    return sup, log, _child_pid(log)


@pytest.mark.parametrize('sig', [signal.SIGKILL, signal.SIGTERM, signal.SIGHUP],
                         ids=['SIGKILL', 'SIGTERM', 'SIGHUP'])
def test_child_stops_when_its_supervisor_dies_by_any_signal(tmp_path, sig):
    sup, log, pid = _run_supervisor(tmp_path, 'direct', 'none')
    try:
        os.kill(sup.pid, sig)
        sup.wait(30)
        # Parent-death signal alone (no lifeline here): the child's own SIGTERM shutdown.
        assert _wait_for(lambda: not _alive(pid), 30.0), log.read_text()
        assert 'child: SIGTERM, stopping' in log.read_text()
        assert 'child: stopped cleanly' in log.read_text()
    finally:
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)
        if sup.poll() is None:
            sup.kill()
        sup.stdout.close()


def test_lifeline_stops_a_child_whose_parent_is_a_wrapper_that_lives_on(tmp_path):
    sup, log, pid = _run_supervisor(tmp_path, 'shell', 'lifeline')
    try:
        os.kill(sup.pid, signal.SIGKILL)
        sup.wait(30)
        assert _wait_for(lambda: not _alive(pid), 30.0), log.read_text()
        text = log.read_text()
        assert 'the supervisor is gone' in text and 'child: stopped cleanly' in text, text
    finally:
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)
        sup.stdout.close()


def test_without_the_lifeline_the_wrapped_child_would_run_on(tmp_path):
    """The control for the test above: the same wrapper, no lifeline, and the child
    outlives its supervisor (what every demo child did before)."""
    sup, log, pid = _run_supervisor(tmp_path, 'shell', 'none')
    try:
        os.kill(sup.pid, signal.SIGKILL)
        sup.wait(30)
        time.sleep(2.0)   # a control: nothing should happen in this time
        assert _alive(pid)
    finally:
        if _alive(pid):
            os.kill(pid, signal.SIGTERM)
            _wait_for(lambda: not _alive(pid), 30.0)
        sup.stdout.close()


def test_sighup_is_taken_like_sigterm(tmp_path):
    log = tmp_path / 'child.log'
    with open(log, 'w') as out:
        child = subprocess.Popen([sys.executable, '-c', CHILD], stdout=out,
                                 stderr=subprocess.STDOUT, start_new_session=True)
    try:
        _child_pid(log)
        os.kill(child.pid, signal.SIGHUP)
        assert child.wait(30) == 0, log.read_text()   # SIGHUP's default would give -1
        text = log.read_text()
        assert 'SIGHUP: shutting down as on SIGTERM' in text and 'child: stopped cleanly' in text
    finally:
        if child.poll() is None:
            child.kill()


#: A child whose orderly shutdown never ends (a teardown stuck on a thread that never
#: finishes): its SIGTERM handler starts the shutdown and the process hangs on.
STUCK_CHILD = r'''
import os, signal, sys, threading, time
from softsnap_ros.lifeline import supervise
def on_term(signum, frame):
    print('child: SIGTERM, stopping (and stuck)', flush=True)
signal.signal(signal.SIGTERM, on_term)
supervise()
print('child: ready', os.getpid(), flush=True)
while True:
    time.sleep(0.5)
'''


def test_an_orphan_whose_shutdown_hangs_ends_by_the_deadline(tmp_path):
    """The lifeline's last resort: a child that takes its SIGTERM but never exits is
    ended ORPHAN_EXIT_DEADLINE_S after its supervisor died, saying so."""
    from softsnap_ros.lifeline import ORPHAN_EXIT_DEADLINE_S, ORPHAN_EXIT_STATUS
    log = tmp_path / 'child.log'
    log.write_text('')
    sup = subprocess.Popen([sys.executable, '-c', SUPERVISOR, 'shell', 'lifeline',
                            STUCK_CHILD, str(log)],
                           stdout=subprocess.PIPE, text=True, start_new_session=True)
    sup.stdout.readline()
    pid = _child_pid(log)
    try:
        os.kill(sup.pid, signal.SIGKILL)
        killed_at = time.monotonic()
        sup.wait(30)
        assert _wait_for(lambda: 'SIGTERM, stopping (and stuck)' in log.read_text(), 30.0)
        early = ORPHAN_EXIT_DEADLINE_S - 1.0 - (time.monotonic() - killed_at)
        if early > 0:   # (on a starved machine this point may come late: then skip it)
            time.sleep(early)
            assert _alive(pid), 'ended before its deadline: no time for an orderly stop'
        assert _wait_for(lambda: not _alive(pid), 30.0), log.read_text()
        text = log.read_text()
        assert f'exiting now (status {ORPHAN_EXIT_STATUS})' in text, text
    finally:
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)
        sup.stdout.close()
