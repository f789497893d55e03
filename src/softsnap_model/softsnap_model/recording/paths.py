"""Entity paths and timelines of SoftSnap recordings (the tree:
:mod:`softsnap_model.recording`)."""
from __future__ import annotations

import functools



APPLICATION_ID = 'softsnap'

TIMELINE = 'ros_time'

STEP_TIMELINE = 'step'

ROBOT_ROOT = 'robot'

PLOTS_ROOT = 'plots'

SOURCES = ('commanded', 'predicted', 'simulated')


def module_path(module: str) -> str:
    """Entity carrying the base pose of ``module``: ``robot/<module>``."""
    _check_name(module)
    return f'{ROBOT_ROOT}/{module}'


@functools.lru_cache(maxsize=4096)  # called for every row: the paths are few
def shape_path(module: str, source: str, part: str) -> str:
    """Entity of one drawn part (spine, ribs, cable) of a module's shape."""
    if source not in SOURCES:
        raise ValueError(f'source must be one of {SOURCES}, got {source!r}')
    return f'{module_path(module)}/{source}/{part}'


@functools.lru_cache(maxsize=4096)
def plot_path(quantity: str, module: str, *series: str) -> str:
    """Entity of a time series: ``plots/<quantity>/<module>[/<series>]``.

    For example ``plot_path('cable_length_mm', 'red', 'measured')``.
    """
    _check_name(module)
    return '/'.join((PLOTS_ROOT, quantity, module, *series))


def _check_name(module: str) -> None:
    if not module or '/' in module or module.strip() != module:
        raise ValueError(f'module name must be a non-empty word without "/", got {module!r}')


LEGEND_ROOT = 'legend'
