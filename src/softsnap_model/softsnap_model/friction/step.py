"""Following the path: ``friction_sweep`` (a sequence of cable lengths, with its
hysteresis) and ``friction_step`` (one quasi-static step from a previous state: stick,
slip fronts and reversals)."""
from __future__ import annotations

import numpy as np

from ..geometry import segment_length_derivatives
from ..skeleton import Skeleton
from .equations import (_as_length, _check_inputs, _check_length, _make_result, _slack_result,
                        _solve_active)
from .results import (FrictionResult, FrictionSweepResult, MAX_ITER, PULL, RELEASE, STICK,
                      _CONE_TOL, _MOVE_TOL_MM)
from .solve import _branch_solve
from .wrap import _wraps


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
