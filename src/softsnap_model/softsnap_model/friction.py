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
"""
from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass

import numpy as np

from .forward import (InfeasibleLengthError, reachable_range, segment_angle_at_tension,
                      segment_branch, solve_forward)
from .geometry import half_angle_functions, rib_centers, cable_path, segment_length_derivatives
from .skeleton import Skeleton

__all__ = [
    'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD', 'SLIP_TOL', 'BRANCH_TOL_RAD', 'MAX_ITER',
    'TYPICAL_FRICTION_RANGE', 'PULL', 'RELEASE', 'STICK',
    'FrictionResult', 'FrictionSweepResult',
    'wrap_angles', 'solve_friction', 'friction_sweep', 'friction_step',
]

#: Length contract (mm): ``|sum L_i - L| <= CONSTRAINT_TOL_MM``; also stuck holes' ``S_k``.
CONSTRAINT_TOL_MM = 1e-9
#: Equilibrium contract (rad): every angle within this of its branch angle at its tension.
STATIONARITY_TOL_RAD = 1e-10
#: Slip contract (dimensionless): ``|log(T_k/T_{k-1}) -+ mu_k theta_k|`` on slipping holes.
SLIP_TOL = 1e-10
#: Branch check (rad): every angle within this of the followed branch's angle at its
#: tension (:func:`~softsnap_model.forward.segment_angle_at_tension`).
BRANCH_TOL_RAD = 1e-6
#: Newton iterations per active set before the fallback.
MAX_ITER = 60
#: Estimated friction coefficient of a PE/nylon line in printed TPU holes (not measured).
TYPICAL_FRICTION_RANGE = (0.1, 0.3)

#: Hole modes: slipping towards the winch (pulled), towards the tip (released), stuck.
PULL, RELEASE, STICK = -1, 1, 0

# Internal targets, tighter than the contracts.
_TOL_RAD = 1e-13
_TOL_MM = 1e-12
_TOL_SLIP = 1e-13
# A stuck hole's tension ratio may leave its cone by this much (log units) before it slips.
_CONE_TOL = 1e-9
# A slipping hole may move against its friction by this much (mm) before it sticks.
_MOVE_TOL_MM = 1e-9


# ----------------------------------------------------------------------------------------
# Wrap angles
# ----------------------------------------------------------------------------------------
def _segment_direction(a, d1, d2, s):
    """Direction ``phi`` (rad) of each segment's chord in its proximal rib's frame, and
    ``dphi/da``. The chord runs from hole ``d1`` (at ``(0, -d1)``) to hole ``d2`` on the
    next rib."""
    u = 0.5 * a
    f0, f1, cos_u = half_angle_functions(u)
    sin_u = np.sin(u)
    sin_a, cos_a = np.sin(a), np.cos(a)
    px, py = s * f0 * cos_u, s * f0 * sin_u
    # d/da of s f0(u) (cos u, sin u) with f0'(u) = -u f1(u) (no cancellation at u = 0).
    df0 = -u * f1
    dpx = 0.5 * s * (df0 * cos_u - f0 * sin_u)
    dpy = 0.5 * s * (df0 * sin_u + f0 * cos_u)
    vx = px + d2 * sin_a
    vy = py - d2 * cos_a + d1
    dvx = dpx + d2 * cos_a
    dvy = dpy + d2 * sin_a
    phi = np.arctan2(vy, vx)
    dphi = (vx * dvy - vy * dvx) / (vx * vx + vy * vy)
    return phi, dphi


def _wraps(a, d1, d2, s):
    """Wrap angles ``theta`` (n,) at holes 0..n-1 and their derivatives: ``dth_self[k] =
    dtheta_k/da_k`` and ``dth_prev[k] = dtheta_k/da_{k-1}`` (0 for k = 0)."""
    phi, dphi = _segment_direction(a, d1, d2, s)
    psi = np.empty_like(phi)
    psi[0] = phi[0]                       # winch side: along +x of rib 0
    psi[1:] = phi[1:] - phi[:-1] + a[:-1]
    psi = np.arctan2(np.sin(psi), np.cos(psi))
    sign = np.where(psi >= 0.0, 1.0, -1.0)
    dth_self = sign * dphi
    dth_prev = np.zeros_like(phi)
    dth_prev[1:] = sign[1:] * (1.0 - dphi[:-1])
    return np.abs(psi), dth_self, dth_prev


def wrap_angles(skeleton: Skeleton, threading, angles_rad) -> np.ndarray:
    """Wrap angle (rad) of the cable at the holes of ribs ``0 .. n_ribs-2``.

    ``theta_k`` (k >= 1) is the angle between the cable direction arriving at rib k's
    hole and the direction leaving it towards rib k+1; ``theta_0`` is measured from the
    winch side, the base frame's +x (the spine's direction at rib 0). The tip hole is
    the anchor and has no wrap.

    Examples
    --------
    >>> sk = Skeleton()
    >>> t = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()
    >>> round(float(wrap_angles(sk, t, np.zeros(11)).sum()), 3)   # yellow, straight
    0.768
    """
    d = skeleton.threading_mm(threading)
    a = np.asarray(angles_rad, dtype=float)
    if a.shape != (skeleton.n_segments,):
        raise ValueError(f'expected {skeleton.n_segments} angles, got shape {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'angles must be finite, got {a.tolist()}')
    return _wraps(a, d[:-1], d[1:], skeleton.spacing_mm)[0]


# ----------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrictionResult:
    """Result of :func:`solve_friction` (and one step of :func:`friction_sweep`).

    Attributes
    ----------
    angles : ndarray (n_segments,)
        Bending angles (rad).
    rib_centers, cable_path : ndarray (n_ribs, 2)
        Rib centres and threaded hole positions (mm), base frame.
    segment_tensions : ndarray (n_segments,)
        Tension of each cable segment (rad^2/mm; times K for N); 0 when slack.
    winch_tension : float
        Tension on the winch side of the base hole (rad^2/mm).
    wrap_angles : ndarray (n_segments,)
        Wrap angle at the holes of ribs 0..n-2 (rad), :func:`wrap_angles`.
    total_wrap_rad : float
        ``sum wrap_angles``.
    tip_tension_ratio : float
        ``segment_tensions[-1] / winch_tension`` (1 without friction; nan when slack).
    hole_modes : ndarray of int (n_segments,)
        Per hole: ``PULL`` (-1), ``RELEASE`` (+1) or ``STICK`` (0); entry 0 is the winch
        motion.
    at_contact, held_straight : ndarray of bool (n_segments,)
        Segments held at rib contact, and mirror segments held straight.
    friction : ndarray (n_segments,)
        Friction coefficient per hole used.
    direction : str
        'pull', 'release' or 'hold'.
    converged : bool
        Every check of the accuracy contract passed (module docstring).
    constraint_residual : float
        ``|sum L_i - L|`` (mm).
    stationarity_residual : float
        ``max |a_i + T_i L_i'/(2 k_i)|`` over free segments, ``|a_i - a_branch|`` over
        held ones (rad).
    slip_residual : float
        Largest slip-relation residual (dimensionless), or stick-relation (mm) residual.
    iterations : int
        Newton iterations, all active sets together.
    slack : bool
        Length at or above the straight length: straight shape, no tension.
    cable_length_mm : float
    message : str
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    segment_tensions: np.ndarray
    winch_tension: float
    wrap_angles: np.ndarray
    total_wrap_rad: float
    tip_tension_ratio: float
    hole_modes: np.ndarray
    at_contact: np.ndarray
    held_straight: np.ndarray
    friction: np.ndarray
    direction: str
    converged: bool
    constraint_residual: float
    stationarity_residual: float
    slip_residual: float
    iterations: int
    slack: bool
    cable_length_mm: float
    message: str

    @property
    def success(self) -> bool:
        """Alias of ``converged`` (scipy naming)."""
        return self.converged


@dataclass(frozen=True)
class FrictionSweepResult:
    """Result of :func:`friction_sweep`: one :class:`FrictionResult` per length.

    Attributes
    ----------
    steps : tuple of FrictionResult
    cable_lengths_mm : ndarray (B,)
    angles : ndarray (B, n_segments)
    rib_centers : ndarray (B, n_ribs, 2)
    winch_tension : ndarray (B,)
    converged : bool
        Every step converged.
    """

    steps: tuple
    cable_lengths_mm: np.ndarray
    angles: np.ndarray
    rib_centers: np.ndarray
    winch_tension: np.ndarray
    converged: bool

    def __len__(self):
        return len(self.steps)


# ----------------------------------------------------------------------------------------
# Problem data and the Newton engine
# ----------------------------------------------------------------------------------------
class _Ctx:
    """Length-independent data of one (skeleton, threading, friction)."""

    def __init__(self, skeleton, d, mu):
        self.skeleton = skeleton
        self.d = d
        self.d1, self.d2 = d[:-1], d[1:]
        self.s = skeleton.spacing_mm
        self.k = skeleton.stiffness_array
        self.n = skeleton.n_segments
        self.mu = mu
        self.contact = skeleton.contact_angle_rad
        br = segment_branch(self.d1, self.d2, self.s, max_angle_rad=self.contact)
        self.direction = br.direction.astype(float)
        self.mirror = br.mirror
        self.end_angle = br.end_angle_rad
        self.end_tension = br.end_tension * self.k     # tension reaching contact
        self.buckling = br.buckling_tension * self.k    # mirror segments start bending
        self.lo, self.hi = reachable_range(skeleton, d)

    def branch_angles(self, T):
        return segment_angle_at_tension(T, self.d1, self.d2, self.s, self.k,
                                        max_angle_rad=self.contact)


def _friction_array(friction, n) -> np.ndarray:
    try:
        mu = np.asarray(friction, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'friction must be a number or {n} numbers, got {friction!r}') \
            from None
    if mu.ndim == 0:
        mu = np.full(n, float(mu))
    if mu.shape != (n,):
        raise ValueError(f'expected 1 or {n} friction coefficients (one per hole of ribs '
                         f'0..{n - 1}), got shape {mu.shape}')
    if not np.all(np.isfinite(mu)) or np.any(mu < 0) or np.any(mu > 2.0):
        raise ValueError(f'friction coefficients must be in [0, 2], got {mu.tolist()}')
    return mu


def _held_from_branch(ctx, A):
    contact = np.abs(A) >= ctx.end_angle * (1.0 - 1e-12)
    straight = ctx.mirror & (A == 0.0)
    return contact, straight


def _equations(ctx, x, L, modes, S_prev, contact, straight, fixed):
    """Residual vector F and Jacobian J of the 2n equations at ``x = [a, u]``."""
    n = ctx.n
    a, u = x[:n], x[n:]
    T = np.exp(u)
    length, lp, lpp = segment_length_derivatives(a, ctx.d1, ctx.d2, ctx.s)
    theta, dth_self, dth_prev = _wraps(a, ctx.d1, ctx.d2, ctx.s)
    F = np.empty(2 * n)
    J = np.zeros((2 * n, 2 * n))
    held = contact | straight
    free = ~held
    idx = np.arange(n)
    # Segment equilibrium (rad); held segments stay at their fixed angle.
    F[:n] = np.where(free, a + T * lp / (2.0 * ctx.k), a - fixed)
    J[idx, idx] = np.where(free, 1.0 + T * lpp / (2.0 * ctx.k), 1.0)
    J[idx, n + idx] = np.where(free, T * lp / (2.0 * ctx.k), 0.0)
    # Length constraint (mm).
    F[n] = length.sum() - L
    J[n, :n] = lp
    # Interior holes k = 1..n-1: slip relation (dimensionless) or stick relation (mm).
    S = np.cumsum(length[::-1])[::-1]        # S_k = sum_{j>=k} L_j
    m = np.asarray(modes[1:], dtype=float)
    kk = np.arange(1, n)
    stick = m == STICK
    slip_f = u[1:] - u[:-1] - m * ctx.mu[1:] * theta[1:]
    F[n + 1:] = np.where(stick, S[1:] - (S_prev[1:] if S_prev is not None else 0.0), slip_f)
    rows = n + kk
    sl = ~stick
    J[rows[sl], n + kk[sl]] = 1.0
    J[rows[sl], n + kk[sl] - 1] = -1.0
    J[rows[sl], kk[sl]] = -m[sl] * ctx.mu[kk[sl]] * dth_self[kk[sl]]
    J[rows[sl], kk[sl] - 1] = -m[sl] * ctx.mu[kk[sl]] * dth_prev[kk[sl]]
    if stick.any():
        upper = np.triu(np.ones((n, n)))[1:]          # row k-1: columns j >= k
        J[n + 1:, :n] += np.where(stick[:, None], upper * lp[None, :], 0.0)
    return F, J, dict(length=length, theta=theta, S=S)


def _newton(ctx, x, L, modes, S_prev, contact, straight, fixed, max_iter):
    """Damped Newton; returns (x, converged, iterations, F)."""
    F, J, _ = _equations(ctx, x, L, modes, S_prev, contact, straight, fixed)
    norm = float(np.max(np.abs(F)))
    it = 0
    for it in range(1, max_iter + 1):
        if _small(F, ctx.n, modes):
            return x, True, it - 1, F
        try:
            step = np.linalg.solve(J, -F)
            if not np.all(np.isfinite(step)):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(J, -F, rcond=1e-13)[0]
        # Keep angles inside (-pi, pi) and log-tensions finite: limit the step.
        scale = 1.0
        big = max(float(np.max(np.abs(step[:ctx.n]))) / 0.5,
                  float(np.max(np.abs(step[ctx.n:]))) / 3.0, 1.0)
        scale /= big
        accepted = False
        for _ in range(30):
            xt = x + scale * step
            with np.errstate(all='ignore'):
                Ft, Jt, _ = _equations(ctx, xt, L, modes, S_prev, contact, straight, fixed)
            nt = float(np.max(np.abs(Ft)))
            if np.isfinite(nt) and (nt < norm or nt <= 1e-14 or scale < 1e-8
                                    and nt <= 1.01 * norm):
                accepted = True
                break
            scale *= 0.5
        if not accepted:
            return x, False, it, F
        x, F, J, norm = xt, Ft, Jt, nt
    return x, _small(F, ctx.n, modes), max_iter, F


def _small(F, n, modes):
    stick = np.zeros(n, dtype=bool)
    stick[1:] = np.asarray(modes[1:]) == STICK
    return (np.max(np.abs(F[:n])) <= _TOL_RAD and abs(F[n]) <= _TOL_MM
            and np.all(np.abs(F[n + 1:][stick[1:]]) <= _TOL_MM)
            and np.all(np.abs(F[n + 1:][~stick[1:]]) <= _TOL_SLIP))


def _classify(ctx, T):
    """Held sets from the tensions alone: at contact from the contact tension on, mirror
    segments straight up to their buckling tension (the branch is monotone between)."""
    contact = T >= ctx.end_tension * (1.0 - 1e-12)
    straight = ctx.mirror & (T <= ctx.buckling) & ~contact
    return contact, straight


def _solve_active(ctx, x0, L, modes, S_prev, max_iter, open_contact=False):
    """Newton with the free/held sets updated until every angle is on its branch.

    ``open_contact``: start the segments at contact as free, just below their contact
    tension. A segment held at contact between stuck holes has an undetermined tension,
    and may open when the length grows: its tension then drops below the contact value.
    """
    n = ctx.n
    x = x0.copy()
    T = np.exp(x[n:])
    if open_contact:
        c0, _ = _classify(ctx, T)
        if c0.any():
            T = np.where(c0, np.minimum(T, ctx.end_tension * (1.0 - 1e-6)), T)
            x[n:] = np.log(T)
            x[:n] = np.where(c0, ctx.branch_angles(T), x[:n])
    contact, straight = _classify(ctx, T)
    total = 0
    seen = set()
    for _ in range(2 * n + 2):
        fixed = np.where(contact, ctx.direction * ctx.end_angle, 0.0)
        x[:n] = np.where(contact | straight, fixed, x[:n])
        x, ok, it, F = _newton(ctx, x, L, modes, S_prev, contact, straight, fixed, max_iter)
        total += it
        if not ok:
            return x, False, total, 'Newton did not reach the residual targets'
        T = np.exp(x[n:])
        c2, s2 = _classify(ctx, T)
        free = ~(c2 | s2)
        b = ctx.direction * x[:n]
        # A free segment must sit strictly inside its branch (right side, before
        # contact); the stationarity root there is unique, the branch being monotone.
        wrong = free & ~((b > 0.0) & (b < ctx.end_angle))
        if not wrong.any() and (c2 == contact).all() and (s2 == straight).all():
            return x, True, total, ''
        key = (tuple(c2), tuple(s2), tuple(wrong))
        if key in seen:
            break
        seen.add(key)
        # Restart the segments that changed set, or sit off their branch, on the branch.
        moved = wrong | (c2 != contact) | (s2 != straight)
        x[:n] = np.where(moved, ctx.branch_angles(T), x[:n])
        contact, straight = c2, s2
    return x, False, total, 'free/held segment sets did not settle'


# ----------------------------------------------------------------------------------------
# Public solvers
# ----------------------------------------------------------------------------------------
def _check_inputs(skeleton, threading, friction):
    if not isinstance(skeleton, Skeleton):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')
    d = skeleton.threading_mm(threading)
    mu = _friction_array(friction, skeleton.n_segments)
    return _context(skeleton, tuple(d.tolist()), tuple(mu.tolist()))


@functools.lru_cache(maxsize=256)
def _context(skeleton, d, mu):
    """Memoised (pure function of its arguments; the context is never mutated)."""
    return _Ctx(skeleton, np.array(d), np.array(mu))


def _as_length(value) -> float:
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating,
                                                         np.integer)):
        raise ValueError(f'cable_length_mm must be a real number (mm), got {value!r}')
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f'cable_length_mm must be finite and > 0, got {value!r}')
    return v


def _check_length(ctx, L):
    if L <= ctx.lo:
        raise InfeasibleLengthError(
            f'cable length {L!r} mm is below the reachable range ({ctx.lo:.6f}, '
            f'{ctx.hi:.6f}] mm (friction does not change the range: it is set by rib '
            f'contact)', (ctx.lo, ctx.hi))


def _slack_result(ctx, L, modes, direction):
    n = ctx.n
    a = np.zeros(n)
    theta = _wraps(a, ctx.d1, ctx.d2, ctx.s)[0]
    return FrictionResult(
        angles=a, rib_centers=rib_centers(a, ctx.s), cable_path=cable_path(a, ctx.d, ctx.s),
        segment_tensions=np.zeros(n), winch_tension=0.0, wrap_angles=theta,
        total_wrap_rad=float(theta.sum()), tip_tension_ratio=float('nan'),
        hole_modes=np.asarray(modes, dtype=int), at_contact=np.zeros(n, bool),
        held_straight=np.zeros(n, bool), friction=ctx.mu.copy(), direction=direction,
        converged=True, constraint_residual=0.0, stationarity_residual=0.0,
        slip_residual=0.0, iterations=0, slack=True, cable_length_mm=L,
        message='slack cable: length at or above the straight length, straight shape')


def _make_result(ctx, x, L, modes, S_prev, direction, ok, iterations, why):
    """Evaluate every contract check independently of the solver's own residuals."""
    n = ctx.n
    a, u = x[:n], x[n:]
    T = np.exp(u)
    length, lp, _ = segment_length_derivatives(a, ctx.d1, ctx.d2, ctx.s)
    theta = _wraps(a, ctx.d1, ctx.d2, ctx.s)[0]
    A = ctx.branch_angles(T)
    contact, straight = _held_from_branch(ctx, A)
    c_res = abs(float(length.sum()) - L)
    held = contact | straight
    # Stationarity as in softsnap_model.forward, ``|a + T L'/(2k)|`` on free segments (near a mirror
    # segment's buckling point ``a_branch(T)`` is infinitely steep, so ``|a - a_branch|``
    # would measure the tension's rounding); held segments must sit exactly at their
    # branch angle, and every free one on its branch (a loose check, for the branch).
    free_res = np.abs(a + T * lp / (2.0 * ctx.k))
    s_res = float(np.max(np.where(held, np.abs(a - A), free_res)))
    off_branch = float(np.max(np.abs(a - A)))
    S = np.cumsum(length[::-1])[::-1]
    slip_res, stick_res = 0.0, 0.0
    problems = []
    if not off_branch <= BRANCH_TOL_RAD:
        problems.append(f'angle {off_branch:.3g} rad off the followed branch')
    for kk in range(1, n):
        m = modes[kk]
        if m == STICK:
            stick_res = max(stick_res, abs(S[kk] - S_prev[kk]))
            ratio = u[kk] - u[kk - 1]
            if abs(ratio) > ctx.mu[kk] * theta[kk] + 1e3 * _CONE_TOL:
                problems.append(f'hole {kk} stuck outside its friction cone')
        else:
            slip_res = max(slip_res, abs(u[kk] - u[kk - 1] - m * ctx.mu[kk] * theta[kk]))
            if S_prev is not None and ctx.mu[kk] > 0:
                moved = S[kk] - S_prev[kk]
                if m * moved < -1e3 * _MOVE_TOL_MM:
                    problems.append(f'hole {kk} slips against its motion')
    if not math.isfinite(c_res) or c_res > CONSTRAINT_TOL_MM:
        problems.append(f'constraint residual {c_res:.3g} mm > {CONSTRAINT_TOL_MM:g}')
    if not math.isfinite(s_res) or s_res > STATIONARITY_TOL_RAD:
        problems.append(f'equilibrium residual {s_res:.3g} rad > {STATIONARITY_TOL_RAD:g}')
    if not slip_res <= SLIP_TOL:
        problems.append(f'slip residual {slip_res:.3g} > {SLIP_TOL:g}')
    if not stick_res <= CONSTRAINT_TOL_MM:
        problems.append(f'stick residual {stick_res:.3g} mm > {CONSTRAINT_TOL_MM:g}')
    if not np.all(np.isfinite(x)):
        problems.append('non-finite state')
    converged = bool(ok) and not problems
    if converged:
        message = 'converged'
    else:
        message = 'not converged: ' + '; '.join(([why] if why else []) + problems)
    m_w = modes[0] if modes[0] != STICK else PULL
    winch = float(T[0] * math.exp(-m_w * ctx.mu[0] * theta[0]))
    return FrictionResult(
        angles=a.copy(), rib_centers=rib_centers(a, ctx.s), cable_path=cable_path(a, ctx.d, ctx.s),
        segment_tensions=T.copy(), winch_tension=winch, wrap_angles=theta,
        total_wrap_rad=float(theta.sum()), tip_tension_ratio=float(T[-1] / winch),
        hole_modes=np.asarray(modes, dtype=int).copy(), at_contact=contact,
        held_straight=straight, friction=ctx.mu.copy(), direction=direction,
        converged=converged, constraint_residual=c_res, stationarity_residual=s_res,
        slip_residual=max(slip_res, stick_res), iterations=int(iterations), slack=False,
        cable_length_mm=L, message=message)


def _branch_solve(ctx, L, mode, max_iter):
    """All holes slipping one way: returns (x, ok, iterations, why)."""
    n = ctx.n
    fr = solve_forward(ctx.skeleton, ctx.d, L)
    x0 = np.concatenate([fr.angles, np.full(n, math.log(fr.tension))])
    modes = np.full(n, mode)
    x, ok, it, why = _solve_active(ctx, x0, L, modes, None, max_iter)
    if ok or not np.any(ctx.mu > 0):
        return x, ok, it, why
    # Fallback (slow, robust): the winch tension by bracketing on the total length, the
    # angles segment by segment (the branch equations are lower triangular for a given
    # winch tension), then the Newton polish for the contract.
    xs, reason = _sequential_solve(ctx, L, mode)
    if xs is None:
        return x, ok, it, f'{why}; {reason}'
    x2, ok2, it2, why2 = _solve_active(ctx, xs, L, modes, None, max_iter)
    return x2, ok2, it + it2, why2


def _sequential_angles(ctx, T_w, mode):
    """Branch angles and log-tensions for a winch tension: segment i's tension
    ``T_w exp(mode sum_{k<=i} mu_k theta_k)`` depends on a_0..a_i, so each angle is a
    scalar root (brentq on the bend side, where ``a - a_branch(T(a))`` changes sign)."""
    from scipy.optimize import brentq
    n = ctx.n
    a = np.zeros(n)
    u = np.zeros(n)
    acc = 0.0
    for i in range(n):
        lo_i = max(i - 1, 0)

        def tension(ai):
            a[i] = ai
            th = _wraps(a[lo_i:i + 1], ctx.d1[lo_i:i + 1], ctx.d2[lo_i:i + 1], ctx.s)[0]
            return T_w * math.exp(mode * (acc + ctx.mu[i] * (th[-1] if i else th[0])))

        def h(b):
            ai = ctx.direction[i] * b
            Ai = segment_angle_at_tension(tension(ai), ctx.d1[i], ctx.d2[i], ctx.s,
                                          ctx.k[i], max_angle_rad=ctx.contact)
            return b - ctx.direction[i] * float(Ai)

        end = float(ctx.end_angle[i])
        h0 = h(0.0)
        if h0 >= 0.0:
            b = 0.0
        elif h(end) <= 0.0:
            b = end
        else:
            b = brentq(h, 0.0, end, xtol=1e-14, rtol=1e-14)
        T_i = tension(ctx.direction[i] * b)
        a[i] = ctx.direction[i] * b
        u[i] = math.log(T_i)
        acc = math.log(T_i / T_w) * mode
    return a, u


def _sequential_solve(ctx, L, mode):
    from scipy.optimize import brentq

    def excess(log_t):
        a, _ = _sequential_angles(ctx, math.exp(log_t), mode)
        return float(segment_length_derivatives(a, ctx.d1, ctx.d2, ctx.s)[0].sum()) - L

    # First crossing on a grid of winch tensions: the length first reached by pulling.
    grid = np.linspace(-12.0, 8.0, 41)
    prev = None
    for g in grid:
        e = excess(g)
        if e <= 0.0:
            if prev is None:
                return None, 'the bracketing fallback found no winch tension'
            log_t = brentq(excess, prev, g, xtol=1e-13, rtol=1e-14)
            a, u = _sequential_angles(ctx, math.exp(log_t), mode)
            jump = abs(excess(log_t))
            if jump > 1e-6:
                # The length jumps at this winch tension: friction made a segment's
                # buckling subcritical (its own bend lowers the wrap before it, so its
                # tension rises as it bends) and it snaps to contact.
                lo_len = L + excess(log_t + 1e-9)
                hi_len = L + excess(log_t - 1e-9)
                return None, (f'snap-through: the {"pull" if mode == PULL else "release"} '
                              f'branch jumps from {hi_len:.6f} to {lo_len:.6f} mm at winch '
                              f'tension {math.exp(log_t):.6g}; no equilibrium on it at '
                              f'this length')
            return np.concatenate([a, u]), ''
        prev = g
    return None, 'the bracketing fallback found no winch tension'


def solve_friction(skeleton: Skeleton, threading, cable_length_mm, friction=0.0,
                   direction: str = 'pull', *, max_iter: int = MAX_ITER) -> FrictionResult:
    """Shape of a module with cable friction at the holes, on the pull or release branch.

    Parameters
    ----------
    skeleton : Skeleton
    threading : sequence of str or float
        One hole per rib, rib 0 first.
    cable_length_mm : float
        Cable length between the holes of rib 0 and the last rib (mm).
    friction : float or array_like (n_segments,)
        Friction coefficient ``mu`` per hole of ribs 0..n-2 (the tip hole is the
        anchor), in [0, 2]; 0 is the frictionless model. Typical 0.1-0.3 (estimate).
    direction : {'pull', 'release'}
        'pull': the shape reached by shortening the cable from straight (tension decays
        towards the tip); 'release': every hole slipping towards the tip (tension
        grows towards the tip), reached after lengthening far enough.
    max_iter : int
        Newton iterations per active set.

    Returns
    -------
    FrictionResult
        Check ``converged``; ``message`` names any failed check.

    Raises
    ------
    InfeasibleLengthError
        Length at or below the reachable minimum (the same range as without friction).
    ValueError
        Bad skeleton, threading, friction, length or direction.

    Examples
    --------
    >>> sk = Skeleton()
    >>> t = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()
    >>> r = solve_friction(sk, t, 150.0, friction=0.2)
    >>> bool(r.converged), bool(r.segment_tensions[-1] < r.segment_tensions[0])
    (True, True)
    """
    if direction not in ('pull', 'release'):
        raise ValueError(f"direction must be 'pull' or 'release', got {direction!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) \
            or max_iter < 1:
        raise ValueError(f'max_iter must be an integer >= 1, got {max_iter!r}')
    ctx = _check_inputs(skeleton, threading, friction)
    L = _as_length(cable_length_mm)
    _check_length(ctx, L)
    mode = PULL if direction == 'pull' else RELEASE
    modes = np.full(ctx.n, mode)
    if L >= ctx.hi:
        return _slack_result(ctx, L, modes, direction)
    x, ok, it, why = _branch_solve(ctx, L, mode, int(max_iter))
    return _make_result(ctx, x, L, modes, None, direction, ok, it, why)


def friction_sweep(skeleton: Skeleton, threading, cable_lengths_mm, friction=0.0, *,
                   max_iter: int = MAX_ITER) -> FrictionSweepResult:
    """Follow a sequence of cable lengths with per-hole stick/slip (hysteresis).

    The first length is reached by pulling from straight (:func:`solve_friction`,
    'pull'). Then each step shortens (the winch pulls), lengthens (releases) or keeps
    the length (nothing moves). At every interior hole the cable either slips, in the
    direction the step moves it, with the capstan ratio of its wrap angle, or sticks
    (the cable length from that hole to the tip is kept) while the tension ratio
    across the hole stays inside the friction cone. Which holes slip is found per step
    by an active-set iteration (slip where a stuck hole leaves its cone, stick where a
    slipping hole would move against its friction).

    After a reversal the slip front starts at the winch: the base segment moves first
    and the front travels tipwards as the length keeps changing, so the shape moves
    continuously from one branch to the other. Mode changes inside a step are taken
    at the step's end, which is exact as long as holes only change from stuck to
    slipping within a monotone run (the case for reversals at the sample lengths).

    Parameters
    ----------
    skeleton : Skeleton
    threading : sequence of str or float
    cable_lengths_mm : array_like (B,)
        Lengths in order (mm), e.g. ``L_straight - c`` for contractions ``c`` going out
        and back.
    friction : float or array_like (n_segments,)
    max_iter : int

    Returns
    -------
    FrictionSweepResult
        ``converged`` is False if any step failed (its ``message`` says why); the steps
        after a failed one start from its (unconverged) state.

    Examples
    --------
    >>> sk = Skeleton()
    >>> t = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()
    >>> L0 = sk.straight_length_mm(t)
    >>> c = np.r_[np.linspace(0, 50, 11), np.linspace(50, 0, 11)[1:]]
    >>> sw = friction_sweep(sk, t, L0 - c, friction=0.2)
    >>> bool(sw.converged), [sw.steps[i].direction for i in (5, 15)]
    (True, ['pull', 'release'])
    """
    ctx = _check_inputs(skeleton, threading, friction)
    lengths = np.asarray(cable_lengths_mm, dtype=float)
    if lengths.ndim != 1 or lengths.size == 0:
        raise ValueError(f'cable_lengths_mm must be a non-empty 1-D array, got shape '
                         f'{lengths.shape}')
    if not np.all(np.isfinite(lengths)) or np.any(lengths <= 0):
        bad = lengths[~(np.isfinite(lengths) & (lengths > 0))][0]
        raise ValueError(f'cable_lengths_mm must be finite and > 0, got {bad!r}')
    for L in lengths:
        _check_length(ctx, float(L))
    steps = []
    previous = None
    for L in lengths.tolist():
        previous = _step(ctx, previous, L, int(max_iter))
        steps.append(previous)
    return FrictionSweepResult(
        steps=tuple(steps), cable_lengths_mm=lengths,
        angles=np.array([r.angles for r in steps]),
        rib_centers=np.array([r.rib_centers for r in steps]),
        winch_tension=np.array([r.winch_tension for r in steps]),
        converged=all(r.converged for r in steps))


def _step(ctx, previous, L, max_iter):
    """One length of a sweep, from the previous step's result (None: from straight)."""
    n = ctx.n
    friction_holes = ctx.mu > 0
    friction_holes[0] = False
    prev_L = None if previous is None else previous.cable_length_mm
    if L >= ctx.hi:
        direction = 'pull' if prev_L is None else (
            'release' if L > prev_L else ('hold' if L == prev_L else 'pull'))
        return _slack_result(ctx, L, np.full(n, PULL), direction)
    if previous is None or previous.slack:
        # From slack (or the start): pulled from straight.
        x, ok, it, why = _branch_solve(ctx, L, PULL, max_iter)
        return _make_result(ctx, x, L, np.full(n, PULL), None, 'pull', ok, it, why)
    x_prev = np.concatenate([previous.angles, np.log(previous.segment_tensions)])
    modes_prev = previous.hole_modes
    length = segment_length_derivatives(previous.angles, ctx.d1, ctx.d2, ctx.s)[0]
    S_prev = np.cumsum(length[::-1])[::-1]
    if L == prev_L:
        return _replace_direction(_make_result(ctx, x_prev, L, modes_prev, S_prev, 'hold',
                                               True, 0, ''), 'hold')
    mode = PULL if L < prev_L else RELEASE
    direction = 'pull' if mode == PULL else 'release'
    if modes_prev[0] == mode:
        modes = modes_prev.copy()
    else:
        # Reversal: every hole with friction sticks at first.
        modes = np.where(friction_holes, STICK, mode)
    modes[0] = mode
    modes[~friction_holes] = mode
    x, ok, it, why, modes, S_start = _advance(ctx, x_prev, prev_L, L, modes, S_prev, mode,
                                              friction_holes, max_iter)
    return _make_result(ctx, x, L, modes, S_start, direction, ok, it, why)


def friction_step(skeleton: Skeleton, threading, cable_length_mm, friction=0.0,
                  previous: FrictionResult | None = None, *,
                  max_iter: int = MAX_ITER) -> FrictionResult:
    """Advance a module's stick/slip state to a new cable length (one sweep step).

    For callers that receive lengths one at a time (e.g. a model node tracking a
    module): ``previous`` is the result of the last call for the same skeleton,
    threading and friction (None, or a slack result: pulled from straight). The
    sequence of calls gives the same results as :func:`friction_sweep` of the lengths.

    Raises
    ------
    InfeasibleLengthError, ValueError
        As :func:`solve_friction`; a ``previous`` of another size or with non-finite
        state is a ValueError.
    """
    ctx = _check_inputs(skeleton, threading, friction)
    L = _as_length(cable_length_mm)
    _check_length(ctx, L)
    if previous is not None:
        if not isinstance(previous, FrictionResult):
            raise ValueError(f'previous must be a FrictionResult or None, got '
                             f'{type(previous).__name__}')
        if previous.angles.shape != (ctx.n,) or previous.hole_modes.shape != (ctx.n,):
            raise ValueError(f'previous: expected {ctx.n} segments, got shape '
                             f'{previous.angles.shape}')
        if not previous.slack and not (np.all(np.isfinite(previous.angles))
                                       and np.all(previous.segment_tensions > 0)):
            raise ValueError('previous: angles must be finite and tensions > 0')
    return _step(ctx, previous, L, int(max_iter))


def _replace_direction(res, direction):
    from dataclasses import replace
    return replace(res, direction=direction)


def _advance(ctx, x_prev, L_from, L_to, modes, S_prev, mode, friction_holes, max_iter,
             depth=0):
    """One sweep step from ``L_from`` to ``L_to``; halves the step (up to 2^8 pieces)
    where the stick/slip set found for the whole step has no consistent solution, so
    the slip front is followed in small enough pieces. Returns ``(x, ok, iterations,
    why, modes, S_start)`` with ``S_start`` the stick lengths of the last piece's start.
    """
    x, ok, it, why, new_modes = _active_set_step(ctx, x_prev, L_to, modes, S_prev, mode,
                                                 friction_holes, max_iter)
    if ok or depth >= 8:
        return x, ok, it, why, new_modes, S_prev
    mid = 0.5 * (L_from + L_to)
    xm, ok1, it1, why1, modes_m, _ = _advance(ctx, x_prev, L_from, mid, modes, S_prev, mode,
                                              friction_holes, max_iter, depth + 1)
    if not ok1:
        return xm, False, it + it1, why1, modes_m, S_prev
    length = segment_length_derivatives(xm[:ctx.n], ctx.d1, ctx.d2, ctx.s)[0]
    S_mid = np.cumsum(length[::-1])[::-1]
    x2, ok2, it2, why2, modes2, S2 = _advance(ctx, xm, mid, L_to, modes_m, S_mid, mode,
                                              friction_holes, max_iter, depth + 1)
    return x2, ok2, it + it1 + it2, why2, modes2, S2


def _slip_start(ctx, x_prev, modes, mode):
    """Start for Newton: the previous state with the tensions on the winch side of the
    slip front made consistent with the slip relations, propagated from the first
    segment beyond the front (whose tension is the best known: the segments before it
    are often held at contact, where the tension is free)."""
    n = ctx.n
    x = x_prev.copy()
    stuck = np.nonzero(modes[1:] == STICK)[0]
    front = int(stuck[0]) + 1 if stuck.size else n    # first stuck hole (or none)
    theta = _wraps(x[:n], ctx.d1, ctx.d2, ctx.s)[0]
    u = x[n:]
    for j in range(front - 2, -1, -1):
        u[j] = u[j + 1] - mode * ctx.mu[j + 1] * theta[j + 1]
    return x


def _active_set_step(ctx, x_prev, L, modes, S_prev, mode, friction_holes, max_iter):
    """Solve one sweep step, switching holes between stick and slip until consistent."""
    n = ctx.n
    total = 0
    seen = set()
    x = x_prev
    why = 'active set did not settle'
    for _ in range(3 * n):
        key = tuple(modes.tolist())
        if key in seen:
            break
        seen.add(key)
        start = _slip_start(ctx, x_prev, modes, mode)
        x, ok, it, why = _solve_active(ctx, start, L, modes, S_prev, max_iter)
        total += it
        if not ok:
            x, ok, it, why = _solve_active(ctx, start, L, modes, S_prev, max_iter,
                                           open_contact=True)
            total += it
        if not ok:
            # No solution with this stick/slip set: the stuck part cannot give the
            # length change (e.g. the segments next to the winch are held at contact, so
            # the cable cannot move through them unless the holes beyond slip too). The
            # slip front moves from the winch tipwards: let the base-most stuck hole slip.
            stuck = np.nonzero(modes == STICK)[0]
            if stuck.size == 0:
                return x, False, total, why, modes
            modes = modes.copy()
            modes[stuck[0]] = mode
            continue
        a, u = x[:n], x[n:]
        length = segment_length_derivatives(a, ctx.d1, ctx.d2, ctx.s)[0]
        theta = _wraps(a, ctx.d1, ctx.d2, ctx.s)[0]
        S = np.cumsum(length[::-1])[::-1]
        new = modes.copy()
        for kk in range(1, n):
            if not friction_holes[kk]:
                continue
            limit = ctx.mu[kk] * theta[kk]
            ratio = u[kk] - u[kk - 1]
            if modes[kk] == STICK:
                # Outside the cone on the side the step moves the cable: slip that way.
                # (The other side cannot be reached by a monotone step; a held segment's
                # tension is undetermined and is left where it was.)
                if mode * ratio > limit + _CONE_TOL:
                    new[kk] = mode
            else:
                if modes[kk] * (S[kk] - S_prev[kk]) < -_MOVE_TOL_MM:
                    new[kk] = STICK
        if (new == modes).all():
            return x, True, total, '', modes
        modes = new
    return x, False, total, why, modes
