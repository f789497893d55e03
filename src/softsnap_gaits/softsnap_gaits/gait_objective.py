"""How fast a gait moves a robot in MuJoCo, robustly: rollouts and their score.

No ROS. A rollout runs the whole simulated robot of ``sim_robot``
(:class:`softsnap_driver.sim_robot.SimRobot`: every module's firmware, its loaded winch
and the MuJoCo robot on the ground) driven with the gait's contraction schedule the way
the drivers send it (50 Hz ``set`` requests, PWM 200), in-process, without sockets, so a
rollout is a deterministic function of its gait and its :class:`SimSetting`.

Measured over the gait's run (after a 0.3 s settle, from the gait's start):

* ``travel_mm_s``: the robot frame's displacement along the chosen heading (robot frame
  at the start, degrees counter-clockwise from its x axis) per simulated second, over
  the whole number of gait cycles nearest to the rollout's ``seconds`` (at least one);
* ``fell``: some module's base tipped more than 60 degrees from upright (sampled every
  0.1 s);
* ``lag_mm``: the mean distance (mm of cable) between each winch's commanded and actual
  position: a winch that cannot keep up with its gait (load, battery);
* ``power_w``: the mean mechanical power the winches spend hauling (tension x haul speed).

The score (mm/s, larger is better) is the travel minus penalties: the family's winch-speed
excess (:attr:`~softsnap_gaits.gait_family.DecodedGait.speed_excess`), a fall, the lag
beyond :data:`LAG_FREE_MM`, and the power. A candidate is scored over several settings
(:data:`DEFAULT_SETTINGS`: ground friction, bending stiffness, two resolutions, timing
jitter) and the scores are combined by their mean or their worst (:func:`aggregate`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

__all__ = ['SimSetting', 'DEFAULT_SETTINGS', 'RolloutResult', 'Penalties', 'rollout',
           'score', 'aggregate', 'SETTLE_S', 'LAG_FREE_MM']

#: Settling time before the gait starts (s), as in benchmarks/walk_direction.py.
SETTLE_S = 0.3
#: Physics timestep of sim_robot (s): the demo's.
PHYSICS_TIMESTEP_S = 0.003
#: Command rate (Hz) and PWM of the drivers' defaults.
COMMAND_RATE_HZ = 50.0
COMMAND_PWM = 200
#: Winch lag (mm) free of penalty: about the firmware's deadband and a 50 Hz tick.
LAG_FREE_MM = 1.5
#: A module base whose z axis points less than this far up (cos 60 deg) has fallen.
UPRIGHT_MIN = 0.5
#: Sampling period of the fall check and of a recording (s).
SAMPLE_S = 0.1
DEFAULT_STIFFNESS_NMM = 17.6   # softsnap_model.loads.DEFAULT_BENDING_STIFFNESS_NMM


@dataclass(frozen=True)
class SimSetting:
    """One simulator setting a gait is scored under.

    Attributes
    ----------
    name : str
    rib_friction : float
        Sliding friction of ribs and connectors on the ground (the model's 0.6 nominal).
    stiffness_scale : float
        Bending stiffness as a multiple of the model's 17.6 N mm/rad^2.
    links_per_segment : int
        Resolution of the MuJoCo model (sim_robot's 2; 1 is the coarse one).
    jitter_s : float
        Each command samples the gait up to this much late (s, uniform): Wi-Fi and ROS
        latency varying from command to command.
    seed : int
        Seed of the jitter's random stream.
    """

    name: str
    rib_friction: float = 0.6
    stiffness_scale: float = 1.0
    links_per_segment: int = 2
    jitter_s: float = 0.0
    seed: int = 0


#: The robust set: the demo's model (sim_robot's resolution, 2 links per segment), and
#: three perturbed ones at the coarse resolution (1 link per segment, ~2.5x cheaper).
DEFAULT_SETTINGS = (
    SimSetting('nominal'),
    SimSetting('slippery-stiff-coarse', rib_friction=0.45, stiffness_scale=1.25,
               links_per_segment=1, jitter_s=0.02, seed=1),
    SimSetting('grippy-soft-coarse', rib_friction=0.8, stiffness_scale=0.8,
               links_per_segment=1, jitter_s=0.02, seed=2),
    SimSetting('coarse-jitter', links_per_segment=1, jitter_s=0.04, seed=3),
)


@dataclass(frozen=True)
class Penalties:
    """Weights of the score's penalties (mm/s of travel each costs)."""

    speed_excess_mm_s: float = 20.0     # per unit of DecodedGait.speed_excess
    fall_mm_s: float = 50.0             # a fall
    lag_mm_s_per_mm: float = 1.0        # per mm of mean winch lag beyond LAG_FREE_MM
    power_mm_s_per_w: float = 1.0       # per watt of mean hauling power


@dataclass(frozen=True)
class RolloutResult:
    """One gait under one setting (see the module docstring for the measures)."""

    setting: str
    seconds: float
    travel_mm_s: float
    displacement_mm: tuple[float, float]
    distance_mm_s: float
    fell: bool
    lag_mm: float
    power_w: float
    #: With ``record=True``: sample times (s) and every rib centre in the world
    #: (m, (samples, modules, ribs, 3)), and the robot frame's position (m, (samples, 3)).
    times_s: np.ndarray | None = field(default=None, repr=False, compare=False)
    ribs_m: np.ndarray | None = field(default=None, repr=False, compare=False)
    base_m: np.ndarray | None = field(default=None, repr=False, compare=False)


@lru_cache(maxsize=8)
def _scene(scene_ref: str):
    from softsnap_model.scene import load_scene
    return load_scene(scene_ref)


class _JitteredCommands:
    """ScriptedCommands with each command's sample time late by a seeded random delay."""

    def __init__(self, contraction_mm, start_s: float, jitter_s: float, seed: int):
        from softsnap_driver.protocol import encode_set_request
        self._encode = encode_set_request
        self.contraction_mm = contraction_mm
        self.start_s = start_s
        self.period_s = 1.0 / COMMAND_RATE_HZ
        self.jitter_s = jitter_s
        self._rng = np.random.default_rng(seed)
        self._next_s = start_s

    def __call__(self, robot) -> None:
        now = robot.clock()
        if now + 1e-12 < self._next_s:
            return
        self._next_s += self.period_s
        delay = float(self._rng.uniform(0.0, self.jitter_s)) if self.jitter_s > 0 else 0.0
        contraction = self.contraction_mm(max(0.0, now - self.start_s - delay))
        for name, value in zip(robot.module_names, contraction):
            count = int(round(float(value) * robot.counts_per_mm(name)))
            robot.request(name, self._encode(count, COMMAND_PWM))


def _upright(quats_wxyz: np.ndarray) -> np.ndarray:
    """World z component of each body's z axis, from (n, 4) quaternions w, x, y, z."""
    w, x, y, z = quats_wxyz.T
    return 1.0 - 2.0 * (x * x + y * y)


def rollout(scene_ref: str, spec: dict, setting: SimSetting, *, seconds: float,
            heading_deg: float | None = 0.0, record: bool = False,
            warmup_cycles: int = 0) -> RolloutResult:
    """Run gait `spec` on scene `scene_ref` (name or path) under `setting` for `seconds`.

    `warmup_cycles` gait cycles run before the measured ones (the first cycle starts from
    the straight robot, its legs resting until their onsets: a gait can lurch there in a
    way it never repeats). `heading_deg` None scores the straight-line distance in any
    direction. Deterministic: the same arguments give the same result in any process.
    """
    from softsnap_driver.sim_robot import SimRobot
    from softsnap_model.physics.parameters import PhysicsParameters
    from softsnap_model.physics.simulation import RobotSimulation
    from .gaits import make_gait

    scene = _scene(scene_ref)
    gait = make_gait(spec, scene, name='candidate')
    params = PhysicsParameters(timestep_s=PHYSICS_TIMESTEP_S, rib_friction=setting.rib_friction,
                               bending_stiffness_nmm=DEFAULT_STIFFNESS_NMM * setting.stiffness_scale)
    sim = RobotSimulation(scene, links_per_segment=setting.links_per_segment, parameters=params)
    robot = SimRobot(scene, sim, seed=0)
    robot.run_until(SETTLE_S)
    p0, q0 = sim.robot_base_pose()
    w, x, y, z = q0
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    h = yaw + math.radians(heading_deg or 0.0)
    heading = np.array([math.cos(h), math.sin(h)])
    start = robot.clock()
    commands = _JitteredCommands(gait.contraction_mm, start, setting.jitter_s, setting.seed)
    names = robot.module_names
    per_mm = np.array([robot.counts_per_mm(n) for n in names])
    last = np.array([robot.modules[n].position for n in names], dtype=float)
    acc = {'lag': 0.0, 'energy': 0.0, 'steps': 0}

    def on_step(r) -> None:
        commands(r)
        pos = np.array([r.modules[n].position for n in names], dtype=float)
        target = np.array([r.modules[n].target for n in names], dtype=float)
        hauled_mm = np.maximum(pos - last, 0.0) / per_mm
        if hauled_mm.any():
            acc['energy'] += sum(r.tension_n(n) * h_mm for n, h_mm in zip(names, hauled_mm)) * 1e-3
        acc['lag'] += float(np.mean(np.abs(target - pos) / per_mm))
        acc['steps'] += 1
        last[:] = pos

    fell = False
    p0 = None if warmup_cycles else p0
    t_measure = robot.clock()
    times, ribs, base = [], [], []
    t = start
    # Whole cycles only: a part cycle would reward a lurch the rest of the cycle undoes.
    cycles = max(1, round(seconds / gait.period_s))
    measure_from = start + int(warmup_cycles) * gait.period_s
    end = measure_from + cycles * gait.period_s
    while t < end - 1e-9:
        t = min(end, t + SAMPLE_S)
        if p0 is None and t >= measure_from - 1e-9:
            robot.run_until(measure_from, on_step)
            p0, t_measure = sim.robot_base_pose()[0], robot.clock()
        robot.run_until(t, on_step)
        quats = sim.module_states()[3]
        fell = fell or bool(np.any(_upright(np.asarray(quats)) < UPRIGHT_MIN))
        if record:
            times.append(robot.clock() - start)
            ribs.append(np.stack([sim.rib_centers_world(n) for n in sim.module_names]))
            base.append(sim.robot_base_pose()[0])
    p1 = sim.robot_base_pose()[0]
    d = (np.asarray(p1) - np.asarray(p0))[:2] * 1e3
    duration = robot.clock() - t_measure
    steps = max(acc['steps'], 1)
    travel = float(d @ heading) if heading_deg is not None else float(np.hypot(*d))
    return RolloutResult(
        setting=setting.name, seconds=duration, travel_mm_s=travel / duration,
        displacement_mm=(float(d[0]), float(d[1])),
        distance_mm_s=float(np.hypot(*d)) / duration, fell=fell,
        lag_mm=float(acc['lag']) / steps, power_w=float(acc['energy']) / (robot.clock() - start),
        times_s=np.array(times) if record else None,
        ribs_m=np.array(ribs) if record else None, base_m=np.array(base) if record else None)


def score(result: RolloutResult, speed_excess: float = 0.0,
          penalties: Penalties = Penalties()) -> float:
    """A rollout's score (mm/s): travel along the heading minus the penalties."""
    p = penalties
    return (result.travel_mm_s - p.speed_excess_mm_s * speed_excess
            - (p.fall_mm_s if result.fell else 0.0)
            - p.lag_mm_s_per_mm * max(0.0, result.lag_mm - LAG_FREE_MM)
            - p.power_mm_s_per_w * result.power_w)


def aggregate(scores, how: str = 'mean') -> float:
    """Combine a candidate's scores over the settings: ``mean`` or ``worst``."""
    scores = np.asarray(scores, dtype=float)
    if how == 'mean':
        return float(scores.mean())
    if how == 'worst':
        return float(scores.min())
    raise ValueError(f"aggregate must be 'mean' or 'worst', got {how!r}")


def with_seed(settings, seed: int):
    """The settings with their jitter streams derived from `seed` (a search's seed)."""
    return tuple(replace(s, seed=int(seed) * 1000 + s.seed) for s in settings)
