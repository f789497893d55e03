"""A private ROS domain id and private loopback ports per demo or test session (no ROS).

Two demos (or a demo and the test suite) on one machine used to share the default domain
and the scenes' fixed simulated ports: the second one's modules could not bind, and its
observer saw the first robot's topics. Each run now claims a *slot* 1..101:

- the slot is an exclusive ``flock`` on ``<tmp>/softsnap-slot-<N>.lock``, held as long as
  the claiming process (or any child it passes the descriptor to) lives; the kernel drops
  it when they exit, even on SIGKILL, so a crashed run leaves no stale claim;
- the slot number is the ROS domain id unless ``ROS_DOMAIN_ID`` is set (1..101 are valid
  domain ids for Fast DDS on Linux; 0 is left to the user's own nodes);
- the slot owns the TCP port block ``PORT_BASE + N * PORT_BLOCK`` (20100-30199), below
  Linux's ephemeral range (32768-60999), so no outgoing connection takes one of these
  ports between the check and the bind; each port is still checked free before use.

Slots are tried in a random order, so concurrent claimers rarely contend, and a taken
lock is skipped without waiting: two runs can never get the same slot.
"""
from __future__ import annotations

import dataclasses
import fcntl
import os
import random
import socket
import tempfile
from pathlib import Path

__all__ = ['Slot', 'claim_slot', 'SLOTS', 'PORT_BASE', 'PORT_BLOCK']

SLOTS = range(1, 102)  # usable ROS domain ids (0 is the default everyone else uses)
PORT_BASE = 20000
PORT_BLOCK = 100       # TCP ports per slot


@dataclasses.dataclass
class Slot:
    """A claimed slot: its number, the domain id to use and its lock file descriptor."""

    number: int
    domain_id: int
    lock_fd: int
    _next_port: int = 0

    @property
    def ports(self) -> range:
        start = PORT_BASE + self.number * PORT_BLOCK
        return range(start, start + PORT_BLOCK)

    def free_port(self, count: int = 1, host: str = '127.0.0.1') -> int:
        """The first of `count` consecutive ports of this slot's block, none listened on.

        Ports are handed out in block order; once the block is used up, again from its
        start (a whole test suite needs more than PORT_BLOCK ports, and the ones handed
        out first are long closed by then), skipping those still listened on.
        RuntimeError if one lap over the block finds no `count` free ports in a row.
        """
        laps = 0
        while laps < 2:
            if self._next_port + count > PORT_BLOCK:
                self._next_port = 0
                laps += 1
                continue
            first = self._next_port
            taken = [i for i in range(first, first + count) if not port_is_free(self.ports[i], host)]
            self._next_port = (taken[-1] + 1) if taken else first + count
            if not taken:
                return self.ports[first]
        raise RuntimeError(f'no {count} free consecutive ports in '
                           f'{self.ports.start}-{self.ports.stop - 1}')

    def release(self) -> None:
        try:
            os.close(self.lock_fd)
        except OSError:
            pass


def port_is_free(port: int, host: str = '127.0.0.1') -> bool:
    """Whether a TCP listener could bind `host`:`port` now (the way SimServer binds)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError:
            return False
    return True


def _lock_path(number: int) -> Path:
    return Path(tempfile.gettempdir()) / f'softsnap-slot-{number}.lock'


def _try_lock(number: int) -> int | None:
    try:
        fd = os.open(_lock_path(number), os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        return None  # another user's file, unreadable: treat as taken
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def claim_slot(environ: dict[str, str] | None = None) -> tuple[Slot, str | None]:
    """Claim a free slot; returns it and a warning (or None).

    With ``ROS_DOMAIN_ID`` set in `environ` (default ``os.environ``) that id is kept as
    the domain, and its own slot is claimed when free so that other runs avoid it; when
    another run holds it, the warning says so and the ports come from another slot.
    """
    environ = os.environ if environ is None else environ
    wanted = environ.get('ROS_DOMAIN_ID', '').strip()
    warning = None
    if wanted:
        if not wanted.isdigit():
            raise ValueError(f'ROS_DOMAIN_ID must be a whole number, got {wanted!r}')
        domain = int(wanted)
        if domain in SLOTS:
            fd = _try_lock(domain)
            if fd is not None:
                return Slot(domain, domain, fd), None
            warning = (f'ROS_DOMAIN_ID={domain} is in use by another SoftSnap demo or test '
                       'on this machine: their topics will mix')
    order = list(SLOTS)
    random.SystemRandom().shuffle(order)
    for number in order:
        fd = _try_lock(number)
        if fd is not None:
            return Slot(number, int(wanted) if wanted else number, fd), warning
    raise RuntimeError(f'all {len(SLOTS)} SoftSnap slots (ROS domain ids) on this machine are '
                       f'in use ({_lock_path(SLOTS[0]).parent}/softsnap-slot-*.lock)')
