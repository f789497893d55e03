"""Benchmark scripts that tests exercise, loaded from their files.

The scripts in benchmarks/ are run as ``python benchmarks/<name>.py``, not installed: a
test loads one by its path (no ``sys.path`` change that would let any test import any
script by accident). A script loaded here must import only installed packages.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / 'benchmarks'


def load(name: str) -> ModuleType:
    """The module of ``benchmarks/<name>.py`` (loaded once per test process)."""
    key = f'benchmarks.{name}'
    module = sys.modules.get(key)
    if module is None:
        spec = importlib.util.spec_from_file_location(key, BENCHMARKS / f'{name}.py')
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module   # dataclasses look their module up while it executes
        spec.loader.exec_module(module)
    return module
