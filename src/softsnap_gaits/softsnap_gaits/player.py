"""Gait playback state machine: start, stop, pause, resume, switch, with smooth transitions.

Pure Python + numpy, no ROS: the gait node feeds it the clock and publishes what it
returns. Times are seconds on any monotonic clock (the node uses its ROS clock).

States: ``stopped`` -> start -> ``running`` <-> pause/resume <-> ``paused``; stop from
either returns to ``stopped``; a gait played once ends by itself (``finished`` is then
reported and the state is ``stopped``). Whenever the commanded target changes abruptly
(start from a non-straight robot, switching gaits, stop) the command is blended from the
last command to the new target over `transition_s` with a cosine ease, so the motors
never see a jump.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softsnap_gaits.gaits import Gait

__all__ = ['GaitPlayer', 'PlayerOutput', 'STOPPED', 'RUNNING', 'PAUSED']

STOPPED, RUNNING, PAUSED = 'stopped', 'running', 'paused'


@dataclass(frozen=True)
class PlayerOutput:
    """What to publish at one tick.

    Attributes
    ----------
    contraction_mm : ndarray or None
        Commanded contraction per module (mm), or None when nothing is to be commanded
        (stopped and the relax transition is over).
    cable_length_mm : ndarray or None
        Straight length minus contraction (mm), or None like `contraction_mm`.
    phase : float
        Phase in the cycle, 0 to 1.
    cycle : int
        Completed cycles.
    state : str
        ``stopped``, ``running`` or ``paused``.
    """

    contraction_mm: np.ndarray | None
    cable_length_mm: np.ndarray | None
    phase: float
    cycle: int
    state: str


class GaitPlayer:
    """Plays one `Gait` at a time against an external clock."""

    def __init__(self, gait: Gait, *, transition_s: float = 0.3):
        if not (math.isfinite(transition_s) and transition_s >= 0.0):
            raise ValueError(f'transition_s must be >= 0 s, got {transition_s!r}')
        self.gait = gait
        self.transition_s = float(transition_s)
        self.state = STOPPED
        self.finished = False
        self._t0 = 0.0            # clock time at which gait time was 0
        self._paused_at = 0.0     # gait time at which we paused
        self._last = np.zeros(len(gait.module_names))
        self._blend_from: np.ndarray | None = None
        self._blend_start = 0.0

    # ------------------------------------------------------------------ transitions
    def gait_time(self, now: float) -> float:
        """Seconds of gait played at clock time `now` (frozen while paused, 0 when stopped)."""
        if self.state == RUNNING:
            return max(now - self._t0, 0.0)
        if self.state == PAUSED:
            return self._paused_at
        return 0.0

    def start(self, now: float) -> tuple[bool, str]:
        if self.state == RUNNING:
            return False, f'gait {self.gait.name!r} is already running'
        if self.state == PAUSED:
            return False, f'gait {self.gait.name!r} is paused: call resume (or stop first)'
        self._begin_blend(now)
        self.state, self._t0, self.finished = RUNNING, now, False
        return True, f'started gait {self.gait.name!r}'

    def stop(self, now: float) -> tuple[bool, str]:
        if self.state == STOPPED:
            return True, 'already stopped'
        self._begin_blend(now)
        self.state = STOPPED
        return True, f'stopped gait {self.gait.name!r}; relaxing the modules'

    def pause(self, now: float) -> tuple[bool, str]:
        if self.state != RUNNING:
            return False, f'cannot pause: gait {self.gait.name!r} is {self.state}'
        self._paused_at = self.gait_time(now)
        self.state = PAUSED
        return True, f'paused gait {self.gait.name!r} at {self._paused_at:.3f} s'

    def resume(self, now: float) -> tuple[bool, str]:
        if self.state != PAUSED:
            return False, f'cannot resume: gait {self.gait.name!r} is {self.state}'
        self._t0 = now - self._paused_at
        self.state = RUNNING
        return True, f'resumed gait {self.gait.name!r}'

    def switch(self, gait: Gait, now: float) -> tuple[bool, str]:
        """Replace the gait; a running or paused gait restarts the new one from its start."""
        if gait.module_names != self.gait.module_names:
            return False, (f'gait {gait.name!r} drives modules {list(gait.module_names)}, '
                           f'not {list(self.gait.module_names)}')
        was = self.state
        self._begin_blend(now)
        self.gait = gait
        if was != STOPPED:
            self.state, self._t0, self.finished = RUNNING, now, False
        return True, f'switched to gait {gait.name!r} (period {gait.period_s:g} s, ' \
                     f'amplitude {gait.amplitude_mm:g} mm, {"running" if was != STOPPED else "stopped"})'

    def _begin_blend(self, now: float) -> None:
        # With transition_s = 0 the blend ends at the next tick (which still publishes).
        self._blend_from = self._last.copy()
        self._blend_start = now

    # ---------------------------------------------------------------------- output
    def tick(self, now: float) -> PlayerOutput:
        """Commands and phase at clock time `now`; call at the publishing rate."""
        if self.state == RUNNING and self.gait.finished(self.gait_time(now)):
            self.state, self.finished = STOPPED, True
            self._last = self.gait.contraction_mm(self.gait.period_s)
            self._blend_from = None
            return self._output(self._last, 1.0, 1)
        if self.state == STOPPED:
            target = self._last if self.finished else np.zeros_like(self._last)
            if self._blend_from is None:
                phase, cycle = (1.0, 1) if self.finished else (0.0, 0)
                return PlayerOutput(None, None, phase, cycle, STOPPED)
        else:
            target = self.gait.contraction_mm(self.gait_time(now))
        command = self._blend(target, now)
        self._last = command
        phase, cycle = self.gait.phase(self.gait_time(now))
        if self.state == STOPPED:
            phase, cycle = (1.0, 1) if self.finished else (0.0, 0)
        return self._output(command, phase, cycle)

    def _blend(self, target: np.ndarray, now: float) -> np.ndarray:
        if self._blend_from is None:
            return target
        s = (now - self._blend_start) / self.transition_s if self.transition_s > 0 else 1.0
        if s >= 1.0:
            self._blend_from = None
            return target
        w = 0.5 + 0.5 * math.cos(math.pi * max(s, 0.0))   # 1 -> 0, zero slope at both ends
        return w * self._blend_from + (1.0 - w) * target

    def _output(self, contraction: np.ndarray, phase: float, cycle: int) -> PlayerOutput:
        contraction = np.asarray(contraction, dtype=float)
        return PlayerOutput(contraction, self.gait.straight_length_mm - contraction,
                            float(phase), int(cycle), self.state)
