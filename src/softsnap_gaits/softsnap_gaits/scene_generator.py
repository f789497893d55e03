"""Scenes of any size: a snake of N modules or a 2-D lattice of rows x columns.

``python -m softsnap_gaits.scene_generator snake 50 -o snake50.yaml`` writes a chain of
50 modules (the snake scene's threading, pitch and concertina gait, the wave's lag scaled
so the wave still fits one period); ``lattice 5x10`` writes 50 independent modules lying
side by side on a grid, walking with two alternating checkerboard groups. The files are
ordinary scenes (docs/scenes.md): ``make demo SCENE=path/to/file.yaml`` runs them, and
every reader validates them with :func:`softsnap_model.scene.load_scene`.

Ports are 9000, 9001, ... (the demo gives simulated modules free ports of its own; a real
robot of this size would name its modules' addresses in the file).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import yaml

__all__ = ['snake_scene', 'lattice_scene', 'main']

#: The snake and ring threading (FACTS.md).
SNAKE_THREADING = ['R2', 'R3', 'R3', 'R3', 'L3', 'L3', 'L3', 'L3', 'R3', 'R3', 'R3', 'R3']
#: The brittle star's legs, repeated over a lattice (FACTS.md).
LATTICE_THREADINGS = [
    ['R1', 'R1', 'R1', 'R1', 'R1', 'R1', 'R1', 'R1', 'R2', 'R2', 'R3', 'R3'],
    ['R1', 'R1', 'R1', 'R1', 'R1', 'R2', 'R2', 'R2', 'R2', 'R3', 'R3', 'R3'],
    ['R3', 'R1', 'R1', 'R1', 'R1', 'R2', 'R2', 'R2', 'R2', 'R3', 'R3', 'R3'],
]
MODULE_PITCH_MM = 248.0     # the snake scene's 198 mm spine + 50 mm link
LINK_MM = 50.0              # tip rib of one module to rib 0 of the next
LATTICE_ROW_PITCH_MM = 260.0   # along x: a 201 mm skeleton, its motor module and a gap
LATTICE_COLUMN_PITCH_MM = 120.0  # along y: room for a leg bent by 80 mm of contraction
FIRST_PORT = 9000
DEFAULTS = {
    'host': '127.0.0.1',
    'counts_per_mm': 89.13,
    'max_contraction_mm': 80.0,
    'winch_speed_mm_s': 92.4,
}


def _name(i: int, n: int) -> str:
    return f'm{i:0{max(2, len(str(n - 1)))}d}'


def snake_scene(n_modules: int) -> dict:
    """A chain of `n_modules` (head first, each on the tip of the one behind it).

    The concertina wave keeps the snake scene's 3 s cycle, 25 mm steps and 0.6 s ramps;
    neighbours start ``lag`` of the period apart with ``lag = min(0.05, 0.5 / n)`` so the
    whole wave spans at most half a cycle whatever the length.
    """
    if n_modules < 1:
        raise ValueError(f'a snake needs at least one module, got {n_modules}')
    names = [_name(i, n_modules) for i in range(n_modules)]
    modules = []
    for i, name in enumerate(names):
        x_mm = (n_modules - 1 - i) * MODULE_PITCH_MM   # the tail (last) at the origin
        module = {'name': name, 'threading': list(SNAKE_THREADING), 'port': FIRST_PORT + i,
                  'base': {'position_mm': [x_mm, 0.0, 0.0], 'rpy_deg': [0.0, 0.0, 0.0]}}
        if i < n_modules - 1:
            module['parent'] = names[i + 1]
            module['parent_offset'] = {'position_mm': [LINK_MM, 0.0, 0.0],
                                       'rpy_deg': [0.0, 0.0, 0.0]}
        modules.append(module)
    lag = min(0.05, 0.5 / n_modules)
    return {
        'format': 1, 'name': f'snake_{n_modules}',
        'description': f'A generated chain of {n_modules} SoftSnap modules on the ground '
                       '(softsnap_gaits.scene_generator), moving by concertina waves.',
        'frame': 'Robot frame: origin at rib 0 of the tail module, x toward the head, z up.',
        'connector': {'type': 'chain', 'source': 'The snake scene\'s estimate, repeated.',
                      'link_length_mm': LINK_MM, 'module_pitch_mm': MODULE_PITCH_MM},
        'defaults': dict(DEFAULTS),
        'modules': modules,
        'gaits': {'concertina': {'type': 'wave', 'period_s': 3.0, 'order': names,
                                 'lag': lag, 'duty': 0.5, 'amplitude_mm': 25.0,
                                 'rise_time_s': 0.6}},
        'default_gait': 'concertina',
    }


def lattice_scene(rows: int, columns: int) -> dict:
    """`rows` x `columns` independent modules on a grid, all spines along +x.

    The walk alternates two checkerboard groups (the brittle star's 3 s cycle, 30 mm
    steps on 0.75 s ramps), so every module's neighbours move against it.
    """
    if rows < 1 or columns < 1:
        raise ValueError(f'a lattice needs at least 1 x 1 modules, got {rows} x {columns}')
    n = rows * columns
    modules, groups = [], ([], [])
    for r in range(rows):
        for c in range(columns):
            i = r * columns + c
            name = _name(i, n)
            modules.append({
                'name': name, 'threading': list(LATTICE_THREADINGS[i % len(LATTICE_THREADINGS)]),
                'port': FIRST_PORT + i,
                'base': {'position_mm': [r * LATTICE_ROW_PITCH_MM, c * LATTICE_COLUMN_PITCH_MM, 0.0],
                         'rpy_deg': [0.0, 0.0, 0.0]}})
            groups[(r + c) % 2].append(name)
    groups = [g for g in groups if g]
    return {
        'format': 1, 'name': f'lattice_{rows}x{columns}',
        'description': f'A generated {rows} x {columns} lattice of SoftSnap modules lying '
                       'side by side (softsnap_gaits.scene_generator).',
        'frame': 'Robot frame: origin at rib 0 of module 0, rows along x, columns along y, z up.',
        'connector': {'type': 'lattice', 'source': 'Generated: a flat frame holding every '
                      'module\'s base.', 'row_pitch_mm': LATTICE_ROW_PITCH_MM,
                      'column_pitch_mm': LATTICE_COLUMN_PITCH_MM},
        'defaults': dict(DEFAULTS),
        'modules': modules,
        'gaits': {'walk': {'type': 'alternating', 'period_s': 3.0, 'groups': groups,
                           'duty': 0.5, 'amplitude_mm': 30.0, 'rise_time_s': 0.75}},
        'default_gait': 'walk',
    }


def _shape(text: str) -> tuple[int, int]:
    try:
        rows, columns = (int(v) for v in text.lower().split('x'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected ROWSxCOLUMNS (e.g. 5x10), got {text!r}') from None
    return rows, columns


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m softsnap_gaits.scene_generator',
        description='Write a scene of a generated SoftSnap robot of any size.')
    sub = parser.add_subparsers(dest='robot', required=True)
    snake = sub.add_parser('snake', help='a chain of N modules')
    snake.add_argument('modules', type=int, help='number of modules (>= 1)')
    lattice = sub.add_parser('lattice', help='a ROWSxCOLUMNS grid of modules')
    lattice.add_argument('shape', type=_shape, help='ROWSxCOLUMNS, e.g. 5x10')
    for p in (snake, lattice):
        p.add_argument('-o', '--output', type=Path, required=True, help='scene YAML to write')
    args = parser.parse_args(argv)
    try:
        data = snake_scene(args.modules) if args.robot == 'snake' else lattice_scene(*args.shape)
    except ValueError as exc:
        print(f'scene_generator: {exc}', file=sys.stderr)
        return 2
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(f'# Generated by python -m softsnap_gaits.scene_generator '
                           f'{" ".join(sys.argv[1:] if argv is None else argv)}\n'
                           + yaml.safe_dump(data, sort_keys=False))
    # Validate what was written with the one scene loader, so a bad file is never left silently.
    from softsnap_model.scene import SceneError, load_scene
    try:
        scene = load_scene(args.output)
    except SceneError as exc:
        print(f'scene_generator: the generated scene does not load: {exc}', file=sys.stderr)
        return 1
    print(f'wrote {args.output}: {scene.name}, {len(scene.modules)} modules')
    return 0


if __name__ == '__main__':
    sys.exit(main())
