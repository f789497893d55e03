"""``softsnap-model`` command line: forward solves and sweeps with JSON output.

Examples::

    softsnap-model forward --threading "R3 R3 R3 R3 R3 R3 L3 L3 L3 L3 L3 L3" --length 150
    softsnap-model forward --threading R1,R1,R1,R1,R1,R1,R1,R1,R2,R2,R3,R3 --contraction 40
    softsnap-model sweep --threading "R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3" --stop 80 --steps 81
    softsnap-model range --threading "R3 L3 R3 L3 R3 L3 R3 L3 R3 L3 R3 L3"
    softsnap-model calibrate --data docs/examples/calibration_example.yaml
    softsnap-model physics --scene gripper --record physics.rrd     (needs mujoco)

Errors are printed as JSON ``{"error": ..., "reachable_range_mm": ...}`` on stderr with
exit status 2.

Adding a subcommand (e.g. ``inverse``)
--------------------------------------
Define in your module a function ``add_cli(subparsers)`` that calls
``subparsers.add_parser(name, help=...)``, adds its arguments and sets
``parser.set_defaults(handler=fn)``, where ``fn(args, skeleton) -> dict`` returns the
JSON-serialisable answer (raise ``ValueError`` for bad input). Then list the module in
:data:`PLUGINS` below as ``'softsnap_model.<module>:add_cli'``. Plugins are imported
lazily; one that fails to import does not break the other subcommands.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys

import numpy as np

#: Subcommands contributed by other modules, ``'package.module:function'``.
PLUGINS: list[str] = ['softsnap_model.inverse:add_cli', 'softsnap_model.recording:add_cli',
                       'softsnap_model.calibration:add_cli', 'softsnap_model.physics.cli:add_cli']


def parse_threading(text: str) -> list:
    """Threading text -> list of hole names and/or offsets in mm, one per rib.

    ``"R3 R3 L3"``, ``"10,10,-10"``, and repeats ``"R3x6 L3x6"`` (a hole name followed by
    ``x`` and a count) are accepted; names are checked later against the skeleton.
    """
    out = []
    for tok in text.replace(',', ' ').split():
        try:
            out.append(float(tok))
            continue
        except ValueError:
            pass
        name, sep, count = tok.rpartition('x') if 'x' in tok.lower() else (tok, '', '')
        if sep and count.isdigit() and name:
            out += [name.upper()] * int(count)
        else:
            out.append(tok)
    return out


def _load_skeleton(path):
    from .skeleton import Skeleton
    return Skeleton() if path is None else Skeleton.from_yaml(path)


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


def _forward_dict(res) -> dict:
    keys = ['angles', 'rib_centers', 'cable_path', 'energy', 'tension', 'iterations',
            'converged', 'residual', 'constraint_residual', 'stationarity_residual',
            'is_minimum', 'min_curvature', 'slack', 'at_contact', 'cable_length_mm',
            'message']
    out = {key: _jsonable(getattr(res, key)) for key in keys if hasattr(res, key)}
    # Units in the JSON names; the raw field names stay for scripting symmetry.
    out['angles_rad'] = out.pop('angles')
    out['rib_centers_mm'] = out.pop('rib_centers')
    out['cable_path_mm'] = out.pop('cable_path')
    return out


def _cmd_forward(args, skeleton) -> dict:
    from .forward import reachable_range, solve_forward
    threading = parse_threading(args.threading)
    if (args.length is None) == (args.contraction is None):
        raise ValueError('give exactly one of --length and --contraction')
    length = args.length
    if length is None:
        length = skeleton.straight_length_mm(threading) - args.contraction
    res = solve_forward(skeleton, threading, length)
    out = _forward_dict(res)
    out['threading'] = threading
    out['reachable_range_mm'] = list(reachable_range(skeleton, threading))
    return out


def _cmd_sweep(args, skeleton) -> dict:
    from .forward import sweep
    threading = parse_threading(args.threading)
    if args.contractions is not None:
        c = np.array([float(v) for v in args.contractions.replace(',', ' ').split()])
    else:
        if args.steps < 1:
            raise ValueError(f'--steps must be >= 1, got {args.steps}')
        c = np.linspace(args.start, args.stop, args.steps)
    res = sweep(skeleton, threading, c)
    keys = ['angles', 'tension', 'energy', 'iterations', 'converged', 'residual', 'slack',
            'cable_length_mm', 'contractions_mm']
    out = {key: _jsonable(getattr(res, key)) for key in keys}
    out['angles_rad'] = out.pop('angles')
    if args.shapes:
        out['rib_centers_mm'] = res.rib_centers.tolist()
        out['cable_path_mm'] = res.cable_path.tolist()
    out['threading'] = threading
    return out


def _cmd_range(args, skeleton) -> dict:
    from .forward import reachable_range
    threading = parse_threading(args.threading)
    lo, hi = reachable_range(skeleton, threading)
    return {'threading': threading, 'reachable_range_mm': [lo, hi],
            'max_contraction_mm': hi - lo}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='softsnap-model',
        description='Quasi-static SoftSnap module model (JSON output on stdout).')
    parser.add_argument('--skeleton', metavar='YAML',
                        help='skeleton description (default: the authors\' 12-rib module)')
    parser.add_argument('--indent', type=int, default=None, help='pretty-print JSON')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    p = sub.add_parser('forward', help='shape for one cable length')
    p.add_argument('--threading', required=True,
                   help='one hole per rib, names or offsets mm, space or comma separated')
    p.add_argument('--length', type=float, help='cable length (mm)')
    p.add_argument('--contraction', type=float, help='shortening from straight (mm)')
    p.set_defaults(handler=_cmd_forward)

    p = sub.add_parser('sweep', help='follow a contraction range')
    p.add_argument('--threading', required=True)
    p.add_argument('--start', type=float, default=0.0, help='first contraction (mm)')
    p.add_argument('--stop', type=float, default=80.0, help='last contraction (mm)')
    p.add_argument('--steps', type=int, default=81, help='number of contractions')
    p.add_argument('--contractions', help='explicit list of contractions (mm)')
    p.add_argument('--shapes', action='store_true', help='include rib centres and holes')
    p.set_defaults(handler=_cmd_sweep)

    p = sub.add_parser('range', help='reachable cable-length range of a threading')
    p.add_argument('--threading', required=True)
    p.set_defaults(handler=_cmd_range)

    for spec in PLUGINS:
        module, _, func = spec.partition(':')
        try:
            add = getattr(importlib.import_module(module), func)
        except (ImportError, AttributeError):
            continue
        add(sub)
    return parser


def main(argv=None) -> int:
    """Console entry point ``softsnap-model``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        skeleton = _load_skeleton(args.skeleton)
        out = args.handler(args, skeleton)
    except (ValueError, OSError) as exc:
        err = {'error': str(exc), 'type': type(exc).__name__}
        if hasattr(exc, 'reachable_range_mm'):
            err['reachable_range_mm'] = list(exc.reachable_range_mm)
        print(json.dumps(err), file=sys.stderr)
        return 2
    print(json.dumps(out, indent=args.indent, allow_nan=False))
    return 0


if __name__ == '__main__':
    sys.exit(main())
