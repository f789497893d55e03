"""A recording opened in rerun's bundled web viewer, offline, in headless Chromium.

The viewer is served by `python -m softsnap_model.recording view` (the web viewer files
ship inside rerun-sdk); Chromium comes from scripts/install_browser.sh (Debian's package)
and is driven by Playwright without any browser download. The screenshot must show the
robot: pixels in every module's colour (predicted, bold) and in its dim commanded colour,
not just the loading screen.

The screenshot in the README (docs/viewer.png) is this test's: run it with
SOFTSNAP_UPDATE_DOCS=1 to write it there (otherwise it stays in the test's tmp_path).
"""
from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from softsnap_ros.processes import stop_process_group
from softsnap_model import recording as rec_mod

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
VIEWPORT = {'width': 1280, 'height': 800}
# Software WebGL: there is no GPU on CI machines.
CHROMIUM_ARGS = ['--no-sandbox', '--enable-unsafe-swiftshader', '--use-angle=swiftshader',
                 '--ignore-gpu-blocklist', '--disable-dev-shm-usage']
RENDER_TIMEOUT_S = 90.0
#: Playwright's own deadline per page load and per screenshot (ms). Its default, 30 s, is
#: too short for a software-rendered frame when other processes keep both cores busy.
PAGE_TIMEOUT_MS = 180_000
COLOR_TOLERANCE = 60   # sum of absolute RGB differences counted as "this colour"
MIN_SPINE_PIXELS = 100
STABLE_SHOTS = 5
#: For the docs picture: the software-rendered viewer on a busy machine draws a frame
#: every few seconds while it streams the file in, so wait for a long still period.
DOCS_STABLE_SHOTS, DOCS_TIMEOUT_S = 30, 400.0
#: Set to 1 to save the screenshot as docs/viewer.png (the README's picture).
UPDATE_DOCS_ENV = 'SOFTSNAP_UPDATE_DOCS'
DOCS_SHOT = REPO / 'docs' / 'viewer.png'


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


def write_walk(path: Path, ticks: int = 60, physics: bool = False) -> None:
    """The brittle star's walk (3 s cycle, 30 mm steps) solved by the model: the measured
    length lags the commanded one (a winch at 62.8 mm/s of cable), so the predicted legs
    trail the commanded ones on each ramp and meet them in each hold."""
    from softsnap_gaits.gaits import make_gait
    from softsnap_model.forward import solve_forward
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    gait = make_gait('walk', scene)
    colors, bounds = rec_mod.scene_style(scene)
    # physics: as a --physics run records it (sim_robot's /clock from 0: simulated
    # seconds on a duration timeline, the world view, the robot frame moving in it).
    rec = rec_mod.open_recording(path, blueprint=rec_mod.build_blueprint(
        colors, bounds, world_view=physics))
    recorder = rec_mod.RobotRecorder(
        rec, threadings_mm={m.name: m.threading_mm for m in scene.modules}, rate_hz=0.0,
        colors=colors, sim_time=physics)
    t0 = 2_000_000_000 if physics else 1_795_000_000_000_000_000
    recorder.base_poses(t0, {m.name: (m.base_position_m, m.base_orientation_xyzw)
                             for m in scene.modules})
    for tick in range(ticks):
        t_s = 3.0 + tick / 30.0          # from the first group's ramp into the second's
        stamp = t0 + int(tick * 33_333_333)
        if physics:   # the robot base creeping forward and turning a little in the world
            recorder.robot_pose(stamp, (0.0002 * tick, 0.0, 0.0045),
                                (0.0, 0.0, math.sin(0.001 * tick), math.cos(0.001 * tick)))
        commanded = gait.cable_length_mm(t_s)
        measured = gait.cable_length_mm(max(t_s - 0.25, 0.0))   # the winch 0.25 s behind
        for k, module in enumerate(scene.modules):
            for source, length in (('commanded', commanded[k]), ('predicted', measured[k])):
                shape = solve_forward(scene.skeleton, module.threading_mm, float(length))
                recorder.shape(stamp, module.name, source, shape.angles,
                               solve_time_s=0.001 if source == 'commanded' else 0.002)
            recorder.cable_length(stamp, module.name, 'commanded', commanded[k] / 1000.0)
            recorder.cable_length(stamp, module.name, 'measured', measured[k] / 1000.0)
            recorder.module_state(stamp, module.name, 4.1 - 0.001 * tick - 0.01 * k)
    rec_mod.close_recording(rec)


@pytest.fixture
def served_recording(tmp_path):
    """Serve a fresh recording to the web viewer; yields the viewer url."""
    yield from _serve(tmp_path, physics=False)


@pytest.fixture
def served_physics_recording(tmp_path):
    """The same walk recorded as a --physics run records it."""
    yield from _serve(tmp_path, physics=True)


def _serve(tmp_path, physics: bool):
    path = tmp_path / 'walk.rrd'
    write_walk(path, physics=physics)
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
        stop_process_group(proc, 10.0)


def colour_pixels(image: np.ndarray, rgb) -> int:
    """Pixels within COLOR_TOLERANCE of ``rgb``, ignoring the top and bottom bars."""
    body = image[40:-40].astype(int)
    return int((np.abs(body - np.asarray(rgb)).sum(axis=2) < COLOR_TOLERANCE).sum())


@pytest.mark.timeout(1200)  # the first run may install Chromium (apt-get, ~100 MB)
def test_web_viewer_shows_the_robot_offline(chromium, served_recording, tmp_path):
    """Every module drawn in its own colour, bold (predicted) and dim (commanded)."""
    sync_api = pytest.importorskip(
        'playwright.sync_api',
        reason='playwright is not installed: it is listed in requirements/jazzy.in; '
               'regenerate the lock (scripts/lock_requirements.sh) and re-run bootstrap')
    from io import BytesIO

    from PIL import Image

    shot = tmp_path / 'viewer.png'
    counts = {}
    colors = {name: rec_mod.NAMED_COLORS[name]
              for name in ('yellow', 'blue', 'green', 'red', 'orange')}
    targets = {f'{name} predicted': rgb for name, rgb in colors.items()}
    targets.update({f'{name} commanded': rec_mod.role_color(rgb, 'commanded')
                    for name, rgb in colors.items()})
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, headless=True,
                                             args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(PAGE_TIMEOUT_MS)
            page.goto(served_recording)
            docs = os.environ.get(UPDATE_DOCS_ENV) == '1'
            stable = DOCS_STABLE_SHOTS if docs else STABLE_SHOTS
            deadline = time.monotonic() + (DOCS_TIMEOUT_S if docs else RENDER_TIMEOUT_S)
            # Poll until the 3D view has drawn every module (software WebGL takes ~6-15 s)
            # and the page has settled: STABLE_SHOTS screenshots a second apart are identical
            # (the viewer streams the file in; on a loaded machine it pauses between chunks).
            history = []
            while True:
                png = page.screenshot(path=str(shot))
                image = np.asarray(Image.open(BytesIO(png)).convert('RGB'))
                counts = {key: colour_pixels(image, rgb) for key, rgb in targets.items()}
                drawn = min(counts.values()) >= MIN_SPINE_PIXELS
                history = history[1 - stable:] + [png]
                if (drawn and len(history) == stable and len(set(history)) == 1) \
                        or time.monotonic() > deadline:
                    break
                page.wait_for_timeout(1000)
        finally:
            browser.close()

    if docs:
        DOCS_SHOT.write_bytes(shot.read_bytes())
    assert image.std() > 15.0, f'screenshot is nearly uniform (blank or loading): {shot}'
    assert min(counts.values()) >= MIN_SPINE_PIXELS, (
        f'module colours not drawn {counts}: see {shot}')


@pytest.mark.timeout(1200)
def test_the_viewer_page_requests_nothing_beyond_this_machine(chromium, served_recording,
                                                             tmp_path):
    """Every request the page makes while it loads and draws goes to 127.0.0.1 (no web
    fonts, no examples list from rerun's site; softsnap_model.viewer_offline)."""
    sync_api = pytest.importorskip('playwright.sync_api')
    from urllib.parse import urlparse
    requests = []
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, headless=True,
                                             args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(PAGE_TIMEOUT_MS)
            page.on('request', lambda request: requests.append(request.url))
            page.goto(served_recording)
            deadline = time.monotonic() + RENDER_TIMEOUT_S
            while time.monotonic() < deadline:   # until the page fetched the examples list
                if any('examples_manifest' in url for url in requests):
                    break
                page.wait_for_timeout(1000)
            page.wait_for_timeout(5000)
        finally:
            browser.close()
    hosts = {urlparse(url).hostname for url in requests if not url.startswith(('data:', 'blob:'))}
    assert requests and hosts == {'127.0.0.1'}, sorted(set(requests))[:20]
    assert any('manifest' in url for url in requests), 'the page never asked for examples'


@pytest.mark.timeout(1200)
def test_a_physics_recording_shows_the_robot_with_simulated_seconds(chromium,
                                                                   served_physics_recording,
                                                                   tmp_path):
    """Regression: --physics recordings (stamps from 0 s of simulated time, the world
    view) showed an empty 3D view and a date in January 1970 on the timeline."""
    sync_api = pytest.importorskip('playwright.sync_api')
    from io import BytesIO

    from PIL import Image
    shot = tmp_path / 'physics.png'
    targets = {name: rec_mod.NAMED_COLORS[name]
               for name in ('yellow', 'blue', 'green', 'red', 'orange')}
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, headless=True,
                                             args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(PAGE_TIMEOUT_MS)
            page.goto(served_physics_recording)
            deadline = time.monotonic() + RENDER_TIMEOUT_S
            while True:
                png = page.screenshot(path=str(shot))
                image = np.asarray(Image.open(BytesIO(png)).convert('RGB'))
                counts = {key: colour_pixels(image, rgb) for key, rgb in targets.items()}
                if min(counts.values()) >= MIN_SPINE_PIXELS or time.monotonic() > deadline:
                    break
                page.wait_for_timeout(1000)
        finally:
            browser.close()
    assert min(counts.values()) >= MIN_SPINE_PIXELS, f'modules not drawn {counts}: see {shot}'
    # The timeline is simulated seconds (a duration), not a timestamp near the epoch.
    import pyarrow as pa
    from rerun.chunk import RrdReader
    types = {field.type for chunk in RrdReader(str(tmp_path / 'walk.rrd')).stream().to_chunks()
             for field in chunk.to_record_batch().schema if field.name == 'ros_time'}
    assert types and all(pa.types.is_duration(t) for t in types), types
