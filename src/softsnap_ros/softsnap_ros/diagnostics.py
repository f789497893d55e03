"""Helpers for ``diagnostic_msgs`` shared by every node that reports its health."""
from __future__ import annotations

from diagnostic_msgs.msg import KeyValue

__all__ = ['key_values']


def key_values(values: dict) -> list[KeyValue]:
    """DiagnosticStatus values from a dict: floats to 6 significant digits, the rest str()."""
    out = []
    for key, value in values.items():
        if isinstance(value, float):
            value = f'{value:.6g}'
        out.append(KeyValue(key=key, value=str(value)))
    return out
