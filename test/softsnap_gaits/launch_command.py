"""The command line ``launch_ros.actions.Node`` builds, for tests (launch is not on PyPI).

Reproduces launch_ros (branch ``jazzy``, ``launch_ros/actions/node.py``) for the keyword
arguments of :func:`softsnap_gaits.launching.node_action_kwargs` (package, executable,
name, namespace, a list of parameters: one dict, then for a driver_container the path of
its drivers' parameters file):

- ``Node.__init__``: ``[<lib>/<package>/<executable>, '--ros-args', '-r', '__node:=NAME']``
  (``ExecutableInPackage`` resolves to ``<prefix>/lib/<package>/<executable>``);
- ``Node._perform_substitutions``: then ``'-r', '__ns:=/NS'`` (the namespace made
  absolute), then per parameters dict ``'--params-file', FILE``;
- ``Node._create_params_file_from_dict``: FILE is a ``NamedTemporaryFile(mode='w',
  prefix='launch_params_', delete=False)`` holding ``yaml.dump({'/NS/NAME':
  {'ros__parameters': params}}, default_flow_style=False)``; the key is the fully
  qualified node name (``/**`` only when name or namespace is unspecified);
- ``normalize_parameter_dict`` + ``evaluate_parameter_dict``: nested dicts flatten to
  dotted names; int, float and bool values stay as they are, a str goes through
  ``yaml.safe_load(yaml.dump(value))`` (so it stays the same str).

Not reproduced: list values (none in our graph; refused here), ``emulate_tty`` (a pty
for stdout; our tests read logs from files) and launch's global remaps/parameters
(``PushRosNamespace``, ``SetParameter``: the launch files use none).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import yaml


def _flatten(params: dict, prefix: str = '') -> dict:
    flat = {}
    for key, value in params.items():
        name = f'{prefix}.{key}' if prefix else str(key)
        if isinstance(value, dict):
            flat.update(_flatten(value, name))
        elif isinstance(value, str):
            flat[name] = yaml.safe_load(yaml.dump(value))
        elif isinstance(value, (bool, int, float)):
            flat[name] = value
        else:
            raise TypeError(f'{name}: {type(value).__name__} values are not reproduced here')
    return flat


def launch_ros_command(kwargs: dict, package_prefix: Path, params_dir: Path) -> list[str]:
    """argv launch_ros would run for ``Node(**kwargs)``; params files go to `params_dir`."""
    package, executable = kwargs['package'], kwargs['executable']
    name, namespace = kwargs['name'], kwargs['namespace']
    namespace = namespace if namespace.startswith('/') else '/' + namespace
    cmd = [str(package_prefix / 'lib' / package / executable), '--ros-args',
           '-r', f'__node:={name}', '-r', f'__ns:={namespace}']
    fqn = f'{namespace.rstrip("/")}/{name}'
    for params in kwargs.get('parameters') or []:
        if isinstance(params, Path):
            cmd += ['--params-file', str(params)]
            continue
        with tempfile.NamedTemporaryFile(mode='w', prefix='launch_params_', delete=False,
                                         dir=params_dir) as h:
            yaml.dump({fqn: {'ros__parameters': _flatten(params)}}, h, default_flow_style=False)
        cmd += ['--params-file', h.name]
    return cmd
