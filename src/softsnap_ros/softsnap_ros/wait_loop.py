"""The one wait on raw subscriptions outside an executor: :class:`SubscriptionWaiter`.

Why not an executor: every executor wake rebuilds its wait set over all of the node's
entities in Python (0.5 ms against 0.04 ms for a whole idle tick of the model node,
measured on the development machine), and rclpy's per-message dispatch (~0.2 ms) would
dominate at 50-100 Hz. The driver's command inbox and the model's prediction thread
instead block in one rcl wait set over their subscriptions and a guard condition, and
take the messages as bytes (read by :mod:`softsnap_ros.cdr`).

The waiter is the only user of rclpy's private C binding in the project; the loops
around it (when to wait, how much to take) stay with their nodes. Thread use: one
thread waits and takes; any thread may :meth:`wake` it or replace the subscriptions.
"""
from __future__ import annotations

import contextlib
import threading

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

__all__ = ['SubscriptionWaiter']


class SubscriptionWaiter:
    """Blocks until one of some subscriptions has a message or :meth:`wake` is called.

    Parameters
    ----------
    context : rclpy.context.Context
        The context of the subscriptions' node.
    subscriptions : sequence of rclpy.subscription.Subscription
        Waited on in this order: :meth:`wait` returns indices into it.
    """

    def __init__(self, context, subscriptions=()):
        self._context = context
        self._guard = _rclpy.GuardCondition(context.handle)
        self._lock = threading.Lock()  # guards _next
        self._next: tuple | None = None
        self._handles: tuple = ()
        self._index: dict[int, int] = {}
        self._wait_set = None
        self._adopt(tuple(subscription.handle for subscription in subscriptions))

    def set_subscriptions(self, subscriptions, wake: bool = True) -> None:
        """Wait on these from the next :meth:`wait`; ``wake``: end a wait in progress
        (not needed when the waiting thread itself calls this)."""
        handles = tuple(subscription.handle for subscription in subscriptions)
        with self._lock:
            self._next = handles
        if wake:
            self.wake()

    @property
    def count(self) -> int:
        """How many subscriptions the next wait is over."""
        with self._lock:
            return len(self._next if self._next is not None else self._handles)

    def _adopt(self, handles: tuple) -> None:
        # Built aside and adopted only when complete: a build that raises is tried again
        # at the next wait, never half applied.
        wait_set = (_rclpy.WaitSet(len(handles), 1, 0, 0, 0, 0, self._context.handle)
                    if handles else None)
        old = self._wait_set
        self._handles, self._wait_set = handles, wait_set
        self._index = {handle.pointer: i for i, handle in enumerate(handles)}
        if old is not None:
            old.destroy_when_not_in_use()

    def wake(self) -> None:
        """End the current (or the next) wait at once."""
        try:
            self._guard.trigger_guard_condition()
        except Exception:  # noqa: BLE001 - the context is gone: the wait ends by itself
            pass

    def wait(self, timeout_s: float) -> list[int]:
        """Block until a subscription is ready, :meth:`wake` or ``timeout_s`` (s);
        the indices of the ready subscriptions (empty after a wake or a timeout)."""
        with self._lock:
            handles, self._next = self._next, None
        if handles is not None:
            self._adopt(handles)
        timeout_ns = max(0, int(timeout_s * 1e9))
        with contextlib.ExitStack() as held:  # none may be destroyed while waited on
            for handle in self._handles:
                held.enter_context(handle)
            held.enter_context(self._guard)
            wait_set = self._wait_set
            if wait_set is None:  # nothing to wait on: only a wake ends the wait
                wait_set = _rclpy.WaitSet(0, 1, 0, 0, 0, 0, self._context.handle)
                held.callback(wait_set.destroy_when_not_in_use)
            held.enter_context(wait_set)
            # rcl_wait empties the slots of entities that are not ready: refill every time.
            wait_set.clear_entities()
            for handle in self._handles:
                wait_set.add_subscription(handle)
            wait_set.add_guard_condition(self._guard)
            wait_set.wait(timeout_ns)
            index = self._index
            return [index[p] for p in wait_set.get_ready_entities('subscription')]

    def take(self, index: int, msg_type) -> bytes | None:
        """The oldest waiting message of subscription ``index`` as bytes, or None."""
        handle = self._handles[index]
        with handle:
            taken = handle.take_message(msg_type, True)
        return None if taken is None else taken[0]

    def take_all(self, index: int, msg_type, on_bytes) -> None:
        """Every waiting message of subscription ``index``, oldest first, to on_bytes."""
        handle = self._handles[index]
        with handle:
            while (taken := handle.take_message(msg_type, True)) is not None:
                on_bytes(index, taken[0])

    def close(self) -> None:
        """Release the wait set and the guard (both hold the rcl context: left alive they
        would keep it from being finalised). Call once the waiting thread has ended."""
        for entity in (self._wait_set, self._guard):
            if entity is not None:
                entity.destroy_when_not_in_use()
