"""A MuJoCo module as a ROS plant for closed-loop benchmarks and tests (in-process node).

One clamped module of a scene (MuJoCo, softsnap_model.physics) with physical parameters
the controller's model does not know (bending stiffness, a mass at the tip), stepped in
real time. It takes cable-length commands on ``<module>/cable_length/command``
(softsnap_interfaces/CableLength, m) through a winch that moves the cable at most
``winch_speed_m_s``, and publishes its rib centres as softsnap_interfaces/MeasuredShape
(source "simulator") on ``<module>/shape/ground_truth`` every ``period_s``, each
``latency_s`` after it was observed (stamped with the observation time) with normal
noise of ``noise_m`` per coordinate. The noise-free tip is kept for the benchmark's
error (:attr:`tip_history`).

With ``camera_rate_hz`` > 0 it also films the module from its marked side
(softsnap_driver's simulated camera, ``view='module'``: the paper's camera, perpendicular
to the bending plane) and publishes ``camera/image_raw`` and ``camera/camera_info`` at
that rate, stamped with the ROS time of the instant shown, for the marker tracker: the
measurement then comes through real images and real OpenCV.

It stands in for sim_robot's ground-truth publisher (softsnap_driver.sim_robot): it
skips the drivers, the firmware's 30-count deadband and the HTTP link, so it measures
the control law on the physics, not the whole driver chain.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque

import numpy as np

#: Wall time per physics tick (s): the simulation is advanced by the elapsed wall time.
TICK_S = 0.005
#: Largest simulated step per tick (s; MuJoCo still integrates it in its fixed 2 ms
#: steps): a process starved for longer falls behind the wall clock instead.
MAX_STEP_S = 0.1


def _wxyz(xyzw):
    x, y, z, w = xyzw
    return (w, x, y, z)


def build_module_simulation(scene, module_name: str, *, bending_stiffness_nmm=None,
                            tip_mass_kg: float = 0.0):
    """The clamped module under gravity, posed as in the scene (gravity along world -z)."""
    from softsnap_model.loads import DEFAULT_END_RIB_MASS_KG
    from softsnap_model.physics.parameters import PhysicsParameters
    from softsnap_model.physics.simulation import RobotSimulation
    module = scene.module(module_name)
    params = PhysicsParameters(end_rib_mass_kg=DEFAULT_END_RIB_MASS_KG + tip_mass_kg) \
        if tip_mass_kg else None
    return RobotSimulation.single_module(
        module.holes, scene.skeleton, gravity=True, parameters=params,
        bending_stiffness_nmm=bending_stiffness_nmm,
        base_orientation_wxyz=_wxyz(module.base_orientation_xyzw))


def settled_tip_m(scene, module_name: str, cable_length_m: float, **physics) -> np.ndarray:
    """Where the physics module's tip rests at a cable length (m, module frame): a
    reachable target for it. The mean over 1 s after 3 s: a heavy tip load keeps the
    finger swinging by up to ~1 mm (closed_loop_run)."""
    sim = build_module_simulation(scene, module_name, **physics)
    sim.ramp_cable_length('module', cable_length_m, 0.05)
    sim.step(3.0)
    tips = []
    for _ in range(100):
        sim.step(0.01)
        tips.append(sim.rib_centers('module')[-1, :2].copy())
    return np.mean(tips, axis=0)


class MujocoModulePlant:
    """The plant node and its physics thread; :meth:`close` stops both."""

    def __init__(self, node, scene, module_name: str, *, bending_stiffness_nmm=None,
                 tip_mass_kg: float = 0.0, latency_s: float = 0.0, noise_m: float = 0.0,
                 period_s: float = 0.05, winch_speed_m_s: float = 0.069, seed: int = 0,
                 initial_length_m: float | None = None, camera_rate_hz: float = 0.0,
                 camera_size_px: tuple[int, int] = (640, 480), camera_tag_id: int = 0):
        from softsnap_interfaces.msg import CableLength, MeasuredShape
        self._MeasuredShape = MeasuredShape
        self.node = node
        self.module = module_name
        self.sim = build_module_simulation(scene, module_name,
                                           bending_stiffness_nmm=bending_stiffness_nmm,
                                           tip_mass_kg=tip_mass_kg)
        straight = self.sim.straight_cable_length('module')
        self.length_m = straight if initial_length_m is None else initial_length_m
        self.sim.set_cable_length('module', self.length_m)
        self.commanded_m = self.length_m
        self.latency_s, self.noise_m, self.period_s = latency_s, noise_m, period_s
        self.winch_speed_m_s = winch_speed_m_s
        self.rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        self.pending: deque = deque()
        #: (wall time s, noise-free tip (2,) m, cable length m), every observation.
        self.tip_history: list = []
        self.commands = 0
        node.create_subscription(CableLength, f'{module_name}/cable_length/command',
                                 self._command, 50)
        self.publisher = node.create_publisher(MeasuredShape,
                                               f'{module_name}/shape/ground_truth', 20)
        self.camera = None
        if camera_rate_hz > 0.0:
            from softsnap_driver.sim_camera import CameraSettings, MarkerLayout
            from softsnap_driver.sim_camera_publisher import CameraPublisher
            # Frames are stamped with the ROS time of the instant they show (the
            # simulation's own clock starts at zero), as the ground truth is.
            self.camera = CameraPublisher(
                node, self.sim, CameraSettings(width_px=camera_size_px[0],
                                               height_px=camera_size_px[1], view='module'),
                MarkerLayout(tags={'module': int(camera_tag_id)}), camera_rate_hz,
                frame_id=f'{module_name}_camera',
                capture_stamp_ns=lambda: node.get_clock().now().nanoseconds)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _command(self, msg) -> None:
        if math.isfinite(msg.cable_length) and msg.cable_length > 0.0:
            with self.lock:
                self.commanded_m = min(msg.cable_length,
                                       self.sim.straight_cable_length('module'))
                self.commands += 1

    def _run(self) -> None:
        last = time.monotonic()
        next_sample = last
        while not self._stop.is_set():
            time.sleep(TICK_S)
            now = time.monotonic()
            dt = min(now - last, MAX_STEP_S)
            last = now
            with self.lock:
                wanted = self.commanded_m
            step = self.winch_speed_m_s * dt
            self.length_m = min(max(wanted, self.length_m - step), self.length_m + step)
            self.sim.set_cable_length('module', self.length_m)
            self.sim.step(dt)
            if self.camera is not None:
                self.camera.on_tick(self.sim.time_s)
            if now >= next_sample:
                next_sample = now + self.period_s
                ribs = self.sim.rib_centers('module')[:, :2].copy()
                with self.lock:
                    self.tip_history.append((now, ribs[-1].copy(), self.length_m))
                stamp = self.node.get_clock().now()
                noisy = ribs + self.rng.normal(0.0, self.noise_m, ribs.shape) \
                    if self.noise_m else ribs
                self.pending.append((now + self.latency_s, stamp, noisy))
            while self.pending and self.pending[0][0] <= now:
                _, stamp, ribs = self.pending.popleft()
                self._publish(stamp, ribs)

    def _publish(self, stamp, ribs) -> None:
        from geometry_msgs.msg import Point
        msg = self._MeasuredShape()
        msg.header.stamp = stamp.to_msg()
        msg.header.frame_id = self.module
        msg.module, msg.source = self.module, 'simulator'
        msg.rib_centers = [Point(x=float(x), y=float(y), z=0.0) for x, y in ribs]
        msg.visible = [True] * len(ribs)
        msg.residual = 0.0
        msg.cable_length = float(self.length_m)
        msg.rmse_to_model = math.nan
        self.publisher.publish(msg)

    def history(self) -> list:
        with self.lock:
            return list(self.tip_history)

    def camera_plane_distance_m(self) -> float:
        """The camera's distance to the marker plane, m (the tracker's ``plane_distance``;
        the module bends in that plane)."""
        return self.camera.marker_distance_m

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        if self.camera is not None:
            self.camera.stop()
