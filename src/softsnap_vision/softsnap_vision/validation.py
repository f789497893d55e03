"""Batch validation like the paper's Fig. d1/d2: RMSE to the model per threading and step.

    python -m softsnap_vision.validation --camera-info CAMERA.yaml --plane-distance-m H \\
        --manifest MANIFEST.csv|.yaml --output DIR [--markers MARKERS.yaml]

Manifest: one row per image (paths relative to the manifest), as CSV with the header
``image,threading,cable_length_mm[,label]`` (threading as hole names separated by
spaces) or as YAML, a list of mappings with the same keys. ``label`` names the threading
in the table (default: the threading itself).

Writes to DIR: ``rmse.csv`` (one row per image: label, contraction, RMSE, ribs seen,
error), ``table.md`` (RMSE per threading and step, mm: the mean over images of that step),
``rmse.png`` (RMSE against contraction, one line per threading) and ``validation.rrd``
(rerun: per threading ``validation/<label>/rmse_mm`` and the measured and model rib
centres at each step, on the ``step`` timeline). Prints the table. Exit status 0, 1 when
an image could not be measured (the others are), 2 for bad arguments.
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from softsnap_model import Skeleton

from .camera_info import CameraInfoError, load_camera_info
from .marker_config import MarkerConfigError, load_marker_config
from .measure import measure_files
from .measurement import model_rib_centers_mm

__all__ = ['ManifestRow', 'ValidationRow', 'load_manifest', 'validate', 'rmse_table', 'main']


@dataclass(frozen=True)
class ManifestRow:
    image: Path
    holes: tuple[str, ...]
    cable_length_mm: float
    label: str


@dataclass(frozen=True)
class ValidationRow:
    label: str
    contraction_mm: float
    rmse_mm: float | None
    ribs_seen: int
    error: str | None
    ribs_mm: list | None
    model_mm: np.ndarray


class ManifestError(ValueError):
    """A manifest is missing, malformed or names a bad threading or length."""


def load_manifest(path) -> list[ManifestRow]:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ManifestError(f'{path}: cannot read: {exc}') from None
    if path.suffix.lower() in ('.yaml', '.yml'):
        try:
            entries = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ManifestError(f'{path}: not valid YAML: {exc}') from None
        if not isinstance(entries, list):
            raise ManifestError(f'{path}: expected a list of images')
    else:
        entries = list(csv.DictReader(text.splitlines()))
    rows = []
    for i, e in enumerate(entries):
        where = f'{path}: row {i + 1}'
        if not isinstance(e, dict) or not {'image', 'threading', 'cable_length_mm'} <= set(e):
            raise ManifestError(f'{where}: needs image, threading and cable_length_mm')
        holes = e['threading']
        holes = tuple(holes.replace(',', ' ').split() if isinstance(holes, str) else map(str, holes))
        try:
            length = float(e['cable_length_mm'])
        except (TypeError, ValueError):
            raise ManifestError(f'{where}: cable_length_mm must be a number, got '
                                f'{e["cable_length_mm"]!r}') from None
        if not (math.isfinite(length) and length > 0):
            raise ManifestError(f'{where}: cable_length_mm must be > 0, got {length!r}')
        label = str(e.get('label') or ' '.join(holes))
        rows.append(ManifestRow(path.parent / str(e['image']), holes, length, label))
    if not rows:
        raise ManifestError(f'{path}: no images')
    return rows


def validate(rows, camera, plane_distance_m, config, skeleton=Skeleton()) -> list[ValidationRow]:
    out = []
    for row in rows:
        try:
            model = model_rib_centers_mm(skeleton, list(row.holes), row.cable_length_mm)
        except ValueError as exc:
            raise ManifestError(f'{row.image}: {exc}') from None
        record = measure_files([row.image], camera, plane_distance_m, config, skeleton, model)[0]
        contraction = skeleton.straight_length_mm(list(row.holes)) - row.cable_length_mm
        seen = 0 if record['ribs_mm'] is None else sum(r is not None for r in record['ribs_mm'])
        out.append(ValidationRow(row.label, round(contraction, 3), record['rmse_to_model_mm'],
                                 seen, record['error'], record['ribs_mm'], model))
    return out


def rmse_table(results) -> tuple[list[float], dict[str, dict[float, float]]]:
    """(sorted contraction steps, label -> step -> mean RMSE in mm) over measured images."""
    cells: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in results:
        if r.rmse_mm is not None:
            cells[r.label][r.contraction_mm].append(r.rmse_mm)
    steps = sorted({s for by_step in cells.values() for s in by_step})
    return steps, {label: {s: float(np.mean(v)) for s, v in by_step.items()}
                   for label, by_step in cells.items()}


def _markdown(steps, table) -> str:
    lines = ['| threading | ' + ' | '.join(f'{s:g} mm' for s in steps) + ' |',
             '|---|' + '---|' * len(steps)]
    for label, by_step in table.items():
        lines.append(f'| {label} | ' + ' | '.join(
            f'{by_step[s]:.2f}' if s in by_step else '-' for s in steps) + ' |')
    return '\n'.join(lines)


def _plot(steps, table, path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for label, by_step in table.items():
        xs = sorted(by_step)
        ax.plot(xs, [by_step[x] for x in xs], marker='o', label=label)
    ax.set_xlabel('cable contraction (mm)')
    ax.set_ylabel('RMSE of the rib centres to the model (mm)')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _entity(label: str) -> str:
    return ''.join(c if c.isalnum() else '_' for c in label)


def _rerun(results, path: Path) -> None:
    import rerun as rr

    rec = rr.RecordingStream('softsnap_validation')
    rec.save(str(path))
    by_label = defaultdict(list)
    for r in results:
        by_label[r.label].append(r)
    for label, rows in by_label.items():
        base = f'validation/{_entity(label)}'
        for step, r in enumerate(sorted(rows, key=lambda r: r.contraction_mm)):
            rec.set_time('step', sequence=step)
            rec.log(f'{base}/contraction_mm', rr.Scalars(r.contraction_mm))
            if r.rmse_mm is not None:
                rec.log(f'{base}/rmse_mm', rr.Scalars(r.rmse_mm))
            rec.log(f'{base}/model', rr.Points2D(r.model_mm, radii=1.0))
            if r.ribs_mm is not None:
                seen = np.array([p for p in r.ribs_mm if p is not None]).reshape(-1, 2)
                rec.log(f'{base}/measured', rr.Points2D(seen, radii=1.5))
    rec.flush()
    rec.disconnect()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m softsnap_vision.validation',
                                description='RMSE to the model per threading and step')
    p.add_argument('--camera-info', required=True)
    p.add_argument('--plane-distance-m', type=float, required=True)
    p.add_argument('--manifest', required=True, help='CSV or YAML: image, threading, cable_length_mm')
    p.add_argument('--output', required=True, help='directory for rmse.csv, table.md, rmse.png, validation.rrd')
    p.add_argument('--markers')
    args = p.parse_args(argv)
    try:
        camera = load_camera_info(args.camera_info)
        config = load_marker_config(args.markers)
        rows = load_manifest(args.manifest)
        results = validate(rows, camera, args.plane_distance_m, config)
    except (CameraInfoError, MarkerConfigError, ValueError) as exc:
        print(f'validation: {exc}', file=sys.stderr)
        return 2
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / 'rmse.csv', 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['image', 'label', 'contraction_mm', 'rmse_to_model_mm', 'ribs_seen', 'error'])
        for row, r in zip(rows, results):
            w.writerow([row.image, r.label, r.contraction_mm,
                        '' if r.rmse_mm is None else f'{r.rmse_mm:.4f}', r.ribs_seen, r.error or ''])
    steps, table = rmse_table(results)
    text = _markdown(steps, table)
    (out / 'table.md').write_text(text + '\n')
    _plot(steps, table, out / 'rmse.png')
    _rerun(results, out / 'validation.rrd')
    print(text)
    for row, r in zip(rows, results):
        if r.error:
            print(f'{row.image}: {r.error}', file=sys.stderr)
    return 1 if any(r.error for r in results) else 0


if __name__ == '__main__':
    sys.exit(main())
