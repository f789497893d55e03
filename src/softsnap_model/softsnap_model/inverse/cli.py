"""``softsnap-model inverse``: the command line of the threading design."""
from __future__ import annotations

from .design import design_threading
from .results import result_to_dict
from .search import GLOBAL_TOL_RAD


def add_cli(subparsers):
    """Register ``softsnap-model inverse`` (see :mod:`softsnap_model.cli`)."""
    parser = subparsers.add_parser(
        'inverse', help='globally best threading and cable length for a target shape')
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument('--angles', help='target angle per segment, rad ("a0 a1 ..." or '
                        'comma separated)')
    target.add_argument('--points', help='JSON file with the target polyline [[x, y], ...] '
                        'in mm, base frame, starting at the origin')
    parser.add_argument('--k', type=int, default=3, help='ranked alternatives (default 3)')
    parser.add_argument('--fixed', action='append', default=[],
                        help='RIB:HOLE, e.g. 0:R1 (repeatable)')
    parser.add_argument('--forbid', action='append', default=[], help='forbidden hole '
                        '(repeatable)')
    parser.add_argument('--allow', action='append', default=None, help='allowed hole '
                        '(repeatable; default all)')
    parser.add_argument('--length-range', nargs=2, type=float, metavar=('MIN_MM', 'MAX_MM'))
    parser.add_argument('--tol', type=float, default=GLOBAL_TOL_RAD,
                        help='global optimality tolerance, rad')
    parser.add_argument('--hole-tolerance', type=float, default=0.0, metavar='MM',
                        help='hole-position tolerance (1 sigma, mm): report each design\'s '
                        'error under it and rank by the median (default 0: nominal)')
    parser.add_argument('--length-tolerance', type=float, default=0.0, metavar='MM',
                        help='cable-length tolerance (1 sigma, mm), as --hole-tolerance')
    parser.set_defaults(handler=_cli_handler)


def _cli_handler(args, skeleton):
    import json

    kwargs = dict(k=args.k, forbidden_holes=args.forbid, allowed_holes=args.allow,
                  cable_length_range=args.length_range, tol_rad=args.tol,
                  hole_tolerance_mm=args.hole_tolerance,
                  length_tolerance_mm=args.length_tolerance)
    fixed = {}
    for item in args.fixed:
        rib, sep, hole = item.partition(':')
        if not sep or not rib.strip().lstrip('-').isdigit():
            raise ValueError(f'--fixed expects RIB:HOLE such as 0:R1, got {item!r}')
        fixed[int(rib)] = hole.strip()
    kwargs['fixed_holes'] = fixed or None
    if args.angles is not None:
        try:
            kwargs['target_angles'] = [float(v) for v in args.angles.replace(',', ' ').split()]
        except ValueError:
            raise ValueError(f'--angles must be numbers, got {args.angles!r}') from None
    else:
        with open(args.points) as handle:
            kwargs['target_points'] = json.load(handle)
    res = design_threading(skeleton, **kwargs)
    return result_to_dict(res)
