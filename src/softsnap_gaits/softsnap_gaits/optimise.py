"""Optimise a gait in MuJoCo and write the winner into a scene: ``python -m softsnap_gaits.optimise``.

No ROS. Example (the brittle star's ``walk_optimised``, docs/gait_search.md)::

    python -m softsnap_gaits.optimise --scene brittle_star --family walk --start-gait walk \\
        --name walk_optimised --seed 3 --generations 10 --popsize 8 --sigma 0.3 --seconds 6 \\
        --warmup-cycles 1 --any-heading --workers 2 --out runs/opt3-brittle_star

prints one progress line per generation (a bar, the best score so far), and writes into
``--out`` (default ``runs/optimise-<scene>-<UTC>/``): ``learning_curve.png`` (best and mean
score per generation), ``best.rrd`` (the best gait's rollout on the nominal setting, a
rerun recording), ``<scene>.yaml`` (the scene with the best gait added under ``--name``)
and ``result.json`` (scores per setting, the spec, the command); ``best_so_far.json`` holds the
best gait each time it improves, so a stopped search keeps it. ``--into-scene`` writes
the gait into the scene file itself instead of a copy.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .gait_family import FAMILIES, FAMILY_ALIASES, gait_family
from .gait_objective import DEFAULT_SETTINGS, SETTLE_S, rollout
from .gait_search import Generation, SearchConfig, make_backend, search

__all__ = ['main', 'build_parser', 'plot_learning_curve', 'record_rollout']


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='optimise', description=__doc__.splitlines()[0])
    p.add_argument('--scene', default='brittle_star', help='scene name or file')
    p.add_argument('--family', default='walk',
                   choices=sorted(FAMILIES) + sorted(FAMILY_ALIASES),
                   help='gait family: pulse (alias walk) or wave (alias concertina)')
    p.add_argument('--start-gait', default=None,
                   help='start the search at this gait of the scene (default: the cube centre)')
    p.add_argument('--name', default=None, help='name of the gait written (default <family>_optimised)')
    p.add_argument('--seed', type=int, default=1)
    p.add_argument('--generations', type=int, default=10)
    p.add_argument('--popsize', type=int, default=8)
    p.add_argument('--sigma', type=float, default=0.25, help='CMA-ES initial step in the unit cube')
    p.add_argument('--seconds', type=float, default=6.0, help='simulated gait time per rollout, s')
    p.add_argument('--heading-deg', type=float, default=0.0,
                   help='direction scored, deg counter-clockwise from the robot x axis')
    p.add_argument('--any-heading', action='store_true',
                   help='score the straight-line distance in any direction (the demo\'s measure)')
    p.add_argument('--warmup-cycles', type=int, default=1,
                   help='gait cycles run before the measured ones (default 1: the first cycle '
                   'starts from the straight robot and can lurch in a way it never repeats)')
    p.add_argument('--aggregate', choices=('mean', 'worst'), default='mean',
                   help='combine the settings by their mean or their worst score')
    p.add_argument('--settings', default='all',
                   help=f'comma-separated setting names or "all" ({", ".join(s.name for s in DEFAULT_SETTINGS)})')
    p.add_argument('--backend', choices=('process', 'ray'), default='process')
    p.add_argument('--workers', type=int, default=1, help='processes (process backend)')
    p.add_argument('--address', default=None, help='Ray cluster address (default: start a local Ray)')
    p.add_argument('--ray-num-cpus', type=int, default=None, help='CPUs of a local Ray')
    p.add_argument('--out', default=None, help='output folder')
    p.add_argument('--into-scene', action='store_true',
                   help='write the gait into the scene file itself, not a copy in --out')
    p.add_argument('--no-record', action='store_true', help='skip the .rrd of the best rollout')
    return p


def _progress(total: int):
    def show(g: Generation) -> None:
        done = int(round(20 * g.index / total))
        print(f'[{"#" * done}{"." * (20 - done)}] gen {g.index}/{total}  '
              f'best so far {g.best_so_far:+.2f} mm/s  this gen {g.best_score:+.2f} '
              f'(mean {g.mean_score:+.2f})  {g.rollouts} rollouts  {g.wall_s:.0f} s', flush=True)
    return show


def plot_learning_curve(history, start_score: float, path: Path, title: str) -> Path:
    """PNG of the best-so-far and per-generation scores against rollouts."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=100)
    x = [0] + [g.rollouts for g in history]
    ax.plot(x, [start_score] + [g.best_so_far for g in history], '-o', ms=3, label='best so far')
    ax.plot(x[1:], [g.best_score for g in history], '.', label='best of generation')
    ax.plot(x[1:], [g.mean_score for g in history], ':', label='mean of generation')
    ax.set_xlabel('rollouts')
    ax.set_ylabel('score (mm per simulated second)')
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def record_rollout(scene_ref: str, spec: dict, setting, seconds: float, heading_deg: float,
                   path: Path, title: str):
    """Roll the gait out once more with recording on and write it as a rerun .rrd."""
    import rerun as rr
    from softsnap_model.recording import close_recording, open_recording
    result = rollout(scene_ref, spec, setting, seconds=seconds, heading_deg=heading_deg,
                     record=True)
    rec = open_recording(path, application_id='softsnap_gait_search')
    rec.log('description', rr.TextDocument(title), static=True)
    rec.log('world', rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    start = result.base_m[0]
    for t, ribs, base in zip(result.times_s, result.ribs_m, result.base_m):
        rec.set_time('sim_time', duration=float(t))
        rec.log('world/robot/ribs', rr.LineStrips3D([r for r in ribs], radii=0.002))
        rec.log('world/robot/base', rr.Points3D([base], radii=0.006))
        rec.log('plots/travel_mm', rr.Scalars(float(np.hypot(*(base - start)[:2]) * 1e3)))
    rec.log('world/path', rr.LineStrips3D([result.base_m], radii=0.001), static=True)
    close_recording(rec)
    return result


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from softsnap_model.scene import load_scene
    from .gait_yaml import write_scene_gait
    from .gaits import make_gait
    scene = load_scene(args.scene)
    family = gait_family(args.family, scene)
    name = args.name or f'{args.family}_optimised'
    if args.settings == 'all':
        settings = DEFAULT_SETTINGS
    else:
        by_name = {s.name: s for s in DEFAULT_SETTINGS}
        try:
            settings = tuple(by_name[n] for n in args.settings.split(','))
        except KeyError as exc:
            print(f'optimise: unknown setting {exc}; known: {", ".join(by_name)}', file=sys.stderr)
            return 2
    x0 = None
    if args.start_gait:
        gait = make_gait(args.start_gait, scene)
        hint = dict(gait.params, phases=gait.params.get('phase', {}),
                    lag=scene.gaits[args.start_gait].get('lag', 0.0))
        x0 = tuple(family.encode_hint(hint))
    config = SearchConfig(scene=str(scene.path), family=family.kind, seed=args.seed,
                          generations=args.generations, popsize=args.popsize,
                          sigma0=args.sigma, seconds=args.seconds,
                          heading_deg=None if args.any_heading else args.heading_deg,
                          warmup_cycles=args.warmup_cycles, aggregate=args.aggregate,
                          settings=settings, x0=x0)
    out = Path(args.out or f'runs/optimise-{scene.name}-{time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())}')
    out.mkdir(parents=True, exist_ok=True)
    ray_init = {}
    if args.backend == 'ray' and args.address is None:
        # A local Ray for this run only: no dashboard, a small object store (the tasks
        # pass a few kB each).
        ray_init = {'num_cpus': args.ray_num_cpus or args.workers or 1, 'include_dashboard': False,
                    'object_store_memory': 200 * 2**20}
    backend = make_backend(args.backend, args.workers, args.address, **ray_init)
    print(f'optimise: scene {scene.name}, family {family.kind} ({family.dimension} numbers), '
          f'seed {args.seed}, {args.generations} x {args.popsize} candidates x '
          f'{len(settings)} settings ({args.aggregate}), {args.seconds:g} s rollouts, '
          f'backend {backend.name} ({backend.workers} workers)', flush=True)
    try:
        checkpoint = out / 'best_so_far.json'
        result = search(config, family, backend, progress=_progress(args.generations),
                        on_best=lambda spec, value: checkpoint.write_text(
                            json.dumps({'score_mm_s': value, 'spec': spec}, indent=2)))
    finally:
        backend.close()
    command = 'python -m softsnap_gaits.optimise ' + ' '.join(sys.argv[1:] if argv is None else argv)
    per = ', '.join(f'{s.name} {v:+.2f}' for s, v in zip(settings, result.best_scores))
    comments = [f'Found by softsnap_gaits.optimise (docs/gait_search.md): score '
                f'{result.best_score:+.2f} mm/s ({args.aggregate} of {len(settings)} settings, '
                f'heading {"any" if args.any_heading else f"{args.heading_deg:g} deg"}; '
                f'{args.warmup_cycles} warm-up cycles; start {result.start_score:+.2f} mm/s),',
                f'{result.rollouts} rollouts of {args.seconds:g} s. Per setting: {per}.',
                f'Command: {command}']
    scene_out = write_scene_gait(scene.path, name, result.best_spec, comments=comments,
                                 output=None if args.into_scene else out / f'{scene.name}.yaml')
    curve = plot_learning_curve(result.history, result.start_score, out / 'learning_curve.png',
                                f'{scene.name} / {name}: CMA-ES, seed {args.seed}, '
                                f'{args.aggregate} of {len(settings)} settings')
    recorded = None
    if not args.no_record:
        recorded = record_rollout(str(scene.path), result.best_spec, DEFAULT_SETTINGS[0],
                                  args.seconds, config.heading_deg, out / 'best.rrd',
                                  f'{scene.name} / {name}: best gait of the search, nominal setting')
    summary = {'scene': scene.name, 'name': name, 'family': family.kind, 'seed': args.seed,
               'command': command, 'best_score_mm_s': result.best_score,
               'start_score_mm_s': result.start_score,
               'best_scores_mm_s': dict(zip((s.name for s in settings), result.best_scores)),
               'best_results': [{k: v for k, v in asdict(replace(r, times_s=None, ribs_m=None,
                                                                  base_m=None)).items()
                                 if k not in ('times_s', 'ribs_m', 'base_m')}
                                for r in result.best_results],
               'best_spec': result.best_spec, 'rollouts': result.rollouts,
               'wall_s': result.wall_s, 'aggregate': args.aggregate,
               'history': [asdict(g) for g in result.history],
               'scene_file': str(scene_out), 'learning_curve': str(curve),
               'recording': None if recorded is None else str(out / 'best.rrd'),
               'settle_s': SETTLE_S}
    (out / 'result.json').write_text(json.dumps(summary, indent=2))
    print(f'optimise: best {result.best_score:+.2f} mm/s (start {result.start_score:+.2f}); '
          f'per setting: {per}')
    print(f'optimise: gait {name!r} written to {scene_out}; curve {curve}; '
          f'{"recording " + str(out / "best.rrd") if recorded is not None else "no recording"}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
