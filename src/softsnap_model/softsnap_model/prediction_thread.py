"""The model node's prediction thread: takes the length messages and predicts, woken by
the lengths (no executor)."""
from __future__ import annotations

import math
import threading
import time

from softsnap_ros.wait_loop import SubscriptionWaiter


#: After a length wakes the idle prediction thread, the fraction of a period it waits
#: for more (lengths published together are solved together).
GATHER_FRACTION = 0.5
#: Longest the idle prediction thread blocks without checking the context (s).
IDLE_WAIT_MAX_S = 1.0
#: While a long period runs, how often the length queues are taken (s): the queues then
#: never overflow below LENGTH_QUEUE_DEPTH / DRAIN_S messages a second.
DRAIN_S = 0.05


class PredictionThread:
    """Takes the length messages and predicts on a daemon thread, woken by the lengths.

    Why not an rclpy timer or executor subscriptions: every executor wake rebuilds the
    wait set over all of the node's entities in Python (0.5 ms against 0.04 ms for a
    whole idle tick, measured on the development machine), and rclpy's per-message
    dispatch (~0.2 ms) would dominate at 100 Hz. Why not a fixed tick: an idle node then
    still wakes ``rate`` times a second to find nothing.

    Two states:

    - idle: the thread blocks in one rcl wait set over the length subscriptions (and a
      guard condition for :meth:`stop` and :meth:`wake`), until a length arrives or the
      next chore is due (``chores()`` says when; at most ``IDLE_WAIT_MAX_S``). It takes
      only from the subscriptions the wait reports ready, then turns active with its
      next prediction ``GATHER_FRACTION`` of a period later (the mean delay of a fixed
      tick; lengths published together, such as a gait's five commands, are solved
      together), and at least a period after the last prediction.
    - active: predictions follow on a grid of ``period_s`` from there (in phase with the
      arrivals; at most one prediction per period, a late wake skips to the next
      boundary). Between two boundaries the thread sleeps without asking DDS: lengths
      wait in the subscriptions' queues (``LENGTH_QUEUE_DEPTH``) and are taken at the
      boundary from every subscription (ten takes that find nothing cost a third of one
      wait-set round, measured), and every ``DRAIN_S`` while a long period runs, so that
      no queue overflows below LENGTH_QUEUE_DEPTH / DRAIN_S messages a second. A boundary
      that finds nothing to solve turns the thread idle.

    ``on_length(index, data)`` gets every message of ``subscriptions[index]`` as bytes,
    oldest first; ``predict()`` solves what is pending and returns False if nothing was;
    ``chores()`` does what is due (markers) and returns the monotonic time (s) of the
    next. None of them may raise: ``on_error(exception)`` reports what escapes, and the
    loop goes on (never a dead thread). The thread ends on :meth:`stop` or when the
    context shuts down.
    """

    def __init__(self, name: str, period_s: float, context, subscriptions, msg_type, *,
                 on_length, predict, chores, on_error):
        self._period_s = float(period_s)
        self._context = context
        self._waiter = SubscriptionWaiter(context, subscriptions)
        self._count = len(subscriptions)
        self._msg_type = msg_type
        self._on_length, self._predict, self._chores = on_length, predict, chores
        self._on_error = on_error
        self._stop = threading.Event()
        self._wake = threading.Event()  # a new period or a stop, for the active state
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    @property
    def period_s(self) -> float:
        return self._period_s

    @period_s.setter
    def period_s(self, value: float) -> None:
        """A new period applies at once: a sleeping thread wakes and computes again."""
        self._period_s = float(value)
        self.wake()

    def wake(self) -> None:
        """Wake the thread to look again at the period and at when chores are due."""
        self._wake.set()
        self._waiter.wake()

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        last = time.monotonic()  # the boundary of the last prediction (the grid's origin)
        active = False
        drained = last           # when the queues were last taken while active
        while not self._stop.is_set():
            try:
                if not self._context.ok():
                    return  # shut down (SIGINT) before stop(): no chores, no spin until it
                due = self._chores()
                now = time.monotonic()
                if not active:
                    ready = self._waiter.wait(min(due - now, IDLE_WAIT_MAX_S))
                    if not ready:
                        continue  # a chore, the guard, the safety timeout or a shutdown
                    arrived = time.monotonic()
                    self._take(ready)
                    # Half a period after the first arrival (the mean delay of a fixed
                    # tick), and at least a period after the last prediction: lengths
                    # published together (a gait's five commands) are solved together.
                    period = self._period_s
                    last = max(last, arrived - period * (1.0 - GATHER_FRACTION))
                    active = True
                    continue
                period = self._period_s
                boundary = last + period  # read again after every wake: a new rate applies
                if now < boundary:
                    if now - drained >= DRAIN_S:
                        self._take(range(self._count))
                        drained = now
                    if self._wake.wait(min(boundary, due, drained + DRAIN_S) - now):
                        self._wake.clear()
                    continue
                self._take(range(self._count))
                drained = now
                if self._predict():
                    # On the grid (in phase with the lengths' arrivals); after a late
                    # wake, the next boundary of the grid (no catch-up predictions).
                    last = boundary + math.floor((now - boundary) / period) * period
                else:
                    active = False  # a whole period without a length
            except Exception as error:  # noqa: BLE001 - report and go on; never die silently
                if self._stop.is_set() or not self._context.ok():
                    return  # shutting down: the context or a handle is gone
                self._on_error(error)
                self._stop.wait(0.01)  # no busy loop if the error repeats

    def _take(self, indices) -> None:
        """Every waiting message of the given subscriptions, oldest first, to on_length.

        Taken as bytes: reading the two fields needed costs a quarter of building the
        message object (see :func:`softsnap_ros.cdr.decode_cable_length`).
        """
        msg_type, on_length, take_all = self._msg_type, self._on_length, self._waiter.take_all
        for index in indices:
            take_all(index, msg_type, on_length)

    def stop(self, timeout: float) -> bool:
        """Stop after the current prediction; True if the thread ended within timeout (s)."""
        self._stop.set()
        self.wake()
        if self._thread.is_alive():
            self._thread.join(timeout)
        if self._thread.is_alive():
            return False
        self._waiter.close()
        return True
