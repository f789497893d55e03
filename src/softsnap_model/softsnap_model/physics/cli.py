"""``softsnap-model physics``: MuJoCo against the quasi-static model, as JSON and in rerun.

Examples::

    softsnap-model physics --scene brittle_star
    softsnap-model physics --scene gripper --payload-mass 0.005 --payload-radius 0.045 \\
        --record physics.rrd
    softsnap-model physics --scene snake --links 4 --cases fidelity

Reports, for the scene's threadings (mm, N):

* ``fidelity``: gravity off, the winch shortened slowly by ``--contraction``: the settled
  MuJoCo shape against ``solve_forward`` (largest rib-centre distance, tensions).
* ``gravity``: the first module's threading clamped at its base lying on the ground
  (``flat``), hanging tip down (``hanging``) and horizontal bending in the vertical plane
  (``side``), against ``solve_loaded``.
* ``payload`` (robots held in the world, i.e. the gripper): closing on the payload, letting
  go; whether it is held, and each finger against ``solve_loaded`` with the contact force.

``--record FILE.rrd`` writes the shapes (``physics/<case>/<module>/{simulated,
quasi_static}``, metres, module base frame; the payload case in the world frame).
"""
from __future__ import annotations

import math
import time

import numpy as np

__all__ = ['add_cli', 'run_physics']

CASES = ('fidelity', 'gravity', 'payload')


def add_cli(subparsers) -> None:
    """Register ``softsnap-model physics`` (see :mod:`softsnap_model.cli`)."""
    p = subparsers.add_parser('physics', help='MuJoCo physics against the quasi-static model '
                                              '(needs the mujoco package)')
    p.add_argument('--scene', default='brittle_star', help='scene name or file')
    p.add_argument('--links', type=int, default=None,
                   help='links per segment (default: the model default)')
    p.add_argument('--contraction', type=float, default=20.0,
                   help='cable shortening of the comparisons (mm)')
    p.add_argument('--cases', default=','.join(CASES),
                   help=f'comma-separated subset of {",".join(CASES)}')
    p.add_argument('--payload-mass', type=float, default=0.005, help='payload mass (kg)')
    p.add_argument('--payload-radius', type=float, default=0.045, help='ball radius (m)')
    p.add_argument('--record', metavar='RRD', help='write a rerun recording here')
    p.set_defaults(handler=_handler)


def _handler(args, skeleton) -> dict:
    from ..skeleton import Skeleton
    if skeleton != Skeleton():
        raise ValueError('physics uses the scene\'s skeleton; --skeleton is not supported')
    cases = [c.strip() for c in args.cases.split(',') if c.strip()]
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise ValueError(f'unknown case(s) {bad}; known: {", ".join(CASES)}')
    return run_physics(args.scene, links_per_segment=args.links,
                       contraction_mm=args.contraction, cases=cases,
                       payload_mass_kg=args.payload_mass, payload_radius_m=args.payload_radius,
                       record=args.record)


def run_physics(scene_name: str, *, links_per_segment: int | None = None,
                contraction_mm: float = 20.0, cases=CASES, payload_mass_kg: float = 0.005,
                payload_radius_m: float = 0.045, record=None) -> dict:
    """Run the comparisons and return a JSON-ready dict (see the module docstring)."""
    try:
        import mujoco  # noqa: F401
    except ImportError:
        raise ValueError('softsnap-model physics needs the mujoco package '
                         '(pip install mujoco)') from None
    from ..scene import load_scene
    from .compare import load_case, payload_case, static_fidelity, LOAD_CASES
    from .parameters import DEFAULT_LINKS_PER_SEGMENT, Payload
    n = DEFAULT_LINKS_PER_SEGMENT if links_per_segment is None else links_per_segment
    c = float(contraction_mm)
    if not math.isfinite(c) or c <= 0.0:
        raise ValueError(f'--contraction must be a finite number of mm > 0, got {c!r}')
    scene = load_scene(scene_name)
    out: dict = {'scene': scene.name, 'links_per_segment': n, 'contraction_mm': c}
    shapes: list = []          # (entity, simulated (n, 2|3) m, reference (n, 2|3) m)
    threadings: dict = {}
    for m in scene.modules:
        threadings.setdefault(' '.join(m.holes), m.name)
    if 'fidelity' in cases:
        rows = []
        for text, module in threadings.items():
            r = static_fidelity(text, c, links_per_segment=n, skeleton=scene.skeleton)
            rows.append({'module': module, 'threading': text,
                         'max_rib_error_mm': r.max_rib_error_mm, 'tip_error_mm': r.tip_error_mm,
                         'tension_n': r.tension_n, 'reference_tension_n': r.reference_tension_n,
                         'settled': r.settled, 'wall_time_s': r.wall_time_s})
            shapes.append((f'physics/fidelity/{module}', r.rib_centers_mm * 1e-3,
                           r.reference_rib_centers_mm * 1e-3))
        out['fidelity'] = rows
    if 'gravity' in cases:
        text, module = next(iter(threadings.items()))
        rows = []
        for case in LOAD_CASES:
            r = load_case(case, text, c, links_per_segment=n, skeleton=scene.skeleton)
            rows.append({'case': case, 'module': module, 'threading': text,
                         'max_rib_error_mm': r.max_rib_error_mm, 'tip_error_mm': r.tip_error_mm,
                         'tip_sag_mm': r.tip_sag_mm, 'tension_n': r.tension_n,
                         'reference_tension_n': r.reference_tension_n,
                         'quasi_static_converged': r.quasi_static_converged,
                         'settled': r.settled})
            shapes.append((f'physics/gravity/{case}', r.rib_centers_mm * 1e-3,
                           r.reference_rib_centers_mm * 1e-3))
        out['gravity'] = rows
    if 'payload' in cases:
        from .robot_mjcf import _hanging
        if _hanging(scene):
            pl = Payload('ball', payload_mass_kg, payload_radius_m)
            start = time.perf_counter()
            r = payload_case(scene, pl, links_per_segment=n)
            out['payload'] = {
                'mass_kg': payload_mass_kg, 'radius_m': payload_radius_m,
                'contraction_mm': r.contraction_mm, 'held': r.held, 'drop_m': r.drop_m,
                'hold_time_s': r.hold_time_s,
                'finger_force_n': r.finger_force_n, 'contact_rib': r.contact_rib,
                'max_rib_error_mm': {k: (None if math.isnan(v) else v)
                                     for k, v in r.max_rib_error_mm.items()},
                'tension_n': r.tension_n, 'wall_time_s': time.perf_counter() - start}
        else:
            out['payload'] = None      # only robots held in the world (the gripper)
    if record:
        out['recording'] = _record(record, scene.name, shapes)
    return out


def _record(path, scene_name: str, shapes) -> str:
    """Write the simulated and quasi-static shapes to an .rrd file (static entities)."""
    from pathlib import Path
    import rerun as rr
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream('softsnap_physics')
    rec.save(str(path))
    rec.log('physics', rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log('physics/scene', rr.TextDocument(f'scene: {scene_name}; module base frames, '
                                             f'metres; simulated (MuJoCo) in full colour, '
                                             f'quasi-static in grey'), static=True)
    for entity, sim, ref in shapes:
        for name, pts, color in (('simulated', sim, (230, 120, 20)),
                                 ('quasi_static', ref, (140, 140, 140))):
            pts = np.asarray(pts, dtype=float)
            if pts.shape[1] == 2:
                pts = np.column_stack([pts, np.zeros(len(pts))])
            rec.log(f'{entity}/{name}', rr.LineStrips3D([pts], colors=[color],
                                                        radii=[0.0015]), static=True)
            rec.log(f'{entity}/{name}/ribs', rr.Points3D(pts, colors=[color],
                                                         radii=[0.003]), static=True)
    rec.flush()
    rec.disconnect()
    return str(path.resolve())
