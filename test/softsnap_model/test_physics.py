"""MuJoCo physics of SoftSnap modules and robots (real MuJoCo, no mocks).

Reference problems: the paper's threadings (softsnap_model.physics.compare.PAPER_THREADINGS)
against the exact quasi-static model (solve_forward, solve_loaded).
"""
from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from softsnap_model import Skeleton, solve_forward
from softsnap_model.physics import (DEFAULT_LINKS_PER_SEGMENT, Payload, PhysicsParameters,
                                    module_mjcf, robot_mjcf)

mujoco = pytest.importorskip('mujoco')

from softsnap_model.physics.compare import (PAPER_THREADINGS, load_case,  # noqa: E402
                                            static_fidelity)
from softsnap_model.physics.simulation import RobotSimulation  # noqa: E402

#: Fidelity target of the issue: rib centres within 0.5 mm of solve_forward at 20 mm
#: contraction at the default links per segment.
FIDELITY_TOL_MM = 0.5


# ----------------------------------------------------------------------------- MJCF

def test_core_package_does_not_import_mujoco():
    code = ('import sys, softsnap_model, softsnap_model.physics, softsnap_model.physics.mjcf; '
            'print("mujoco" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == 'False'


def test_module_mjcf_structure():
    n = 3
    xml = module_mjcf(Skeleton(), PAPER_THREADINGS['yellow'].split(), links_per_segment=n)
    root = ET.fromstring(xml)
    bodies = [b.get('name') for b in root.iter('body')]
    assert sum(1 for b in bodies if b.startswith('module/rib')) == 11   # rib 0 is the base
    hinges = [j for j in root.iter('joint') if j.get('type') == 'hinge']
    assert len(hinges) == 11 * n
    # Stiffness reproduces K a^2 per segment: N hinges of 2 N K (x 1e-3 N m/rad).
    k_h = float(hinges[0].get('stiffness'))
    assert k_h == pytest.approx(2 * n * PhysicsParameters().bending_stiffness_nmm * 1e-3)
    sites = [s.get('site') for s in root.find('tendon').find('spatial')]
    assert len(sites) == 12
    # Couplings: N - 1 per segment keep each segment at constant curvature.
    assert len(root.find('equality').findall('joint')) == 11 * (n - 1)


def test_mujoco_straight_cable_length_is_the_models():
    sk = Skeleton()
    holes = PAPER_THREADINGS['w'].split()
    sim = RobotSimulation.single_module(holes, sk)
    assert sim.cable_path_length('module') * 1e3 == pytest.approx(
        sk.straight_length_mm(holes), abs=1e-9)
    assert sim.straight_cable_length('module') * 1e3 == pytest.approx(
        sk.straight_length_mm(holes), abs=1e-9)


# ------------------------------------------------------------------------- fidelity

@pytest.mark.parametrize('name', ['yellow', 'red', 'gripper'])
def test_fidelity_default_links_within_half_mm(name):
    res = static_fidelity(name, 20.0)
    assert res.links_per_segment == DEFAULT_LINKS_PER_SEGMENT
    assert res.settled
    assert res.max_rib_error_mm < FIDELITY_TOL_MM, res
    assert res.tension_n == pytest.approx(res.reference_tension_n, rel=0.02)


def test_fidelity_error_falls_with_links():
    # One hinge per segment cannot place the next rib on the arc (its chord is short by
    # s a^2 / 12); from two links the chord-matched lengths bring the error down to
    # the soft constraints' floor (~0.01 mm).
    errors = [static_fidelity('yellow', 20.0, links_per_segment=n).max_rib_error_mm
              for n in (1, 2, 4)]
    assert errors[0] > 1.0, errors
    assert errors[1] < 0.1 * errors[0] and errors[2] < 0.1 * errors[0], errors
    assert max(errors[1:]) < 0.1, errors


def test_free_robot_leg_without_gravity_matches_solve_forward():
    # The whole brittle star on its free base, gravity off, resting 0.2 mm above the
    # ground (no contact): one leg hauled in by 20 mm must take the clamped module's
    # quasi-static shape. The hub used to be a cylinder whose collision with the ground
    # misfired once the robot turned about the vertical (the leg's recoil): a -27 mm
    # penetration launched the robot at 3.5 m/s, and its tumbling bent the leg 7 mm
    # RMS away from solve_forward.
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    sim = RobotSimulation(scene, gravity=False)
    z0 = sim.robot_base_pose()[0][2]
    module = scene.modules[0]
    straight = sim.straight_cable_length(module.name)
    sim.ramp_cable_length(module.name, straight - 0.02, 0.05)
    sim.settle(5.0)
    assert sim.data.ncon == 0                         # the ground does not touch
    assert np.abs(sim.data.qvel[:3]).max() < 1e-2     # m/s: the robot was not kicked
    assert np.abs(sim.data.qvel[3:6]).max() < 1e-2    # rad/s: and does not tumble
    assert abs(sim.robot_base_pose()[0][2] - z0) < 1e-3
    ref = solve_forward(scene.skeleton, module.threading_mm, straight * 1e3 - 20.0)
    got = sim.rib_centers(module.name)[:, :2] * 1e3
    err = np.linalg.norm(got - ref.rib_centers[:, :2], axis=1)
    assert err.max() < FIDELITY_TOL_MM, err


def test_free_robot_with_gravity_off_is_not_kicked_by_the_ground():
    # Every leg hauled in one after the other turns the hub about the vertical; the
    # robot must stay where it floats (the cylinder hub's false contact launched it).
    sim = RobotSimulation('brittle_star', gravity=False)
    for name in sim.module_names:
        sim.ramp_cable_length(name, sim.straight_cable_length(name) - 0.015, 0.1)
    sim.step(0.5)
    # It may slide and turn in its plane (the legs' recoil), not leave it.
    assert abs(sim.data.qvel[2]) < 1e-2, sim.data.qvel[:6]
    assert np.abs(sim.data.qvel[3:5]).max() < 1e-2, sim.data.qvel[:6]
    root = ET.fromstring(sim.xml)
    hub = [g for g in root.iter('geom') if g.get('name') == 'connector'][0]
    assert hub.get('type') == 'mesh'


# -------------------------------------------------------------------------- cable

def test_slack_cable_has_no_tension_and_module_straightens():
    holes = PAPER_THREADINGS['yellow'].split()
    sim = RobotSimulation.single_module(holes)
    straight = sim.straight_cable_length('module')
    sim.ramp_cable_length('module', straight - 0.02, 0.05)
    sim.settle(5.0)
    assert sim.cable_tension('module') > 0.5
    assert np.abs(sim.segment_angles('module')).max() > 0.1
    # Pay out beyond the straight length: the cable goes slack, the skeleton springs back.
    sim.set_cable_length('module', straight + 0.01)
    sim.settle(10.0)
    assert sim.cable_tension('module') == 0.0
    assert sim.cable_path_length('module') < sim.cable_length('module')
    assert np.abs(sim.segment_angles('module')).max() < 1e-3
    tip = sim.rib_centers('module')[-1]
    assert tip[0] == pytest.approx(0.198, abs=1e-4) and abs(tip[1]) < 1e-3   # within 1 mm


def test_cable_tensions_in_one_pass_equal_each_modules_tension():
    # The brittle star on the ground (hundreds of contact rows), three legs hauled in by
    # different amounts, two slack: the one-pass reader (sim_robot's) must give exactly
    # what cable_tension gives module by module, taut and slack alike.
    sim = RobotSimulation('brittle_star')
    names = sim.module_names
    for name, pull in zip(names[:3], (0.01, 0.02, 0.03)):
        sim.set_cable_length(name, sim.straight_cable_length(name) - pull)
    sim.step(0.3)
    assert sim.data.ncon > 10                           # contacts are in the rows too
    tensions = sim.cable_tensions()
    assert tensions == {n: sim.cable_tension(n) for n in names}
    assert all(tensions[n] > 0.1 for n in names[:3])
    assert all(tensions[n] == 0.0 for n in names[3:])



def test_module_states_equal_the_per_module_reads():
    # sim_robot's snapshots read every module in one vectorised pass: it must give what
    # rib_centers, segment_angles and module_base_pose give module by module.
    sim = RobotSimulation('brittle_star')
    names = sim.module_names
    sim.set_cable_length(names[1], sim.straight_cable_length(names[1]) - 0.02)
    sim.step(0.2)
    centers, angles, positions, orientations = sim.module_states()
    assert centers.shape[:2] == (len(names), 12) and angles.shape[0] == len(names)
    for i, name in enumerate(names):
        np.testing.assert_allclose(centers[i], sim.rib_centers(name), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(angles[i], sim.segment_angles(name))
        position, orientation = sim.module_base_pose(name)
        np.testing.assert_array_equal(positions[i], position)
        np.testing.assert_array_equal(orientations[i], orientation)
    assert abs(angles[1]).max() > 0.05           # the hauled-in leg is bent


# ------------------------------------------------------------------------- gravity

def test_hanging_module_matches_loaded_model():
    res = load_case('hanging', 'yellow', 20.0)
    assert res.quasi_static_converged and res.settled
    assert res.tip_sag_mm > 20.0                   # gravity matters here...
    assert res.max_rib_error_mm < 2.0, res         # ...and both models agree on it


def test_module_bends_down_under_gravity_when_horizontal():
    # Spine horizontal, bending in the vertical plane, slack cable: the tip sags (-z).
    sim = RobotSimulation.single_module(PAPER_THREADINGS['yellow'].split(), gravity=True,
                                        base_position_m=(0, 0, 0.5),
                                        base_orientation_wxyz=(np.sqrt(0.5), np.sqrt(0.5),
                                                               0, 0))
    sim.settle(10.0)
    tip = sim.rib_centers_world('module')[-1]
    assert tip[2] < 0.5 - 0.01                     # more than 10 mm below the base
    assert sim.cable_tension('module') == 0.0


# ---------------------------------------------------------------------- validation

@pytest.mark.parametrize('kwargs, match', [
    (dict(shape='cone'), "shape must be one of ball, box, cylinder, got 'cone'"),
    (dict(mass_kg=-0.1), 'mass_kg'),
    (dict(mass_kg=float('nan')), 'mass_kg'),
    (dict(size_m=0.5), 'size_m'),
    (dict(shape='box', size_m=0.02), '3 half extents'),
    (dict(shape='cylinder', size_m=0.1), r'\(radius, half height\)'),
    (dict(shape='cylinder', size_m=(0.1, 0.3)), r'cylinder size_m.*0.3'),
    (dict(position_m=(0, 0)), 'position_m'),
])
def test_bad_payload_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Payload(**kwargs)


@pytest.mark.parametrize('kwargs, match', [
    (dict(links_per_segment=0), 'links_per_segment'),
    (dict(links_per_segment=2.5), 'links_per_segment'),
    (dict(base='floating'), "base must be"),
    (dict(payload='ball'), 'payload must be a Payload'),
    (dict(bending_stiffness_nmm=-1.0), 'bending_stiffness_nmm'),
    (dict(chain='rope'), "chain must be"),
])
def test_bad_robot_options_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        robot_mjcf('brittle_star', **kwargs)


def test_bending_stiffness_scales_the_hinges():
    soft = ET.fromstring(robot_mjcf('brittle_star', bending_stiffness_nmm=8.8))
    hinge = next(j for j in soft.iter('joint') if j.get('type') == 'hinge')
    assert float(hinge.get('stiffness')) == pytest.approx(2 * 2 * 8.8 * 1e-3)


def test_bad_parameters_are_refused():
    for kwargs, match in [(dict(timestep_s=0.0), 'timestep_s'),
                          (dict(rib_friction=float('inf')), 'rib_friction'),
                          (dict(contact_rib_stride=0), 'contact_rib_stride'),
                          (dict(motor_box_size_mm=(30, 25)), 'motor_box_size_mm')]:
        with pytest.raises(ValueError, match=match):
            PhysicsParameters(**kwargs)


def test_unknown_scene_is_refused():
    with pytest.raises(ValueError, match='no_such_robot'):
        robot_mjcf('no_such_robot')


def test_payload_without_place_is_refused_for_a_walking_robot():
    with pytest.raises(ValueError, match='no default payload place'):
        robot_mjcf('brittle_star', payload=Payload())


def test_bad_cable_length_is_refused():
    sim = RobotSimulation.single_module(PAPER_THREADINGS['yellow'].split())
    for bad in (0.0, -0.1, float('nan'), 1.0):
        with pytest.raises(ValueError, match='length_m'):
            sim.set_cable_length('module', bad)
    with pytest.raises(ValueError, match='no module'):
        sim.set_cable_length('nobody', 0.1)


# --------------------------------------------------------------------- determinism

def _trajectory(scene):
    sim = RobotSimulation(scene, links_per_segment=2)
    out = []
    for k in range(5):
        for m in sim.module_names:
            sim.set_cable_length(m, sim.straight_cable_length(m) - 0.002 * (k + 1))
        sim.step(0.05)
        out.append(np.concatenate([sim.data.qpos, sim.data.qvel]))
    return np.array(out)


def test_same_run_twice_gives_identical_trajectory():
    a = _trajectory('brittle_star')
    b = _trajectory('brittle_star')
    assert np.array_equal(a, b)
    assert np.abs(a[-1] - a[0]).max() > 0       # and it moved


# --------------------------------------------------------------------------- robots

@pytest.mark.parametrize('scene', ['brittle_star', 'starfish', 'snake', 'ring', 'gripper'])
def test_every_scene_builds_and_rests(scene):
    sim = RobotSimulation(scene)
    assert len(sim.module_names) in (4, 5)
    pos0, _ = sim.robot_base_pose()
    sim.step(0.5)
    pos1, quat = sim.robot_base_pose()
    assert np.all(np.isfinite(sim.data.qpos))
    # Resting: the robot stays where it was put (a free robot on the ground; the gripper
    # held by its arm) and keeps its orientation.
    assert np.linalg.norm(pos1 - pos0) < 2e-3
    assert abs(abs(quat[0]) - 1.0) < 1e-3
    if sim.layout.free_base:
        assert -1e-3 < sim._lowest_point_z() < 1e-3
    for m in sim.module_names:
        assert sim.cable_tension(m) == 0.0          # built with slack cables
        # module base frame: rib 0 at the origin, the straight spine along +x
        centers = sim.rib_centers(m)
        assert np.linalg.norm(centers[0]) < 1e-9
        assert centers[-1][0] == pytest.approx(0.198, abs=2e-3)


def test_chained_modules_stay_joined():
    sim = RobotSimulation('snake')
    for m in sim.module_names:
        sim.ramp_cable_length(m, sim.straight_cable_length(m) - 0.02, 0.1)
    sim.step(0.5)
    scene = __import__('softsnap_model.scene', fromlist=['load_scene']).load_scene('snake')
    for m in scene.modules:
        if m.parent is None:
            continue
        tip = sim.rib_centers_world(m.parent)[-1]
        base, _ = sim.module_base_pose(m.name)
        # 50 mm link from the parent's tip rib to the child's rib 0, within 1 mm.
        assert np.linalg.norm(base - tip) == pytest.approx(0.050, abs=1e-3)


def test_gripper_holds_a_light_ball_between_its_fingers():
    from softsnap_model.physics.compare import payload_case
    res = payload_case('gripper', Payload('ball', 0.005, 0.045))
    assert res.held, res
    assert all(f > 0.01 for f in res.finger_force_n.values())   # every finger presses
    assert all(t > 0.5 for t in res.tension_n.values())


def test_cli_physics_reports_and_records(tmp_path):
    import json
    from softsnap_model.cli import main
    out = tmp_path / 'physics.rrd'
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(['physics', '--scene', 'ring', '--cases', 'gravity', '--record', str(out)])
    assert code == 0
    report = json.loads(buf.getvalue())
    assert [r['case'] for r in report['gravity']] == ['flat', 'hanging', 'side']
    hanging = report['gravity'][1]
    assert hanging['tip_sag_mm'] > 5.0 and hanging['max_rib_error_mm'] < 3.0
    assert 'payload' not in report and 'fidelity' not in report
    assert out.stat().st_size > 1000


def test_cli_physics_refuses_bad_input(capsys):
    from softsnap_model.cli import main
    assert main(['physics', '--cases', 'wobble']) == 2
    assert 'unknown case' in capsys.readouterr().err
    assert main(['physics', '--scene', 'gripper', '--contraction', '-5',
                 '--cases', 'fidelity']) == 2
    assert 'contraction' in capsys.readouterr().err


def test_ring_cages_its_payload_on_the_ground():
    sim = RobotSimulation('ring', payload=Payload('ball', 0.02, 0.03))
    start, _ = sim.payload_pose()
    robot, _ = sim.robot_base_pose()
    assert np.linalg.norm(start[:2] - robot[:2]) < 1e-6          # at the ring's centre
    for m in sim.module_names:
        sim.ramp_cable_length(m, sim.straight_cable_length(m) - 0.03, 0.06)
    sim.step(1.0)
    end, _ = sim.payload_pose()
    assert end[2] == pytest.approx(0.03, abs=2e-3)               # resting on the ground
    assert np.linalg.norm(end[:2] - sim.robot_base_pose()[0][:2]) < 0.1   # still inside


def test_ring_cylinder_payload_stands_on_the_ground_inside_the_ribs():
    # A puck of 100 mm radius and 30 mm height: its wall is at the flat ring's ribs.
    sim = RobotSimulation('ring', payload=Payload('cylinder', 0.02, (0.1, 0.015)))
    sim.step(0.5)
    end, _ = sim.payload_pose()
    assert end[2] == pytest.approx(0.015, abs=2e-3)              # on its end face
    ribs = np.concatenate([sim.rib_centers_world(m) for m in sim.module_names])
    assert np.min(np.linalg.norm(ribs[:, :2] - end[:2], axis=1)) > 0.1   # no rib inside
    centre = sim.rib_centroid_world()      # the flat ring's centre: under the puck, 4.5 mm up
    assert np.linalg.norm(centre[:2] - end[:2]) < 1e-3
    assert centre[2] == pytest.approx(0.0045, abs=1e-3)


def test_reset_restores_the_start_and_repeats_the_run():
    sim = RobotSimulation('brittle_star')
    q0 = sim.data.qpos.copy()
    sim.set_cable_length('yellow', sim.straight_cable_length('yellow') - 0.005)
    sim.step(0.2)
    first = sim.data.qpos.copy()
    sim.reset()
    assert sim.time_s == 0.0 and np.array_equal(sim.data.qpos, q0)
    assert sim.cable_length('yellow') > sim.straight_cable_length('yellow')   # slack again
    sim.set_cable_length('yellow', sim.straight_cable_length('yellow') - 0.005)
    sim.step(0.2)
    assert np.array_equal(sim.data.qpos, first)
