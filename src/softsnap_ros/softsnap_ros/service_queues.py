"""Service and action queues sized for bursts, and a count of any request lost anyway.

ROS's default service QoS keeps the last 10 requests: 20 clients calling ``forward_shape``
at once got 11 answers and nothing was logged. Every service and action of the stack is
created here with a queue of :data:`SERVICE_QUEUE_DEPTH` requests (reliable, volatile).
Each answered request is entered in a :class:`RequestLedger`: the middleware numbers a
client's requests 1, 2, 3, ..., so missing numbers are requests overwritten in a full
queue before the node took them (exact per client where the middleware names the client,
a lower bound where it gives only the number). Lost requests are logged with the count
(a warning, at most once per second with the total), never dropped silently. Requests
taken out of the order they arrived in (the middleware's receive time) are counted too.
"""
from __future__ import annotations

import threading
import time

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Requests a service (or an action's goal, result and cancel services) queues before the
#: oldest unanswered one is overwritten. 1000 is 10 s of 100 calls per second arriving
#: while the node is busy, at a few hundred bytes each.
SERVICE_QUEUE_DEPTH = 1000
#: Lost-request warnings are logged at most once per this period (s), with the total.
WARN_PERIOD_S = 1.0


def service_qos(depth: int = SERVICE_QUEUE_DEPTH) -> QoSProfile:
    """ROS's service QoS (reliable, volatile) with a queue of `depth` requests."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def action_qos_kwargs(depth: int = SERVICE_QUEUE_DEPTH) -> dict:
    """Keyword arguments of ``rclpy.action.ActionServer``: deep goal, result and cancel
    queues (feedback and status keep their defaults)."""
    return {'goal_service_qos_profile': service_qos(depth),
            'result_service_qos_profile': service_qos(depth),
            'cancel_service_qos_profile': service_qos(depth)}


class RequestLedger:
    """Answered, lost and reordered requests of one service. Thread-safe.

    ``seen(client, number, received_ns)`` for each answered request. With the client's
    id (a middleware that gives the request writer's GUID), a gap in one client's
    numbers is exactly the requests of that client that were lost. Without it (rclpy 7,
    Jazzy, gives only the number), the count is a lower bound: every client numbers its
    requests 1, 2, 3, ..., so if s_k answered requests carried number k, at least
    max(s_j, j >= k) clients sent a number k, and the difference was lost. One client's
    gaps are then still exact; a lost lone request of a client leaves no trace. Numbers
    above MAX_TRACKED_NUMBER are not tracked (memory).
    """

    MAX_TRACKED_NUMBER = 100_000

    def __init__(self, name: str, warn, clock=time.monotonic):
        self.name = name
        self._warn = warn
        self._clock = clock
        self._lock = threading.Lock()
        self._last: dict[bytes, int] = {}
        self._by_number: dict[int, int] = {}
        self._exact_lost = 0
        self.answered = 0
        self.out_of_order = 0
        self._last_received_ns = 0
        self._warned_at = -float('inf')
        self._lost_at_warning = 0

    @property
    def lost(self) -> int:
        """Requests known to be lost."""
        with self._lock:
            return self._exact_lost + self._bound()

    def _bound(self) -> int:
        lost, running_max = 0, 0
        for k in range(max(self._by_number, default=0), 0, -1):
            count = self._by_number.get(k, 0)
            running_max = max(running_max, count)
            lost += running_max - count
        return lost

    def seen(self, client: bytes | None, number: int, received_ns: int = 0) -> None:
        with self._lock:
            self.answered += 1
            if client is not None:
                previous = self._last.get(client)
                if previous is not None and number > previous + 1:
                    self._exact_lost += number - previous - 1
                if number > (previous or 0):
                    self._last[client] = number
            elif 0 < number <= self.MAX_TRACKED_NUMBER:
                self._by_number[number] = self._by_number.get(number, 0) + 1
            if received_ns and received_ns < self._last_received_ns:
                self.out_of_order += 1
            self._last_received_ns = max(self._last_received_ns, received_ns)
            due = self._clock() - self._warned_at >= WARN_PERIOD_S
            lost = self._exact_lost + self._bound() if due else 0
            due = due and lost > self._lost_at_warning
            if due:
                self._warned_at, self._lost_at_warning = self._clock(), lost
            answered = self.answered
        if due:
            self._warn(f'{self.name}: {lost} request(s) lost so far (its queue was full '
                       f'before they were taken); {answered} answered')


def _header_key(header) -> tuple[bytes | None, int, int] | None:
    """(client id or None, request number, receive time ns) of a taken request's header."""
    try:
        request_id = header.request_id
        guid = getattr(request_id, 'writer_guid', None)
        return (None if guid is None else bytes(guid), int(request_id.sequence_number),
                int(getattr(header, 'received_timestamp', 0) or 0))
    except (AttributeError, TypeError, ValueError):
        return None


def track_requests(service, name: str, warn) -> RequestLedger:
    """Enter `service`'s answered requests in a RequestLedger (``service.ledger``)."""
    ledger = RequestLedger(name, warn)
    send = service.send_response

    def send_response(response, header):
        key = _header_key(header)
        if key is not None:
            ledger.seen(*key)
        return send(response, header)

    service.send_response = send_response
    service.ledger = ledger
    return ledger


def create_queued_service(node, srv_type, name: str, callback, *,
                          depth: int = SERVICE_QUEUE_DEPTH, **kwargs):
    """``node.create_service`` with a queue of `depth` requests and a ledger of lost ones
    (``service.ledger``)."""
    service = node.create_service(srv_type, name, callback, qos_profile=service_qos(depth),
                                  **kwargs)
    track_requests(service, service.srv_name, node.get_logger().warning)
    return service
