"""Stopping a robot graph in dependency order, and saying honestly how it stopped.

The demo runner (:mod:`softsnap_gaits.demo`) stops its processes stage by stage, each
stage only once the one before has exited:

0. the gait (no new command after this);
1. the drivers: each confirms its stop while its module (simulated or real) still
   answers; a driver whose last stop was not confirmed exits with
   :data:`softsnap_driver.core.STOP_UNCONFIRMED_EXIT`;
2. then, together, the simulators (``sim_module``, ``sim_robot``), the model and the
   recorders (``rerun_logger``, the bag recorder): none of them commands anything or
   needs another to stop, and the recorders have by then taken everything the drivers
   reported, their last stops included. (Staged one by one as well, each stage's Python
   exit costing about 1.3 s on the loaded 2-core machine, an orderly stop took 5.8-7.2 s;
   the issue asks for nothing alive 5 s after a SIGHUP.)

Stopped all at once (SIGINT to every process, as before) the simulated modules went in
the same instant as their drivers and every driver logged "stop NOT confirmed ...
refused the connection" while the summary said "all stopped cleanly".

A process that ignores SIGINT for ``timeout_s`` is killed, and that is reported.
:func:`shutdown_problems` turns exit statuses into what went wrong; an empty result is
the only "stopped cleanly". No ROS imports.
"""
from __future__ import annotations

import dataclasses
import re
import signal
import subprocess
import time

from softsnap_driver.core import STOP_UNCONFIRMED_EXIT

#: Shutdown stage of each executable (lower stops first); anything else stops with the model.
SHUTDOWN_STAGES = {
    'gait_node': 0,
    'driver_container': 1, 'driver_node': 1,
    'sim_module': 2, 'sim_robot': 2,
    'model_node': 2,
    'rerun_logger': 2, 'bag': 2,
}
DEFAULT_STAGE = 2
#: Exit statuses of a process stopped by its SIGINT (rclpy nodes: 0; Python's default
#: KeyboardInterrupt exit: 130 or -SIGINT). None: never started.
CLEAN_EXITS = (0, None, -signal.SIGINT, 128 + signal.SIGINT)


def shutdown_stage(executable: str) -> int:
    return SHUTDOWN_STAGES.get(executable, DEFAULT_STAGE)


@dataclasses.dataclass(frozen=True)
class StopRecord:
    """How one process stopped: its stage, exit status, whether it had to be killed and
    the seconds from its SIGINT to its exit."""

    name: str
    stage: int
    returncode: int | None
    killed: bool
    seconds: float


def stop_in_order(processes, timeout_s: float, warn=print) -> list[StopRecord]:
    """SIGINT each stage's processes, wait for all of them (SIGKILL after `timeout_s`),
    then the next stage. `processes` have ``.spec`` (``name``, ``executable``),
    ``.popen`` and ``.signal(sig)`` (the demo's Process). Returns one record per
    process, in stopping order; already exited processes are only reaped."""
    records = []
    stages = sorted({shutdown_stage(p.spec.executable) for p in processes})
    for stage in stages:
        group = [p for p in processes if shutdown_stage(p.spec.executable) == stage]
        started = time.monotonic()
        for p in group:
            p.signal(signal.SIGINT)
        for p in group:
            killed = False
            try:
                p.popen.wait(max(0.0, started + timeout_s - time.monotonic()))
            except subprocess.TimeoutExpired:
                warn(f'{p.spec.name} ignored SIGINT for {timeout_s:g} s: killing it')
                p.signal(signal.SIGKILL)
                p.popen.wait()
                killed = True
            records.append(StopRecord(p.spec.name, stage, p.popen.returncode, killed,
                                      round(time.monotonic() - started, 3)))
    return records


def shutdown_problems(exit_codes: dict[str, int | None], executables: dict[str, str] | None = None,
                      killed: set[str] = frozenset()) -> dict[str, str]:
    """Process name -> what went wrong when it stopped (empty: all stopped cleanly).

    `executables` (name -> executable) tells drivers apart: their
    STOP_UNCONFIRMED_EXIT is a stop that was not confirmed.
    """
    executables = executables or {}
    problems = {}
    for name, code in exit_codes.items():
        driver = executables.get(name) in ('driver_container', 'driver_node')
        if name in killed:
            problems[name] = 'ignored SIGINT and was killed'
        elif driver and code == STOP_UNCONFIRMED_EXIT:
            problems[name] = 'last stop NOT confirmed (the module may still move)'
        elif code not in CLEAN_EXITS:
            problems[name] = f'exit status {code}'
    return problems


_STOP_LINE = re.compile(r'\[(?:[\w/]+\.)*(\w+)_driver(?:\.shutdown)?\]: '
                        r'stop (confirmed|NOT confirmed)[^\n]*?\(([a-z][a-z ]+[a-z])\)')


def last_stop_outcomes(log_text: str) -> dict[str, tuple[bool, str]]:
    """Module -> (confirmed, why) of each driver's last stop in a drivers' log (the
    link's "stop confirmed at ... (why)" and "stop NOT confirmed ... (why)" lines)."""
    outcomes = {}
    for match in _STOP_LINE.finditer(log_text):
        outcomes[match.group(1)] = (match.group(2) == 'confirmed', match.group(3))
    return outcomes
