"""Unit constants and ROS stamp conversions: the one definition of each.

The cores work in mm (the CAD's unit, FACTS.md); every ROS interface is SI (REP 103):
m, rad, s. Stamps are ``builtin_interfaces/Time`` (sec, nanosec) on the wire and integer
ns inside the nodes (one int: ordered, exact, cheap to compare).
"""
from __future__ import annotations

#: Millimetres per metre: core lengths (mm) = interface lengths (m) * MM_PER_M.
MM_PER_M = 1000.0
#: Nanoseconds per second.
NS_PER_S = 1_000_000_000
#: The largest ``sec`` a ``builtin_interfaces/Time`` holds (int32).
TIME_SEC_MAX = 2**31 - 1


def stamp_ns(stamp) -> int:
    """A ``builtin_interfaces/Time`` (anything with ``sec`` and ``nanosec``) in ns."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def sec_nanosec(time_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a time in ns: the fields of a ``builtin_interfaces/Time``,
    nanosec < 1e9.

    A time past the last representable second is held there: a command's stamp is echoed
    back in ``ModuleState``, and a sender's header with ``nanosec`` >= 1e9 near the end of
    int32 seconds would not fit once normalised (every state message would then fail to
    publish).
    """
    sec, nanosec = divmod(int(time_ns), NS_PER_S)
    if sec > TIME_SEC_MAX:
        return TIME_SEC_MAX, NS_PER_S - 1
    return sec, nanosec
