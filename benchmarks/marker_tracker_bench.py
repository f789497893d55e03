"""Frames per second of the marker measurement at 1280x960 on one core, against rib error.

    .venv/bin/python benchmarks/marker_tracker_bench.py [--frames 40] [--repeat 3]

Frames are rendered once by the tests' independent renderer (test/softsnap_vision/render.py: one
module, 0.5 mm/px, lens distortion, uneven light, textured table, noise), then measured
with OpenCV limited to one thread. Rows: the paper's orange-marker measurement
(measure_image) and the marker_tracker's core (MarkerTracker, one ArUco-tagged module) at
tag detection scales 0.5 (the node's default) and 1.0, each with and without the shape
fit. Per row: median frames/s over ``--repeat`` passes (range), CPU time per frame of the
measuring thread and its inverse (frames/s on one core of its own: on the shared machine
the wall rate counts the time other processes hold the cores), and the rib error against the rendered truth (mean and max over every
seen rib of every frame).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test' / 'softsnap_vision'))
from benchlib import fmt_spread, load_line  # noqa: E402
from render import Camera, ModuleDrawing, centred_origin, render  # noqa: E402

from softsnap_model import Skeleton, solve_forward  # noqa: E402
from softsnap_vision.camera_info import CameraInfo  # noqa: E402
from softsnap_vision.measurement import measure_image  # noqa: E402
from softsnap_vision.tracker import MarkerTracker, TagTarget  # noqa: E402

THREADING = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()


def frames(n: int, tag: bool):
    cam = Camera(width=1280, height=960, focal_px=1000.0, height_m=0.5)
    sk = Skeleton()
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    out = []
    for i in range(n):
        contraction = 60.0 * i / max(n - 1, 1) * 0.6
        ribs = solve_forward(sk, THREADING, sk.straight_length_mm(THREADING) - contraction).rib_centers
        yaw = 0.4 * math.sin(i)
        d = ModuleDrawing(ribs_mm=ribs, yaw_rad=yaw, base_marker=not tag, tag_id=0 if tag else None,
                          origin_mm=centred_origin(ribs, yaw, 48.0 if tag else 30.0,
                                                   at=(30.0 * math.cos(i), 20.0 * math.sin(i))))
        out.append((render(cam, [d], seed=i, tag_dictionary=dictionary), ribs))
    info = CameraInfo(width=cam.width, height=cam.height, camera_matrix=cam.K, distortion=cam.D)
    return cam, info, out


def star_frames(n: int):
    """Five tagged modules in the brittle star's pentagon, 0.6 mm/px (the star is ~550 mm
    across): what the physics demo's camera shows."""
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    cam = Camera(width=1280, height=960, focal_px=1000.0, height_m=0.6)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    out = []
    for i in range(n):
        drawings, truths = [], {}
        for m in scene.modules:
            yaw = math.radians(72.0 * m.index)
            c = 10.0 + 20.0 * ((i + m.index) % 3)
            ribs = solve_forward(scene.skeleton, m.holes,
                                 m.straight_length_mm - c).rib_centers
            origin = (72.5 * math.cos(yaw), 72.5 * math.sin(yaw))
            drawings.append(ModuleDrawing(ribs_mm=ribs, yaw_rad=yaw, origin_mm=origin,
                                          base_marker=False, tag_id=m.tag_id))
            truths[m.name] = ribs
        out.append((render(cam, drawings, seed=i, tag_dictionary=dictionary), truths))
    info = CameraInfo(width=cam.width, height=cam.height, camera_matrix=cam.K, distortion=cam.D)
    targets = [TagTarget(m.name, m.tag_id) for m in scene.modules]
    return cam, info, targets, out


def run(label, fn, data, repeat):
    rates, cpus, errs = [], [], []
    for _ in range(repeat):
        wall0, cpu0 = time.perf_counter(), time.thread_time()
        for image, truth in data:
            ribs, visible = fn(image)
            if _ == 0:
                errs.extend(np.hypot(*(ribs[visible] - truth[visible]).T))
        wall, cpu = time.perf_counter() - wall0, time.thread_time() - cpu0
        rates.append(len(data) / wall)
        cpus.append(cpu / len(data))
    errs = np.array(errs)
    one_core = [1.0 / c for c in cpus]
    print(f'| {label} | {fmt_spread(rates)} | {fmt_spread(cpus, 1e3, 2)} | {fmt_spread(one_core)} | '
          f'{errs.mean():.3f} | {errs.max():.3f} | {errs.size} |')


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--frames', type=int, default=40)
    p.add_argument('--repeat', type=int, default=3)
    p.add_argument('--star', action='store_true',
                   help='also the five modules of the brittle star in one frame')
    args = p.parse_args(argv)
    cv2.setNumThreads(1)
    print(load_line('start'))
    cam, info, orange = frames(args.frames, tag=False)
    _, _, tagged = frames(args.frames, tag=True)
    print(f'{args.frames} frames {cam.width}x{cam.height}, 0.5 mm/px, one module; OpenCV threads: '
          f'{cv2.getNumThreads()}')
    print('| measurement | frames/s wall, median (range) | CPU ms/frame | frames/s per CPU core '
          '(1 / CPU time) | rib error mean (mm) | max (mm) | ribs |')
    print('|---|---|---|---|---|---|---|')
    for fit in (True, False):
        def orange_fn(image, fit=fit):
            m = measure_image(image, info, cam.height_m, fit=fit)
            return m.ribs_mm, m.visible
        run(f'orange marker (measure_image), fit={fit}', orange_fn, orange, args.repeat)
    for scale in (0.5, 1.0):
        for fit in (True, False):
            tracker = MarkerTracker(info, cam.height_m, [TagTarget('m', 0)], tag_scale=scale, fit=fit)

            def tag_fn(image, tracker=tracker):
                m = tracker.track(image).modules['m']
                return m.ribs_mm, m.visible
            run(f'ArUco tag (MarkerTracker), tag_scale={scale}, fit={fit}', tag_fn, tagged,
                args.repeat)
    if args.star:
        cam5, info5, targets, star = star_frames(max(args.frames // 3, 4))
        tracker = MarkerTracker(info5, cam5.height_m, targets)
        rates, cpus, errs, tracked = [], [], [], 0
        for rep in range(args.repeat):
            wall0, cpu0 = time.perf_counter(), time.thread_time()
            for image, truths in star:
                result = tracker.track(image)
                if rep == 0:
                    for name, truth in truths.items():
                        m = result.modules.get(name)
                        if m is not None and m.error is None:
                            tracked += 1
                            errs.extend(np.hypot(*(m.ribs_mm[m.visible] - truth[m.visible]).T))
            rates.append(len(star) / (time.perf_counter() - wall0))
            cpus.append((time.thread_time() - cpu0) / len(star))
        errs = np.array(errs)
        print(f'\nbrittle star, five tagged modules, {len(star)} frames at 0.6 mm/px: '
              f'{tracked} of {5 * len(star)} module views tracked')
        print('| measurement | frames/s wall | CPU ms/frame | frames/s per CPU core | '
              'rib error mean (mm) | max (mm) | ribs |')
        print('|---|---|---|---|---|---|---|')
        print(f'| MarkerTracker, 5 modules | {fmt_spread(rates)} | {fmt_spread(cpus, 1e3, 2)} | '
              f'{fmt_spread([1 / c for c in cpus])} | {errs.mean():.3f} | {errs.max():.3f} | '
              f'{errs.size} |')
    print(load_line('end'))


if __name__ == '__main__':
    main()
