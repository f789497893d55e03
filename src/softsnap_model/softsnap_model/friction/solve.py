"""``solve_friction``: the pull and release branches from straight, solved at one cable
length."""
from __future__ import annotations

import math
import numbers

import numpy as np

from ..forward import segment_angle_at_tension, solve_forward
from ..geometry import segment_length_derivatives
from ..skeleton import Skeleton
from .equations import (_as_length, _check_inputs, _check_length, _make_result, _slack_result,
                        _solve_active)
from .results import FrictionResult, MAX_ITER, PULL, RELEASE
from .wrap import _wraps


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
