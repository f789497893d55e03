"""Service and action queues sized for bursts, and a count of any request lost anyway.

ROS's default service QoS keeps the last 10 requests: 20 clients calling ``forward_shape``
at once got 11 answers and nothing was logged. Every service and action of the stack is
created here with a queue of :data:`SERVICE_QUEUE_DEPTH` requests (reliable, volatile),
and each answered request is checked against its client's previous one: the middleware
numbers a client's requests 1, 2, 3, ..., so a gap is requests that were overwritten in a
full queue before the node took them. Gaps are counted and logged with the count (a
warning, at most once per second with the total), never dropped silently. Requests
taken out of the order they arrived in (by the middleware's receive time) are counted
too.
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
    """Per client, the last request number answered; gaps are lost requests.

    ``seen(client, number, received_ns)`` for each answered request. Thread-safe.
    """

    def __init__(self, name: str, warn, clock=time.monotonic):
        self.name = name
        self._warn = warn
        self._clock = clock
        self._lock = threading.Lock()
        self._last: dict[bytes, int] = {}
        self.answered = 0
        self.lost = 0
        self.out_of_order = 0
        self._last_received_ns = 0
        self._warned_at = -float('inf')
        self._lost_at_warning = 0

    def seen(self, client: bytes, number: int, received_ns: int = 0) -> None:
        with self._lock:
            self.answered += 1
            previous = self._last.get(client)
            if previous is not None and number > previous + 1:
                self.lost += number - previous - 1
            if number > (previous or 0):
                self._last[client] = number
            if received_ns and received_ns < self._last_received_ns:
                self.out_of_order += 1
            self._last_received_ns = max(self._last_received_ns, received_ns)
            due = (self.lost > self._lost_at_warning
                   and self._clock() - self._warned_at >= WARN_PERIOD_S)
            if due:
                self._warned_at, self._lost_at_warning = self._clock(), self.lost
                lost, answered = self.lost, self.answered
        if due:
            self._warn(f'{self.name}: {lost} request(s) lost so far (the queue of '
                       f'{SERVICE_QUEUE_DEPTH} was full before they were taken); '
                       f'{answered} answered')


def _header_key(header) -> tuple[bytes, int, int] | None:
    """(client id, request number, receive time ns) of a taken request's header."""
    try:
        request_id = header.request_id
        return (bytes(request_id.writer_guid), int(request_id.sequence_number),
                int(getattr(header, 'received_timestamp', 0) or 0))
    except (AttributeError, TypeError, ValueError):
        return None


def track_requests(service, name: str, warn) -> RequestLedger:
    """Count `service`'s answered, lost and reordered requests (see RequestLedger)."""
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
