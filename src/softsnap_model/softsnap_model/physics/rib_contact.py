"""Rib contact in the MuJoCo model: how hard the hinge limits are (no ``mujoco`` import).

Two ribs touch when their segment reaches ``Skeleton.contact_angle_rad``; the model
stops the segment there with a joint limit on its first hinge (the coupling equalities
keep the segment's other hinges equal to it; a limit on every hinge as well would be
redundant with them and fight them).

``'hard'`` (issue 32, opt-in: :func:`hard_contact_parameters`): the limit has its own solver reference, in the same
dimensionless form as the cable's (``k dt^2``, ``b dt``): a deadbeat reference
(``k dt^2 = 0.25``, ``b dt = 1``, critical damping) at impedance 0.99. Together with a
hinge armature of 1e-5 kg m^2 (:class:`~softsnap_model.physics.mjcf.PhysicsParameters`)
a single module settles at the quasi-static shape up to 95 % of its reachable
contraction (benchmarks/rib_contact_bench.py, docs/physics.md "Rib contact"). The
lighter armature of before (3e-8) with these references chatters at full contraction:
the 10 mg links' local modes are then faster than the 2 ms step can follow once the
cable pulls ~10 N against a limit.

``'soft'`` (the default): MuJoCo's default limit (time constant 0.02 s) on every hinge.
It lets a 5-10 N cable push segments 0.1-0.2 rad past contact. It stays the default
because the hard set changes the robots' dynamics: the brittle star's walk and the
ring's transport travel 1-4 mm instead of > 5 mm per test run with it (test_sim_robot),
which needs its own study before the gaits move to it.
:func:`legacy_parameters` gives the default set explicitly for side-by-side runs.
"""
from __future__ import annotations

from dataclasses import replace

__all__ = ['RIB_CONTACT_MODES', 'hinge_armature_kgm2', 'hinge_limit_attributes',
           'hard_contact_parameters', 'legacy_parameters',
           'quasi_static_parameters']

#: Accepted values of ``PhysicsParameters.rib_contact``.
RIB_CONTACT_MODES = ('hard', 'soft')


def _f(*values) -> str:
    return ' '.join(f'{float(v):.10g}' for v in values)


def hinge_limit_attributes(params, limit_rad: float, hinge_index: int, coupled: bool) -> dict:
    """MJCF attributes of one hinge's rib-contact limit (``range``, ``solreflimit``, ...).

    ``limit_rad`` is the hinge's share of the contact angle (``a_c / N``);
    ``hinge_index`` its place in the segment (0 first); ``coupled``: the segment's hinges
    are held equal by equalities.
    """
    if params.rib_contact == 'soft':
        return {'range': _f(-limit_rad, limit_rad)}
    if coupled and hinge_index > 0:
        return {}                       # held equal to hinge 0, which carries the limit
    dt = params.timestep_s
    imp = params.rib_contact_impedance
    return {'range': _f(-limit_rad, limit_rad),
            'solreflimit': _f(-params.rib_contact_stiffness_dt2 / dt ** 2,
                              -params.rib_contact_damping_dt / dt),
            'solimplimit': _f(imp, imp, 0.001, 0.5, 2.0)}


#: Step (s) and links per segment at which ``PhysicsParameters.hinge_armature_kgm2`` is
#: given when ``scale_armature`` is on.
ARMATURE_REFERENCE_STEP_S = 0.002
ARMATURE_REFERENCE_LINKS = 2


def hinge_armature_kgm2(params, n_links: int) -> float:
    """Armature of each hinge (kg m^2).

    With ``params.scale_armature`` (default) the table's value holds at the 2 ms step and
    2 links per segment and scales with ``N / 2`` (each hinge's stiffness grows with N)
    and ``(dt / 2 ms)^2`` (a local mode ``sqrt(k / I)`` stays as many steps long):
    measured, 1e-5 settles N = 2 at 2 ms, 2e-5 N = 4, 1.5e-5 N = 3, 2.25e-5 N = 2 at 3 ms,
    where the unscaled 1e-5 chattered (N = 4 at 30 %, 3 ms at 95 % of the reach).
    """
    a = params.hinge_armature_kgm2
    if not params.scale_armature:
        return a
    return a * (n_links / ARMATURE_REFERENCE_LINKS) \
        * (params.timestep_s / ARMATURE_REFERENCE_STEP_S) ** 2


def hard_contact_parameters(params=None, **overrides):
    """Hard rib contact (issue 32): hard limits on each segment's first hinge, deadbeat
    cable and couplings (``k dt^2 = 0.25``, ``b dt = 1``), hinge armature 1e-5 kg m^2
    scaled with the step and N. A single module then settles within 0.5 mm of
    ``solve_forward`` up to 95 % of its reach (docs/physics.md, "Rib contact")."""
    from .parameters import PhysicsParameters
    base = PhysicsParameters() if params is None else params
    return replace(base, rib_contact='hard', hinge_armature_kgm2=1e-5, scale_armature=True,
                   constraint_stiffness_dt2=0.25, constraint_damping_dt=1.0, **overrides)


def legacy_parameters(params=None, **overrides):
    """The default (soft) set, explicitly: soft limits on every hinge, 3e-8 kg m^2
    armature, the cable's overdamped ``k dt^2 = 1``, ``b dt = 10``; for comparisons."""
    from .parameters import PhysicsParameters
    base = PhysicsParameters() if params is None else params
    return replace(base, rib_contact='soft', hinge_armature_kgm2=3e-8, scale_armature=False,
                   constraint_stiffness_dt2=1.0, constraint_damping_dt=10.0, **overrides)


def quasi_static_parameters(params=None, **overrides):
    """Parameters of the static comparisons: the defaults with a heavier hinge damping
    (the settled shape does not depend on damping; the first bending mode settles
    sooner)."""
    from .parameters import PhysicsParameters
    from .compare import QUASI_STATIC_DAMPING_TIME_S
    base = PhysicsParameters() if params is None else params
    return replace(base, damping_time_s=QUASI_STATIC_DAMPING_TIME_S, **overrides)
