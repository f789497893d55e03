"""sim_robot: the winch under load, options, determinism and locomotion of the core loop.

The socket and ROS side (the graph's driver_container) is in test_sim_robot_ros.py.
"""
from __future__ import annotations

import argparse
import math

import numpy as np
import pytest
from benchmark_scripts import load as load_benchmark

from softsnap_driver.firmware import DEADBAND_COUNTS, MotorModel
from softsnap_driver.protocol import encode_set_request
from softsnap_driver.sim_robot import (DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_TIMESTEP_S,
                                       ScriptedCommands, SimRobot, SimRobotError, WinchMotor,
                                       build_simulation)
from softsnap_driver.sim_robot_runner import (OPTIONS, build_payload, build_robot, check_options,
                                              module_ports)

BOOST_V = 6.0


def options(**changes) -> argparse.Namespace:
    values = {name: default for name, (_kind, default, _text) in OPTIONS.items()}
    values.update(changes)
    return argparse.Namespace(**values)


# ------------------------------------------------------------------- the winch's motor

def test_winch_speed_falls_linearly_with_tension_and_stops_at_the_stall_tension():
    base = MotorModel()
    winch = WinchMotor(base, stall_torque_nm=0.15, drum_radius_m=0.005)
    stall_n = winch.stall_tension_n(255, BOOST_V)
    assert stall_n == pytest.approx(30.0)
    assert winch.stall_tension_n(200, BOOST_V) == pytest.approx(30.0 * 200 / 255)
    no_load = base.no_load_rpm / 60.0 * base.counts_per_rev
    assert winch.speed_counts_per_s(255, BOOST_V) == pytest.approx(no_load)
    winch.tension_n = stall_n / 2
    assert winch.speed_counts_per_s(255, BOOST_V) == pytest.approx(no_load / 2)
    half_current = winch.current_a(255, BOOST_V, stalled=False)
    winch.tension_n = stall_n * 1.5
    assert winch.speed_counts_per_s(255, BOOST_V) == 0.0
    assert winch.current_a(255, BOOST_V, stalled=False) == pytest.approx(base.stall_current_a)
    assert half_current < base.stall_current_a
    # Paying out, the tension does not hold the winch back.
    winch.hauling = False
    assert winch.speed_counts_per_s(255, BOOST_V) == pytest.approx(no_load)


def test_winch_rejects_non_physical_constants():
    with pytest.raises(SimRobotError, match='stall_torque_nm must be positive'):
        WinchMotor(MotorModel(), stall_torque_nm=0.0, drum_radius_m=0.005)
    with pytest.raises(SimRobotError, match='drum radius'):
        WinchMotor(MotorModel(), stall_torque_nm=0.1, drum_radius_m=math.nan)


# --------------------------------------------------------------------------- options

@pytest.mark.parametrize('changes, message', [
    ({'payload': 'sphere'}, "payload must be one of none, ball, box, cylinder, got 'sphere'"),
    ({'payload': 'ball', 'payload_mass_kg': -0.1}, 'mass_kg'),
    ({'payload': 'ball', 'payload_size_m': 0.5}, 'size_m'),
    ({'payload': 'cylinder', 'payload_height_m': 0.0},
     r'payload_height_m must be in \(0, 0.4\] m, got 0.0'),
    ({'payload': 'cylinder', 'payload_size_m': 0.3}, r'cylinder size_m.*0.3'),
    ({'time_factor': -1.0}, r'time_factor must be in \[0, 1000\], got -1.0'),
    ({'stall_torque_nm': math.inf}, 'stall_torque_nm must be in'),
    ({'port_base': 70000}, 'port_base must be in'),
    ({'links_per_segment': 100}, 'links_per_segment must be in'),
    ({'physics_timestep_s': 0.01}, r'physics_timestep_s must be in \[0.0005, 0.004\], got 0.01'),
])
def test_bad_options_are_refused_with_the_value_and_range(changes, message):
    with pytest.raises(SimRobotError, match=message):
        check_options(options(**changes))


def test_bad_scene_and_misplaced_payload_give_clear_errors():
    from softsnap_model.scene import SceneError
    with pytest.raises(SceneError, match='no_such_robot'):
        build_robot(options(scene='no_such_robot'))
    # The brittle star has no place for a payload: the physics says so, named.
    with pytest.raises(SimRobotError, match="brittle_star.*payload"):
        build_robot(options(scene='brittle_star', payload='ball'))


def test_module_ports_are_consecutive_from_the_base_or_the_scene_ports():
    from softsnap_model.scene import load_scene
    scene = load_scene('gripper')
    assert module_ports(scene, 0) == {m.name: m.port for m in scene.modules}
    assert list(module_ports(scene, 21000).values()) == [21000, 21001, 21002, 21003]
    with pytest.raises(SimRobotError, match='port_base must leave room for 4 ports'):
        module_ports(scene, 65534)


# ------------------------------------------------------------------- the coupled loop

def _robot(scene_name: str, **kwargs) -> SimRobot:
    from softsnap_model.scene import load_scene
    scene = load_scene(scene_name)
    return SimRobot(scene, build_simulation(scene, links_per_segment=1), **kwargs)


def test_ring_transport_carries_its_demo_payload_with_it():
    """The demo's ring payload (a puck at the centre) travels with the ring: its
    displacement along the ring's, over 2 cycles of ``transport``, is more than 5 mm
    (benchmarks/ring_transport.py measured 10 mm, the ring 15 mm)."""
    from softsnap_gaits.demo import PHYSICS_PAYLOADS
    from softsnap_gaits.gaits import make_gait
    from softsnap_model.scene import load_scene
    robot = build_robot(options(scene='ring', **PHYSICS_PAYLOADS['ring']))
    assert robot.has_payload
    sim = robot.simulation
    robot.run_until(0.3)
    ring0, load0 = sim.rib_centroid_world(), np.asarray(sim.payload_pose()[0])
    gait = make_gait('transport', load_scene('ring'))
    robot.run_until(0.3 + 2 * gait.period_s, ScriptedCommands(gait.contraction_mm,
                                                               start_s=robot.clock()))
    ring = (sim.rib_centroid_world() - ring0)[:2]
    load = (np.asarray(sim.payload_pose()[0]) - load0)[:2]
    assert np.all(np.isfinite(ring)) and np.linalg.norm(ring) > 0.005
    assert float(load @ ring) / float(np.linalg.norm(ring)) > 0.005


def test_ring_transport_payload_items_are_sim_robots_payloads():
    """benchmarks/ring_transport.py's ``cylinder:R:H`` takes the half height (mm), sim_robot's
    payload_height_m the full height (m): both give the demo's puck, through one mapping."""
    parse_payload = load_benchmark('ring_transport').parse_payload
    from softsnap_gaits.demo import PHYSICS_PAYLOADS
    from softsnap_model.physics.parameters import Payload
    demo_puck = build_payload(options(**PHYSICS_PAYLOADS['ring']))
    assert parse_payload('cylinder:85:15', 0.02) == demo_puck
    assert parse_payload('ball:40', 0.01) == Payload('ball', 0.01, 0.04)
    assert parse_payload('box:30', 0.01) == Payload('box', 0.01, (0.03, 0.03, 0.03))
    for bad in ('cylinder:85', 'ball:40:10', 'none:1', 'cone:10'):
        with pytest.raises(ValueError, match='expected cylinder:R:H'):
            parse_payload(bad, 0.02)
    with pytest.raises(SimRobotError, match='payload_height_m must be in'):
        parse_payload('cylinder:85:250', 0.02)      # 0.5 m tall


def test_a_set_command_hauls_the_cable_in_and_bends_the_module():
    robot = _robot('gripper')
    name = robot.module_names[0]
    straight = np.asarray(robot.simulation.rib_centers(name))
    target = int(round(20.0 * robot.counts_per_mm(name)))      # 20 mm of cable
    robot.request(name, encode_set_request(target, 200))
    robot.run_until(1.5)
    module = robot.modules[name]
    assert abs(module.encoder_count - target) <= DEADBAND_COUNTS
    length_m = robot.cable_length_m(name, module.position)
    assert robot.simulation.cable_length(name) == pytest.approx(length_m)
    assert robot.tension_n(name) > 0.0            # the cable pulls the skeleton
    bent = np.asarray(robot.simulation.rib_centers(name))
    assert np.linalg.norm(bent[-1] - straight[-1]) > 0.01    # the tip moved > 10 mm
    # The other modules were not commanded: their cables stay at the straight length.
    other = robot.module_names[1]
    assert robot.modules[other].encoder_count == 0


def test_the_live_timestep_keeps_a_settled_leg_on_the_exact_shape():
    # sim_robot steps its model at DEFAULT_PHYSICS_TIMESTEP_S (3 ms, for speed), not the
    # physics model's 2 ms: the fidelity contract must hold there too. The brittle star
    # floating (gravity off), one leg hauled in 20 mm through its firmware and settled:
    # its rib centres within 0.5 mm of solve_forward for the cable length it reached.
    from softsnap_model import solve_forward
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    sim = build_simulation(scene, gravity=False, links_per_segment=2)
    assert sim.timestep_s == pytest.approx(DEFAULT_PHYSICS_TIMESTEP_S)
    robot = SimRobot(scene, sim)
    assert robot.control_period_s == pytest.approx(2 * DEFAULT_PHYSICS_TIMESTEP_S)
    name = robot.module_names[0]
    robot.request(name, encode_set_request(int(round(20.0 * robot.counts_per_mm(name))), 200))
    robot.run_until(5.0)
    length_mm = robot.cable_length_m(name, robot.modules[name].position) * 1e3
    assert robot.modules[name].position / robot.counts_per_mm(name) > 19.0
    ref = solve_forward(scene.skeleton, scene.modules[0].threading_mm, length_mm)
    got = sim.rib_centers(name)[:, :2] * 1e3
    err = np.linalg.norm(got - ref.rib_centers[:, :2], axis=1)
    assert err.max() < 0.5, err


def test_a_winch_stalls_under_a_tension_beyond_its_motor():
    # A motor 100 times weaker than the GA12-N20 cannot pull the module into shape.
    robot = _robot('gripper', stall_torque_nm=0.0015)
    name = robot.module_names[0]
    target = int(round(30.0 * robot.counts_per_mm(name)))
    robot.request(name, encode_set_request(target, 200))
    robot.run_until(2.0)
    module = robot.modules[name]
    stuck = module.encoder_count
    robot.run_until(3.0)
    assert module.encoder_count == stuck < target - DEADBAND_COUNTS   # no progress
    assert module.moving()                    # the firmware keeps driving it
    winch = robot.motors[name]
    assert robot.tension_n(name) >= 0.9 * winch.stall_tension_n(200, winch.rated_voltage_v)
    # ... drawing the stall current, which the power history shows like a real module.
    assert module.current_a > module.battery.idle_current_a + 0.5 * module.motor.base.stall_current_a


def _trajectory(robot: SimRobot, script, until_s: float, every_s: float = 0.1):
    points = []
    t = 0.0
    while t < until_s - 1e-9:
        t += every_s
        robot.run_until(t, script)
        snap = robot.snapshot()
        points.append(np.concatenate([np.ravel(snap.base_position_m)]
                                     + [np.ravel(m.rib_centers_m) for m in snap.modules]))
    return np.array(points)


def test_the_same_commands_give_the_same_trajectory():
    from softsnap_gaits.gaits import make_gait
    runs = []
    for _ in range(2):
        robot = _robot('brittle_star')
        gait = make_gait('walk', robot.scene)
        runs.append(_trajectory(robot, ScriptedCommands(gait.contraction_mm), 1.2))
    assert np.abs(runs[0][-1] - runs[0][0]).max() > 1e-3      # it moved
    assert np.array_equal(runs[0], runs[1])                    # bit for bit


def _travel_m(gait_name: str, cycles: int, links_per_segment: int = 1) -> np.ndarray:
    from softsnap_gaits.gaits import make_gait
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    robot = SimRobot(scene, build_simulation(scene, links_per_segment=links_per_segment))
    robot.run_until(0.3)                       # settle on the ground
    start = np.asarray(robot.simulation.robot_base_pose()[0])
    gait = make_gait(gait_name, robot.scene)
    script = ScriptedCommands(gait.contraction_mm, start_s=robot.clock())
    robot.run_until(robot.clock() + cycles * gait.period_s, script)
    return (np.asarray(robot.simulation.robot_base_pose()[0]) - start)[:2]


@pytest.mark.parametrize('links_per_segment', [1, 2])
def test_brittle_star_walk_and_walk_reverse_move_it_in_opposite_directions(links_per_segment):
    # walk: blue and orange, then yellow, green and red (a two-state cycle);
    # walk_reverse: yellow in, green and red in, yellow out, green and red out, in turn
    # (a loop in the legs' shape space; scene file). Measured after 2 cycles (docs/sim_robot.md):
    # 1 link (+11.5, -5.4) and (-12.3, -1.4) mm; 2 links (+9.8, -2.2) and (-24.9, -9.3).
    forward = _travel_m('walk', 2, links_per_segment)
    backward = _travel_m('walk_reverse', 2, links_per_segment)
    # Each clearly more than a gait that goes nowhere: yellow stepping alone moves the
    # robot under 1 mm per cycle (docs/sim_robot.md).
    assert np.linalg.norm(forward) > 0.005 and np.linalg.norm(backward) > 0.005, \
        (forward, backward)
    # walk goes towards yellow (+x), walk_reverse away from it.
    assert forward[0] > 0.005 and backward[0] < -0.005, (forward, backward)
    # Opposite: a negative dot product, and more than 120 degrees between them.
    assert float(forward @ backward) < 0.0, (forward, backward)
    cos = float(forward @ backward) / (np.linalg.norm(forward) * np.linalg.norm(backward))
    assert cos < -0.5, (forward, backward, cos)


def _grasp_payload_heights_m(mass_kg: float, radius_m: float) -> tuple:
    """The gripper's first grasp (scene's default gait, sim_robot's default model) on a
    ball: (release time s, payload height at the start and the end of the hold, m)."""
    from softsnap_gaits.gaits import make_gait
    from softsnap_model.physics.parameters import Payload
    from softsnap_model.scene import load_scene
    scene = load_scene('gripper')
    robot = SimRobot(scene, build_simulation(scene, payload=Payload('ball', mass_kg, radius_m),
                                             links_per_segment=DEFAULT_LINKS_PER_SEGMENT))
    gait = make_gait(scene.default_gait, scene)
    spec = scene.gaits[scene.default_gait]
    script = ScriptedCommands(gait.contraction_mm)
    robot.run_until(spec['close_s'], script)
    z0 = robot.simulation.payload_pose()[0][2]
    robot.run_until(spec['close_s'] + spec['hold_s'], script)
    return robot.payload_released_at_s, z0, robot.simulation.payload_pose()[0][2]


def test_gripper_holds_its_demo_payload_through_a_grasp():
    from softsnap_gaits.demo import PAYLOAD_HOLD_TOL_MM, PHYSICS_PAYLOADS
    demo = PHYSICS_PAYLOADS['gripper']
    assert demo['payload'] == 'ball'
    # sim_robot's defaults are the demo's payload.
    assert (OPTIONS['payload_mass_kg'][1], OPTIONS['payload_size_m'][1]) == \
        (demo['payload_mass_kg'], demo['payload_size_m'])
    released, z0, z1 = _grasp_payload_heights_m(demo['payload_mass_kg'], demo['payload_size_m'])
    # The helper hold let go while the fingers closed, before the hold began ...
    assert released is not None and released < 1.5, released
    # ... and the ball stayed in the closed fingers, well above the ground (0.40 m arm).
    assert (z0 - z1) * 1e3 < PAYLOAD_HOLD_TOL_MM, (z0, z1)
    assert z1 > 0.2, z1


def test_gripper_drops_a_ball_that_passes_between_its_fingertips_or_is_too_heavy():
    # The demo's old payload, 20 g of 20 mm radius, falls through the closed fingers, and
    # 30 g at the demo's 45 mm radius weighs them open (docs/sim_robot.md: up to 20 g).
    for mass_kg, radius_m in ((0.02, 0.02), (0.03, 0.045)):
        released, z0, z1 = _grasp_payload_heights_m(mass_kg, radius_m)
        assert released is not None
        assert z1 < radius_m + 0.005, (mass_kg, radius_m, z1)     # on the ground
