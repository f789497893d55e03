"""End-to-end demo: run a whole robot as separate ROS 2 processes, then summarise.

``make demo`` (or ``.venv/bin/python -m softsnap_gaits.demo --scene snake --seconds 20``,
or ``ros2 run softsnap_gaits demo``) starts the graph of :func:`softsnap_gaits.graph.robot_graph`:
one simulated module per module, one ``driver_container`` driving every module (or, with
``--drivers separate``, one ``driver_node`` per module), the model node, the gait node and
the rerun logger, each its own OS process talking over ROS 2. It runs the scene's gait for a
fixed time, stops every process (also on Ctrl-C or when a node crashes; no orphans:
each child runs in its own process group, which is signalled and reaped), and prints a
summary: commands sent by the gait node and received by each driver by their own
counters (so "lost" is the true difference, and what this process's observer missed is
shown apart), shapes predicted, tracking error between the commanded and the predicted
shape, solver time, and the paths of the ``.rrd`` recording and of the ROS 2 bag (a
rosbag2 directory with the robot's topics, every topic with ``--bag-all``;
:mod:`softsnap_gaits.bag`; ``bag play`` replays it).

Each demo claims a private slot (:mod:`softsnap_gaits.isolation`): a ROS domain id no
other demo or test on this machine uses (unless ``ROS_DOMAIN_ID`` is set) and free
loopback ports for its simulated modules, so several demos can run at once. A robot that
does not start (a process exits, a module never comes online) is reported with the
failing process's log and exit code 1, never with a table of zeros; what the observer
did not see of a module is shown as ``-`` (``null`` in JSON).

With ``--physics`` the robot runs on ``sim_robot`` (the whole robot in MuJoCo, serving
every module's firmware protocol) instead of one ``sim_module`` per module; the gripper
gets a 10 g ball of 45 mm radius between its fingers and the ring a puck to cage (:data:`PHYSICS_PAYLOADS`).
The summary then adds, from ``sim/base_pose``, ``sim/payload_pose`` and
``model/shape/simulated``: the distance the robot travelled per gait cycle, where the
payload went (the gripper: whether it held it through the first grasp), the simulated
versus predicted shape error per module (root mean square over the 12 rib centres, mm,
against ``solve_forward`` at each snapshot's own cable length; also with the winch at
rest) and sim_robot's real-time factor; the recording shows the simulated shapes beside the
commanded and predicted ones, with the robot moving in the world. Every node then runs on
sim_robot's ``/clock`` (``use_sim_time``, :func:`softsnap_gaits.graph.robot_graph`), and
so does the observer: ``--seconds`` counts simulated seconds, and every rate, stamp and
distance per gait cycle of the summary is in simulated time, whatever the real-time
factor (the wall time the run took is shown beside it).

The runner observes the robot with its own rclpy node; it holds no science itself (tip
positions come from :func:`softsnap_model.geometry.rib_centers`, predicted shapes for
simulated ones from :func:`softsnap_model.forward.solve_forward`).

``--camera`` (with ``--physics``) adds sim_robot's camera and the marker tracker, and the
summary's ``camera`` entry (:mod:`softsnap_gaits.demo_camera`).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from softsnap_model.scene import SceneError

from .graph import DRIVER_MODES, SIM_MODULE_MODES
# The demo's parts (the names tests, benchmarks and users import from softsnap_gaits.demo):
from .demo_config import (PAYLOAD_HOLD_TOL_MM, PHYSICS_PAYLOADS, READY_TIMEOUT_S,
                          SETTLED_SNAPSHOTS, SHARED_SIMS_ABOVE)
from .demo_metrics import (CommandCounts, commands_counted, running_tip_errors_mm,
                           settled_tip_errors_mm, simulated_shape_errors_mm)
from .demo_observer import ModuleStats, Observer
from .demo_report import print_summary, summarise
from .demo_run import Process, run

__all__ = ['CommandCounts', 'ModuleStats', 'Observer', 'PAYLOAD_HOLD_TOL_MM', 'PHYSICS_PAYLOADS',
           'Process', 'SETTLED_SNAPSHOTS', 'build_parser', 'commands_counted', 'main',
           'print_summary', 'run', 'running_tip_errors_mm', 'settled_tip_errors_mm',
           'simulated_shape_errors_mm', 'summarise']


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='demo', description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='brittle_star',
                        help='brittle_star, starfish, snake, gripper, ring, or a scene YAML path')
    parser.add_argument('--seconds', type=float, default=10.0,
                        help='gait run time, s (default 10; with --physics, simulated seconds)')
    parser.add_argument('--gait', default=None, help="gait name (default: the scene's default gait)")
    parser.add_argument('--gait-rate', type=float, default=50.0, help='command rate, Hz (default 50)')
    parser.add_argument('--model-rate', type=float, default=100.0, help='prediction rate, Hz (default 100)')
    parser.add_argument('--real', action='store_true',
                        help="drive real modules at the scene's addresses instead of simulated ones")
    parser.add_argument('--physics', action='store_true',
                        help='simulate the whole robot in MuJoCo (sim_robot: gravity, ground, '
                             'payloads, locomotion) instead of one sim_module per module')
    parser.add_argument('--time-factor', type=float, default=1.0,
                        help='with --physics: simulated seconds per wall second (default 1)')
    parser.add_argument('--drivers', choices=DRIVER_MODES, default='container',
                        help='container: every module\'s driver in one driver_container process '
                             '(default); separate: one driver_node process per module')
    parser.add_argument('--sim-modules', choices=('auto', *SIM_MODULE_MODES), default='auto',
                        help='separate: one sim_module process per simulated module; shared: one '
                             f'process for all; auto (default): shared above {SHARED_SIMS_ABOVE} '
                             'modules')
    parser.add_argument('--scene-ports', action='store_true',
                        help="simulated modules on the scene's fixed ports (default: free ports "
                             "of this demo's slot, so several demos can run at once)")
    parser.add_argument('--ready-timeout', type=float, default=READY_TIMEOUT_S,
                        help='how long the whole robot may take to come up, s (default '
                             f'{READY_TIMEOUT_S:g}); then the demo stops and says what is missing')
    parser.add_argument('--output', default=None, help='.rrd path (default runs/<scene>-<time>/<scene>.rrd)')
    parser.add_argument('--run-dir', default=None, help='folder for logs and the recording')
    parser.add_argument('--no-rerun', action='store_true', help='do not record the .rrd')
    parser.add_argument('--bag', default=None,
                        help="ROS 2 bag directory to record the robot's topics to (default "
                             'runs/<scene>-<time>/bag; must not exist)')
    parser.add_argument('--bag-all', action='store_true',
                        help='record every topic of the ROS domain in the bag, not only '
                             "the robot's (its namespace, TF, robot_description, "
                             'joint_states, diagnostics, clock, rosout)')
    parser.add_argument('--no-bag', action='store_true', help='do not record a ROS 2 bag')
    parser.add_argument('--json', action='store_true', help='print the summary as JSON')
    parser.add_argument('--closed-loop', action='store_true', help='with --physics: the shape '
                        'controller reaching a target on a MuJoCo gripper finger (docs/control.md)')
    parser.add_argument('--camera', action='store_true',
                        help="with --physics: sim_robot's camera and the marker tracker")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.closed_loop:   # its own module (closed_loop_demo.py), its own summary
        from softsnap_gaits.closed_loop_demo import main as closed_loop_main
        return closed_loop_main(argv)
    if not (args.seconds > 0 and math.isfinite(args.seconds)):
        build_parser().error(f'--seconds must be positive, got {args.seconds}')
    if args.physics and args.real:
        build_parser().error('--physics simulates the robot; it cannot drive --real modules')
    if args.camera and not args.physics:
        build_parser().error('--camera renders the physics simulation: add --physics')
    if not (0 < args.time_factor <= 100 and math.isfinite(args.time_factor)):
        build_parser().error(f'--time-factor must be in (0, 100], got {args.time_factor}')
    if not (args.ready_timeout > 0 and math.isfinite(args.ready_timeout)):
        build_parser().error(f'--ready-timeout must be positive, got {args.ready_timeout}')
    if args.bag and Path(args.bag).exists():
        build_parser().error(f'--bag {args.bag} exists: a bag is never written over')
    try:
        return run(args)
    except (SceneError, ValueError, RuntimeError) as error:  # bad scene, ROS_DOMAIN_ID, no slot
        print(f'demo: {error}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
