"""The shape controller's core in-process: convergence from a wrong model, bounds under
hostile targets, stale measurements, refusals.

The plant is independent of the controller's model: the quasi-static model with other
parameters (solve_loaded with another stiffness or a tip payload), and MuJoCo
(softsnap_model.physics), which the controller never calls.
"""
import math

import numpy as np
import pytest

from softsnap_gaits.shape_control import (CONVERGING, REACHED, STALE, TIMED_OUT,
                                          ControllerConfig, ShapeController, TargetError,
                                          make_target, module_model, named_shape_m)
from softsnap_model.scene import load_scene

SCENE = load_scene('gripper')
MODULE = 'front_left'
DT = 0.05   # s, control and measurement period


@pytest.fixture(scope='module')
def model():
    return module_model(SCENE, MODULE)


def run(ctl, plant, steps, *, delay_steps=0, noise_m=0.0, seed=0, t0=0.0):
    """Closed loop against `plant` (cable length m -> ribs m); returns the steps."""
    rng = np.random.default_rng(seed)
    pending, out, t = [], [], t0
    for _ in range(steps):
        t += DT
        step = ctl.step(t)
        out.append(step)
        if step.command_m is not None:
            ribs = plant(step.command_m) + rng.normal(0.0, noise_m, (12, 2))
            pending.append((t, ribs))
        if len(pending) > delay_steps:
            stamp, ribs = pending.pop(0)
            ctl.observe(ribs, stamp)
    return out


@pytest.mark.parametrize('case', ['stiffness_0.8', 'stiffness_1.2', 'payload_20g'])
@pytest.mark.parametrize('kind', ['tip', 'ribs'])
def test_converges_from_a_wrong_model(model, case, kind):
    if case == 'payload_20g':
        truth = module_model(SCENE, MODULE, tip_load_n=(0.020 * 9.81, 0.0, 0.0))
    else:
        truth = module_model(SCENE, MODULE,
                             bending_stiffness_nmm=17.6 * float(case.split('_')[1]))
    length_true = model.range_m[1] - 0.03
    ribs_true = truth.rib_centers_m(length_true)
    target = make_target(kind, ribs_true[-1] if kind == 'tip' else ribs_true, 12)
    ctl = ShapeController(model)
    ff = ctl.set_target(target, 0.0)
    open_loop_tip_mm = np.linalg.norm(truth.rib_centers_m(ff.cable_length_m)[-1]
                                      - ribs_true[-1]) * 1e3
    steps = run(ctl, truth.rib_centers_m, 120)
    final_tip_mm = np.linalg.norm(truth.rib_centers_m(ctl.command_m)[-1] - ribs_true[-1]) * 1e3
    print(case, kind, f'open loop {open_loop_tip_mm:.2f} mm, closed {final_tip_mm:.4f} mm')
    assert steps[-1].state == REACHED
    assert final_tip_mm < 0.1
    assert final_tip_mm < open_loop_tip_mm
    assert abs(ctl.command_m - length_true) < 1e-4
    # The steady correction is recorded once, and it is what the model got wrong.
    assert len(ctl.corrections) == 1
    assert ctl.corrections[0].correction_m == pytest.approx(
        length_true - ff.cable_length_m, abs=3e-4)
    if case == 'payload_20g':
        assert open_loop_tip_mm > 3.0    # the open loop misses by far more than 1 mm


def test_latency_and_noise_stay_stable(model):
    truth = module_model(SCENE, MODULE, tip_load_n=(0.020 * 9.81, 0.0, 0.0))
    length_true = model.range_m[1] - 0.03
    tip = truth.rib_centers_m(length_true)[-1]
    ctl = ShapeController(model)
    ctl.set_target(make_target('tip', tip, 12), 0.0)
    steps = run(ctl, truth.rib_centers_m, 200, delay_steps=2, noise_m=0.0005)
    errors = [np.linalg.norm(truth.rib_centers_m(s.command_m)[-1] - tip) * 1e3
              for s in steps[-60:]]
    print(f'last 3 s: tip error max {max(errors):.3f} mm')
    assert max(errors) < 1.0


def test_hostile_targets_are_refused_with_the_reason(model):
    with pytest.raises(TargetError, match='finite'):
        make_target('tip', [math.nan, 0.0], 12)
    with pytest.raises(TargetError, match='12 point'):
        make_target('ribs', [[0.0, 0.0]] * 5, 12)
    with pytest.raises(TargetError, match='tolerance'):
        make_target('tip', [0.1, 0.0], 12, tolerance_m=-1.0)
    with pytest.raises(TargetError, match='timeout'):
        make_target('tip', [0.1, 0.0], 12, timeout_s=math.inf)
    ctl = ShapeController(model)
    with pytest.raises(TargetError, match='unreachable'):
        ctl.set_target(make_target('tip', [2.0, -3.0], 12), 0.0)
    assert ctl.target is None and ctl.step(1.0).command_m is None


@pytest.mark.parametrize('offset', [(0.0, 0.02), (0.02, 0.0), (-0.01, -0.03)])
@pytest.mark.parametrize('end', ['contracted', 'straight'])
def test_commands_stay_in_range_and_speed(model, end, offset):
    """Targets beyond the ends of the reachable family (accepted: within the model-miss
    limit): the commands never leave the reachable range, never move faster than the
    speed bound, and the correction stays within its bound."""
    config = ControllerConfig(max_speed_m_s=0.05)
    ctl = ShapeController(model, config)
    lo, hi = model.range_m
    tip = model.rib_centers_m(lo if end == 'contracted' else hi)[-1] + np.array(offset)
    # A plant far from the model (no gravity): pushes the correction to its bound.
    plant = module_model(SCENE, MODULE, gravity=False).rib_centers_m
    ctl.set_target(make_target('tip', tip, 12, timeout_s=30.0), 0.0)
    steps = run(ctl, plant, 150)
    commands = np.array([s.command_m for s in steps])
    assert np.all(commands >= lo - 1e-12) and np.all(commands <= hi + 1e-12)
    assert np.max(np.abs(np.diff(commands))) <= config.max_speed_m_s * DT + 1e-9
    assert all(abs(s.correction_m) <= config.max_correction_m + 1e-12 for s in steps)
    assert steps[-1].state != REACHED


def test_no_windup_at_the_range_end(model):
    """Anti-windup: held at the straight end by a robot that looks more contracted than
    commanded, the correction stays at what the range allows; when the robot changes
    (a payload dropped), the controller corrects at once instead of unwinding first."""
    ctl = ShapeController(model, ControllerConfig(max_speed_m_s=10.0))
    lo, hi = model.range_m
    target = make_target('ribs', model.rib_centers_m(hi - 0.005), 12, timeout_s=60.0)
    ff = ctl.set_target(target, 0.0)
    steps = run(ctl, lambda length: model.rib_centers_m(length - 0.01), 100)
    assert all(s.correction_m <= hi - ff.cable_length_m + 1e-12 for s in steps)
    assert ctl.command_m == pytest.approx(hi)
    # Now the robot is the model: it needs hi - 5 mm.
    plant = model.rib_centers_m
    steps = run(ctl, plant, 60, t0=5.0)
    first_good = next(i for i, s in enumerate(steps)
                      if abs(s.command_m - (hi - 0.005)) < 2e-4)
    print(f'within 0.2 mm of the new length after {first_good} steps')
    # Without anti-windup the integrator would hold a correction far past the range end
    # (up to its 20 mm bound) and take seconds to unwind it.
    assert first_good <= 20


def test_stale_measurement_holds_the_command(model):
    truth = module_model(SCENE, MODULE, bending_stiffness_nmm=14.0)
    ctl = ShapeController(model, ControllerConfig(stale_after_s=0.3))
    ctl.set_target(make_target('tip', truth.rib_centers_m(model.range_m[1] - 0.02)[-1], 12,
                               timeout_s=5.0), 0.0)
    run(ctl, truth.rib_centers_m, 4)      # a few measurements (the last at 0.2 s), then none
    held = ctl.step(0.25).command_m       # takes in the last one
    step = None
    for k in range(10):
        step = ctl.step(0.25 + 0.1 * (k + 1))
        assert step.command_m == held
    assert step.state == STALE and 'old' in step.reason and 'holding' in step.reason
    # A fresh measurement resumes the loop.
    ctl.observe(truth.rib_centers_m(held), 1.3)
    assert ctl.step(1.32).state in (CONVERGING, REACHED)
    # No measurement until the timeout: TIMED_OUT, still holding.
    for k in range(60):
        step = ctl.step(1.4 + 0.1 * k)
    assert step.state == TIMED_OUT and step.command_m is not None
    assert 'timed out' in step.reason and 'old' in step.reason


def test_invisible_ribs_and_bad_measurements(model):
    ctl = ShapeController(model)
    ribs = model.rib_centers_m(model.range_m[1] - 0.02)
    with pytest.raises(ValueError, match='12 rib centres'):
        ctl.observe(ribs[:5], 0.0)
    ctl.set_target(make_target('tip', ribs[-1], 12), 0.0)
    hidden = ribs.copy()
    hidden[-1] = math.nan                 # the tip unseen: no tip error, no integration
    ctl.step(0.05)
    ctl.observe(hidden, 0.06)
    step = ctl.step(0.1)
    assert math.isnan(step.error_m) and step.correction_m == 0.0


def test_named_shapes(model):
    straight = named_shape_m(SCENE, model, 'straight')
    closed = named_shape_m(SCENE, model, 'grasp')
    assert straight[-1, 0] > closed[-1, 0]
    with pytest.raises(TargetError, match='no named shape'):
        named_shape_m(SCENE, model, 'nope')


def test_converges_on_mujoco(model):
    """The physics robot (MuJoCo, one clamped gripper module hanging under gravity, bending
    stiffness 20 % below the model's), stepped in-process between measurements."""
    pytest.importorskip('mujoco')
    from softsnap_model.physics.simulation import RobotSimulation
    module = SCENE.module(MODULE)
    sim = RobotSimulation.single_module(
        module.holes, SCENE.skeleton, gravity=True, bending_stiffness_nmm=17.6 * 0.8,
        base_orientation_wxyz=_wxyz(module.base_orientation_xyzw))
    # The target: where the physics robot itself settles at a length (so it is reachable).
    length_true = model.range_m[1] - 0.03
    sim.ramp_cable_length('module', length_true, 0.05)
    sim.step(1.0)
    sim.settle(max_time_s=3.0)
    tip = sim.rib_centers('module')[-1, :2].copy()
    sim.reset()
    ctl = ShapeController(model)
    ff = ctl.set_target(make_target('tip', tip, 12), 0.0)
    t = 0.0
    for _ in range(100):
        t += DT
        step = ctl.step(t)
        sim.set_cable_length('module', step.command_m)
        sim.step(DT)
        ctl.observe(sim.rib_centers('module'), t)
    error_mm = np.linalg.norm(sim.rib_centers('module')[-1, :2] - tip) * 1e3
    print(f'MuJoCo: feedforward {ff.cable_length_m * 1e3:.2f} mm, true '
          f'{length_true * 1e3:.2f} mm, final tip error {error_mm:.3f} mm')
    assert ctl.state == REACHED and error_mm < 1.0


def _wxyz(xyzw):
    x, y, z, w = xyzw
    return (w, x, y, z)
