"""Reference threadings of the SoftSnap paper (FACTS.md, authors' notebooks), rib 0 first.

Shared by the tests and the benchmarks as known problems; each value is a tuple of hole
names of the authors' module, one per rib.
"""
from __future__ import annotations

__all__ = ['PAPER_THREADINGS', 'BRITTLE_STAR_MODULES']


def _holes(text: str) -> tuple[str, ...]:
    return tuple(text.split())


#: Threadings used on the paper's robots and in its tests.
PAPER_THREADINGS: dict[str, tuple[str, ...]] = {
    'yellow': _holes('R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'),
    'blue': _holes('R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2'),
    'green': _holes('R1 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3'),
    'red': _holes('R3 R3 R3 R3 R3 R2 R1 L3 L3 L3 L3 L3'),
    'orange': _holes('R3 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3'),
    'gripper': _holes('R1 R2 R2 L1 L3 L3 L3 L3 L3 L3 L3 L3'),
    'snake': _holes('R2 R3 R3 R3 L3 L3 L3 L3 R3 R3 R3 R3'),
    's': _holes('R3 R3 R3 R3 R3 R3 L3 L3 L3 L3 L3 L3'),
    'w': _holes('R3 R3 R3 R3 L2 L3 L2 R3 R3 R3 R3 R3'),
}

#: The five modules of the starfish and brittle star, in scene order.
BRITTLE_STAR_MODULES = ('yellow', 'blue', 'green', 'red', 'orange')
