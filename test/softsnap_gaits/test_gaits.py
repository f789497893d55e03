"""Gait library: each robot's command sequence over one period against its definition."""
import math

import numpy as np
import pytest

from softsnap_gaits.gaits import (GAIT_TYPES, WINCH_SPEED_MARGIN, GaitError, ease_keyframes,
                                  make_gait, pulse_shape, reachable_contraction_mm)
from softsnap_gaits.player import PAUSED, RUNNING, STOPPED, GaitPlayer
from softsnap_model.scene import list_scenes, load_scene

RATE_HZ = 1000.0          # sampling of the command sequences in these tests
ALL_GAITS = [(s, g) for s in ['brittle_star', 'starfish', 'snake', 'gripper', 'ring']
             for g in load_scene(s).gaits]


@pytest.fixture(scope='module')
def scenes():
    return {name: load_scene(name) for name in list_scenes()}


def contraction(gait, module, t):
    return gait.contraction_mm(np.asarray(t, dtype=float))[..., gait.index(module)]


# --------------------------------------------------------------- properties of every gait

@pytest.mark.parametrize('scene_name, gait_name', ALL_GAITS)
def test_every_gait_starts_straight_stays_in_range_and_is_smooth(scenes, scene_name, gait_name):
    scene = scenes[scene_name]
    gait = make_gait(gait_name, scene)
    assert gait.reachable_checked
    assert gait.module_names == scene.module_names
    t, c = gait.sample(RATE_HZ)
    assert c.shape == (len(t), len(scene.modules))
    assert np.all(gait.contraction_mm(0.0) == 0.0)                 # starts from straight
    assert np.all(c >= 0.0)
    assert np.all(c.max(axis=0) <= gait.peak_contraction_mm + 1e-9)
    assert np.all(gait.peak_contraction_mm <= gait.limit_contraction_mm)
    assert gait.amplitude_mm > 0
    for m, limit in zip(scene.modules, gait.limit_contraction_mm):
        assert limit <= min(m.max_contraction_mm,
                            reachable_contraction_mm(scene.skeleton, m.threading_mm))
    # Smooth for a motor: no step larger than the peak speed allows between samples.
    dt = 1.0 / RATE_HZ
    steps = np.abs(np.diff(gait.contraction_mm(np.arange(0, 2 * gait.period_s, dt)), axis=0))
    assert np.all(np.isfinite(gait.peak_speed_mm_s))
    # ... and no faster than the winches follow (the scene's winch speed, with margin).
    assert np.all(gait.peak_speed_mm_s <= gait.speed_limit_mm_s)
    assert gait.speed_limit_mm_s == pytest.approx(
        [WINCH_SPEED_MARGIN * m.winch_speed_mm_s for m in scene.modules])
    assert np.all(steps <= gait.peak_speed_mm_s * dt * (1 + 1e-6) + 1e-9)
    lengths = gait.cable_length_mm(t)
    assert lengths == pytest.approx(gait.straight_length_mm - c)
    if gait.loop:   # periodic after the first cycle
        t2 = np.arange(gait.period_s, 2 * gait.period_s, 0.013)
        assert gait.contraction_mm(t2 + gait.period_s) == pytest.approx(gait.contraction_mm(t2),
                                                                        abs=1e-9)


# --------------------------------------------------------------- each robot's definition

def _shape_area_mm2(gait, a: str, b: str) -> float:
    """Signed area (mm^2) the contractions of modules a and b enclose over one cycle
    (the second, past the start-up): positive when a moves first (counter-clockwise)."""
    t = np.linspace(gait.period_s, 2.0 * gait.period_s, 30001)
    c = gait.contraction_mm(t)
    x, y = c[:, gait.index(a)], c[:, gait.index(b)]
    return 0.5 * float(np.sum(x[:-1] * np.diff(y) - y[:-1] * np.diff(x)))


def test_brittle_star_walk_reverse_loops_through_shape_space_and_walk_does_not(scenes):
    # In a quasi-static world with Coulomb friction, a cycle of shapes that goes back
    # and forth along one path moves the robot only through slip hysteresis, whatever
    # its timing; a cycle enclosing an area moves it by the loop, and the loop traversed
    # backwards moves it the other way (docs/sim_robot.md). walk is a two-state cycle,
    # walk_reverse a loop: yellow in, green and red in, yellow out, green and red out.
    scene = scenes['brittle_star']
    walk, reverse = make_gait('walk', scene), make_gait('walk_reverse', scene)
    assert reverse.period_s == walk.period_s == 3.0
    pairs = [(a, b) for k, a in enumerate(walk.module_names) for b in walk.module_names[k + 1:]]
    assert all(abs(_shape_area_mm2(walk, a, b)) < 1e-6 for a, b in pairs)
    # Nearly the whole 40 x 40 mm square, yellow first; no other pair loops.
    for other in ('green', 'red'):
        assert 0.95 * 40.0 ** 2 < _shape_area_mm2(reverse, 'yellow', other) <= 40.0 ** 2
    assert abs(_shape_area_mm2(reverse, 'green', 'red')) < 1e-6
    assert abs(_shape_area_mm2(reverse, 'yellow', 'blue')) < 1e-6
    # Not walk shifted in time (swapped groups would be, and walk the same way).
    t = np.linspace(0.0, 3.0, 301)
    for shift in np.linspace(0.0, 3.0, 31):
        assert not np.allclose(reverse.contraction_mm(t + 3.0),
                               walk.contraction_mm(t + 3.0 + shift), atol=1.0)
    # The order within a cycle: yellow rising alone; yellow in while green and red
    # rise; green and red in while yellow falls; green and red falling alone.
    expect = {3.3: (9.1, 0.0), 4.4: (40.0, 30.9), 5.3: (2.4, 39.7), 5.9: (0.0, 9.1)}
    for t_s, (yellow, green) in expect.items():
        c = dict(zip(reverse.module_names, reverse.contraction_mm(t_s)))
        assert c == pytest.approx({'yellow': yellow, 'blue': 0.0, 'green': green,
                                   'red': green, 'orange': 0.0}, abs=0.05), t_s
    # Within the winches: 40 mm on 0.95 s ramps, 66.1 mm/s <= 75 % of 92.4 mm/s.
    assert reverse.peak_speed_mm_s.max() == pytest.approx(40.0 * math.pi / 1.9)
    assert np.all(reverse.peak_speed_mm_s <= reverse.speed_limit_mm_s)


def test_brittle_star_walk_alternates_two_groups_every_half_cycle(scenes):
    gait = make_gait('walk', scenes['brittle_star'])
    assert gait.period_s == 3.0 and gait.loop and gait.time_scale == 1.0
    first, second = ['blue', 'orange'], ['yellow', 'green', 'red']
    rise = gait.params['rise_time_s']
    assert rise == 0.75
    for cycle in (0, 1, 5):
        # Holding parts of each half: one group at 30 mm, the other straight.
        for t in 3.0 * cycle + np.linspace(rise, 1.5, 20, endpoint=False):
            c = dict(zip(gait.module_names, gait.contraction_mm(t)))
            assert all(c[m] == pytest.approx(30.0) for m in first)
            assert all(c[m] == pytest.approx(0.0, abs=1e-9) for m in second)
        for t in 3.0 * cycle + np.linspace(1.5 + rise, 3.0, 20, endpoint=False):
            c = dict(zip(gait.module_names, gait.contraction_mm(t)))
            assert all(c[m] == pytest.approx(30.0) for m in second)
            assert all(c[m] == pytest.approx(0.0, abs=1e-9) for m in first)
    # Edges: half-way up half a rise time after each switch.
    assert contraction(gait, 'blue', 3 + rise / 2) == pytest.approx(15.0)
    assert contraction(gait, 'yellow', 4.5 + rise / 2) == pytest.approx(15.0)
    assert contraction(gait, 'blue', 4.5 + rise / 2) == pytest.approx(15.0)
    # First cycle: the second group rests until its first onset at 1.5 s.
    assert contraction(gait, 'yellow', 0.75) == 0.0
    # The winch can follow: 30 mm on a 0.75 s cosine ramp peaks at 30 pi / 1.5 mm/s.
    assert gait.peak_speed_mm_s == pytest.approx(np.full(5, 20.0 * math.pi))


def test_snake_concertina_deforms_head_to_tail_then_restores_head_to_tail(scenes):
    gait = make_gait('concertina', scenes['snake'])
    assert gait.period_s == pytest.approx(3.0)
    order = ['head', 'body2', 'body3', 'body4', 'tail']
    t = np.arange(0.0, 3.0, 1e-4)
    c = gait.contraction_mm(t)
    half = 25.0 / 2
    onsets, releases = [], []
    for m in order:
        x = c[:, gait.index(m)]
        onsets.append(t[np.argmax(x >= half)])
        releases.append(t[np.nonzero(x >= half)[0][-1]])
    rise = gait.params['rise_time_s']
    # Onset k at k * 0.15 s (+ half the rise), release 1.5 s (duty 0.5) later.
    assert onsets == pytest.approx([k * 0.15 + rise / 2 for k in range(5)], abs=2e-4)
    assert releases == pytest.approx([k * 0.15 + 1.5 + rise / 2 for k in range(5)], abs=2e-4)
    # Fully contracted body between the tail's full contraction and the head's release.
    full = (t > 0.6 + rise) & (t < 1.5)
    assert full.any() and np.all(c[full] == pytest.approx(25.0))
    assert np.all(c[t > 2.1 + rise] == pytest.approx(0.0, abs=1e-9))  # straight before next cycle


def test_starfish_righting_plays_the_script_then_relaxes(scenes):
    scene = scenes['starfish']
    gait = make_gait('righting', scene)
    assert not gait.loop and gait.period_s == 10.5 and gait.duration_s == 10.5
    for module, frames in scene.gaits['righting']['keyframes'].items():
        for t, value in frames:
            assert contraction(gait, module, t) == pytest.approx(value, abs=1e-9)
    # Midway between two keyframes: the mean of their values (cosine ease).
    assert contraction(gait, 'yellow', 0.55) == pytest.approx(22.5)
    # The top legs are raised by 1.75 s and held until the fall at 3.25 s.
    for m in ('yellow', 'green', 'red'):
        assert contraction(gait, m, 1.75) > 25 and contraction(gait, m, 3.25) > 25
    # After the script the robot relaxes and stays relaxed.
    assert np.all(gait.contraction_mm(np.array([10.5, 11.25, 30.0])) == 0.0)
    assert gait.phase(5.25) == (0.5, 0) and gait.phase(12.0) == (1.0, 1)
    assert gait.finished(10.5) and not gait.finished(10.4)


def test_gripper_grasp_closes_holds_opens_all_four_together(scenes):
    gait = make_gait('grasp', scenes['gripper'])
    p = gait.params
    assert (p['close_s'], p['hold_s'], p['open_s'], p['rest_s']) == (1.5, 2.5, 1.5, 0.5)
    assert gait.period_s == 6.0 and gait.loop
    t, c = gait.sample(RATE_HZ)
    assert np.all(c == c[:, :1])                                       # same signal
    x = c[:, 0]
    assert np.all(np.diff(x[t < 1.5]) >= 0) and x[t < 1.5].max() < 45.0   # closing
    assert np.all(x[(t >= 1.5) & (t <= 4.0)] == pytest.approx(45.0))        # holding
    assert np.all(np.diff(x[(t > 4.0) & (t < 5.5)]) <= 0)                  # opening
    assert np.all(x[t >= 5.5] == pytest.approx(0.0, abs=1e-9))               # resting
    assert x[t == 0.75][0] == pytest.approx(22.5)


def test_ring_transport_always_cages_with_one_pair_while_the_other_regrips(scenes):
    gait = make_gait('transport', scenes['ring'])
    assert gait.period_s == 12.0
    # Adjacent pairs (opposite pairs keep the ring half-turn symmetric: it cannot travel).
    a, b = ['south', 'east'], ['north', 'west']
    t = np.arange(gait.period_s, 2 * gait.period_s, 1e-3)               # steady state
    c = gait.contraction_mm(t)
    grip_a = np.all(c[:, [gait.index(m) for m in a]] >= 60.0 - 1e-9, axis=1)
    grip_b = np.all(c[:, [gait.index(m) for m in b]] >= 60.0 - 1e-9, axis=1)
    assert np.all(grip_a | grip_b)                                      # always caged
    # The modules of a pair move together.
    for x, y in (a, b):
        assert c[:, gait.index(x)] == pytest.approx(c[:, gait.index(y)])
    # Each pair releases (returns to straight) once per cycle, in turn: B then A.
    u = t - gait.period_s
    released_b = u[c[:, gait.index('north')] < 1e-9]
    released_a = u[c[:, gait.index('south')] < 1e-9]
    # B grips from 6 s to 9 s + 6 s (mod 12), falls for 1.4 s: straight in [4.4, 6] s.
    assert released_b.min() > 4.0 and released_b.max() <= 6.0 + 1e-6
    assert set(np.round(released_a, 3)) - {0.0} <= set(np.round(np.arange(10.4, 12.0, 1e-3), 3))
    assert len(released_a) and len(released_b)


# ------------------------------------------------------------------------ overrides

def test_period_and_amplitude_overrides(scenes):
    scene = scenes['brittle_star']
    base = make_gait('walk', scene)
    slow = make_gait('walk', scene, period_s=2.0, amplitude_mm=20.0)
    assert slow.period_s == 2.0 and slow.amplitude_mm == pytest.approx(20.0)
    assert slow.params['rise_time_s'] == base.params['rise_time_s']    # rise kept in seconds
    # In the holds: the same pattern at 2/3 of the amplitude.
    assert slow.contraction_mm(2.9) == pytest.approx(base.contraction_mm(4.0) * 2 / 3)
    righting = make_gait('righting', scenes['starfish'], period_s=21.0, amplitude_mm=25.0)
    ref = make_gait('righting', scenes['starfish'])
    assert righting.contraction_mm(7.0) == pytest.approx(ref.contraction_mm(3.5) * 0.5)


def test_amplitude_beyond_the_paper_range_refused(tmp_path):
    # Thin ribs (the paper's model) let yellow reach 83 mm, so the scene's 80 mm limit
    # binds; this also checks that a scene's skeleton carries rib_thickness_mm.
    import yaml
    from softsnap_model.scene import find_scene
    data = yaml.safe_load(find_scene('brittle_star').read_text())
    data['skeleton'] = {'rib_thickness_mm': 0.0}
    path = tmp_path / 'thin.yaml'
    path.write_text(yaml.safe_dump(data))
    scene = load_scene(path)
    assert scene.skeleton.rib_thickness_mm == 0.0
    with pytest.raises(GaitError, match=r"module 'yellow' would contract 90\.000 mm, beyond "
                                        r"the scene's max_contraction_mm \(80\.000 mm\)"):
        make_gait('walk', scene, amplitude_mm=90.0)


def test_amplitude_beyond_the_solver_reach_refused(tmp_path):
    import yaml
    from softsnap_model.scene import find_scene
    data = yaml.safe_load(find_scene('brittle_star').read_text())
    data['defaults']['max_contraction_mm'] = 150.0
    path = tmp_path / 'greedy.yaml'
    path.write_text(yaml.safe_dump(data))
    scene = load_scene(path)
    reach = reachable_contraction_mm(scene.skeleton, scene.module('yellow').threading_mm)
    assert 60.0 < reach < 80.0      # yellow (R1..R3) reaches 70.4 mm with the CAD's 3 mm ribs
    with pytest.raises(GaitError, match=r"'yellow'.*solver's reachable contraction"):
        make_gait('walk', scene, amplitude_mm=75.0)
    assert make_gait('walk', scene, amplitude_mm=70.0, time_scale='auto').amplitude_mm == 70.0


@pytest.mark.parametrize('period', [0.0, -1.0, 1e9, math.nan])
def test_bad_period_override_refused(scenes, period):
    with pytest.raises(GaitError, match='period'):
        make_gait('walk', scenes['brittle_star'], period_s=period)


# ------------------------------------------------------------- winch speed, time scale

#: Brittle star winches: 92.4 mm/s stated, 75 % of it usable.
LIMIT_MM_S = WINCH_SPEED_MARGIN * 92.4
#: 40 mm on 0.1 s cosine ramps: peak speed 40 pi / (2 * 0.1) = 628.3 mm/s.
FAST_PULSE = {'type': 'alternating', 'period_s': 1.0, 'groups': [['blue'], ['red']],
              'amplitude_mm': 40.0, 'rise_time_s': 0.1}


def test_gait_too_fast_for_the_winch_refused_with_the_numbers(scenes):
    """Regression (issue 14): 40 mm steps every 0.5 s that a 92 mm/s winch cannot follow."""
    assert LIMIT_MM_S == pytest.approx(69.3)
    with pytest.raises(GaitError, match=r"gaits\.custom: module 'blue' needs 628\.3 mm/s of cable "
                       r"on its 40 mm pulse edges \(0\.1 s cosine ramps, rise_time_s\), beyond "
                       r"69\.3 mm/s \(75% of its winch speed 92\.4 mm/s.*at least 9\.07 times "
                       r"\(time_scale: auto"):
        make_gait(FAST_PULSE, scenes['brittle_star'])
    # Keyframes: the fastest ease is named. 20 mm in 0.4 s: 20 pi / 0.8 = 78.5 mm/s.
    frames = {'type': 'keyframes', 'period_s': 2.0, 'loop': False,
              'keyframes': {'green': [[0, 0], [1.0, 20.0], [1.4, 0.0]]}}
    with pytest.raises(GaitError, match=r"module 'green' needs 78\.5 mm/s of cable on its "
                       r"keyframes \[1 s, 20 mm\] -> \[1\.4 s, 0 mm\]"):
        make_gait(frames, scenes['brittle_star'])
    # 20 mm in 0.5 s (62.8 mm/s) is within the limit.
    frames['keyframes']['green'][2][0] = 1.5
    assert make_gait(frames, scenes['brittle_star']).peak_speed_mm_s[2] == pytest.approx(
        20.0 * math.pi)


def test_an_amplitude_override_is_held_to_the_winch_speed_too(scenes):
    # walk: 30 mm on 0.75 s ramps = 62.8 mm/s; 40 mm would need 83.8 mm/s.
    with pytest.raises(GaitError, match=r"needs 83\.8 mm/s of cable on its 30 mm pulse edges "
                       r"\(0\.75 s cosine ramps, rise_time_s\) scaled by 1\.33 \(amplitude override\)"):
        make_gait('walk', scenes['brittle_star'], amplitude_mm=40.0)


def test_time_scale_auto_slows_a_fast_gait_just_enough(scenes):
    scene = scenes['brittle_star']
    gait = make_gait(FAST_PULSE, scene, time_scale='auto')
    scale = 40.0 * math.pi / 0.2 / LIMIT_MM_S                        # 9.067
    assert gait.time_scale == pytest.approx(scale) and gait.params['time_scale'] == gait.time_scale
    assert gait.period_s == pytest.approx(scale) and gait.params['rise_time_s'] == pytest.approx(0.1 * scale)
    assert gait.peak_speed_mm_s.max() == pytest.approx(LIMIT_MM_S)   # exactly at the limit
    # The same curve, slower: contraction at scale * t equals the spec's at t.
    t = np.array([0.05, 0.1, 0.3, 0.55, 0.62, 0.9])
    blue = 40.0 * pulse_shape(t, duty=0.5, rise=0.1)
    assert gait.contraction_mm(t * scale)[:, gait.index('blue')] == pytest.approx(blue)
    # Measured on samples: no step between 1 ms samples beyond the limit.
    c = gait.contraction_mm(np.arange(0.0, 2 * gait.period_s, 1e-3))
    assert np.abs(np.diff(c, axis=0)).max() <= LIMIT_MM_S * 1e-3 * (1 + 1e-6)
    # A gait slow enough already is left alone.
    walk = make_gait('walk', scene, time_scale='auto')
    assert walk.time_scale == 1.0 and walk.period_s == 3.0


def test_time_scale_from_the_spec_or_the_caller(scenes):
    scene = scenes['brittle_star']
    spec = dict(FAST_PULSE, time_scale=10)
    gait = make_gait(spec, scene)
    assert gait.time_scale == 10.0 and gait.period_s == 10.0
    assert gait.peak_speed_mm_s.max() == pytest.approx(62.83, abs=0.01)
    assert make_gait(dict(FAST_PULSE, time_scale='auto'), scene).time_scale == pytest.approx(
        40.0 * math.pi / 0.2 / LIMIT_MM_S)
    # The caller's scale overrides the spec's; keyframes and grasp phases stretch alike.
    assert make_gait(spec, scene, time_scale=20).period_s == 20.0
    righting = make_gait('righting', scenes['starfish'], time_scale=2.0)
    ref = make_gait('righting', scenes['starfish'])
    assert righting.period_s == 21.0
    assert righting.contraction_mm(7.0) == pytest.approx(ref.contraction_mm(3.5))
    assert make_gait('grasp', scenes['gripper'], time_scale=1.2).period_s == pytest.approx(7.2)
    # Faster (45 mm closed in 0.75 s: 94.2 mm/s) than the winches follow: refused.
    with pytest.raises(GaitError, match=r"needs 94\.2 mm/s.*keyframes \[0 s, 0 mm\] -> "
                       r"\[0\.75 s, 45 mm\]"):
        make_gait('grasp', scenes['gripper'], time_scale=0.5)


@pytest.mark.parametrize('scale', [0, -1.0, 1000.0, 'fast', True, math.nan])
def test_bad_time_scale_refused(scenes, scale):
    with pytest.raises(GaitError, match=r'time.scale.*expected auto or a number from 0\.01 to 100'):
        make_gait('walk', scenes['brittle_star'], time_scale=scale)


def test_a_step_without_ramp_cannot_be_time_scaled(scenes):
    step = dict(FAST_PULSE, rise_time_s=0.0)
    with pytest.raises(GaitError, match=r"needs inf mm/s.*give it a ramp"):
        make_gait(step, scenes['brittle_star'])
    with pytest.raises(GaitError, match=r"steps without a ramp.*no time scale"):
        make_gait(step, scenes['brittle_star'], time_scale='auto')


def test_each_module_is_held_to_its_own_winch_speed(tmp_path):
    import yaml
    from softsnap_model.scene import find_scene
    data = yaml.safe_load(find_scene('brittle_star').read_text())
    data['modules'][1]['winch_speed_mm_s'] = 1000.0               # blue: a fast winch
    path = tmp_path / 'fast_blue.yaml'
    path.write_text(yaml.safe_dump(data))
    scene = load_scene(path)
    assert scene.module('blue').winch_speed_mm_s == 1000.0
    assert scene.module('red').winch_speed_mm_s == 92.4
    only_blue = dict(FAST_PULSE, groups=[['blue'], ['orange']])
    with pytest.raises(GaitError, match=r"module 'orange' needs 628\.3"):
        make_gait(only_blue, scene)
    gait = make_gait(dict(FAST_PULSE, groups=[['blue']]), scene)  # 628 of 750 mm/s
    assert gait.speed_limit_mm_s[1] == pytest.approx(750.0)


# --------------------------------------------------------------------- refusals

def test_unknown_gait_and_type_refused_naming_the_known_ones(scenes):
    with pytest.raises(GaitError, match="unknown gait 'fly'; known gaits: walk, walk_reverse"):
        make_gait('fly', scenes['brittle_star'])
    with pytest.raises(ValueError, match="unknown gait type 'hop'; known types: " +
                       ', '.join(GAIT_TYPES)):
        make_gait({'type': 'hop'}, scenes['brittle_star'])


BAD_SPECS = [
    ({'type': 'alternating', 'period_s': 1, 'groups': [['yellow', 'nobody']],
      'amplitude_mm': 10}, r'groups\[0\]\[1\].*a module of scene'),
    ({'type': 'alternating', 'period_s': 1, 'groups': [['yellow'], ['yellow']],
      'amplitude_mm': 10}, r'groups\[1\]\[0\].*at most one group'),
    ({'type': 'alternating', 'period_s': 1, 'groups': [['yellow']], 'duty': 0.5,
      'amplitude_mm': 10, 'rise_time_s': 0.6}, r'rise_time_s: expected at most'),
    ({'type': 'alternating', 'period_s': 1, 'groups': [['yellow']], 'duty': 1.0,
      'amplitude_mm': 10}, r'duty'),
    ({'type': 'alternating', 'period_s': 1, 'groups': [['yellow']], 'amplitude_mm': -3},
     r'amplitude_mm: expected a number >= 0'),
    ({'type': 'alternating', 'period_s': 1, 'groups': [['yellow']], 'amplitude_mm': 10,
      'speed': 3}, r'speed: expected one of the known keys'),
    ({'type': 'wave', 'period_s': 1, 'order': ['yellow', 'blue'], 'lag': 0.7,
      'amplitude_mm': 10}, r'lag: expected a number <= 0.5'),
    ({'type': 'keyframes', 'period_s': 2, 'keyframes': {'yellow': [[0.5, 0], [1, 10]]}},
     r'keyframes\.yellow\[0\]: expected the first keyframe at \[0, 0\]'),
    ({'type': 'keyframes', 'period_s': 2, 'keyframes': {'yellow': [[0, 0], [1, 10], [1, 5]]}},
     r'keyframes\.yellow\[2\]\[0\]: expected a time after'),
    ({'type': 'keyframes', 'period_s': 2, 'keyframes': {'yellow': [[0, 0], [3, 10]]}},
     r'keyframes\.yellow\[1\]\[0\]: expected a number <= 2'),
    ({'type': 'grasp', 'close_s': 0, 'open_s': 1, 'amplitude_mm': 5}, r'close_s'),
    ({'type': 'pulse', 'period_s': 1, 'phases': {'yellow': 1.5}, 'amplitude_mm': 5},
     r'phases\.yellow'),
]


@pytest.mark.parametrize('spec, pattern', BAD_SPECS)
def test_invalid_gait_spec_refused_with_key_and_reason(scenes, spec, pattern):
    with pytest.raises(GaitError, match=r"scene 'brittle_star'.*gaits\.custom\." + pattern):
        make_gait(spec, scenes['brittle_star'])


# ------------------------------------------------------------------------ pure shapes

def test_pulse_shape_reference_values():
    u = np.array([0.0, 0.025, 0.05, 0.3, 0.5, 0.525, 0.55, 0.8, 1.025])
    assert pulse_shape(u, duty=0.5, rise=0.05) == pytest.approx(
        [0.0, 0.5, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0, 0.5])
    assert pulse_shape([0.2, 0.7], duty=0.5, rise=0.0).tolist() == [1.0, 0.0]


def test_ease_keyframes_loop_returns_to_the_start():
    v = ease_keyframes([0.0, 1.0, 1.5, 2.0, 2.5], [0.0, 1.0], [0.0, 10.0], period=2.0)
    assert v == pytest.approx([0.0, 10.0, 5.0, 0.0, 5.0])


# ----------------------------------------------------------------------------- player

def test_player_start_pause_resume_stop_and_switch(scenes):
    scene = scenes['brittle_star']
    walk, reverse = make_gait('walk', scene), make_gait('walk_reverse', scene)
    player = GaitPlayer(walk, transition_s=0.0)
    out = player.tick(0.0)
    assert out.state == STOPPED and out.contraction_mm is None
    assert player.start(10.0) == (True, "started gait 'walk'")
    assert player.start(10.1)[0] is False
    out = player.tick(10.25)
    assert out.state == RUNNING and out.contraction_mm == pytest.approx(walk.contraction_mm(0.25))
    assert out.phase == pytest.approx(0.25 / walk.period_s)
    assert player.pause(10.3)[0] and player.state == PAUSED
    held = player.tick(50.0).contraction_mm
    assert held == pytest.approx(walk.contraction_mm(0.3))
    assert player.resume(60.0)[0]
    assert player.tick(60.1).contraction_mm == pytest.approx(walk.contraction_mm(0.4))
    ok, message = player.switch(reverse, 61.0)
    assert ok and 'walk_reverse' in message and player.state == RUNNING
    assert player.tick(61.25).contraction_mm == pytest.approx(reverse.contraction_mm(0.25))
    assert player.stop(62.0)[0]
    relaxed = player.tick(62.0)
    assert relaxed.contraction_mm == pytest.approx(np.zeros(5))      # one relax command
    assert relaxed.cable_length_mm == pytest.approx(walk.straight_length_mm)
    assert player.tick(62.1).contraction_mm is None                  # then silent
    assert player.pause(63.0)[0] is False and player.resume(63.0)[0] is False


def test_player_blends_without_jumps_and_finishes_a_script(scenes):
    walk = make_gait('walk', scenes['brittle_star'])
    player = GaitPlayer(walk, transition_s=0.3)
    player.start(0.0)
    before = player.tick(0.3).contraction_mm              # blue/orange at 40 mm
    player.stop(0.3)
    after = [player.tick(0.3 + k * 0.01).contraction_mm for k in range(1, 31)]
    steps = np.abs(np.diff(np.vstack([before] + after), axis=0))
    assert steps.max() < 40.0 * math.pi / 2 / 30 + 1e-9   # eased, no jump
    assert after[-1] == pytest.approx(np.zeros(5))
    righting = make_gait('righting', load_scene('starfish'))
    player = GaitPlayer(righting, transition_s=0.0)
    player.start(0.0)
    assert player.tick(5.0).state == RUNNING
    end = player.tick(11.0)
    assert end.state == STOPPED and player.finished and end.phase == 1.0
    assert end.contraction_mm == pytest.approx(np.zeros(5))


# ------------------------------------------------- settled shapes of the default gaits

#: The demo's target for the settled tip error (issue 14), mm.
SETTLED_TIP_ERROR_MM = 5.0


@pytest.mark.parametrize('scene_name', ['brittle_star', 'starfish', 'snake', 'gripper', 'ring'])
def test_default_gait_holds_are_within_5_mm_of_tip_at_the_firmware_deadband(scenes, scene_name):
    """Known answer for the demo's settled tip error.

    A winch that follows stops within the firmware's deadband of its target (30 counts,
    0.34 mm of cable); the settled error is then the tip displacement that cable error
    makes at the held contraction. The demo measured exactly these values (e.g. yellow
    of the brittle star at straight: 4.29 mm). Every hold of every default gait must
    keep it within 5 mm.
    """
    from softsnap_driver.protocol import FIRMWARE_DEADBAND_COUNTS
    from softsnap_model.forward import solve_forward

    scene = scenes[scene_name]
    gait = make_gait(scene.default_gait, scene)
    t = np.arange(0.0, gait.period_s, 1e-3)
    c = gait.contraction_mm(t)
    for i, m in enumerate(scene.modules):
        held = np.abs(np.diff(c[:, i])) == 0.0
        holds = set(np.round(c[1:, i][held], 6))
        assert holds, m.name
        error_mm = FIRMWARE_DEADBAND_COUNTS / m.counts_per_mm
        for contraction in holds:
            length = m.straight_length_mm - contraction
            # Contracting into a hold the winch stops short (less contracted); released to
            # straight it stays a little contracted.
            near = length + error_mm if contraction > 0 else length - error_mm
            tip = solve_forward(scene.skeleton, m.threading_mm, length).rib_centers[-1]
            off = solve_forward(scene.skeleton, m.threading_mm, near).rib_centers[-1]
            assert np.linalg.norm(np.asarray(tip) - np.asarray(off)) < SETTLED_TIP_ERROR_MM, \
                (m.name, contraction)
