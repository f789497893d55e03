"""The slot's port block (softsnap_gaits.isolation.Slot.free_port) outlasts a whole suite.

CI failed with "no 4 free consecutive ports left" once the suite needed more than one
block's worth of ports: ports handed out early, long closed, are handed out again.
"""
from __future__ import annotations

import dataclasses
import socket
from contextlib import ExitStack

import pytest

from softsnap_gaits.isolation import PORT_BLOCK, Slot


def _listen(stack: ExitStack, port: int) -> None:
    sock = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_STREAM))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(('127.0.0.1', port))
    sock.listen()


@pytest.fixture
def fresh_slot(slot_port) -> Slot:
    """A second view of this session's slot (its block is ours), from the block's start."""
    return dataclasses.replace(slot_port.__self__, _next_port=0)


def test_ports_are_handed_out_again_from_the_start_skipping_busy_ones(fresh_slot):
    block = fresh_slot.ports
    with ExitStack() as stack:
        _listen(stack, block[0])
        handed = [fresh_slot.free_port() for _ in range(PORT_BLOCK - 1)]
        assert handed == list(block[1:])
        # Used up: from the start again, past the port still listened on.
        assert fresh_slot.free_port() == block[1]
        assert fresh_slot.free_port(3) == block[2]


def test_a_block_with_no_free_run_of_ports_is_refused(fresh_slot):
    block = fresh_slot.ports
    with ExitStack() as stack:
        for port in block[::2]:
            _listen(stack, port)
        assert fresh_slot.free_port() == block[1]
        with pytest.raises(RuntimeError, match='no 2 free consecutive ports'):
            fresh_slot.free_port(2)
