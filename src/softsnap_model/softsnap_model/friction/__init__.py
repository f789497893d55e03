"""Cable friction at the holes (capstan effect, stick/slip, hysteresis), pure numpy.

Model
-----
The cable is tied at the last rib's hole and passes through the holes of ribs
``n-1 ... 0`` to the winch. Segment ``i`` runs from the hole of rib ``i`` to the hole
of rib ``i+1`` and carries its own tension ``T_i`` (rad^2/mm, the same unit as
``ForwardResult.tension``; multiply by the bending stiffness K for newtons). Only
segment ``i``'s length depends on ``a_i`` and every segment pulls its two ribs with
equal and opposite forces, so by virtual work each segment is in equilibrium on its
own, exactly as without friction::

    2 k_i a_i + T_i dL_i/da_i(a_i) = 0          (on the branch softsnap_model.forward follows)

At a hole ``k`` the cable turns by the wrap angle ``theta_k`` (the angle between the
incoming and outgoing cable directions, from the exact straight-line path between the
holes). Capstan law: where the cable slips through hole ``k``::

    pulled   (moving towards the winch):  T_k = T_{k-1} exp(-mu_k theta_k)
    released (moving towards the tip):    T_k = T_{k-1} exp(+mu_k theta_k)

and where it sticks, the cable length from hole ``k`` to the tip, ``S_k = sum_{j>=k}
L_j``, keeps its value while ``T_k / T_{k-1}`` stays inside
``[exp(-mu_k theta_k), exp(+mu_k theta_k)]``. ``T_{-1}`` is the winch tension.

The winch side of the base hole: the cable arrives at rib 0's hole parallel to the spine,
travelling along +x of the base frame (from the motor box behind rib 0 towards the tip),
so ``theta_0`` is the angle of segment 0 to the spine's base direction. Since the winch
tension is free (it is whatever the length constraint needs), ``theta_0`` and ``mu_0``
change only the reported winch tension, never the shape.

*Pull branch* (:func:`solve_friction` with ``direction='pull'``): every hole slips
towards the winch, ``T_i = T_w exp(-Theta_i)``, ``Theta_i = sum_{k<=i} mu_k theta_k``:
the shape reached by shortening the cable slowly from straight. *Release branch*
(``'release'``): every hole slips towards the tip, ``T_i = T_w exp(+Theta_i)``: the
shape reached after releasing long enough for the slip to reach the tip.
:func:`friction_sweep` follows any sequence of lengths with the per-hole stick/slip
rule above, so after a reversal the cable sticks in the holes and the slip front moves
from the winch towards the tip: the base segment relaxes first, and the path moves from
one branch to the other continuously (the hysteresis loop).

With every ``mu_k = 0`` all tensions are equal and the model is the frictionless one of
:mod:`.forward` (the same shape to rounding).

Typical friction coefficient: a PE (or nylon) braided line in printed TPU holes,
``mu`` about 0.1-0.3 (:data:`TYPICAL_FRICTION_RANGE`); an estimate from the literature
values of polymer-on-polymer sliding, not measured on the modules: calibrate it
(:mod:`.calibration`).

Left out: friction along the cable between holes (it touches only the holes), the
rib thickness of the hole (a hole is a point on the rib), cable stretch, and dynamic
(velocity-dependent) friction; Coulomb friction with one coefficient for stick and slip.

Solver and accuracy contract
----------------------------
Unknowns: the angles ``a`` (n) and ``u = log T`` (n). Equations: segment equilibrium
(rad), the length constraint (mm), and per interior hole the slip relation
``u_k - u_{k-1} = +-mu_k theta_k`` or the stick relation ``S_k = S_k_prev`` (mm).
Newton with the analytic Jacobian (wrap-angle derivatives included), least-squares
steps where the system is singular (a segment held at contact between two stuck holes
has an undetermined tension: it keeps its previous value) and a backtracking line
search; started from the frictionless solution, with continuation in ``mu`` as the
fallback. Segments follow the branch rules of :mod:`.forward` (direction, mirror
buckling, rib contact): after Newton every angle is compared with
:func:`~softsnap_model.forward.segment_angle_at_tension` at its own tension and
segments are moved between free / held-at-contact / held-straight until they agree.

On ``converged``: ``|sum L_i - L| <= CONSTRAINT_TOL_MM`` (1e-9 mm);
``|a_i + T_i L_i'/(2 k_i)| <= STATIONARITY_TOL_RAD`` (1e-10 rad) on free segments and
held ones exactly at contact or straight; every angle within ``BRANCH_TOL_RAD`` (1e-6
rad) of :func:`~softsnap_model.forward.segment_angle_at_tension` at its own tension
(the branch check); slipping holes ``|u_k - u_{k-1} -+ mu_k theta_k| <= SLIP_TOL`` (1e-10);
stuck holes ``|S_k - S_k_prev| <= CONSTRAINT_TOL_MM`` and their tension ratio inside
the friction cone, and every slipping hole moves the way its friction assumes. Otherwise
``converged=False`` and ``message`` says which check failed; an answer is never returned
as converged without these checks.

Where each part lives: :mod:`.results` (contracts, branch directions, result types),
:mod:`.wrap` (the wrap angle of the cable at each hole), :mod:`.equations` (the
equilibrium and capstan equations, their Newton solve and the result assembly),
:mod:`.solve` (:func:`solve_friction`, :func:`friction_sweep`) and :mod:`.step`
(:func:`friction_step`, one quasi-static step from the previous state).
"""
from __future__ import annotations

from .results import (BRANCH_TOL_RAD, CONSTRAINT_TOL_MM, MAX_ITER, PULL, RELEASE, SLIP_TOL,
                      STATIONARITY_TOL_RAD, STICK, TYPICAL_FRICTION_RANGE, FrictionResult,
                      FrictionSweepResult)
from .solve import solve_friction
from .step import friction_step, friction_sweep
from .wrap import wrap_angles

__all__ = [
    'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD', 'SLIP_TOL', 'BRANCH_TOL_RAD', 'MAX_ITER',
    'TYPICAL_FRICTION_RANGE', 'PULL', 'RELEASE', 'STICK',
    'FrictionResult', 'FrictionSweepResult',
    'wrap_angles', 'solve_friction', 'friction_sweep', 'friction_step',
]
