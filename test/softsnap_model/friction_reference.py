"""Independent slow reference for the cable-friction model (tests and benchmark only).

Shares no code with softsnap_model.friction or softsnap_model.geometry: rib poses are
integrated as circular arcs, holes placed on them, segment lengths are distances
between holes, dL/da comes from the complex step, wrap angles from arccos of the
dot product of consecutive cable directions. For a given winch tension the branch
equations are lower triangular (segment i's tension depends on the wrap at holes
0..i, i.e. on a_0..a_i), so each segment is solved in turn by brentq on its bend
side, and the winch tension by brentq on the total length.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq


def _rib_pose(t, p, a, s):
    """Pose (angle, centre) of the next rib after a constant-curvature arc of angle a."""
    if a == 0:
        step = s * np.array([np.cos(t), np.sin(t)])
    else:
        r = s / a
        step = r * np.array([np.sin(t + a) - np.sin(t), np.cos(t) - np.cos(t + a)])
    return t + a, p + step


def _hole(t, p, d):
    return p + d * np.array([np.sin(t), -np.cos(t)])


def segment_length_c(a, d1, d2, s):
    """Segment length for a complex (or real) angle a != 0, in rib 1's frame."""
    # sin(a)/a and 2 sin^2(a/2)/a: no cancellation for small (complex) a.
    p2 = s * np.array([np.sin(a) / a, 2.0 * np.sin(0.5 * a) ** 2 / a])
    h1 = np.array([0.0, -d1])
    h2 = p2 + d2 * np.array([np.sin(a), -np.cos(a)])
    v = h2 - h1
    return np.sqrt(v[0] * v[0] + v[1] * v[1])


def dlength(a, d1, d2, s):
    """dL/da by the complex step (a = 0 moved to 1e-30: L is smooth there)."""
    a = float(a) if a != 0 else 1e-300
    h = 1e-30
    return float(np.imag(segment_length_c(complex(a, h), d1, d2, s)) / h)


def length(a, d1, d2, s):
    a = float(a) if a != 0 else 1e-300
    return float(np.real(segment_length_c(complex(a, 0.0), d1, d2, s)))


def holes(angles, d, s):
    t, p = 0.0, np.zeros(2)
    out = [_hole(t, p, d[0])]
    for i, a in enumerate(angles):
        t, p = _rib_pose(t, p, float(a), s)
        out.append(_hole(t, p, d[i + 1]))
    return np.array(out)


def rib_centres(angles, s):
    t, p = 0.0, np.zeros(2)
    out = [p]
    for a in angles:
        t, p = _rib_pose(t, p, float(a), s)
        out.append(p)
    return np.array(out)


def wraps(angles, d, s):
    """Wrap angle at holes 0..n-1; the winch side of hole 0 runs along +x."""
    h = holes(angles, d, s)
    dirs = np.diff(h, axis=0)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    prev = np.vstack([[1.0, 0.0], dirs[:-1]])
    return np.arccos(np.clip(np.sum(prev * dirs, axis=1), -1.0, 1.0))


def _bend_direction(d1, d2):
    sig = d1 + d2
    if sig != 0:
        return -1.0 if sig > 0 else 1.0
    return -1.0 if d1 >= 0 else 1.0


def _solve_segment(g, b_max, n_scan=80):
    """Smallest b in (0, b_max] with g(b) = 0 after g < 0 (the followed branch), b_max
    when g stays negative (contact), 0 when g >= 0 right away (mirror below buckling)."""
    grid = np.linspace(0.0, b_max, n_scan + 1)[1:]
    prev_b, prev_g = 0.0, None
    for b in grid:
        gb = g(b)
        if prev_g is None:
            if gb >= 0:
                # Mirror segment below buckling, or the root is below the first sample.
                g0 = g(1e-9 * b_max)
                if g0 >= 0:
                    return 0.0
                return brentq(g, 1e-9 * b_max, b, xtol=1e-15, rtol=1e-15)
        elif gb >= 0 > prev_g:
            return brentq(g, prev_b, b, xtol=1e-15, rtol=1e-15)
        prev_b, prev_g = b, gb
    return b_max


def angles_at_winch_tension(T_w, d, s, k, mu, contact, sign):
    """Branch angles for winch tension T_w; sign -1 pull, +1 release."""
    n = len(d) - 1
    a = np.zeros(n)
    for i in range(n):
        direction = _bend_direction(d[i], d[i + 1])

        def tension(b):
            trial = a.copy()
            trial[i] = direction * b
            th = wraps(trial[:i + 1], d[:i + 2], s)
            return T_w * math.exp(sign * float(np.dot(mu[:i + 1], th)))

        def g(b):
            return 2.0 * k[i] * b + tension(b) * direction * dlength(direction * b, d[i],
                                                                      d[i + 1], s)

        a[i] = direction * _solve_segment(g, contact)
    return a


def reference_branch(d, s, k, mu, contact, cable_length_mm, sign):
    """Angles on the pull (sign -1) or release (+1) branch at a given length."""
    d = np.asarray(d, float)
    n = len(d) - 1
    k = np.asarray(k, float) * np.ones(n)
    mu = np.asarray(mu, float) * np.ones(n)

    def total(log_t):
        a = angles_at_winch_tension(math.exp(log_t), d, s, k, mu, contact, sign)
        return sum(length(a[i], d[i], d[i + 1], s) for i in range(n)) - cable_length_mm

    lo, hi = -12.0, 2.0
    while total(hi) > 0:
        hi += 2.0
        if hi > 30:
            raise ValueError('length not reached')
    log_t = brentq(total, lo, hi, xtol=1e-14, rtol=1e-15)
    return angles_at_winch_tension(math.exp(log_t), d, s, k, mu, contact, sign), \
        math.exp(log_t)


def check_stick_slip(angles, prev_angles, d, s, k, mu, modes, mode, tensions):
    """Independent check of one sweep step's complementarity conditions.

    Returns the largest violation of: stuck hole keeps ``S_k``; slipping hole moves the
    way its friction assumes (not against it); free segments' tension from their own
    equilibrium; stuck holes inside the cone; slipping holes on the cone's edge.
    """
    n = len(d) - 1
    h_new, h_old = holes(angles, d, s), holes(prev_angles, d, s)
    seg_new = np.linalg.norm(np.diff(h_new, axis=0), axis=1)
    seg_old = np.linalg.norm(np.diff(h_old, axis=0), axis=1)
    S_new = np.cumsum(seg_new[::-1])[::-1]
    S_old = np.cumsum(seg_old[::-1])[::-1]
    th = wraps(angles, d, s)
    worst = 0.0
    for kk in range(1, n):
        ratio = math.log(tensions[kk] / tensions[kk - 1])
        lim = mu[kk] * th[kk]
        if modes[kk] == 0:
            worst = max(worst, abs(S_new[kk] - S_old[kk]), abs(ratio) - lim - 1e-9)
        else:
            worst = max(worst, abs(ratio - modes[kk] * lim))
            if mu[kk] > 0:
                worst = max(worst, -modes[kk] * (S_new[kk] - S_old[kk]))
    return worst
