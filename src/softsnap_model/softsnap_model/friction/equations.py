"""The friction model's equations at one cable length: segment equilibrium, the capstan
law or stick at each hole, their Newton solve on an active set, and the result."""
from __future__ import annotations

import functools
import math
import numbers

import numpy as np

from ..forward import (InfeasibleLengthError, reachable_range, segment_angle_at_tension,
                       segment_branch)
from ..geometry import cable_path, rib_centers, segment_length_derivatives
from ..skeleton import Skeleton
from .results import (BRANCH_TOL_RAD, CONSTRAINT_TOL_MM, FrictionResult, PULL, SLIP_TOL,
                      STATIONARITY_TOL_RAD, STICK, _CONE_TOL, _MOVE_TOL_MM, _TOL_MM, _TOL_RAD,
                      _TOL_SLIP)
from .wrap import _wraps

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
