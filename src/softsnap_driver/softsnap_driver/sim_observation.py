"""What sim_robot's node samples of the running simulation besides its snapshots.

No rclpy here (the node, :mod:`softsnap_driver.sim_robot_node`, translates to messages).

Samples are taken **in the simulation thread**, on the ``/clock`` ticks
(:attr:`SimRobot.clock_listener <softsnap_driver.sim_robot.SimRobot.clock_listener>`),
right after the step that reached the tick: the physics is between two steps, so the
state read is one instant of the simulation, stamped with the physics' own time
(``simulation.time_s``). Reading costs a vectorised pass over the rib bodies
(``module_states``, tens of microseconds); building and publishing messages happens in
an :class:`ObservationWorker` thread, so the physics never waits for ROS.

Rates are counted on the tick grid by :class:`TickSchedule`: a schedule fires on the
first tick at or after each multiple of its period. Two schedules whose rates divide
each other fire on the same ticks (the 15 Hz camera on every other 30 Hz ground-truth
sample), so every camera frame has a ground truth with the same stamp.
"""
from __future__ import annotations

import math
import queue
import threading
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

#: Default rate of the ground-truth shapes (``<module>/shape/ground_truth``), Hz of
#: simulated time: the snapshot rate, and twice the camera's default 15 Hz (each camera
#: frame then has a ground truth of its own instant).
DEFAULT_GROUND_TRUTH_RATE_HZ = 30.0
#: Slack of :meth:`TickSchedule.due`, in periods: the tick times (multiples of the clock
#: period) carry rounding errors of ~1e-16 periods; 1e-6 keeps schedules with dividing
#: rates on the same ticks.
_TICK_SLACK = 1e-6
#: How long stop() waits for a worker thread, s.
_JOIN_S = 5.0


class TickSchedule:
    """Fires on the first tick at or after each multiple of ``1 / rate_hz`` (s)."""

    def __init__(self, rate_hz: float):
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f'rate must be positive and finite, got {rate_hz!r} Hz')
        self.rate_hz = float(rate_hz)
        self._index = -1     # periods fired so far (-1: none yet; t = 0 is period 0)

    def due(self, time_s: float) -> bool:
        """True (once) when `time_s` has reached the next period boundary."""
        index = math.floor(time_s * self.rate_hz + _TICK_SLACK)
        if index <= self._index:
            return False
        self._index = index
        return True


@dataclass(frozen=True)
class GroundTruthSample:
    """Every module's simulated rib centres at one simulation instant.

    ``rib_centers_m``: shape (n_modules, n_ribs, 3), each module's rib body origins in its
    base frame (rib 0 at 0, the straight module along +x), m, in ``names`` order;
    ``cable_lengths_m``: each winch's cable length (the tendon's length limit), m.
    """

    time_s: float
    names: tuple[str, ...]
    rib_centers_m: np.ndarray
    cable_lengths_m: tuple[float, ...]


def sample_ground_truth(simulation, names: tuple[str, ...]) -> GroundTruthSample:
    """The simulation's rib centres now (call from the simulation thread only).

    ``mj_step`` leaves the body positions of its step's start (it integrates ``qpos``
    after computing them): the positions are brought up to the ``qpos`` of
    ``simulation.time_s`` first (``mj_kinematics``, ~20 us; the next step recomputes
    them from ``qpos`` anyway), so the sample, and a camera frame rendered from that
    ``qpos`` at the same tick, show the same instant (a settling leg's tip moves ~0.1 mm
    in one 3 ms step).
    """
    import mujoco
    mujoco.mj_kinematics(simulation.model, simulation.data)
    centers, _angles, _positions, _orientations = simulation.module_states()
    order = [tuple(simulation.module_names).index(n) for n in names]
    return GroundTruthSample(time_s=float(simulation.time_s), names=tuple(names),
                             rib_centers_m=centers[order],
                             cable_lengths_m=tuple(simulation.cable_length(n) for n in names))


class ObservationWorker:
    """A thread that hands each offered item to ``handle(item)``, in order.

    :meth:`offer` never blocks (the simulation thread calls it): when ``depth`` items are
    already waiting the new one is dropped and counted in :attr:`dropped`. An exception in
    ``handle`` is passed to ``failed(item, exc)`` and the thread goes on with the next
    item, never dying silently.
    """

    def __init__(self, name: str, handle: Callable[[Any], None],
                 failed: Callable[[Any, BaseException], None], depth: int = 16):
        self.handle = handle
        self.failed = failed
        self.dropped = 0
        self.handled = 0
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = object()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def offer(self, item) -> bool:
        """Queue `item` for the thread; False (and counted) if the queue is full."""
        try:
            self._queue.put_nowait(item)
            return True
        except queue.Full:
            self.dropped += 1
            return False

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is self._stop:
                return
            try:
                self.handle(item)
                self.handled += 1
            except Exception as exc:  # noqa: BLE001 - reported, and the thread goes on
                self.failed(item, exc)

    def stop(self) -> None:
        """Finish the queued items, then end the thread (waits up to 5 s)."""
        while True:
            try:
                self._queue.put(self._stop, timeout=0.1)
                break
            except queue.Full:
                if not self._thread.is_alive():
                    return
        self._thread.join(_JOIN_S)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()
