"""A recording opened in rerun's bundled web viewer, offline, in headless Chromium.

The viewer is served by `python -m softsnap_model.recording view` (the web viewer files
ship inside rerun-sdk); Chromium comes from scripts/install_browser.sh (Debian's package)
and is driven by Playwright without any browser download. The screenshot must show the
robot: pixels in the commanded (blue) and predicted (orange) spine colours, not just the
loading screen.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from softsnap_model import recording as rec_mod

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
VIEWPORT = {'width': 1280, 'height': 800}
# Software WebGL: there is no GPU on CI machines.
CHROMIUM_ARGS = ['--no-sandbox', '--enable-unsafe-swiftshader', '--use-angle=swiftshader',
                 '--ignore-gpu-blocklist', '--disable-dev-shm-usage']
RENDER_TIMEOUT_S = 90.0
COLOR_TOLERANCE = 60   # sum of absolute RGB differences counted as "this colour"
MIN_SPINE_PIXELS = 100


@pytest.fixture(scope='session')
def chromium(tmp_path_factory) -> str:
    """Path of a Chromium executable, installed by scripts/install_browser.sh if needed."""
    result = subprocess.run(['bash', str(REPO / 'scripts' / 'install_browser.sh')],
                            capture_output=True, text=True, timeout=900)
    if result.returncode != 0:
        pytest.skip('Chromium cannot be installed on this machine: '
                    + (result.stderr.strip().splitlines() or ['no reason given'])[-1])
    return result.stdout.strip().splitlines()[-1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def write_walk(path: Path, ticks: int = 30) -> None:
    """A brittle star whose legs bend over time, commanded ahead of predicted."""
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    rec = rec_mod.open_recording(path, blueprint=rec_mod.build_blueprint())
    recorder = rec_mod.RobotRecorder(
        rec, threadings_mm={m.name: m.threading_mm for m in scene.modules}, rate_hz=0.0)
    t0 = 1_795_000_000_000_000_000
    recorder.base_poses(t0, {m.name: (m.base_position_m, m.base_orientation_xyzw)
                             for m in scene.modules})
    for tick in range(ticks):
        t = t0 + tick * 33_000_000
        for k, module in enumerate(scene.modules):
            bend = -0.9 * np.sin(0.2 * tick + k) ** 2
            recorder.shape(t, module.name, 'commanded', [bend / 11] * 11, solve_time_s=0.001)
            recorder.shape(t, module.name, 'predicted', [0.7 * bend / 11] * 11,
                           solve_time_s=0.002)
            recorder.cable_length(t, module.name, 'commanded', 0.2 + 0.01 * bend)
            recorder.cable_length(t, module.name, 'measured', 0.2 + 0.007 * bend)
            recorder.module_state(t, module.name, 7.4 - 0.001 * tick)
    rec_mod.close_recording(rec)


@pytest.fixture
def served_recording(tmp_path):
    """Serve a fresh recording to the web viewer; yields the viewer url."""
    path = tmp_path / 'walk.rrd'
    write_walk(path)
    web_port, grpc_port = free_port(), free_port()
    proc = subprocess.Popen(
        [sys.executable, '-m', 'softsnap_model.recording', 'view', str(path),
         '--web-port', str(web_port), '--grpc-port', str(grpc_port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith('open '), line + proc.stdout.read() if proc.poll() else line
        url = line.split()[1]
        deadline = time.monotonic() + 30.0
        while True:
            try:
                with urllib.request.urlopen(f'http://127.0.0.1:{web_port}/', timeout=2) as reply:
                    assert reply.status == 200
                    break
            except OSError:
                assert time.monotonic() < deadline, 'web viewer did not answer'
                time.sleep(0.1)
        yield url
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def colour_pixels(image: np.ndarray, rgb) -> int:
    """Pixels within COLOR_TOLERANCE of ``rgb``, ignoring the top and bottom bars."""
    body = image[40:-40].astype(int)
    return int((np.abs(body - np.asarray(rgb)).sum(axis=2) < COLOR_TOLERANCE).sum())


@pytest.mark.timeout(1200)  # the first run may install Chromium (apt-get, ~100 MB)
def test_web_viewer_shows_the_robot_offline(chromium, served_recording, tmp_path):
    sync_api = pytest.importorskip(
        'playwright.sync_api',
        reason='playwright is not installed: it is listed in requirements/jazzy.in; '
               'regenerate the lock (scripts/lock_requirements.sh) and re-run bootstrap')
    from io import BytesIO

    from PIL import Image

    shot = tmp_path / 'viewer.png'
    counts = {}
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, headless=True,
                                             args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(served_recording)
            deadline = time.monotonic() + RENDER_TIMEOUT_S
            previous = None
            # Poll until the 3D view has drawn both spines (software WebGL takes ~6-15 s)
            # and the page has settled: two screenshots a second apart are identical.
            while True:
                png = page.screenshot(path=str(shot))
                image = np.asarray(Image.open(BytesIO(png)).convert('RGB'))
                counts = {source: colour_pixels(image, rec_mod.SPINE_COLORS[source])
                          for source in rec_mod.SOURCES}
                drawn = min(counts.values()) >= MIN_SPINE_PIXELS
                if (drawn and png == previous) or time.monotonic() > deadline:
                    break
                previous = png
                page.wait_for_timeout(1000)
        finally:
            browser.close()

    assert image.std() > 15.0, f'screenshot is nearly uniform (blank or loading): {shot}'
    assert min(counts.values()) >= MIN_SPINE_PIXELS, (
        f'spine colours not drawn {counts}: see {shot}')
