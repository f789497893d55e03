"""Physics of SoftSnap modules and robots on MuJoCo (gravity, loads, ground, dynamics).

:mod:`.mjcf` builds MJCF text from a :class:`~softsnap_model.Skeleton` or a scene
(it needs no ``mujoco``); :mod:`.simulation` loads it into MuJoCo and steps it
(``import softsnap_model.physics.simulation`` needs the ``mujoco`` package). Importing
this package does not import ``mujoco``, so the quasi-static core stays usable without it.

Units: the MJCF and every simulation interface are SI (m, kg, s, N, rad); the
quasi-static core's millimetres appear only in names ending in ``_mm``.
"""
from .mjcf import RobotLayout, module_mjcf
from .parameters import DEFAULT_LINKS_PER_SEGMENT, Payload, PhysicsParameters
from .robot_mjcf import robot_mjcf, robot_mjcf_layout
from .rib_contact import hard_contact_parameters

__all__ = ['DEFAULT_LINKS_PER_SEGMENT', 'PhysicsParameters', 'Payload', 'RobotLayout',
           'module_mjcf', 'robot_mjcf', 'robot_mjcf_layout', 'hard_contact_parameters']
