"""Stopping a process stops everything it started (softsnap_ros.processes), also
children in sessions of their own and children of a process that crashed.

What the demo runner and test/conftest.py's NodeProcess rely on, checked with plain
Python processes standing in for nodes: a parent that starts one child in its own
process group and one in a session of its own (as the demo runner starts each node).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from softsnap_ros.processes import is_alive, stop_process_group, stop_process_tree, tagged_env, \
    tagged_processes

#: The parent: starts its two children, writes their pids, then waits.
PARENT = '''
import subprocess, sys, time
sleeper = [sys.executable, '-c', 'import time; time.sleep(600)']
in_group = subprocess.Popen(sleeper)
own_session = subprocess.Popen(sleeper, start_new_session=True)
print(in_group.pid, own_session.pid, flush=True)
time.sleep(600)
'''


def _children(pids_line: str) -> list:
    import psutil
    return [psutil.Process(int(pid)) for pid in pids_line.split()]


def test_a_process_tree_is_stopped_with_children_out_of_its_group():
    env, tag = tagged_env(dict(os.environ))
    parent = subprocess.Popen([sys.executable, '-c', PARENT], stdout=subprocess.PIPE, text=True,
                              env=env, start_new_session=True)
    try:
        in_group, own_session = children = _children(parent.stdout.readline())
        assert {p.pid for p in tagged_processes(tag)} == {parent.pid, in_group.pid, own_session.pid}
        # The parent's group alone: the child in a session of its own runs on.
        stop_process_group(parent, 10.0)
        assert is_alive(own_session)
        stop_process_tree(parent, tag, 10.0)
        assert [p.pid for p in children if is_alive(p)] == []
        assert tagged_processes(tag) == []
    finally:
        stop_process_tree(parent, tag, 5.0)
        parent.stdout.close()


def test_node_process_stop_stops_the_children_of_a_crashed_node(tmp_path, root_conftest):
    node = root_conftest.NodeProcess([sys.executable, '-c', PARENT], tmp_path / 'parent.log', dict(os.environ))
    try:
        deadline = time.monotonic() + 60.0
        while not node.output().strip() and time.monotonic() < deadline:
            time.sleep(0.05)
        children = _children(node.output())
        os.kill(node.proc.pid, signal.SIGKILL)  # a crash: the node stops nothing itself
        node.proc.wait(30)
        # Both children outlived it (stop_process_group only reaps an exited leader).
        assert all(is_alive(p) for p in children)
    finally:
        node.stop()
    assert [p.pid for p in children if is_alive(p)] == []
