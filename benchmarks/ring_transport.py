#!/usr/bin/env python3
"""Does the ring's ``transport`` gait carry its payload? Travel per cycle in MuJoCo.

The ring runs on a fresh :class:`~softsnap_driver.sim_robot.SimRobot` (firmware, loaded
winches, the MuJoCo ring on the ground) with a payload at its centre, driven with the
gait's contraction schedule as the drivers would send it (``ScriptedCommands``, no
sockets). After a 0.3 s settle, the table gives for each payload the ring's (the mean
of its rib centres) and the payload's ground-plane displacement (mm, robot frame) after each cycle, and the payload's
travel along the ring's direction of travel per cycle.

Payloads: ``cylinder:R:H`` (radius, half height, mm; a puck standing on the ground),
``ball:R`` (radius, mm) or ``box:A`` (half edge, mm); all of ``--mass-kg``.

Not a timing benchmark (deterministic). Each payload takes tens of seconds per cycle on a
loaded 2-core machine.

Usage: .venv/bin/python benchmarks/ring_transport.py [--payloads cylinder:100:15,ball:40]
       [--cycles 2] [--mass-kg 0.02] [--gait transport]
"""
from __future__ import annotations

import argparse

import numpy as np

from softsnap_driver.sim_robot import (DEFAULT_PAYLOAD_HEIGHT_M, ScriptedCommands, SimRobot,
                                       build_simulation)
from softsnap_driver.sim_robot_runner import build_payload
from softsnap_gaits.gaits import make_gait
from softsnap_model.physics.parameters import Payload
from softsnap_model.scene import load_scene

SETTLE_S = 0.3


#: Sizes (mm) each payload shape takes in ``--payloads``.
PAYLOAD_SIZES = {'ball': 1, 'box': 1, 'cylinder': 2}


def parse_payload(text: str, mass_kg: float) -> Payload:
    """One ``--payloads`` item as the physics payload (ValueError if bad).

    The shape-to-sizes mapping and its checks are sim_robot's (:func:`build_payload`, from
    its ``payload*`` options), whose cylinder height is the full height: this script's is
    the half height, as in :class:`Payload`.
    """
    shape, *mm = text.split(':')
    if len(mm) != PAYLOAD_SIZES.get(shape):
        raise ValueError(f'payload {text!r}: expected cylinder:R:H, ball:R or box:A (mm)')
    sizes_m = [float(v) * 1e-3 for v in mm]
    height_m = 2.0 * sizes_m[1] if shape == 'cylinder' else DEFAULT_PAYLOAD_HEIGHT_M
    return build_payload(argparse.Namespace(payload=shape, payload_mass_kg=mass_kg,
                                            payload_size_m=sizes_m[0], payload_height_m=height_m))


def transport_mm(scene, payload: Payload, gait_name: str, cycles: int,
                 links_per_segment: int, groups=None, amplitude_mm=None) -> tuple[np.ndarray, np.ndarray]:
    """Ring base and payload ground-plane displacement after each cycle, 2 x (cycles, 2) mm."""
    robot = SimRobot(scene, build_simulation(scene, payload=payload,
                                             links_per_segment=links_per_segment))
    robot.run_until(SETTLE_S)
    sim = robot.simulation
    ring0 = sim.rib_centroid_world()
    load0 = np.asarray(sim.payload_pose()[0])
    spec = dict(scene.gaits[gait_name])
    if groups:
        spec['groups'] = groups
    if amplitude_mm:
        spec['amplitude_mm'] = amplitude_mm
    gait = make_gait(spec, scene, name=gait_name, time_scale='auto')
    script = ScriptedCommands(gait.contraction_mm, start_s=robot.clock())
    ring, load = [], []
    for c in range(1, cycles + 1):
        robot.run_until(SETTLE_S + c * gait.period_s, script)
        ring.append((sim.rib_centroid_world() - ring0)[:2] * 1e3)
        load.append((np.asarray(sim.payload_pose()[0]) - load0)[:2] * 1e3)
    return np.array(ring), np.array(load)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--payloads', default='cylinder:100:15,ball:40')
    parser.add_argument('--mass-kg', type=float, default=0.02)
    parser.add_argument('--gait', default='transport')
    parser.add_argument('--cycles', type=int, default=2)
    parser.add_argument('--links-per-segment', type=int, default=2)
    parser.add_argument('--amplitude-mm', type=float, default=0.0,
                        help="override of the gait's amplitude, mm (0: the scene's); the "
                             'gait is slowed to the winch speed where needed')
    parser.add_argument('--groups', default='',
                        help="override of the gait's groups, e.g. south+east,north+west")
    args = parser.parse_args(argv)
    scene = load_scene('ring')
    groups = [g.split('+') for g in args.groups.split(',') if g] or None
    for text in [p for p in args.payloads.split(',') if p]:
        ring, load = transport_mm(scene, parse_payload(text, args.mass_kg), args.gait,
                                  args.cycles, args.links_per_segment, groups,
                                  args.amplitude_mm)
        r, l = ring[-1], load[-1]
        along = float(l @ r) / max(float(np.linalg.norm(r)), 1e-9)
        fmt = lambda a: ', '.join(f'({x:+.1f}, {y:+.1f})' for x, y in a)   # noqa: E731
        print(f'{text:>18}: ring {fmt(ring)} mm; payload {fmt(load)} mm; per cycle: ring '
              f'{np.linalg.norm(r) / args.cycles:.1f} mm, payload along the ring '
              f'{along / args.cycles:+.1f} mm', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
