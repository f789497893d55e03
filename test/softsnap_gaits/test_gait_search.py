"""Gait search: families, the MuJoCo objective, CMA-ES on processes and Ray, the YAML writer.

Rollouts are real (SimRobot: firmware, loaded winches, MuJoCo) but short and coarse
(one link per segment, one gait cycle), so the whole file takes a few CPU minutes; the
searches' timeouts allow for a machine loaded many times over.
"""
from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace

import numpy as np
import pytest
import yaml

from softsnap_gaits.gait_family import FamilyBounds, gait_family
from softsnap_gaits.gait_objective import DEFAULT_SETTINGS, SimSetting, rollout
from softsnap_gaits.gait_search import SearchConfig, make_backend, search
from softsnap_gaits.gait_yaml import write_scene_gait
from softsnap_gaits.gaits import GaitError, WINCH_SPEED_MARGIN, make_gait
from softsnap_model.scene import load_scene

COARSE = SimSetting('coarse', links_per_segment=1)
#: Short periods for the searches here: a rollout is one cycle of 1-1.5 s.
SHORT = FamilyBounds(period_s=(1.0, 1.5))
COARSE_JITTER = SimSetting('coarse-jitter', links_per_segment=1, jitter_s=0.03, rib_friction=0.5,
                           stiffness_scale=1.2, seed=3)


def _numeric_peak_speed_mm_s(gait, rate_hz=2000.0) -> np.ndarray:
    """Largest |d contraction / dt| per module from finite differences of the sampled
    curve over two periods (independent of the library's closed-form a*pi/(2r))."""
    t = np.arange(0.0, 2.0 * gait.period_s, 1.0 / rate_hz)
    c = gait.contraction_mm(t)
    return np.max(np.abs(np.diff(c, axis=0)) * rate_hz, axis=0)


@pytest.mark.parametrize('scene_name, family_name', [('brittle_star', 'walk'), ('snake', 'concertina')])
def test_every_decoded_point_is_a_gait_the_winches_follow(scene_name, family_name):
    scene = load_scene(scene_name)
    family = gait_family(family_name, scene)
    rng = np.random.default_rng(0)
    points = list(rng.uniform(0, 1, (40, family.dimension)))
    # Corners: the largest amplitudes with the shortest ramp and the extreme duties.
    points += [np.r_[0.0, 0.0, 0.0, np.ones(family.dimension - 3)],
               np.r_[1.0, 1.0, 0.0, np.ones(family.dimension - 3)]]
    excess_seen = False
    for x in points:
        decoded = family.decode(x)
        gait = make_gait(decoded.spec, scene, name='probe')   # raises if refused
        limit = WINCH_SPEED_MARGIN * np.array([m.winch_speed_mm_s for m in scene.modules])
        assert np.all(_numeric_peak_speed_mm_s(gait) <= limit * 1.001)
        excess_seen |= decoded.speed_excess > 0
        assert yaml.safe_load(yaml.safe_dump(decoded.spec)) == decoded.spec
    assert excess_seen, 'the corners should need their amplitudes scaled down'


def test_a_hand_gait_encodes_to_a_point_that_decodes_back_to_it():
    scene = load_scene('brittle_star')
    family = gait_family('walk', scene)
    gait = make_gait('walk', scene)
    hint = dict(gait.params, phases=gait.params['phase'])
    spec = family.decode(family.encode_hint(hint)).spec
    assert spec['period_s'] == pytest.approx(gait.period_s, abs=1e-3)
    assert spec['duty'] == pytest.approx(0.5, abs=1e-3)
    assert spec['rise_time_s'] == pytest.approx(0.75, abs=1e-3)
    assert spec['phases'] == pytest.approx(dict(gait.params['phase']), abs=1e-3)
    assert spec['amplitude_mm'] == pytest.approx(dict(gait.params['amplitude_mm']), abs=1e-2)


@pytest.mark.timeout(900)
def test_rollout_is_deterministic_and_a_straight_robot_stays_put():
    scene = load_scene('brittle_star')
    walk = dict(scene.gaits['walk'])
    a = rollout('brittle_star', walk, COARSE_JITTER, seconds=1.5)
    b = rollout('brittle_star', walk, COARSE_JITTER, seconds=1.5)
    assert a == b
    still = dict(walk, amplitude_mm=0.0)
    c = rollout('brittle_star', still, COARSE, seconds=1.5)
    assert abs(c.travel_mm_s) < 0.5 and c.power_w == 0.0 and not c.fell
    assert a.power_w > 0.0 and not a.fell


def _tiny(scene='brittle_star', **kw):
    return SearchConfig(scene=scene, family='pulse', seed=kw.pop('seed', 3), generations=2,
                        popsize=4, sigma0=0.3, seconds=kw.pop('seconds', 1.0),
                        settings=kw.pop('settings', (COARSE,)), **kw)


def _bad_start(family):
    """Every leg in phase with 3 mm: the robot only breathes in place."""
    n = len(family.modules)
    amp = 3.0 / family._amplitude_bounds[1]
    return tuple([0.5, 0.5, 0.5] + [0.0] * n + [amp] * n)


@pytest.mark.timeout(1800)
def test_a_tiny_search_improves_a_bad_gait_and_is_reproducible():
    scene = load_scene('brittle_star')
    family = gait_family('walk', scene, bounds=SHORT)
    config = _tiny(x0=_bad_start(family))
    backend = make_backend('serial')
    first = search(config, family, backend)
    assert abs(first.start_score) < 0.5
    assert first.best_score > first.start_score + 0.5, (first.start_score, first.best_score)
    # The written best is what was scored: its rollout reproduces the score.
    again = rollout('brittle_star', first.best_spec, COARSE, seconds=1.0)
    assert again == first.best_results[0]
    second = search(config, family, backend)
    assert [g.mean_score for g in second.history] == [g.mean_score for g in first.history]
    assert np.array_equal(second.best_x, first.best_x)
    other = search(replace(config, seed=4, generations=1), family, backend)
    assert other.history[0].mean_score != first.history[0].mean_score


@pytest.mark.timeout(1800)
def test_process_pool_gives_the_serial_result():
    scene = load_scene('brittle_star')
    family = gait_family('walk', scene, bounds=SHORT)
    config = _tiny(settings=(COARSE, COARSE_JITTER), seconds=1.0)
    config = replace(config, generations=1)
    serial = search(config, family, make_backend('serial'))
    pool = make_backend('process', workers=2)
    try:
        parallel = search(config, family, pool)
    finally:
        pool.close()
    assert [g.mean_score for g in parallel.history] == [g.mean_score for g in serial.history]
    assert np.array_equal(parallel.best_x, serial.best_x)
    assert parallel.best_results == serial.best_results


@pytest.mark.timeout(1800)
def test_ray_backend_on_a_local_cluster_gives_the_serial_result():
    ray = pytest.importorskip('ray')
    scene = load_scene('snake')
    family = gait_family('concertina', scene, bounds=SHORT)
    config = SearchConfig(scene='snake', family='wave', seed=5, generations=1, popsize=3,
                          seconds=1.0, settings=(COARSE,))
    serial = search(config, family, make_backend('serial'))
    backend = make_backend('ray', num_cpus=2, include_dashboard=False,
                           configure_logging=False, object_store_memory=200 * 2**20)
    try:
        assert ray.is_initialized()
        on_ray = search(config, family, backend)
    finally:
        backend.close()
    assert not ray.is_initialized()
    assert [g.best_score for g in on_ray.history] == [g.best_score for g in serial.history]
    assert np.array_equal(on_ray.best_x, serial.best_x)
    assert on_ray.best_results == serial.best_results


def _scene_copy(tmp_path, name='brittle_star'):
    src = load_scene(name).path
    dst = tmp_path / f'{name}.yaml'
    shutil.copy(src, dst)
    return dst


def test_yaml_round_trip_keeps_the_file_and_plays_the_gait(tmp_path):
    path = _scene_copy(tmp_path)
    before = path.read_text()
    family = gait_family('walk', load_scene(path))
    spec = family.decode(np.linspace(0.1, 0.9, family.dimension)).spec
    write_scene_gait(path, 'walk_found', spec, comments=['found by a test'])
    text = path.read_text()
    # Everything that was there is still there, comments included.
    for line in before.splitlines():
        assert line in text
    assert '# found by a test' in text
    scene = load_scene(path)
    assert scene.gaits['walk_found'] == spec
    assert list(scene.gaits)[:2] == ['walk', 'walk_reverse']
    gait = make_gait('walk_found', scene)
    assert gait.period_s == spec['period_s']
    # Replacing it changes only that entry.
    spec2 = dict(spec, period_s=round(spec['period_s'] + 0.5, 4))
    write_scene_gait(path, 'walk_found', spec2)
    scene2 = load_scene(path)
    assert scene2.gaits['walk_found'] == spec2
    assert scene2.gaits['walk'] == scene.gaits['walk']
    assert path.read_text().count('walk_found:') == 1


def test_a_gait_too_fast_for_the_winches_is_refused_and_nothing_written(tmp_path):
    path = _scene_copy(tmp_path)
    before = path.read_text()
    fast = {'type': 'pulse', 'period_s': 1.0, 'phases': {'blue': 0.0, 'red': 0.5},
            'duty': 0.5, 'amplitude_mm': 40.0, 'rise_time_s': 0.1}
    with pytest.raises(GaitError, match='winch'):
        write_scene_gait(path, 'too_fast', fast)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    with pytest.raises(ValueError, match='identifier'):
        write_scene_gait(path, 'bad name', fast)


@pytest.mark.timeout(1800)
def test_the_command_line_writes_curve_recording_and_scene(tmp_path, read_rrd):
    from PIL import Image
    from softsnap_gaits.optimise import main
    out = tmp_path / 'run'
    rc = main(['--scene', 'brittle_star', '--family', 'walk', '--start-gait', 'walk',
               '--generations', '1', '--popsize', '2', '--seconds', '1', '--settings',
               'coarse-jitter', '--warmup-cycles', '0', '--out', str(out), '--name', 'walk_try'])
    assert rc == 0
    image = Image.open(out / 'learning_curve.png')
    assert image.size == (640, 400)
    scene = load_scene(out / 'brittle_star.yaml')
    assert 'walk_try' in scene.gaits and scene.default_gait == 'walk'
    make_gait('walk_try', scene)
    result = json.loads((out / 'result.json').read_text())
    assert result['best_spec'] == scene.gaits['walk_try']
    rec = read_rrd(out / 'best.rrd')
    frames = rec.rows['world/robot/ribs']
    # The gait's whole cycles, sampled every 0.1 s.
    assert len(frames) == round(result['best_results'][0]['seconds'] / 0.1)
    assert len(frames[0]['LineStrips3D:strips']) == 5     # one strip per leg
    assert all(math.isfinite(v) for strip in frames[-1]['LineStrips3D:strips']
               for p in strip for v in p)


def test_the_shipped_optimised_gait_is_a_pulse_gait_the_winches_follow():
    scene = load_scene('brittle_star')
    gait = make_gait('walk_optimised', scene)
    assert gait.type == 'pulse' and scene.default_gait == 'walk'
    limit = WINCH_SPEED_MARGIN * np.array([m.winch_speed_mm_s for m in scene.modules])
    assert np.all(_numeric_peak_speed_mm_s(gait) <= limit * 1.001)
    assert np.all(gait.peak_contraction_mm <= gait.limit_contraction_mm)
