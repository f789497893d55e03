"""The whole robot simulated in MuJoCo, serving the firmware protocol: ``sim_robot``.

Runs without ROS (this module imports no rclpy; the command line and the servers are
:mod:`softsnap_driver.sim_robot_runner`)::

    python -m softsnap_driver.sim_robot_runner --scene brittle_star --time-factor 1

and, with ``--ros-args`` (``ros2 run softsnap_driver sim_robot --ros-args -p scene:=snake``),
as an rclpy node (:mod:`softsnap_driver.sim_robot_node`) that also publishes the robot's
base pose and the simulated rib positions of every module.

Every module of the scene is served on its own loopback port, exactly like
:mod:`softsnap_driver.sim_module` serves one: the same :class:`~softsnap_driver.sim_module.SimServer`
and the same firmware semantics (:class:`~softsnap_driver.firmware.SimModule`), so
unchanged driver nodes drive it. What changes is the winch: its motor pulls the cable of
a module of a MuJoCo model of the whole robot (:mod:`softsnap_model.physics`), and the
cable pulls back.

Coupling, one control period ``dt`` (:data:`CONTROL_PERIOD_S`) at a time, all in one
thread (:meth:`SimRobot.step`):

1. under :attr:`SimRobot.lock`, every module's firmware advances by ``dt`` (bang-bang
   toward its target, :class:`WinchMotor` loaded by the cable tension of the previous
   period); its encoder count gives the cable length
   ``L = straight_length - count / counts_per_mm`` (the driver's own conversion,
   :mod:`softsnap_driver.core`, with the module calibrated straight at count 0);
2. without the lock, the physics gets those lengths (``set_cable_length``) and steps
   ``dt`` at its own fixed timestep; the tendon tensions it reports load the winches in
   the next period.

The HTTP server threads take the same lock to answer a request; they read the
simulation clock (:attr:`SimRobot.clock`, the time the firmware has been advanced to)
and never touch the physics. The loop paces itself to the wall clock times
``time_factor`` (1: real time; 0: as fast as it can).

Winch under load (:class:`WinchMotor`): the GA12-N20 is a DC motor, so at a drive of
``d = pwm/255 * supply/6 V`` its speed falls linearly with the load torque,
``speed = no_load_speed * (d - torque / stall_torque)``, which is the firmware model's
``no_load_speed * d * (1 - load_fraction)`` with ``load_fraction = torque / (d *
stall_torque)``. The torque is the cable tension times the drum radius while the winch
hauls in; paying out, the tension helps and the 1:100 gearbox holds it back (load 0).
At ``load_fraction >= 1`` the winch stalls: the encoder stops and the motor draws its
stall current, which the power history shows, as a real module would; the driver's stall
detection (no progress for ``stall_timeout_s``) then stops it.

Stall torque: FACTS.md gives the motor type (GA12-N20, 1:100) but no torque. Sellers'
data for the 6 V, 1:100 (about 300 rpm) variant give a stall torque of 1.2 to 2 kg cm;
we take :data:`DEFAULT_STALL_TORQUE_NM` = 0.15 N m (1.5 kg cm) at 6 V and full PWM. The
drum radius follows from the scene's ``counts_per_mm``: ``counts_per_rev / (2 pi
counts_per_mm)`` = 2800 / (2 pi 89.13) = 5.0 mm, so the stall tension is 0.15 / 0.005 =
30 N at 6 V and full PWM, 23.5 N at the drivers' default PWM 200 (boosted), about 15 N
on the battery alone (within 60 counts of the target). Measure it by hanging weights on
the cable until the winch stops.

Dependencies: ``softsnap_model`` gives the scenes, the calibration and the MuJoCo model.
``mujoco`` is imported only inside :mod:`softsnap_model.physics`.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Any

from softsnap_driver.firmware import BatteryModel, Faults, MotorModel, SimModule
from softsnap_driver.protocol import encode_set_request
from .scene_calibration import module_calibration

#: Winch-physics coupling period, s (rounded to whole physics timesteps: 6 ms with
#: sim_robot's 3 ms step, 4 ms with the model's 2 ms): the firmware advances and the
#: cable length is handed to the physics this often. The firmware integrates its motion
#: exactly within a period; the winch moves at most 0.75 mm of cable per 6 ms (123 mm/s
#: unloaded at 6 V, PWM 200), which the physics' overdamped cable constraint takes
#: smoothly. The Python work per period is ~25 % of the loop (docs/sim_robot.md).
CONTROL_PERIOD_S = 0.005

#: Stall torque of the GA12-N20 1:100 at 6 V and full PWM, N m (estimate, see above).
DEFAULT_STALL_TORQUE_NM = 0.15

#: Simulated shapes are sampled for publishing this often by default, Hz of sim time.
DEFAULT_SNAPSHOT_RATE_HZ = 30.0

#: The simulation clock is handed out (``/clock`` of the ROS node) this often by default,
#: Hz of sim time. Nodes with ``use_sim_time`` see time advance in steps of 1 / rate, so
#: it bounds their timers' resolution: 50 Hz is the gait's tick rate (every step a tick,
#: at exact multiples of 20 ms = 5 control periods). Every message wakes each such node's
#: executor, 0.8-0.9 ms of CPU per node and message on the loaded 2-core development
#: machine (benchmarks/sim_clock_bench.py), which is why it is not the 1 kHz a C++
#: simulator publishes: at 100 Hz eight nodes would spend two thirds of a core on it.
DEFAULT_CLOCK_RATE_HZ = 50.0

#: Longest the pacing loop sleeps at once, s (reaction time to stop()).
_MAX_SLEEP_S = 0.05

#: A loop further behind its pace than this (wall s: paused, starved) paces on from where
#: it is instead of racing to make the time up: with /clock nothing needs the simulated
#: time to catch up with the wall clock, and a burst only starves the nodes that follow it.
_MAX_LAG_S = 0.25

#: Payload option values: none, or a shape the physics model accepts
#: (softsnap_model.physics.mjcf.Payload).
PAYLOAD_SHAPES = ('none', 'ball', 'box', 'cylinder')

#: Default contraction (mm) every module must reach before a gripper's helper hold lets
#: go of the payload (the grasp gait closes to 45 mm).
DEFAULT_PAYLOAD_RELEASE_MM = 30.0

#: Default payload: a 10 g ball of 45 mm radius, what the gripper holds through its grasp
#: with a 2x margin (docs/sim_robot.md: the closed fingers cage balls of 40-50 mm radius
#: and hold up to 20 g at 45 mm with the estimated K; a 20 mm ball falls between them).
DEFAULT_PAYLOAD_MASS_KG = 0.01

DEFAULT_PAYLOAD_SIZE_M = 0.045

#: Default height (m) of a cylinder payload (a puck standing on the ground, for the ring:
#: its wall must reach above the flat ring's 9 mm ribs; docs/sim_robot.md).
DEFAULT_PAYLOAD_HEIGHT_M = 0.03

#: Links per segment of sim_robot's MuJoCo model. The physics model's fidelity check puts
#: N = 2 within 0.5 mm of the exact constant-curvature shape at 20 mm contraction (its
#: default, 4, leaves a margin for the static comparisons); N = 2 steps about twice as
#: fast, which a robot simulated live needs more (benchmarks/sim_robot_bench.py).
DEFAULT_LINKS_PER_SEGMENT = 2

#: Fixed physics timestep of sim_robot's MuJoCo model, s. The physics model's own default
#: (``PhysicsParameters.timestep_s``, 2 ms) is kept for the static and gravity
#: comparisons; a robot simulated live steps 3 ms (1.3-1.5x the real-time factor,
#: benchmarks/sim_robot_bench.py): the five scenes' gaits run stable and bit for bit
#: repeatable, a leg's settled shape is within 0.5 mm of the exact model, and the brittle
#: star's walk goes the same way and as far as at 1-2 ms (docs/sim_robot.md). The control
#: period becomes 6 ms (two steps).
DEFAULT_PHYSICS_TIMESTEP_S = 0.003

#: Range accepted for ``physics_timestep_s``, s (4 ms: the largest tried on the ground).
PHYSICS_TIMESTEP_RANGE_S = (0.0005, 0.004)


class SimRobotError(ValueError):
    """A sim_robot option or scene the simulation cannot run (names the value and range)."""


class WinchMotor:
    """The firmware model's :class:`MotorModel` with its load taken from the cable tension.

    Duck-types :class:`MotorModel` for :class:`SimModule`; :attr:`tension_n` and
    :attr:`hauling` are set by the simulation loop before each firmware advance.
    """

    def __init__(self, base: MotorModel, stall_torque_nm: float, drum_radius_m: float):
        if not (math.isfinite(stall_torque_nm) and stall_torque_nm > 0):
            raise SimRobotError(f'stall_torque_nm must be positive and finite, got {stall_torque_nm!r}')
        if not (math.isfinite(drum_radius_m) and drum_radius_m > 0):
            raise SimRobotError(f'drum radius must be positive and finite, got {drum_radius_m!r} m')
        self.base = base
        self.stall_torque_nm = stall_torque_nm
        self.drum_radius_m = drum_radius_m
        self.min_pwm = base.min_pwm
        self.rated_voltage_v = base.rated_voltage_v
        self.counts_per_rev = base.counts_per_rev
        #: Cable tension pulling on the drum, N (from the physics, previous period).
        self.tension_n = 0.0
        #: Whether the winch is hauling cable in (the tension opposes it) or paying out.
        self.hauling = True

    def _drive(self, pwm: int, supply_v: float) -> float:
        return (pwm / 255.0) * (supply_v / self.rated_voltage_v)

    def load_fraction(self, pwm: int, supply_v: float) -> float:
        """Load torque over the stall torque at this drive, 0 to 1 (1: stalled)."""
        if not self.hauling or self.tension_n <= 0.0:
            return 0.0
        drive = self._drive(pwm, supply_v)
        if drive <= 0.0:
            return 1.0
        return min(1.0, self.tension_n * self.drum_radius_m / (self.stall_torque_nm * drive))

    def stall_tension_n(self, pwm: int = 255, supply_v: float | None = None) -> float:
        """Cable tension at which the winch stops hauling at this drive, N."""
        supply_v = self.rated_voltage_v if supply_v is None else supply_v
        return self.stall_torque_nm * self._drive(pwm, supply_v) / self.drum_radius_m

    def speed_counts_per_s(self, pwm: int, supply_v: float) -> float:
        if pwm < self.min_pwm:
            return 0.0
        no_load = self.base.no_load_rpm / 60.0 * self.counts_per_rev
        return no_load * self._drive(pwm, supply_v) * (1.0 - self.load_fraction(pwm, supply_v))

    def current_a(self, pwm: int, supply_v: float, stalled: bool) -> float:
        load = 1.0 if stalled or pwm < self.min_pwm else self.load_fraction(pwm, supply_v)
        base = self.base
        full = base.no_load_current_a + (base.stall_current_a - base.no_load_current_a) * load
        return full * self._drive(pwm, supply_v)


@dataclass(frozen=True)
class ModuleSnapshot:
    """One module at one simulation time (SI units).

    ``rib_centers_m``: 12 rib centres in the module's base frame (rib 0 at the origin,
    spine along +x), m; ``angles_rad``: bending angle of each segment, rad.
    ``base_position_m``/``base_orientation_wxyz``: the module base in
    the world frame. ``cable_length_m``: the winch's cable length; ``tension_n``: the
    tendon tension, N; ``encoder_count``/``target``: the firmware's counts.
    """

    name: str
    rib_centers_m: tuple[tuple[float, float, float], ...]
    angles_rad: tuple[float, ...]
    base_position_m: tuple[float, float, float]
    base_orientation_wxyz: tuple[float, float, float, float]
    cable_length_m: float
    tension_n: float
    encoder_count: int
    target: int


@dataclass(frozen=True)
class RobotSnapshot:
    """The simulated robot at simulation time ``time_s`` (s): world poses and shapes."""

    time_s: float
    base_position_m: tuple[float, float, float]
    base_orientation_wxyz: tuple[float, float, float, float]
    modules: tuple[ModuleSnapshot, ...]
    payload_position_m: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class SimRobotStats:
    """How the loop kept up: simulated and busy wall time, s, and their ratio."""

    sim_time_s: float
    busy_wall_s: float
    steps: int

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall second spent stepping (excludes pacing sleeps)."""
        return self.sim_time_s / self.busy_wall_s if self.busy_wall_s > 0 else math.inf


class SimRobot:
    """The firmware of every module of a scene, its winch and the robot's physics.

    Not thread-safe by itself except where stated: :meth:`step`, :meth:`run` and
    :meth:`snapshot` belong to one thread (the simulation loop); :attr:`lock` guards the
    firmware state shared with the HTTP server threads (:meth:`request`,
    :attr:`modules`); :meth:`latest_snapshot` and :meth:`stats` may be called from any
    thread.

    Parameters
    ----------
    scene : softsnap_model.scene.Scene
    simulation : object
        A :class:`softsnap_model.physics.simulation.RobotSimulation` of the same scene
        (module names, ``set_cable_length``, ``step``, ``cable_tension``, ...).
    motor, battery : firmware models shared by every module (the winch's load is added).
    faults : Faults, optional
        Injected faults, the same for every module (each its own random stream).
    stall_torque_nm : float
        Motor stall torque at 6 V and full PWM, N m.
    control_period_s : float
        Winch-physics coupling period, s; rounded to a whole number of the physics'
        fixed timesteps (at least one), so firmware and physics keep the same clock.
    snapshot_rate_hz : float
        How often :meth:`run` stores a :class:`RobotSnapshot`, Hz of simulation time.
    clock_rate_hz : float
        How often :meth:`run` hands the simulation time to :attr:`clock_listener`, Hz of
        simulation time (at most once per control period).
    payload_release_mm : float
        A payload placed between a hanging robot's fingers is held by a helper weld
        (``RobotSimulation.release_payload``) until every module's winch has hauled in at
        least this much cable (mm); from then on only the fingers hold it.
    """

    def __init__(self, scene, simulation, *, motor: MotorModel | None = None,
                 battery: BatteryModel | None = None, faults: Faults | None = None,
                 stall_torque_nm: float = DEFAULT_STALL_TORQUE_NM,
                 control_period_s: float = CONTROL_PERIOD_S,
                 snapshot_rate_hz: float = DEFAULT_SNAPSHOT_RATE_HZ, seed: int | None = None,
                 payload_release_mm: float = DEFAULT_PAYLOAD_RELEASE_MM,
                 clock_rate_hz: float = DEFAULT_CLOCK_RATE_HZ):
        if not (math.isfinite(control_period_s) and 1e-4 <= control_period_s <= 0.05):
            raise SimRobotError(f'control_period_s must be in [0.0001, 0.05] s, got {control_period_s!r}')
        if not (math.isfinite(snapshot_rate_hz) and 0.1 <= snapshot_rate_hz <= 1000.0):
            raise SimRobotError(f'snapshot_rate_hz must be in [0.1, 1000] Hz, got {snapshot_rate_hz!r}')
        if not (math.isfinite(payload_release_mm) and 0.0 <= payload_release_mm <= 200.0):
            raise SimRobotError(f'payload_release_mm must be in [0, 200] mm, got {payload_release_mm!r}')
        if not (math.isfinite(clock_rate_hz) and 1.0 <= clock_rate_hz <= 1000.0):
            raise SimRobotError(f'clock_rate_hz must be in [1, 1000] Hz, got {clock_rate_hz!r}')
        missing = [m.name for m in scene.modules if m.name not in simulation.module_names]
        if missing:
            raise SimRobotError(f'the physics model lacks modules {missing} of scene {scene.name!r}')
        motor = motor or MotorModel()
        self.scene = scene
        self.simulation = simulation
        timestep = float(getattr(simulation, 'timestep_s', control_period_s))
        self.control_period_s = max(1, round(control_period_s / timestep)) * timestep
        self.snapshot_period_s = 1.0 / snapshot_rate_hz
        self.clock_period_s = 1.0 / clock_rate_hz
        #: Called from the simulation thread with the simulation time (s) after the step
        #: that reached each clock period (the ROS node publishes it as ``/clock``);
        #: never with a time the firmware and the physics have not both reached.
        self.clock_listener = None
        self._clock_ticks = 0    # clock periods handed out (the next is due at ticks + 1)
        #: Guards the firmware state (modules, motors) shared with the server threads.
        self.lock = threading.Lock()
        self.modules: dict[str, SimModule] = {}
        self.motors: dict[str, WinchMotor] = {}
        self._straight_mm: dict[str, float] = {}
        self._counts_per_mm: dict[str, float] = {}
        for i, module in enumerate(scene.modules):
            calibration = module_calibration(scene, module)
            straight_mm, counts_per_mm = calibration.straight_length_mm, calibration.counts_per_mm
            drum_radius_m = motor.counts_per_rev / (2.0 * math.pi * counts_per_mm) / 1000.0
            winch = WinchMotor(motor, stall_torque_nm, drum_radius_m)
            sim_module = SimModule(motor=winch, battery=battery, faults=faults, start_time=0.0,
                                   mac=f'02:53:4E:41:50:{i + 1:02X}')
            if seed is not None:
                sim_module.rng.seed(seed + i)
            self.modules[module.name] = sim_module
            self.motors[module.name] = winch
            self._straight_mm[module.name] = straight_mm
            self._counts_per_mm[module.name] = counts_per_mm
        self._names = tuple(self.modules)
        #: (name, firmware, winch, straight mm, counts per mm) in scene order, for step().
        self._units = tuple((n, self.modules[n], self.motors[n], self._straight_mm[n],
                             self._counts_per_mm[n]) for n in self._names)
        self._tension_n = {name: 0.0 for name in self._names}
        #: Row of each module (scene order) in the physics' module_states() arrays.
        self._state_rows = [tuple(simulation.module_names).index(n) for n in self._names]
        self._lengths_m = {name: self._straight_mm[name] / 1000.0 for name in self._names}
        #: Modules whose winch turned in the last period (their tensions are read).
        self._winding: set[str] = set()
        # The clock the firmware has been advanced to (s of simulation time). A float is
        # replaced atomically, so the server threads read it without the lock.
        self._clock = 0.0
        self._steps = 0
        self._busy_s = 0.0
        self._snapshot: RobotSnapshot | None = None
        self._snapshot_lock = threading.Lock()
        self._next_snapshot_s = 0.0
        self.fault: str | None = None
        try:
            simulation.payload_pose()
            self.has_payload = True
        except ValueError:   # the physics raises it for a robot without a payload
            self.has_payload = False
        self.payload_release_mm = float(payload_release_mm)
        #: Simulation time the helper hold let go of the payload (s), None before.
        self.payload_released_at_s: float | None = None
        self._release_pending = self.has_payload and bool(getattr(simulation, 'payload_held', False))
        for name in self._names:
            simulation.set_cable_length(name, self._lengths_m[name])

    # -- time and the firmware -------------------------------------------------------
    @property
    def module_names(self) -> tuple[str, ...]:
        return self._names

    def clock(self) -> float:
        """Simulation time the firmware has been advanced to, s (any thread)."""
        return self._clock

    def counts_per_mm(self, name: str) -> float:
        """Encoder counts per mm of cable of module `name` (the scene's, as its driver)."""
        return self._counts_per_mm[name]

    def cable_length_m(self, name: str, position_counts: float) -> float:
        """Cable length for an encoder position: the driver's conversion, m."""
        return (self._straight_mm[name] - position_counts / self._counts_per_mm[name]) / 1000.0

    def request(self, name: str, head: bytes) -> bytes:
        """Apply one firmware request head to module `name` now; the HTTP reply (any thread)."""
        with self.lock:
            return self.modules[name].handle_request(head, self._clock)

    def step(self) -> None:
        """Advance winches and physics by one control period (the simulation thread)."""
        started = time.perf_counter()
        dt = self.control_period_s
        t_next = (self._steps + 1) * dt   # from the step count: no drift from summing
        changed = []
        lengths = self._lengths_m
        tensions = self._tension_n
        winding = self._winding
        with self.lock:
            for name, module, motor, straight_mm, counts_per_mm in self._units:
                motor.tension_n = tensions[name]
                motor.hauling = module.target > module.position
                module.advance_to(t_next)   # an idle module: clock and drain only (firmware)
                # The driver's conversion (cable_length_m), inlined: five calls a period.
                length = (straight_mm - module.position / counts_per_mm) / 1000.0
                if length != lengths[name]:
                    lengths[name] = length
                    changed.append(name)
                if module.moving():
                    winding.add(name)
            self._clock = t_next
        sim = self.simulation
        for name in changed:     # a winch at rest leaves its tendon limit as it is
            sim.set_cable_length(name, lengths[name])
        if self._release_pending and all(
                self.modules[n].position / self._counts_per_mm[n] >= self.payload_release_mm
                for n in self._names):
            sim.release_payload()
            self._release_pending = False
            self.payload_released_at_s = t_next
        sim.step(dt)
        if winding:
            self._read_tensions(winding)
            # The tension loads a winch only while it turns: read it for those that
            # turned in this period or will in the next (one read after a winch stops).
            self._winding = {n for n in winding if self.modules[n].moving()}
        self._steps += 1
        self._busy_s += time.perf_counter() - started

    def _read_tensions(self, names=None) -> None:
        """The cable tension (N) of `names` (default every module) after the last step."""
        sim = self.simulation
        names = self._names if names is None else [n for n in self._names if n in names]
        if not names:
            return
        batch = getattr(sim, 'cable_tensions', None)   # one pass over the constraints
        if batch is not None:
            tensions = batch()
            for name in names:
                self._tension_n[name] = float(tensions[name])
        else:
            for name in names:
                self._tension_n[name] = float(sim.cable_tension(name))

    def run_until(self, time_s: float, on_step=None) -> None:
        """Step (as fast as possible) until the simulation time reaches `time_s`, s.

        `on_step(robot)` is called before each step (commands of a scripted run).
        """
        while self._clock < time_s - 1e-12:
            if on_step is not None:
                on_step(self)
            self.step()
            self._maybe_snapshot()

    # -- observation ---------------------------------------------------------------
    def snapshot(self) -> RobotSnapshot:
        """The robot now (the simulation thread): world poses, shapes, winch state."""
        sim = self.simulation
        base_position, base_orientation = sim.robot_base_pose()
        modules = []
        with self.lock:
            counts = {n: (self.modules[n].encoder_count, self.modules[n].target) for n in self._names}
        batch = getattr(sim, 'cable_tensions', None)   # one pass over the constraints
        tensions = batch() if batch is not None else {n: sim.cable_tension(n) for n in self._names}
        # Every module in one vectorised pass and one tolist() per array (five modules
        # one by one cost ~3x as much, 30 times a simulated second).
        centers, angles, positions, orientations = sim.module_states()
        rows = self._state_rows
        centers, angles = centers[rows].tolist(), angles[rows].tolist()
        positions, orientations = positions[rows].tolist(), orientations[rows].tolist()
        for name, rib_centers, segment_angles, position, orientation in zip(
                self._names, centers, angles, positions, orientations):
            modules.append(ModuleSnapshot(
                name=name, rib_centers_m=tuple(map(tuple, rib_centers)),
                angles_rad=tuple(segment_angles),
                base_position_m=tuple(position), base_orientation_wxyz=tuple(orientation),
                cable_length_m=self._lengths_m[name], tension_n=float(tensions[name]),
                encoder_count=counts[name][0], target=counts[name][1]))
        payload_position = _vec(sim.payload_pose()[0]) if self.has_payload else None
        return RobotSnapshot(time_s=float(sim.time_s), base_position_m=_vec(base_position),
                             base_orientation_wxyz=_vec(base_orientation), modules=tuple(modules),
                             payload_position_m=payload_position)

    def _maybe_snapshot(self) -> None:
        if self._clock + 1e-12 >= self._next_snapshot_s:
            snap = self.snapshot()
            with self._snapshot_lock:
                self._snapshot = snap
            self._next_snapshot_s += self.snapshot_period_s
            if self._next_snapshot_s <= self._clock:
                self._next_snapshot_s = self._clock + self.snapshot_period_s

    def _maybe_tick_clock(self) -> None:
        # From the tick count, not a running sum: no drift over a long run. A control
        # period longer than the clock period skips ticks (only the newest time matters).
        ticks = math.floor((self._clock + 1e-12) / self.clock_period_s)
        if ticks <= self._clock_ticks:
            return
        self._clock_ticks = ticks
        listener = self.clock_listener
        if listener is not None:
            # The tick's own time (reached during this step): /clock then runs on an exact
            # grid of its period whatever the control period, so a gait ticking on it
            # samples the same phases every cycle.
            listener(ticks * self.clock_period_s)

    def latest_snapshot(self) -> RobotSnapshot | None:
        """The latest stored snapshot (any thread), None before the first."""
        with self._snapshot_lock:
            return self._snapshot

    def stats(self) -> SimRobotStats:
        return SimRobotStats(sim_time_s=self._clock, busy_wall_s=self._busy_s, steps=self._steps)

    def tension_n(self, name: str) -> float:
        return self._tension_n[name]

    # -- the paced loop ------------------------------------------------------------
    def run(self, stop: threading.Event, time_factor: float = 1.0, failed=None) -> None:
        """Step paced to ``time_factor`` x the wall clock (0: unpaced) until `stop` is set.

        Behind its pace by more than ``_MAX_LAG_S`` (paused, starved, or a physics slower
        than the pace), the loop paces on from where it is: no burst to catch up.

        An exception in the physics ends the loop and is kept in :attr:`fault` (and
        reported through `failed(message)`), never a silently dead thread.
        """
        if not (math.isfinite(time_factor) and 0.0 <= time_factor <= 1000.0):
            raise SimRobotError(f'time_factor must be in [0, 1000] (0: as fast as possible), '
                                f'got {time_factor!r}')
        wall_start = time.monotonic()
        sim_start = self._clock
        try:
            self._maybe_snapshot()
            while not stop.is_set():
                if time_factor > 0:
                    ahead = (self._clock - sim_start) / time_factor - (time.monotonic() - wall_start)
                    if ahead > 0:
                        stop.wait(min(ahead, _MAX_SLEEP_S))
                        continue
                    if ahead < -_MAX_LAG_S:
                        wall_start, sim_start = time.monotonic(), self._clock
                self.step()
                self._maybe_snapshot()
                self._maybe_tick_clock()
        except Exception as exc:  # noqa: BLE001 - any physics failure is reported, then we stop
            self.fault = f'simulation stopped at t = {self._clock:.3f} s: {type(exc).__name__}: {exc}'
            if failed is not None:
                failed(self.fault)


def _vec(values) -> tuple[float, ...]:
    # A numpy array's tolist() makes the Python floats in C: a snapshot took 1.5 ms with
    # float() per element.
    tolist = getattr(values, 'tolist', None)
    if tolist is not None and getattr(values, 'dtype', None) is not None \
            and values.dtype.kind == 'f':
        return tuple(tolist())
    return tuple(float(v) for v in values)


class ScriptedCommands:
    """Commands a :class:`SimRobot` like its drivers would, from a contraction schedule.

    An ``on_step`` callback for :meth:`SimRobot.run_until`: every ``1 / rate_hz`` s of
    simulation time it sends each module the firmware ``set`` request for
    ``contraction_mm(t)`` (one value per module in scene order, mm of cable hauled in),
    converted to counts like the driver does (``round(contraction * counts_per_mm)``,
    PWM ``pwm``). Without sockets or ROS, so a run is exactly repeatable (benchmarks,
    determinism and locomotion tests).
    """

    def __init__(self, contraction_mm, rate_hz: float = 50.0, pwm: int = 200,
                 start_s: float = 0.0):
        if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= 1000.0):
            raise SimRobotError(f'rate_hz must be in (0, 1000] Hz, got {rate_hz!r}')
        self.contraction_mm = contraction_mm
        self.period_s = 1.0 / rate_hz
        self.pwm = int(pwm)
        self.start_s = float(start_s)
        self._next_s = self.start_s
        self.sent = 0

    def __call__(self, robot: SimRobot) -> None:
        now = robot.clock()
        if now + 1e-12 < self._next_s:
            return
        self._next_s += self.period_s
        contraction = self.contraction_mm(now - self.start_s)
        for name, value in zip(robot.module_names, contraction):
            count = int(round(float(value) * robot.counts_per_mm(name)))
            robot.request(name, encode_set_request(count, self.pwm))
            self.sent += 1


def build_simulation(scene, *, gravity: bool = True, payload=None,
                     links_per_segment: int = 0,
                     timestep_s: float | None = DEFAULT_PHYSICS_TIMESTEP_S) -> Any:
    """The MuJoCo model of `scene` (imports softsnap_model.physics, hence mujoco).

    `links_per_segment` 0 and `timestep_s` None take the physics model's defaults
    (``PhysicsParameters``); the default timestep is sim_robot's,
    :data:`DEFAULT_PHYSICS_TIMESTEP_S`. A scene the physics cannot model (or a payload it
    has no place for) raises SimRobotError with the physics' reason.
    """
    from softsnap_model.physics.parameters import PhysicsParameters
    from softsnap_model.physics.simulation import RobotSimulation
    kwargs = {'links_per_segment': links_per_segment} if links_per_segment else {}
    try:
        if timestep_s is not None:
            kwargs['parameters'] = PhysicsParameters(timestep_s=timestep_s)
        return RobotSimulation(scene, gravity=gravity, payload=payload, **kwargs)
    except ValueError as exc:
        raise SimRobotError(f'scene {scene.name!r}: {exc}') from None
