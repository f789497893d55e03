"""MuJoCo simulation of a SoftSnap robot or module (needs the ``mujoco`` package).

:class:`RobotSimulation` compiles the MJCF of :mod:`softsnap_model.physics.mjcf` once
(``MjModel``), keeps the state in one ``MjData`` and advances it with a plain fixed-step
``mj_step`` loop, so the same calls give the same trajectory (determinism is tested).
Winches act through the cable tendons' length limits, changed at run time in
``model.tendon_range`` (no rebuild).

Units: metres, kilograms, seconds, newtons, radians throughout; quaternions are
(w, x, y, z) like MuJoCo's. Rib centres are in the module base frame (rib 0 at the
origin, straight spine along +x, bending about +z), poses in the world frame (z up,
ground at z = 0).

Examples
--------
>>> sim = RobotSimulation('brittle_star')
>>> sim.ramp_cable_length('yellow', sim.straight_cable_length('yellow') - 0.02, 0.05)
>>> steps = sim.step(0.5)                # 250 fixed steps of 2 ms
>>> bool(sim.cable_tension('yellow') > 0.5), sim.rib_centers('yellow').shape
(True, (12, 3))
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import mujoco
import numpy as np

from ..skeleton import Skeleton
from .mjcf import RobotLayout, module_mjcf_layout
from .parameters import DEFAULT_LINKS_PER_SEGMENT, Payload, PhysicsParameters
from .robot_mjcf import robot_mjcf_layout

__all__ = ['RobotSimulation', 'SettleResult', 'GROUND_CLEARANCE_M', 'SETTLE_SPEED_TOL',
           'SETTLE_HOLD_S']

#: Gap (m) left between a free robot's lowest point and the ground when it is placed.
GROUND_CLEARANCE_M = 2e-4
#: Default settling criterion: every joint speed below this (rad/s or m/s).
SETTLE_SPEED_TOL = 1e-3
#: Default settling hold: speeds must stay below the tolerance this long (s).
SETTLE_HOLD_S = 0.2
#: Longest cable length accepted, as a multiple of the straight length: beyond it is a
#: unit mistake (mm for m), not a slack cable.
MAX_CABLE_FACTOR = 2.0
# As an int: numpy compares an array with the enum object element by element in Python.
_LIMIT_TENDON = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON)


@dataclass(frozen=True)
class SettleResult:
    """Answer of :meth:`RobotSimulation.settle`.

    Attributes
    ----------
    settled : bool
        The largest joint speed fell below ``speed_tol`` before ``max_time_s``.
    time_s : float
        Simulated time spent settling (s).
    max_speed : float
        Largest joint speed at the end (rad/s for hinges, m/s or rad/s for free joints).
    """

    settled: bool
    time_s: float
    max_speed: float


def _finite(name, value, *, low=None, high=None, low_open=False) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) \
            or not math.isfinite(value):
        raise ValueError(f'{name} must be a finite number, got {value!r}')
    value = float(value)
    if low is not None and (value < low or (low_open and value <= low)):
        raise ValueError(f'{name} must be {">" if low_open else ">="} {low}'
                         + (f' and <= {high}' if high is not None else '')
                         + f', got {value!r}')
    if high is not None and value > high:
        raise ValueError(f'{name} must be <= {high}, got {value!r}')
    return value


class RobotSimulation:
    """A robot of a scene (or one clamped module) simulated in MuJoCo.

    Parameters
    ----------
    scene : Scene or str
        Scene object or name (``'brittle_star'``, ``'snake'``, ...).
    links_per_segment : int
        ``N`` links per segment (see :mod:`softsnap_model.physics.mjcf`).
    parameters : PhysicsParameters, optional
        Masses, stiffness, damping, friction, timestep.
    gravity, ground : bool
        Gravity along world -z; the ground plane z = 0.
    payload : Payload, optional
        Object for the gripper or ring.
    base : str
        ``'auto'``, ``'free'`` or ``'fixed'`` (see :func:`robot_mjcf_layout`).
    coupled : bool
        Constant curvature per segment.
    chain : str
        ``'weld'`` or ``'tree'``: how chained modules are joined (see
        :func:`~softsnap_model.physics.mjcf.robot_mjcf_layout`).
    bending_stiffness_nmm : float, optional
        ``K`` (N mm/rad^2) of every segment, overriding ``parameters``.

    A free robot is lowered onto the ground (lowest point ``GROUND_CLEARANCE_M`` above
    it) at time 0; call :meth:`settle` to let it come to rest.
    """

    def __init__(self, scene, *, links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
                 parameters: PhysicsParameters | None = None, gravity: bool = True,
                 ground: bool = True, payload: Payload | None = None, base: str = 'auto',
                 coupled: bool = True, chain: str = 'weld',
                 bending_stiffness_nmm: float | None = None):
        xml, layout = robot_mjcf_layout(scene, links_per_segment=links_per_segment,
                                        parameters=parameters, gravity=gravity,
                                        ground=ground, payload=payload, base=base,
                                        coupled=coupled, chain=chain,
                                        bending_stiffness_nmm=bending_stiffness_nmm)
        self._init(xml, layout, place_on_ground=ground and layout.free_base)

    @classmethod
    def single_module(cls, threading, skeleton: Skeleton | None = None, *,
                      links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
                      parameters: PhysicsParameters | None = None, gravity: bool = False,
                      ground: bool = False, base_position_m=(0.0, 0.0, 0.0),
                      base_orientation_wxyz=(1.0, 0.0, 0.0, 0.0), coupled: bool = True,
                      name: str = 'module', bending_stiffness_nmm: float | None = None
                      ) -> 'RobotSimulation':
        """One module clamped at its base (motor box fixed in the world).

        Gravity is off by default: the quasi-static model's setting. See
        :func:`softsnap_model.physics.mjcf.module_mjcf_layout` for the arguments.
        """
        xml, layout = module_mjcf_layout(
            skeleton, threading, links_per_segment=links_per_segment, parameters=parameters,
            gravity=gravity, ground=ground, base_position_m=base_position_m,
            base_orientation_wxyz=base_orientation_wxyz, coupled=coupled, name=name,
            bending_stiffness_nmm=bending_stiffness_nmm)
        sim = cls.__new__(cls)
        sim._init(xml, layout, place_on_ground=False)
        return sim

    # -- construction ------------------------------------------------------------------
    def _init(self, xml: str, layout: RobotLayout, place_on_ground: bool) -> None:
        self.xml = xml
        self.layout = layout
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        name2id = mujoco.mj_name2id
        body, tendon = mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_TENDON
        joint = mujoco.mjtObj.mjOBJ_JOINT
        self._modules = {m.name: m for m in layout.modules}
        self._base_id = {m.name: name2id(self.model, body, m.base_body) for m in layout.modules}
        self._rib_ids = {m.name: np.array([name2id(self.model, body, b) for b in m.rib_bodies])
                         for m in layout.modules}
        self._tendon_id = {m.name: name2id(self.model, tendon, m.tendon)
                           for m in layout.modules}
        self._hinge_qpos = {m.name: np.array([[self.model.jnt_qposadr[name2id(self.model, joint, j)]
                                               for j in seg] for seg in m.hinge_joints])
                            for m in layout.modules}
        self._root_id = name2id(self.model, body, layout.root_body)
        #: Stacked ids of every module for module_states(), built on first use.
        self._stacked = None
        self._payload_id = (name2id(self.model, body, layout.payload_body)
                            if layout.payload_body else -1)
        self._hold_id = (mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_EQUALITY,
                                           layout.payload_hold)
                         if layout.payload_hold else -1)
        self._robot_geoms = self._collision_geoms_below(self._root_id)
        mujoco.mj_forward(self.model, self.data)
        if place_on_ground:
            self._place_on_ground()
        self._initial_qpos = self.data.qpos.copy()
        self._initial_range = self.model.tendon_range.copy()

    def _collision_geoms_below(self, root_body: int) -> np.ndarray:
        """Collision geoms of the robot: every non-world body except the payload."""
        m = self.model
        ids = [g for g in range(m.ngeom)
               if m.geom_bodyid[g] > 0 and m.geom_bodyid[g] != self._payload_id
               and (m.geom_contype[g] or m.geom_conaffinity[g])]
        return np.array(ids, dtype=int)

    def _lowest_point_z(self) -> float:
        """Lowest world z (m) over the robot's collision geoms (boxes, cylinders, capsules,
        meshes, spheres; anything else by its bounding sphere)."""
        m, d = self.model, self.data
        low = math.inf
        for g in self._robot_geoms:
            size = m.geom_size[g]
            r = d.geom_xmat[g].reshape(3, 3)
            kind = m.geom_type[g]
            if kind == mujoco.mjtGeom.mjGEOM_BOX:
                ext = float(np.abs(r[2]) @ size)
            elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
                az = abs(r[2, 2])
                ext = az * size[1] + size[0] * math.sqrt(max(0.0, 1.0 - az * az))
            elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                ext = abs(r[2, 2]) * size[1] + size[0]
            elif kind == mujoco.mjtGeom.mjGEOM_MESH:
                # The hub's prism: its lowest vertex (mesh frame = geom frame).
                mesh = m.geom_dataid[g]
                start, count = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
                ext = -float(np.min(m.mesh_vert[start:start + count] @ r[2]))
            else:
                ext = float(m.geom_rbound[g])
            low = min(low, float(d.geom_xpos[g][2]) - ext)
        return low

    def _place_on_ground(self) -> None:
        # Every free body (the robot's root, chained modules, the payload) moves up
        # together, so welds and the payload's place in the robot are kept.
        shift = GROUND_CLEARANCE_M - self._lowest_point_z()
        m = self.model
        for j in range(m.njnt):
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                self.data.qpos[m.jnt_qposadr[j] + 2] += shift
        mujoco.mj_forward(self.model, self.data)

    # -- queries -------------------------------------------------------------------------
    @property
    def module_names(self) -> tuple:
        """Module names in scene order."""
        return tuple(self._modules)

    @property
    def time_s(self) -> float:
        """Simulated time (s) since construction or :meth:`reset`."""
        return float(self.data.time)

    @property
    def timestep_s(self) -> float:
        """Fixed integration step (s)."""
        return float(self.model.opt.timestep)

    def _module(self, module: str):
        try:
            return self._modules[module]
        except (KeyError, TypeError):
            raise ValueError(f'no module {module!r}; modules are '
                             f'{", ".join(self._modules)}') from None

    def straight_cable_length(self, module: str) -> float:
        """Cable length (m) through the holes of the straight module."""
        return self._module(module).straight_length_m

    def cable_length(self, module: str) -> float:
        """Cable length (m) the winch currently allows (the tendon's upper limit)."""
        self._module(module)
        return float(self.model.tendon_range[self._tendon_id[module], 1])

    def cable_path_length(self, module: str) -> float:
        """Hole-to-hole length (m) of the cable's path in the current shape."""
        self._module(module)
        return float(self.data.ten_length[self._tendon_id[module]])

    def set_cable_length(self, module: str, length_m: float) -> None:
        """Set the winch's cable length (m) for a module.

        The cable only pulls: when the path through the holes is shorter than
        ``length_m`` the cable is slack and exerts no force. A length below the
        module's reachable range leaves it at rib contact with a high tension.

        Raises
        ------
        ValueError
            Unknown module, or a length not in ``(0, 2 x straight length]`` m.
        """
        lay = self._module(module)
        length = _finite('length_m', length_m, low=0.0, low_open=True,
                         high=MAX_CABLE_FACTOR * lay.straight_length_m)
        self.model.tendon_range[self._tendon_id[module], 1] = length

    def cable_tension(self, module: str) -> float:
        """Cable tension (N) in the last step, >= 0; 0 when the cable is slack."""
        self._module(module)
        d = self.data
        n = d.nefc
        if n == 0:
            return 0.0
        # int(): numpy compares an array with the enum object element by element in
        # Python (2.4 ms per call at ~850 constraints); with the int it is 20 us.
        rows = (d.efc_type[:n] == int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON)) \
            & (d.efc_id[:n] == self._tendon_id[module])
        return float(max(0.0, np.sum(d.efc_force[:n][rows])))

    def cable_tensions(self) -> dict:
        """Cable tension (N) of every module in the last step, >= 0, in one pass over the
        constraint rows (what :meth:`cable_tension` gives module by module)."""
        d = self.data
        # MuJoCo orders the rows equality, friction, limits, contacts: only the few limit
        # rows (hinge and tendon limits) need a look, not the hundreds of contact rows.
        # A handful of rows: plain lists beat numpy masks here (sim_robot reads this every
        # 6 ms while a winch turns).
        start = d.ne + d.nf
        stop = start + d.nl
        force = dict.fromkeys(self._tendon_id.values(), 0.0)
        for kind, tid, value in zip(d.efc_type[start:stop].tolist(),
                                    d.efc_id[start:stop].tolist(),
                                    d.efc_force[start:stop].tolist()):
            if kind == _LIMIT_TENDON:
                force[tid] = force.get(tid, 0.0) + value
        return {name: max(0.0, force[tid]) for name, tid in self._tendon_id.items()}

    def rib_centers(self, module: str) -> np.ndarray:
        """Rib centres (m), shape (n_ribs, 3), in the module base frame (rib 0 at 0)."""
        self._module(module)
        d = self.data
        b = self._base_id[module]
        rot = d.xmat[b].reshape(3, 3)
        return (d.xpos[self._rib_ids[module]] - d.xpos[b]) @ rot

    def rib_centers_world(self, module: str) -> np.ndarray:
        """Rib centres (m), shape (n_ribs, 3), in the world frame."""
        self._module(module)
        return self.data.xpos[self._rib_ids[module]].copy()

    def rib_centroid_world(self) -> np.ndarray:
        """The mean of every module's rib centres (m, (3,), world): where a robot such as
        the ring is, as opposed to :meth:`robot_base_pose`, whose frame sits on one
        module's base and turns as that module bends."""
        return np.mean([self.rib_centers_world(m) for m in self.module_names], axis=(0, 1))

    def segment_angles(self, module: str) -> np.ndarray:
        """Bending angle of each segment (rad, counter-clockwise about the module's z):
        the sum of its hinges' angles."""
        self._module(module)
        return self.data.qpos[self._hinge_qpos[module]].sum(axis=1)

    def module_states(self) -> tuple:
        """Every module at once, in :attr:`module_names` order (what :meth:`rib_centers`,
        :meth:`segment_angles` and :meth:`module_base_pose` give one by one, in one
        vectorised pass: sim_robot samples it 30 times a simulated second).

        Returns (rib centres in each module base frame, m, shape (n, n_ribs, 3); segment
        angles, rad, (n, n_segments); base positions in the world, m, (n, 3); base
        quaternions w, x, y, z, (n, 4)), fresh arrays.
        """
        if self._stacked is None:
            names = tuple(self._modules)
            self._stacked = (np.array([self._base_id[n] for n in names]),
                             np.stack([self._rib_ids[n] for n in names]),
                             np.stack([self._hinge_qpos[n] for n in names]))
        base, ribs, hinges = self._stacked
        d = self.data
        base_pos = d.xpos[base]
        rot = d.xmat[base].reshape(-1, 3, 3)
        centers = np.matmul(d.xpos[ribs] - base_pos[:, None, :], rot)
        return centers, d.qpos[hinges].sum(axis=2), base_pos, d.xquat[base]

    def module_base_pose(self, module: str) -> tuple:
        """Pose of the module base frame (rib 0) in the world: (position m (3,),
        quaternion w, x, y, z (4,))."""
        self._module(module)
        b = self._base_id[module]
        return self.data.xpos[b].copy(), self.data.xquat[b].copy()

    def robot_base_pose(self) -> tuple:
        """Pose of the robot frame in the world: (position m, quaternion w, x, y, z)."""
        b = self._root_id
        return self.data.xpos[b].copy(), self.data.xquat[b].copy()

    def payload_pose(self) -> tuple:
        """Pose of the payload in the world (position m, quaternion w, x, y, z)."""
        if self._payload_id < 0:
            raise ValueError('this simulation has no payload')
        b = self._payload_id
        return self.data.xpos[b].copy(), self.data.xquat[b].copy()

    @property
    def payload_held(self) -> bool:
        """True while the helper weld still holds the payload (see :meth:`release_payload`)."""
        return self._hold_id >= 0 and bool(self.data.eq_active[self._hold_id])

    def release_payload(self) -> None:
        """Let go of a payload placed between a fixed robot's fingers (it may fall)."""
        if self._hold_id >= 0:
            self.data.eq_active[self._hold_id] = 0

    # -- stepping ------------------------------------------------------------------------
    def step(self, duration_s: float) -> int:
        """Advance by ``duration_s`` (s), rounded to whole fixed timesteps.

        Returns the number of steps taken.
        """
        duration = _finite('duration_s', duration_s, low=0.0, high=1e6)
        n = int(round(duration / self.model.opt.timestep))
        if n > 0:
            mujoco.mj_step(self.model, self.data, nstep=n)
        return n

    def max_speed(self) -> float:
        """Largest joint speed (rad/s or m/s) over all degrees of freedom."""
        return float(np.max(np.abs(self.data.qvel), initial=0.0))

    def settle(self, max_time_s: float = 10.0, speed_tol: float = SETTLE_SPEED_TOL,
               hold_s: float = SETTLE_HOLD_S, check_s: float = 0.01) -> SettleResult:
        """Step until every joint speed stays below ``speed_tol`` for ``hold_s`` seconds
        (checked every ``check_s``), or ``max_time_s`` of simulated time passes.

        The hold keeps a slow swing from passing as rest at its turning point, where
        every speed is near zero at once.
        """
        max_time = _finite('max_time_s', max_time_s, low=0.0, high=1e5)
        tol = _finite('speed_tol', speed_tol, low=0.0, low_open=True)
        hold = _finite('hold_s', hold_s, low=0.0)
        check = _finite('check_s', check_s, low=self.model.opt.timestep, high=1.0)
        start = self.data.time
        calm_since = None
        while True:
            speed = self.max_speed()
            now = self.data.time
            if speed < tol:
                calm_since = now if calm_since is None else calm_since
                if now - calm_since >= hold - 0.5 * self.model.opt.timestep:
                    return SettleResult(True, float(now - start), speed)
            else:
                calm_since = None
            if now - start >= max_time - 0.5 * self.model.opt.timestep:
                return SettleResult(False, float(now - start), speed)
            self.step(min(check, max_time - (now - start)))

    def ramp_cable_length(self, module: str, length_m: float, speed_m_s: float) -> None:
        """Move a winch to ``length_m`` at ``speed_m_s`` (m/s), stepping the simulation
        meanwhile (other winches hold their lengths)."""
        target = _finite('length_m', length_m, low=0.0, low_open=True,
                         high=MAX_CABLE_FACTOR * self._module(module).straight_length_m)
        speed = _finite('speed_m_s', speed_m_s, low=0.0, low_open=True, high=100.0)
        start = min(self.cable_length(module), max(self.cable_path_length(module), target))
        dt = self.model.opt.timestep
        n = max(1, int(math.ceil(abs(target - start) / (speed * dt))))
        for i in range(1, n + 1):
            self.set_cable_length(module, start + (target - start) * i / n)
            mujoco.mj_step(self.model, self.data)

    def reset(self) -> None:
        """Back to the state at construction (time 0, cables as built)."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = self._initial_qpos
        self.model.tendon_range[:] = self._initial_range
        mujoco.mj_forward(self.model, self.data)
