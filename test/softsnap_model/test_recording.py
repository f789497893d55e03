"""softsnap_model.recording without ROS: geometry, entity tree, frame counts, values, writers."""
from __future__ import annotations

import math

import numpy as np
import pytest

from softsnap_model import recording as rec_mod
from softsnap_ros.units import MM_PER_M

STAMP0 = 1_795_000_000_123_456_789  # ns since the epoch, a realistic ROS stamp
PERIOD = 20_000_000                 # 50 Hz in ns


def arc_angles(total_rad: float, segments: int = 11) -> list[float]:
    return [total_rad / segments] * segments


# --- geometry against known answers -----------------------------------------------------

def test_straight_module_rib_centres_are_18_mm_apart_along_x():
    centres = rec_mod.rib_centres_mm([0.0] * 11)
    np.testing.assert_allclose(centres, np.column_stack((18.0 * np.arange(12), np.zeros(12))),
                               atol=1e-12)


def test_uniform_bend_by_pi_is_a_semicircle_of_the_spine_length():
    centres = rec_mod.rib_centres_mm(arc_angles(math.pi))
    radius = 198.0 / math.pi
    # All rib centres lie on the circle centred at (0, R); the tip is at (0, 2R).
    np.testing.assert_allclose(np.hypot(centres[:, 0], centres[:, 1] - radius), radius,
                               atol=1e-9)
    np.testing.assert_allclose(centres[-1], [0.0, 2 * radius], atol=1e-9)


def test_ribs_are_25_mm_and_normal_to_the_spine_and_holes_right_of_it():
    frames = rec_mod.rib_frames(arc_angles(-1.0))
    ribs = rec_mod.rib_segments_m(frames)
    lengths = np.linalg.norm(ribs[:, 1] - ribs[:, 0], axis=1)
    np.testing.assert_allclose(lengths, 0.025, atol=1e-12)
    tangents = np.column_stack((np.cos(frames.headings_rad), np.sin(frames.headings_rad), 0 * frames.headings_rad))
    np.testing.assert_allclose(np.sum((ribs[:, 1] - ribs[:, 0]) * tangents, axis=1), 0.0,
                               atol=1e-15)
    straight = rec_mod.rib_frames([0.0] * 11)
    holes = rec_mod.cable_points_m(straight, [10.0] * 12)
    np.testing.assert_allclose(holes[:, 1], -0.010)  # right side is -y at straight


def test_cable_chords_match_the_length_formula_of_facts():
    # L(a; d1, d2)^2 = (d1 - d2)^2 + (2 sin(a/2)/a)^2 (s + d1 a)(s + d2 a), in mm.
    angles = np.array([0.3, -0.2, 0.25, 0.1, -0.4, 0.05, 0.2, 0.3, -0.1, 0.15, 0.2])
    threading = np.array([3, 6.5, 6.5, -6.5, -10, -10, -10, -10, -10, -10, -6.5, 6.5])
    holes_mm = rec_mod.cable_points_m(rec_mod.rib_frames(angles), threading) * MM_PER_M
    chords = np.linalg.norm(np.diff(holes_mm, axis=0), axis=1)
    d1, d2, s = threading[:-1], threading[1:], 18.0
    expected = np.sqrt((d1 - d2) ** 2
                       + (2 * np.sin(angles / 2) / angles) ** 2 * (s + d1 * angles) * (s + d2 * angles))
    np.testing.assert_allclose(chords, expected, rtol=1e-12)


def test_bad_inputs_are_refused_with_the_value():
    with pytest.raises(ValueError, match='expected 12 hole offsets'):
        rec_mod.cable_points_m(rec_mod.rib_frames([0.0] * 11), [1.0] * 11)
    with pytest.raises(ValueError, match='finite'):
        rec_mod.rib_frames([float('nan')] * 11)
    with pytest.raises(ValueError, match='expected 12 rib centres'):
        rec_mod.rib_frames([0.0] * 11, np.zeros((5, 3)))
    with pytest.raises(ValueError, match='module name'):
        rec_mod.module_path('a/b')
    with pytest.raises(ValueError, match='rate_hz'):
        rec_mod.RateLimiter(-1.0)
    with pytest.raises(ValueError, match='expected 12 holes'):
        rec_mod.parse_threading('R3x11')


def test_parse_threading_names_and_repeats():
    assert rec_mod.parse_threading('R3x6 L3x6') == [10.0] * 6 + [-10.0] * 6
    assert rec_mod.parse_threading('R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3')[-3:] == [6.5, 10.0, 10.0]


def test_rate_limiter_keeps_at_most_rate_per_key_on_stamps():
    limiter = rec_mod.RateLimiter(10.0)  # 100 ms
    kept = [t for t in range(0, 1_000_000_000, 20_000_000) if limiter.allow('a', t)]
    assert kept == list(range(0, 1_000_000_000, 100_000_000))
    assert limiter.allow('b', 20_000_000)       # keys are independent
    assert limiter.allow('a', 0)                # stamps going back reset the key
    assert all(rec_mod.RateLimiter(0.0).allow('a', 5) for _ in range(3))


# --- the recorder, written to a file and read back --------------------------------------

def robot_frames(n: int):
    """Two modules over n ticks: commanded bends faster than predicted (known tip error)."""
    for i in range(n):
        stamp = STAMP0 + i * PERIOD
        for module, sign in (('yellow', -1.0), ('blue', 1.0)):
            commanded = arc_angles(sign * 0.1 * i)
            predicted = arc_angles(sign * 0.08 * i)
            yield stamp, module, commanded, predicted


POSES = {'yellow': ((0.05, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
         'blue': ((-0.05, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0))}  # blue turned by pi about z


def write_robot(path, n=10, rate_hz=0.0, modules=None, threadings=None, **options):
    rec = rec_mod.open_recording(path, blueprint=rec_mod.build_blueprint())
    recorder = rec_mod.RobotRecorder(rec, modules=modules, threadings_mm=threadings,
                                     rate_hz=rate_hz, **options)
    recorder.base_poses(STAMP0, POSES)
    for stamp, module, commanded, predicted in robot_frames(n):
        recorder.shape(stamp, module, 'commanded', commanded, solve_time_s=0.002)
        recorder.shape(stamp, module, 'predicted', predicted, solve_time_s=0.003)
        recorder.cable_length(stamp, module, 'commanded', 0.2 - 0.001 * stamp_index(stamp))
        recorder.cable_length(stamp, module, 'measured', 0.2 - 0.0009 * stamp_index(stamp))
        recorder.module_state(stamp, module, 7.4)
    recorder.flush()
    rec_mod.close_recording(rec)
    return recorder


def stamp_index(stamp: int) -> int:
    return (stamp - STAMP0) // PERIOD


def test_robot_recording_entity_tree_frames_and_values(tmp_path, read_rrd):
    path = tmp_path / 'robot.rrd'
    threadings = {'yellow': [3.0] * 8 + [6.5, 6.5, 10.0, 10.0]}
    write_robot(path, n=10, threadings=threadings)
    rrd = read_rrd(path)

    expected = {'robot', 'robot/connector'}
    for module in ('yellow', 'blue'):
        expected |= {f'robot/{module}', f'plots/tip_error_mm/{module}', f'plots/battery_v/{module}',
                     f'plots/cable_length_mm/{module}/commanded',
                     f'plots/cable_length_mm/{module}/measured',
                     f'plots/solve_time_ms/{module}/commanded',
                     f'plots/solve_time_ms/{module}/predicted'}
        expected |= {f'robot/{module}/{source}/{part}' for source in ('commanded', 'predicted')
                     for part in ('spine', 'ribs')}
    expected |= {'robot/yellow/commanded/cable', 'robot/yellow/predicted/cable'}
    assert expected <= rrd.entities
    assert 'robot/blue/commanded/cable' not in rrd.entities  # no threading given for blue
    assert rrd.blueprints, 'the blueprint was not stored in the file'

    # Colour is the module, style the role; logged once (static), packed RGBA. The module
    # called "blue" is blue (predicted: full colour, bold; commanded: dim and thin).
    def rgba(rgb):
        return (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | 0xFF
    blue, yellow = rec_mod.NAMED_COLORS['blue'], rec_mod.NAMED_COLORS['yellow']
    predicted = rrd.static['robot/blue/predicted/spine']
    commanded = rrd.static['robot/blue/commanded/spine']
    assert predicted['LineStrips3D:colors'] == [rgba(blue)]
    assert commanded['LineStrips3D:colors'] == [rgba(rec_mod.role_color(blue, 'commanded'))]
    assert commanded['LineStrips3D:radii'][0] < 0.5 * predicted['LineStrips3D:radii'][0]
    assert rrd.static['robot/yellow/predicted/spine']['LineStrips3D:colors'] == [rgba(yellow)]
    # Plots: the same colours, named per module and series, thin dim commanded series.
    series = rrd.static['plots/cable_length_mm/blue/measured']
    assert series['SeriesLines:colors'] == [rgba(blue)]
    assert series['SeriesLines:names'] == ['blue measured']
    series = rrd.static['plots/cable_length_mm/blue/commanded']
    assert series['SeriesLines:colors'] == [rgba(rec_mod.role_color(blue, 'commanded'))]
    assert series['SeriesLines:widths'][0] < rrd.static['plots/tip_error_mm/blue'][
        'SeriesLines:widths'][0]
    assert rrd.static['plots/tip_error_mm/yellow']['SeriesLines:colors'] == [rgba(yellow)]
    # The legend names every module and role.
    text = rrd.static['legend']['TextDocument:text'][0]
    assert '**yellow**' in text and '**blue**' in text and 'thin, muted = commanded' in text
    assert 'commanded and measured of each module (4 lines)' in text   # every series counted

    # One frame per tick and entity, on the ros_time timeline at the message stamps.
    stamps = [STAMP0 + i * PERIOD for i in range(10)]
    for entity in ('robot/yellow/commanded/spine', 'robot/blue/predicted/ribs',
                   'plots/cable_length_mm/yellow/measured', 'plots/battery_v/blue'):
        assert rrd.times(entity) == stamps, entity

    # Spine points are the rib centres, in metres, in the module base frame.
    spines = rrd.values('robot/yellow/predicted/spine', 'LineStrips3D:strips')
    for i, strips in enumerate(spines):
        expected_m = rec_mod.rib_centres_mm(arc_angles(-0.08 * i)) * 1e-3
        got = np.asarray(strips[0])
        np.testing.assert_allclose(got[:, :2], expected_m, atol=1e-7)  # float32 in the file
        np.testing.assert_allclose(got[:, 2], 0.0)
    assert len(rrd.values('robot/yellow/commanded/ribs', 'LineStrips3D:strips')[3]) == 12
    cable = np.asarray(rrd.values('robot/yellow/commanded/cable', 'LineStrips3D:strips')[0][0])
    np.testing.assert_allclose(cable[:, 1], -np.asarray(threadings['yellow']) * 1e-3, atol=1e-7)

    # Base transforms in metres with the quaternion as given.
    transform = rrd.rows['robot/blue'][0]
    np.testing.assert_allclose(transform['Transform3D:translation'][0], [-0.05, 0.0, 0.0])
    np.testing.assert_allclose(transform['Transform3D:quaternion'][0], [0.0, 0.0, 1.0, 0.0])
    assert len(rrd.rows['robot/blue']) == 1  # logged once: the poses never changed
    assert rrd.static['robot/connector']['Points3D:labels'] == ['yellow', 'blue']

    # Time series values and units.
    np.testing.assert_allclose(rrd.scalars('plots/cable_length_mm/yellow/commanded'),
                               [200.0 - i for i in range(10)])
    np.testing.assert_allclose(rrd.scalars('plots/solve_time_ms/blue/predicted'), [3.0] * 10)
    np.testing.assert_allclose(rrd.scalars('plots/battery_v/blue'), [7.4] * 10, rtol=1e-6)
    tip = rrd.scalars('plots/tip_error_mm/yellow')
    expected_tip = [np.linalg.norm(rec_mod.rib_centres_mm(arc_angles(-0.1 * i))[-1]
                                   - rec_mod.rib_centres_mm(arc_angles(-0.08 * i))[-1])
                    for i in range(10)]
    # The commanded shape of a tick is compared with the previous predicted one, then the
    # predicted shape with the same tick's commanded: two samples per tick after the first.
    assert len(tip) == 19
    np.testing.assert_allclose(tip[2::2], expected_tip[1:], atol=1e-9)
    assert tip[0] == pytest.approx(0.0, abs=1e-12)


def test_column_batches_record_the_same_rows_as_one_log_per_row(tmp_path, read_rrd):
    # flush_period_s > 0 sends buffered rows with send_columns: the file must hold the
    # same entities, stamps and values as logging every row at once.
    threadings = {'yellow': [3.0] * 8 + [6.5, 6.5, 10.0, 10.0]}
    write_robot(tmp_path / 'rows.rrd', n=12, threadings=threadings)
    ticks = iter(range(10**6))
    recorder = write_robot(tmp_path / 'columns.rrd', n=12, threadings=threadings,
                           flush_period_s=0.05, clock=lambda: 0.01 * next(ticks))
    assert recorder.logged == 12 * 2 * 5
    rows, columns = read_rrd(tmp_path / 'rows.rrd'), read_rrd(tmp_path / 'columns.rrd')
    assert columns.entities == rows.entities
    static = {e: v for e, v in rows.static.items() if e != '__properties'}  # start time
    assert {e: v for e, v in columns.static.items() if e != '__properties'} == static
    for entity in rows.rows:
        assert columns.times(entity) == rows.times(entity), entity
    for entity, component in (('robot/yellow/predicted/spine', 'LineStrips3D:strips'),
                              ('robot/blue/commanded/ribs', 'LineStrips3D:strips'),
                              ('robot/yellow/commanded/cable', 'LineStrips3D:strips')):
        got, want = columns.values(entity, component), rows.values(entity, component)
        assert len(got) == len(want) == 12
        for a, b in zip(got, want):
            assert len(a) == len(b)
            np.testing.assert_array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    for entity in ('plots/tip_error_mm/yellow', 'plots/cable_length_mm/blue/measured',
                   'plots/solve_time_ms/yellow/predicted', 'plots/battery_v/blue'):
        assert columns.scalars(entity) == rows.scalars(entity), entity


def test_column_batches_of_a_module_whose_rib_count_changes_match_one_log_per_row(
        tmp_path, read_rrd):
    """Rows of different rib counts in one flush take the row-by-row path: the same values
    as logging each row at once, given rib centres (with z) and without."""
    def write(path, flush_period_s):
        rec = rec_mod.open_recording(path)
        recorder = rec_mod.RobotRecorder(rec, rate_hz=0.0, flush_period_s=flush_period_s)
        for tick, segments in enumerate((11, 11, 7, 11, 3)):
            angles = arc_angles(0.2 * tick - 0.3, segments)
            centres = rec_mod.rib_frames(angles).centres_m + [0.0, 0.0, 0.001 * tick]
            recorder.shape(STAMP0 + tick * PERIOD, 'yellow', 'commanded', angles, centres)
            recorder.shape(STAMP0 + tick * PERIOD, 'yellow', 'predicted', angles)
        recorder.flush()
        rec_mod.close_recording(rec)

    write(tmp_path / 'rows.rrd', 0.0)
    write(tmp_path / 'columns.rrd', 10.0)
    rows, columns = read_rrd(tmp_path / 'rows.rrd'), read_rrd(tmp_path / 'columns.rrd')
    for source in ('commanded', 'predicted'):
        for part in ('spine', 'ribs'):
            entity = f'robot/yellow/{source}/{part}'
            got, want = (r.values(entity, 'LineStrips3D:strips') for r in (columns, rows))
            # points of the spine strip, or strips of the ribs: one per rib
            assert [len(np.asarray(v[0] if part == 'spine' else v)) for v in got] == [
                12, 12, 8, 12, 4]
            for a, b in zip(got, want, strict=True):
                np.testing.assert_array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    # A tip error only between shapes of equal rib counts: every predicted shape against
    # its tick's commanded one (only z differs: tick mm), and the second commanded shape
    # against the first predicted one; the same in both files.
    tip = columns.scalars('plots/tip_error_mm/yellow')
    assert tip == rows.scalars('plots/tip_error_mm/yellow')
    assert len(tip) == 6 and tip[1] > 10.0
    np.testing.assert_allclose([tip[0], *tip[2:]], [0.0, 1.0, 2.0, 3.0, 4.0], atol=1e-9)


def test_unchanged_shapes_are_logged_once(tmp_path, read_rrd):
    rec = rec_mod.open_recording(tmp_path / 'still.rrd')
    recorder = rec_mod.RobotRecorder(rec, rate_hz=0.0, skip_unchanged=True, flush_period_s=1.0)
    for tick in range(5):
        stamp = STAMP0 + tick * PERIOD
        # yellow holds still after tick 1; blue bends further every tick.
        recorder.shape(stamp, 'yellow', 'predicted', arc_angles(0.1 * min(tick, 1)))
        recorder.shape(stamp, 'blue', 'predicted', arc_angles(0.1 * tick))
    recorder.flush()
    rec_mod.close_recording(rec)
    rrd = read_rrd(tmp_path / 'still.rrd')
    assert rrd.times('robot/yellow/predicted/spine') == [STAMP0, STAMP0 + PERIOD]
    assert rrd.times('robot/blue/predicted/spine') == [STAMP0 + i * PERIOD for i in range(5)]
    assert recorder.unchanged == 3 and recorder.logged == 7


def test_rate_limit_and_module_filter_reduce_what_is_logged(tmp_path, read_rrd):
    path = tmp_path / 'limited.rrd'
    recorder = write_robot(path, n=25, rate_hz=10.0, modules={'blue'})  # ticks at 50 Hz
    rrd = read_rrd(path)
    assert not any('yellow' in e for e in rrd.entities)
    assert 'robot/yellow' not in rrd.entities
    # 25 ticks of 20 ms = 480 ms: stamps 0, 100, 200, 300, 400 ms are kept.
    assert rrd.times('robot/blue/commanded/spine') == [STAMP0 + k * 100_000_000 for k in range(5)]
    assert len(rrd.scalars('plots/battery_v/blue')) == 5
    assert recorder.dropped == 5 * (25 - 5)


def test_recording_without_close_is_detected_and_close_makes_it_complete(tmp_path, read_rrd):
    # The tests of the ROS node rely on store() refusing a file that was never closed.
    import rerun as rr
    from rerun.chunk import RrdReader

    path = tmp_path / 'open.rrd'
    stream = rec_mod.open_recording(path)
    stream.log('plots/x', rr.Scalars(1.0))
    stream.flush()
    with pytest.warns(Warning), pytest.raises(RuntimeError, match='without footer'):
        RrdReader(str(path)).store()
    rec_mod.close_recording(stream)
    assert read_rrd(path).scalars('plots/x') == [1.0]


def test_open_recording_needs_a_sink():
    with pytest.raises(ValueError, match='output file'):
        rec_mod.open_recording(None, None)


# --- no-ROS writers ---------------------------------------------------------------------

def fake_solve(threading_mm, contractions_mm):
    """Stand-in forward solve with a known answer: a uniform bend by -contraction/40 rad."""
    return np.array([arc_angles(-c / 40.0) for c in contractions_mm])


def test_record_sweep_writes_one_step_per_contraction_and_the_tip_path(tmp_path, read_rrd):
    threading = rec_mod.parse_threading('R3x12')
    contractions = [0.0, 10.0, 20.0, 30.0]
    path = rec_mod.record_sweep(tmp_path / 'sweep.rrd', threading, contractions,
                                solve=fake_solve, module='m')
    rrd = read_rrd(path)
    assert {'robot/m/predicted/spine', 'robot/m/predicted/ribs', 'robot/m/predicted/cable',
            'robot/m/workspace/tip_path', 'plots/contraction_mm/m'} <= rrd.entities
    assert rrd.times('robot/m/predicted/spine', 'step') == [0, 1, 2, 3]
    np.testing.assert_allclose(rrd.scalars('plots/contraction_mm/m'), contractions)
    np.testing.assert_allclose(rrd.scalars('plots/tip_angle_deg/m'),
                               [-math.degrees(c / 40.0) for c in contractions], atol=1e-9)
    tip_path = np.asarray(rrd.static['robot/m/workspace/tip_path']['LineStrips3D:strips'][0])
    expected = [rec_mod.rib_centres_mm(a)[-1] * 1e-3 for a in fake_solve(threading, contractions)]
    np.testing.assert_allclose(tip_path[:, :2], expected, atol=1e-7)


def test_record_threadings_places_each_threading_in_its_own_row(tmp_path, read_rrd):
    threadings = {'s': rec_mod.parse_threading('R3x6 L3x6'),
                  'w': rec_mod.parse_threading('R3 R3 R3 R3 L2 L3 L2 R3 R3 R3 R3 R3')}
    path = rec_mod.record_threadings(tmp_path / 'cmp.rrd', threadings, [0.0, 20.0],
                                     solve=fake_solve, row_spacing_m=0.1)
    rrd = read_rrd(path)
    for i, name in enumerate(threadings):
        np.testing.assert_allclose(rrd.static[f'robot/{name}']['Transform3D:translation'][0],
                                   [0.0, -0.1 * i, 0.0])
        cable = np.asarray(rrd.values(f'robot/{name}/predicted/cable', 'LineStrips3D:strips')[0][0])
        np.testing.assert_allclose(cable[:, 1], -np.asarray(threadings[name]) * 1e-3, atol=1e-7)
        assert rrd.times(f'robot/{name}/predicted/spine', 'step') == [0, 1]


def test_drawn_geometry_agrees_with_the_solver_core():
    geometry = pytest.importorskip('softsnap_model.geometry')
    angles = np.array([0.3, -0.2, 0.25, 0.1, -0.4, 0.05, 0.2, 0.3, -0.1, 0.15, 0.2])
    threading = rec_mod.parse_threading('R1 R2 R2 L2 L3 L3 L3 L3 L3 L3 L2 R2')
    frames = rec_mod.rib_frames(angles)
    np.testing.assert_allclose(frames.centres_m[:, :2] * 1e3, geometry.rib_centers(angles, 18.0),
                               atol=1e-12)
    np.testing.assert_allclose(rec_mod.cable_points_m(frames, threading)[:, :2] * 1e3,
                               geometry.cable_path(angles, threading, 18.0), atol=1e-12)


def test_sweep_with_the_forward_solver_draws_a_cable_of_the_target_length(tmp_path, read_rrd):
    # R3 on every rib: straight cable length 11 * 18 = 198 mm; the solved shape must be
    # drawn with a cable polyline 198 - contraction long (float32 in the file: 1e-4 mm).
    pytest.importorskip('softsnap_model.forward')
    contractions = [0.0, 20.0, 40.0, 80.0]
    path = rec_mod.record_sweep(tmp_path / 'r3.rrd', [10.0] * 12, contractions, module='r3')
    rrd = read_rrd(path)
    cables = rrd.values('robot/r3/predicted/cable', 'LineStrips3D:strips')
    assert len(cables) == len(contractions)
    for contraction, strips in zip(contractions, cables):
        holes_mm = np.asarray(strips[0], dtype=float) * 1e3
        length = np.linalg.norm(np.diff(holes_mm, axis=0), axis=1).sum()
        assert length == pytest.approx(198.0 - contraction, abs=1e-3)
    # Right-side holes bend the module clockwise: the tip turns to negative angles.
    angles = rrd.scalars('plots/tip_angle_deg/r3')
    assert angles[0] == pytest.approx(0.0, abs=1e-9) and all(np.diff(angles) < 0)


def test_record_command_line_writes_a_threading_comparison(tmp_path, read_rrd):
    pytest.importorskip('softsnap_model.forward')
    out = tmp_path / 'cmp.rrd'
    assert rec_mod.main(['threadings', '--threading', 's=R3x6 L3x6', '--threading', 'w=R3x12',
                         '--steps', '3', '--max-contraction-mm', '30', '--out', str(out)]) == 0
    rrd = read_rrd(out)
    assert rrd.times('robot/s/predicted/spine', 'step') == [0, 1, 2]
    np.testing.assert_allclose(rrd.scalars('plots/contraction_mm/w'), [0.0, 15.0, 30.0])
    assert rec_mod.main(['sweep', '--threading', 'R3x11', '--out', str(out)]) == 2


# --- legibility: colours are modules, styles are roles (issue 14) ------------------------

def test_module_colours_match_names_and_never_repeat():
    from softsnap_model.scene import load_scene
    colors = rec_mod.module_colors([('yellow', 'yellow'), ('blue', 'blue'), ('green', 'green'),
                                    ('red', 'red'), ('orange', 'orange')])
    assert {m: rec_mod.color_name(c) for m, c in colors.items()} == {
        'yellow': 'yellow', 'blue': 'blue', 'green': 'green', 'red': 'red', 'orange': 'orange'}
    # Names that are no colour take free palette colours: none used twice, and a module
    # named after a colour keeps it even when listed after the others.
    colors = rec_mod.module_colors([('head', ''), ('body', ''), ('blue', '')])
    assert colors['blue'] == rec_mod.NAMED_COLORS['blue']
    assert len(set(colors.values())) == 3
    for name in ('snake', 'gripper', 'ring', 'starfish', 'brittle_star'):
        colors, _ = rec_mod.scene_style(load_scene(name))
        assert len(set(colors.values())) == len(colors), name


def test_roles_differ_by_brightness_and_width_not_by_hue():
    for name, rgb in rec_mod.NAMED_COLORS.items():
        dim = rec_mod.role_color(rgb, 'commanded')
        assert rec_mod.role_color(rgb, 'predicted') == rgb == rec_mod.role_color(rgb, 'measured')
        assert max(dim) - min(dim) < max(rgb) - min(rgb) or name == 'grey'   # less saturated
        # Same hue: the muted colour lies between the module colour and the ghost grey.
        a = rec_mod.COMMANDED_BRIGHTNESS
        assert dim == pytest.approx([a * c + (1 - a) * g for c, g in zip(rgb, rec_mod.GHOST_BASE)],
                                    abs=0.5)
    # No module colour is another module's commanded ghost (identity is unambiguous).
    ghosts = {rec_mod.role_color(c, 'commanded') for c in rec_mod.NAMED_COLORS.values()}
    assert not ghosts & set(rec_mod.NAMED_COLORS.values())
    assert rec_mod.ROLE_WIDTH['commanded'] < 0.5 * rec_mod.ROLE_WIDTH['predicted']
    with pytest.raises(ValueError, match="role must be one of .* got 'target'"):
        rec_mod.role_color((1, 2, 3), 'target')


def test_blueprint_one_plot_per_quantity_no_covering_legends_top_down_camera():
    from softsnap_model.scene import load_scene
    colors, bounds = rec_mod.scene_style(load_scene('brittle_star'))
    centre, radius = bounds
    # The brittle star spans its five straight legs: tips 72.5 + 198 mm from the centre.
    assert 0.26 < radius < 0.30 and abs(centre[2]) < 1e-9
    blueprint = rec_mod.build_blueprint(colors, bounds)
    left, plots = blueprint.root_container.contents
    scene_view, legend_view = left.contents
    assert str(legend_view.origin) == rec_mod.LEGEND_ROOT
    origins = [str(view.origin) for view in plots.contents]
    assert origins == [f'plots/{q}' for q in ('cable_length_mm', 'tip_error_mm',
                                              'solve_time_ms', 'battery_v')]
    for view in plots.contents:
        legend = view.properties['PlotLegend']
        assert legend.visible.as_arrow_array().to_pylist() == [False], view.name
    eye = scene_view.properties['EyeControls3D']
    position = np.array(eye.position.as_arrow_array().to_pylist()[0])
    target = np.array(eye.look_target.as_arrow_array().to_pylist()[0])
    assert target == pytest.approx(centre)
    down = (target - position) / np.linalg.norm(target - position)
    assert down[2] < -0.95                                  # looking (nearly) straight down
    # Far enough that a 55 degree field of view holds the whole robot.
    assert np.linalg.norm(position - target) * math.tan(math.radians(27.5)) > radius
    # Without bounds (no scene) the viewer picks its own camera.
    assert 'EyeControls3D' not in rec_mod.build_blueprint().root_container.contents[0] \
        .contents[0].properties
