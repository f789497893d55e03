"""The demo's settings: timeouts, queue depths and the physics payloads per scene."""
from __future__ import annotations





STOP_TIMEOUT_S = 10.0  # per process, after SIGINT, before SIGKILL

#: --physics: the run ends early (and says so) if the simulated time stood still this long
#: in wall seconds (sim_robot stalled or its /clock lost).
CLOCK_STALL_S = 30.0

#: Robots larger than this get one shared sim_module process by default: the paper's
#: robots keep one process per module (as one ESP32 each), while 30 or more processes
#: outrun localhost-only discovery (docs/scaling.md).
SHARED_SIMS_ABOVE = 10

READY_TIMEOUT_S = 60.0  # the whole graph up: discovery + first predicted shapes

#: After the run (gait node stopped): the observer takes what is still queued for it, at
#: most this long; it stops as soon as it has everything stamped in the run (a 4 s run:
#: 7-26 s with two demos at once on 2 cores kept busy, load average 20-24).
DRAIN_TIMEOUT_S = 60.0

DRAIN_IDLE_S = 2.0  # ... or once no command or gait phase arrived for this long

#: Queue depth of the observer's command, measured-length, driver-state and gait-phase
#: subscriptions: 20 s of 50 Hz commands, so an observer that falls behind on a loaded
#: machine catches up afterwards instead of having its queue overwritten (which DDS does
#: not report as lost; the command counts need the states and phases of the whole run).
STREAM_DEPTH = 1000

#: Two commanded lengths closer than this (m) are the same length: the gait is holding.
#: Holds are exact (the gait library computes a held value from the same numbers), so
#: the tolerance only guards against float noise; a cosine ease moves far more per tick.
SETTLED_HOLD_TOL_M = 1e-9

#: sim_robot parameters per scene with --physics (radii in m). The gripper holds a 10 g
#: ball of 45 mm radius: its closed fingers cage balls of 40-50 mm radius and hold up to
#: 20 g at 45 mm with the estimated bending stiffness; a 20 g ball of 20 mm radius (the
#: issue's question) falls between the fingertips (docs/sim_robot.md). The ring cages a
#: 20 g puck standing on the ground, 85 mm radius and 30 mm tall: lying flat, 9 mm tall,
#: its ribs reach the wall of a puck where they reach a ball only at its bottom (a 40 mm
#: ball is never touched), and 85 mm is inside what the gripping pair's 60 mm contraction
#: closes on (docs/sim_robot.md, benchmarks/ring_transport.py).
PHYSICS_PAYLOADS = {
    'gripper': {'payload': 'ball', 'payload_mass_kg': 0.01, 'payload_size_m': 0.045},
    'ring': {'payload': 'cylinder', 'payload_mass_kg': 0.02, 'payload_size_m': 0.085,
             'payload_height_m': 0.03},
}

#: The gripper holds its payload through a grasp if the payload sinks less than this
#: (mm) between the start and the end of the hold and stays clear of the ground.
PAYLOAD_HOLD_TOL_MM = 10.0

#: sim_robot's snapshot rate (Hz of simulated time; its default, which the demo keeps).
SNAPSHOT_RATE_HZ = 30.0

#: A simulated shape counts as settled when its winch's cable length has not changed for
#: this many snapshots before it (0.5 s of simulated time): the shape error then holds
#: no lag behind a moving winch (docs/sim_robot.md, "What the physics shows").
SETTLED_SNAPSHOTS = 15
