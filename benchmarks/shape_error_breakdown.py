#!/usr/bin/env python3
"""Where the physics demo's simulated-versus-predicted shape error comes from (issue 16).

One gait of a scene (default: the brittle star's ``walk``) runs through ``sim_robot``'s
coupled loop (firmware, loaded winches, the MuJoCo robot; commands as the drivers send
them, ``ScriptedCommands``, no sockets) in settings that add one effect at a time:

1. ``static``: gravity off, no ground, the module clamped, the winch slow and the shape
   settled at the gait's held contraction (``compare.static_fidelity``): the fidelity
   check, the floor of the discretisation;
2. ``free space``: gravity off, no ground, the hub held: the gait's dynamics alone
   (the legs lag the winch, ring after each edge, and swing freely when the cable is
   slack);
3. ``gravity, hanging free``: gravity on, still no ground, the hub held in the air;
4. ``ground, hub held``: lying on the ground with friction, the hub held in place;
5. ``ground, free`` (the demo's setting): lying on the ground, the robot free to move;
6. the same with half the friction (0.3 instead of 0.6): how the ground's share scales.

Every snapshot (30 Hz of simulated time, as ``sim_robot`` publishes them) is compared
with ``solve_forward`` for the module's cable length at that very snapshot (the length
the winch allows), so no pairing of a snapshot with a shape of another length enters:
the root mean square over the 12 rib centres of their distances, mm, mean and max over
the run, and the mean over "settled" snapshots only (the winch at rest for at least
``--rest`` s). The last line shows what pairing each snapshot with the shape of the
cable length ``--lag`` s earlier (a predicted shape still in force when the snapshot
arrives) adds in the demo's setting.

Deterministic (not a timing benchmark): the same numbers on every machine with the same
MuJoCo build. Two cycles of the brittle star take about a minute per setting on a
loaded 2-core machine. Last, per setting, how hard the ribs press on the ground (their
contact normal forces over their weight, sampled every step) and how far the hub rose:
the robot, rigid out of the ground plane, tilts under its legs' friction and shifts
weight onto the ribs, which raises their friction (docs/sim_robot.md); with the hub held
this is unbounded, so the "hub held" row overstates the ground's share.

Usage: nice .venv/bin/python benchmarks/shape_error_breakdown.py [--scene brittle_star]
       [--gait walk] [--modules yellow,orange] [--cycles 2] [--links-per-segment 2]
"""
from __future__ import annotations

import argparse

import mujoco
import numpy as np

from softsnap_driver.sim_robot import ScriptedCommands, SimRobot
from softsnap_gaits.gaits import make_gait
from softsnap_model.forward import solve_forward
from softsnap_model.physics.compare import static_fidelity
from softsnap_model.physics.parameters import PhysicsParameters
from softsnap_model.physics.robot_mjcf import robot_mjcf_layout
from softsnap_model.physics.simulation import RobotSimulation
from softsnap_model.scene import load_scene

#: Simulated time (s) the robot rests before the gait starts (it settles onto the ground).
SETTLE_S = 0.3
#: Snapshot rate (Hz of simulated time): sim_robot's default.
SNAPSHOT_HZ = 30.0

#: Half the default rib friction (0.6): how the ground's share scales with friction. (A
#: near-frictionless ground is no reference with MuJoCo's pyramidal friction cones, the
#: model's default: at 1e-4 contact forces of several newtons on single ribs launch the
#: robot up to 150 mm off the ground; docs/sim_robot.md.)
HALF_FRICTION = 0.3

SETTINGS = (
    ('free space (gravity off, no ground, hub held)',
     dict(gravity=False, ground=False, base='fixed')),
    ('gravity, hanging free (no ground, hub held)', dict(gravity=True, ground=False, base='fixed')),
    ('ground with friction, hub held', dict(gravity=True, ground=True, base='fixed')),
    ('ground with friction, robot free (the demo)', dict(gravity=True, ground=True, base='free')),
    ('ground with half the friction, robot free',
     dict(gravity=True, ground=True, base='free', friction=HALF_FRICTION)),
)


def simulation(scene, links: int, gravity: bool, ground: bool, base: str,
               friction: float | None = None) -> RobotSimulation:
    """The robot in one setting. A hub held on the ground sits where the free robot comes
    to rest (its legs, rigid out of their plane, would not reach the ground otherwise)."""
    params = PhysicsParameters() if friction is None else PhysicsParameters(rib_friction=friction)
    if not (ground and base == 'fixed'):
        return RobotSimulation(scene, links_per_segment=links, gravity=gravity, ground=ground,
                               base=base, parameters=params)
    free = RobotSimulation(scene, links_per_segment=links, gravity=gravity, ground=ground,
                           base='free', parameters=params)
    free.step(SETTLE_S)
    height = float(free.robot_base_pose()[0][2])
    xml, layout = robot_mjcf_layout(scene, links_per_segment=links, parameters=params,
                                    gravity=gravity, ground=ground, base='fixed',
                                    base_height_m=height)
    sim = RobotSimulation.__new__(RobotSimulation)
    sim._init(xml, layout, place_on_ground=False)
    return sim


def rms_mm(centres_m: np.ndarray, reference_mm: np.ndarray) -> float:
    distance = np.linalg.norm(centres_m[:, :2] * 1e3 - reference_mm, axis=1)
    return float(np.sqrt(np.mean(distance ** 2)))


class RibLoad:
    """The ribs' ground contact normal forces over their weight, and the robot's height,
    sampled before every physics step (how hard the legs press on the ground)."""

    def __init__(self, sim: RobotSimulation):
        self.sim = sim
        m = sim.model
        ribs = [int(b) for name in sim.module_names for b in sim._rib_ids[name][1:]]
        self.ribs = np.zeros(m.nbody, dtype=bool)
        self.ribs[ribs] = True
        self.weight_n = float(np.sum(m.body_mass[ribs])) * float(np.linalg.norm(m.opt.gravity))
        self.ratios: list = []
        self.heights_mm: list = []
        self._force = np.zeros(6)

    def sample(self) -> None:
        m, d = self.sim.model, self.sim.data
        total = 0.0
        for i in range(d.ncon):
            c = d.contact[i]
            if self.ribs[m.geom_bodyid[c.geom1]] or self.ribs[m.geom_bodyid[c.geom2]]:
                mujoco.mj_contactForce(m, d, i, self._force)
                total += self._force[0]
        if self.weight_n > 0.0:
            self.ratios.append(total / self.weight_n)
        self.heights_mm.append(float(self.sim.robot_base_pose()[0][2]) * 1e3)

    def summary(self) -> str:
        if not self.ratios or max(self.ratios) == 0.0:
            return 'no rib on the ground'
        r = np.asarray(self.ratios)
        hop = max(self.heights_mm) - self.heights_mm[0]
        return (f'ribs press on the ground with {r.mean():.2f} x their weight on average '
                f'(top 1 %: {np.percentile(r, 99):.1f} x, max {r.max():.1f} x; '
                f'{r[0]:.2f} x at the start); the hub rose up to {hop:.1f} mm')


def run(scene, gait, names, cycles: int, links: int, setting: dict, lag_s: float,
        rest_s: float) -> tuple[dict, RibLoad]:
    """Per module: (errors, settled flags, lagged errors) over the gait's snapshots; and
    the ribs' contact load over the gait."""
    robot = SimRobot(scene, simulation(scene, links, **setting))
    sim = robot.simulation
    robot.run_until(SETTLE_S)
    script = ScriptedCommands(gait.contraction_mm, start_s=robot.clock())
    load = RibLoad(sim)

    def on_step(r):
        script(r)
        load.sample()
    threading = {m.name: m.threading_mm for m in scene.modules}
    cache: dict = {}

    def reference(name, length_mm):
        key = (name, length_mm)
        if key not in cache:
            cache[key] = np.asarray(solve_forward(scene.skeleton, threading[name],
                                                  length_mm).rib_centers)
        return cache[key]

    lag = max(0, int(round(lag_s * SNAPSHOT_HZ)))
    rest = max(1, int(round(rest_s * SNAPSHOT_HZ)))
    history = {n: [] for n in names}     # cable lengths (mm) of the snapshots so far
    out = {n: ([], [], []) for n in names}
    end = SETTLE_S + cycles * gait.period_s
    k = 0
    while robot.clock() < end - 1e-9:
        k += 1
        robot.run_until(SETTLE_S + k / SNAPSHOT_HZ, on_step)
        for n in names:
            length_mm = robot.cable_length_m(n, robot.modules[n].position) * 1e3
            history[n].append(length_mm)
            centres = sim.rib_centers(n)
            errors, settled, lagged = out[n]
            errors.append(rms_mm(centres, reference(n, length_mm)))
            settled.append(len(history[n]) > rest and len(set(history[n][-rest - 1:])) == 1)
            earlier = history[n][max(0, len(history[n]) - 1 - lag)]
            lagged.append(rms_mm(centres, reference(n, earlier)))
    return out, load


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='brittle_star')
    parser.add_argument('--gait', default=None, help="default: the scene's default gait")
    parser.add_argument('--modules', default=None, help='comma-separated; default: all')
    parser.add_argument('--cycles', type=int, default=2)
    parser.add_argument('--links-per-segment', type=int, default=2)
    parser.add_argument('--rest', type=float, default=0.5,
                        help='a snapshot is settled when its winch has not moved for this long, s')
    parser.add_argument('--lag', type=float, default=0.1,
                        help='pairing delay shown on the last line, s')
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    gait = make_gait(args.gait or scene.default_gait, scene)
    names = args.modules.split(',') if args.modules else [m.name for m in scene.modules]
    holes = {m.name: list(m.holes) for m in scene.modules}
    print(f'{scene.name}, gait {gait.name}, {args.cycles} cycles of {gait.period_s:g} s, '
          f'{args.links_per_segment} links per segment; rib-centre RMS against solve_forward '
          'at the same cable length, mm: mean / max over the run (mean over snapshots with '
          f'the winch at rest >= {args.rest:g} s)', flush=True)
    width = max(len(s[0]) for s in SETTINGS) + 2
    print(f"{'setting':<{width}}" + ''.join(f'{n:>22}' for n in names), flush=True)
    # 1. The fidelity floor at the gait's held contraction.
    cells = []
    for n in names:
        peak = float(gait.peak_contraction_mm[[m.name for m in scene.modules].index(n)])
        if peak <= 0.0:
            cells.append(f"{'-':>22}")
            continue
        fid = static_fidelity(holes[n], peak, links_per_segment=args.links_per_segment,
                              skeleton=scene.skeleton)
        d = np.linalg.norm(fid.rib_centers_mm - fid.reference_rib_centers_mm, axis=1)
        cells.append(f'{float(np.sqrt(np.mean(d ** 2))):>10.2f} (max {fid.max_rib_error_mm:.2f})')
    print(f"{'static, settled (fidelity check)':<{width}}" + ''.join(cells), flush=True)
    last = None
    loads = []
    for label, setting in SETTINGS:
        result, load = run(scene, gait, names, args.cycles, args.links_per_segment, setting,
                           args.lag, args.rest)
        cells = []
        for n in names:
            errors, settled, _ = (np.asarray(x) for x in result[n])
            rest = f'{errors[settled].mean():.1f}' if settled.any() else '-'
            cells.append(f'{errors.mean():>8.1f} / {errors.max():5.1f} ({rest:>5})')
        print(f'{label:<{width}}' + ''.join(cells), flush=True)
        loads.append((label, load.summary()))
        if 'the demo' in label:
            last = result
    cells = []
    for n in names:
        lagged = np.asarray(last[n][2])
        cells.append(f'{lagged.mean():>8.1f} / {lagged.max():5.1f}        ')
    print(f"{f'the demo, paired {args.lag:g} s late':<{width}}" + ''.join(cells), flush=True)
    for label, text in loads:
        print(f'{label}: {text}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
