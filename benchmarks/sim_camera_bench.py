#!/usr/bin/env python3
"""sim_robot's simulated camera: the cost of a frame, and what it costs the physics.

1. Frame cost: the brittle star rendered by :class:`~softsnap_driver.sim_camera.SimCamera`
   (MuJoCo offscreen, ``MUJOCO_GL=egl``; Mesa's llvmpipe on a machine without a GPU) at
   each ``--sizes``, ``--frames`` frames each after a warm-up frame: wall ms per frame
   (median, range) and the rendering thread's own CPU ms (with ``LP_NUM_THREADS=0``,
   the camera's setting, llvmpipe rasterises in that thread: its CPU is the frame's
   whole cost; the wall time adds the waits for a core on a busy machine).
2. Physics with and without the camera: a :class:`~softsnap_driver.sim_robot.SimRobot`
   walks the brittle star's default gait for ``--seconds`` of simulated time, unpaced,
   (a) alone and (b) with a camera thread rendering a frame of every ``1/15`` s of
   simulated time from a ``qpos`` copy, the way sim_robot's node does it (the simulation
   thread only copies; a frame is dropped while the renderer is busy; the camera thread
   niced by ``CAMERA_THREAD_NICE``). Runs alternate
   a, b, a, b ... (``--repeat`` pairs) so both see the same load; the table gives the
   real-time factor of the stepping loop (simulated s per wall s of stepping) and the
   ratio b/a of the medians, and the frames rendered and dropped.

The load average is printed at the start and the end: on a shared machine the numbers
are only as good as the cores they ran on.

Usage: .venv/bin/python benchmarks/sim_camera_bench.py [--sizes 1280x960,640x480]
       [--frames 20] [--seconds 3] [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import queue
import threading
import time

os.environ.setdefault('MUJOCO_GL', 'egl')
os.environ.setdefault('LP_NUM_THREADS', '0')   # what SimCamera sets (sim_camera.offscreen_backend)

from benchlib import fmt_spread, load_line  # noqa: E402

from softsnap_driver.sim_camera import (CameraSettings, SimCamera,  # noqa: E402
                                        capture_frame_state, lower_thread_priority)
from softsnap_driver.sim_observation import TickSchedule  # noqa: E402
from softsnap_driver.sim_robot import ScriptedCommands, SimRobot, build_simulation  # noqa: E402
from softsnap_gaits.gaits import make_gait  # noqa: E402
from softsnap_model.scene import load_scene  # noqa: E402

CAMERA_RATE_HZ = 15.0


def frame_cost(size: tuple[int, int], frames: int) -> tuple[list, list]:
    scene = load_scene('brittle_star')
    sim = build_simulation(scene, links_per_segment=2)
    sim.step(0.2)
    camera = SimCamera(sim, CameraSettings(width_px=size[0], height_px=size[1]))
    state = capture_frame_state(sim)
    camera.render(state)
    wall, cpu = [], []
    for _ in range(frames):
        w0, c0 = time.perf_counter(), time.thread_time()
        camera.render(state)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.thread_time() - c0)
    camera.close()
    return wall, cpu


def walk(seconds: float, with_camera: bool, nice: bool = True) -> tuple[float, int, int]:
    """(real-time factor of the stepping loop, frames rendered, frames dropped)."""
    scene = load_scene('brittle_star')
    sim = build_simulation(scene, links_per_segment=2)
    robot = SimRobot(scene, sim)
    script = ScriptedCommands(make_gait(scene.default_gait, scene).contraction_mm)
    frames: queue.Queue = queue.Queue(maxsize=1)
    rendered, dropped = [0], [0]
    ready = threading.Event()

    def render_loop():
        if nice:
            lower_thread_priority()
        camera = SimCamera(sim, CameraSettings())
        ready.set()
        while True:
            state = frames.get()
            if state is None:
                break
            camera.render(state)
            rendered[0] += 1
        camera.close()

    thread = None
    if with_camera:
        thread = threading.Thread(target=render_loop, daemon=True)
        thread.start()
        ready.wait(120.0)
    schedule = TickSchedule(CAMERA_RATE_HZ)

    def on_step(r):
        script(r)
        if with_camera and schedule.due(r.clock()):
            try:
                frames.put_nowait(capture_frame_state(sim))
            except queue.Full:
                dropped[0] += 1

    robot.run_until(seconds, on_step)
    if thread is not None:
        frames.put(None)
        thread.join(30.0)
    return robot.stats().real_time_factor, rendered[0], dropped[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--sizes', default='1280x960,960x720,640x480')
    parser.add_argument('--frames', type=int, default=20)
    parser.add_argument('--seconds', type=float, default=3.0)
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()
    print(load_line('start'))
    print(f"frame cost (brittle star, MUJOCO_GL={os.environ['MUJOCO_GL']}, LP_NUM_THREADS="
          f"{os.environ['LP_NUM_THREADS']}): size, wall ms per frame, render thread CPU ms, "
          'median (range)')
    for text in args.sizes.split(','):
        w, h = (int(v) for v in text.split('x'))
        wall, cpu = frame_cost((w, h), args.frames)
        print(f'  {w}x{h}: {fmt_spread(wall, 1e3)} ms wall, {fmt_spread(cpu, 1e3)} ms CPU')
    alone, camera, counts = [], [], []
    for _ in range(args.repeat):
        alone.append(walk(args.seconds, False)[0])
        factor, rendered, dropped = walk(args.seconds, True)
        camera.append(factor)
        counts.append((rendered, dropped))
    print(f'physics, brittle star walk, {args.seconds:g} s simulated, unpaced, {args.repeat} '
          'alternating pairs: real-time factor of the stepping loop, median (range)')
    print(f'  alone:                 {fmt_spread(alone, 1, 2)}')
    print(f'  with the 15 Hz camera: {fmt_spread(camera, 1, 2)}  '
          f'(ratio {sorted(camera)[len(camera) // 2] / sorted(alone)[len(alone) // 2]:.2f}; '
          f'frames rendered/dropped per run: {counts})')
    print(load_line('end'))


if __name__ == '__main__':
    main()
