"""Exact planar geometry of a SoftSnap skeleton (pure numpy).

Conventions (FACTS.md): rib 0 sits at the origin with the spine leaving it along +x.
A hole offset ``d`` (mm) is measured along the rib from the spine, positive to the
right of the spine seen from base to tip (the authors' "R" side, -y at straight). The
bending angle ``a`` between rib i and rib i+1 (rad) is positive counter-clockwise; each
segment bends with constant curvature and the ribs stay normal to the spine.

The cable length between hole ``d1`` on rib i and hole ``d2`` on rib i+1 is exactly::

    L(a; d1, d2)^2 = (d1 - d2)^2 + c(a)^2 (s + d1 a) (s + d2 a),   c(a) = 2 sin(a/2) / a

which is regular at ``a = 0`` (c(0) = 1). All functions broadcast over their arguments.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['segment_length', 'segment_length_derivatives', 'rib_centers', 'cable_path',
           'half_angle_functions']

# Taylor coefficients in x = u^2 of f0(u) = sin(u)/u and f1(u) = (sin u - u cos u)/u^3.
# 13 terms reach double precision for x <= (pi/2)^2, i.e. |a| <= pi: the last term is
# below 1e-21 there, and the alternating terms never exceed 0.5, so no cancellation.
_N_TERMS = 13
_SERIES_X_MAX = (math.pi / 2) ** 2
_SERIES = np.array([[(-1.0) ** k / math.factorial(2 * k + 1),
                     (-1.0) ** k * 2.0 * (k + 1) / math.factorial(2 * k + 3)]
                    for k in range(_N_TERMS)])

# Power series are evaluated three ways by array size, all accurate to a few ulp (the
# tests compare each against mpmath; they may differ in the last bit): up to
# _POW_MAX_SIZE elements one ``pow`` per term and a matrix product (fewest numpy calls,
# which dominate small arrays); up to _HORNER_MIN_SIZE the powers by repeated products;
# above, Horner's scheme over all columns at once (2 contiguous passes per term, no
# ``pow`` and no (size, n_terms) table: 7-20x faster on large batches).
_POW_MAX_SIZE = 256
_HORNER_MIN_SIZE = 1024
_EXPONENTS = np.arange(32, dtype=float)


def _power_series(x, coef):
    """Columns ``sum_j coef[j, c] x^j`` of a (n_terms, n_cols) table (2 or 3 columns),
    each shaped like ``x``."""
    n_terms, n_cols = coef.shape
    if x.size <= _HORNER_MIN_SIZE:
        if x.size <= _POW_MAX_SIZE:
            powers = x[..., None] ** _EXPONENTS[:n_terms]
        else:
            powers = np.empty(x.shape + (n_terms,))
            powers[..., 0] = 1.0
            powers[..., 1] = x
            for j in range(2, n_terms):
                np.multiply(powers[..., j - 1], x, out=powers[..., j])
        s = powers @ coef
        return (s[..., 0], s[..., 1]) if n_cols == 2 else (s[..., 0], s[..., 1], s[..., 2])
    flat = x.ravel()
    s = np.empty((n_cols, flat.size))
    s[...] = coef[-1][:, None]
    for row in coef[-2::-1]:
        s *= flat
        s += row[:, None]
    return tuple(s[c].reshape(x.shape) for c in range(n_cols))


def half_angle_functions(u):
    """Return ``(sin u / u, (sin u - u cos u) / u^3, cos u)`` accurate for all real ``u``.

    The second function suffers catastrophic cancellation in closed form near ``u = 0``
    (it tends to 1/3); a Taylor series is used for ``|u| <= pi/2`` and the closed form,
    which is well conditioned there, beyond. Both agree to a few ulp at the switch, so
    the result has no jump.
    """
    u = np.asarray(u, dtype=float)
    x = u * u
    f0, f1 = _power_series(x, _SERIES)
    cos_u = np.cos(u)
    big = x > _SERIES_X_MAX
    if big.any():
        # Closed form only where it is well conditioned (|u| > pi/2, so u != 0).
        u_safe = np.where(big, u, 1.0)
        f0_closed = np.sin(u_safe) / u_safe
        f1_closed = (f0_closed - np.cos(u_safe)) / (u_safe * u_safe)
        f0 = np.where(big, f0_closed, f0)
        f1 = np.where(big, f1_closed, f1)
    return f0, f1, cos_u


# g(a) = (2 sin(a/2)/a)^2 = sum_j (-1)^j 2 a^2j / (2j+2)! and its derivatives, as power
# series in x = a^2: g = sum c0_j x^j, g' = a sum c1_j x^j, g'' = sum c2_j x^j. Sixteen
# terms reach double precision for |a| <= pi (the last is below 1e-18 there, and the
# largest term, 0.82 at |a| = pi, is twice the value: no cancellation to speak of).
_G_TERMS = 16
_G_SERIES_A_MAX = math.pi


def _g_coefficients():
    coef = np.zeros((_G_TERMS, 3))
    for j in range(_G_TERMS):
        gamma = (-1.0) ** j * 2.0 / math.factorial(2 * j + 2)
        coef[j, 0] = gamma
        if j + 1 < _G_TERMS:
            gamma_next = (-1.0) ** (j + 1) * 2.0 / math.factorial(2 * j + 4)
            coef[j, 1] = 2 * (j + 1) * gamma_next                    # g'/a
            coef[j, 2] = 2 * (j + 1) * (2 * j + 1) * gamma_next      # g''
    return coef


_G_COEF = _g_coefficients()


def _g_series(a):
    """``(g, g', g'')`` by the power series; exact to rounding for ``|a| <= pi``."""
    g, g_over_a, g_aa = _power_series(a * a, _G_COEF)
    return g, a * g_over_a, g_aa


def _g_closed(a):
    """``(g, g', g'')`` in closed form; well conditioned for ``|a| >= 1``."""
    sin_a, cos_a = np.sin(a), np.cos(a)
    m = 2.0 * (1.0 - cos_a)
    i1 = 1.0 / a
    i2 = i1 * i1
    return (m * i2, (2.0 * sin_a - 2.0 * m * i1) * i2,
            (2.0 * cos_a - 8.0 * sin_a * i1 + 6.0 * m * i2) * i2)


def g_and_derivatives(a):
    """``g(a) = (2 sin(a/2)/a)^2`` and its first two derivatives, accurate for all ``a``.

    Power series for ``|a| <= pi`` (no division: exact at and near 0), closed form
    beyond; both agree to rounding at the switch.
    """
    a = np.asarray(a, dtype=float)
    g, g_a, g_aa = _g_series(a)
    big = np.abs(a) > _G_SERIES_A_MAX
    if big.any():
        closed = _g_closed(np.where(big, a, 4.0))
        g, g_a, g_aa = (np.where(big, c, v) for c, v in zip(closed, (g, g_a, g_aa)))
    return g, g_a, g_aa


def segment_length_derivatives(angle_rad, d1_mm, d2_mm, spacing_mm):
    """Cable length of one segment and its first two derivatives in the bending angle.

    Parameters
    ----------
    angle_rad : array_like
        Bending angle ``a`` between the two ribs (rad, counter-clockwise positive).
    d1_mm, d2_mm : array_like
        Hole offsets on the proximal and distal rib (mm, positive on the right).
    spacing_mm : array_like
        Spine arc length ``s`` between the ribs (mm).

    Returns
    -------
    length_mm, dlength_da, d2length_da2 : ndarray
        ``L`` (mm), ``dL/da`` (mm/rad) and ``d2L/da2`` (mm/rad^2), broadcast together.

    Notes
    -----
    ``Q = L^2 = (d1 - d2)^2 + g(a) (s + d1 a)(s + d2 a)`` with ``g = (2 sin(a/2)/a)^2``.
    ``g`` and its derivatives come from its power series for ``|a| <= pi`` (no division,
    so nothing cancels at or near ``a = 0``) and from the closed form beyond, where it
    is well conditioned; the two agree to rounding at the switch. ``L`` is singular only where
    the two holes coincide (``L = 0``).

    Examples
    --------
    >>> L, dL, d2L = segment_length_derivatives(0.0, 10.0, 10.0, 18.0)
    >>> float(L), float(dL)
    (18.0, 10.0)
    """
    a = np.asarray(angle_rad, dtype=float)
    d1 = np.asarray(d1_mm, dtype=float)
    d2 = np.asarray(d2_mm, dtype=float)
    s = np.asarray(spacing_mm, dtype=float)
    g, g_a, g_aa = g_and_derivatives(a)
    # Product form Q = dd^2 + g p1 p2: no cancellation even where a hole nears the
    # centre of curvature (s + d a -> 0), unlike the expanded G0/G1/G2 sum.
    p1 = s + d1 * a
    p2 = s + d2 * a
    prod = p1 * p2
    prod_a = d1 * p2 + d2 * p1
    dd = d1 - d2
    length = np.sqrt(dd * dd + g * prod)
    half_inv = 0.5 / length
    l_a = (g_a * prod + g * prod_a) * half_inv
    l_aa = (g_aa * prod + 2.0 * g_a * prod_a + 2.0 * d1 * d2 * g - 2.0 * l_a * l_a) * half_inv
    return length, l_a, l_aa


def segment_length(angle_rad, d1_mm, d2_mm, spacing_mm):
    """Cable length (mm) between hole ``d1`` on one rib and ``d2`` on the next.

    Exact closed form of FACTS.md, broadcasting over all arguments; see
    :func:`segment_length_derivatives` for conventions.

    Examples
    --------
    >>> float(segment_length(0.0, 3.0, 6.5, 18.0)) == (18.0**2 + 3.5**2) ** 0.5
    True
    """
    a = np.asarray(angle_rad, dtype=float)
    d1 = np.asarray(d1_mm, dtype=float)
    d2 = np.asarray(d2_mm, dtype=float)
    c, _, _ = half_angle_functions(0.5 * a)
    dd = d1 - d2
    return np.sqrt(dd * dd + c * c * (spacing_mm + d1 * a) * (spacing_mm + d2 * a))


def _rib_frames(angles_rad, spacing_mm):
    """Rib centres (..., n+1, 2) and rib orientations t_k (..., n+1) for n angles."""
    a = np.asarray(angles_rad, dtype=float)
    c, _, cos_half = half_angle_functions(0.5 * a)
    zero = np.zeros(a.shape[:-1] + (1,))
    theta = np.concatenate([zero, np.cumsum(a, axis=-1)], axis=-1)
    chord_dir = theta[..., :-1] + 0.5 * a
    chord = np.asarray(spacing_mm, dtype=float) * c
    steps = np.stack([chord * np.cos(chord_dir), chord * np.sin(chord_dir)], axis=-1)
    centers = np.concatenate([np.zeros(a.shape[:-1] + (1, 2)), np.cumsum(steps, axis=-2)],
                             axis=-2)
    return centers, theta


def rib_centers(angles_rad, spacing_mm):
    """Rib centre points (mm) in the base frame.

    Parameters
    ----------
    angles_rad : array_like, shape (..., n_segments)
        Bending angles (rad).
    spacing_mm : float or array_like broadcastable to (..., n_segments)
        Spine arc length between adjacent ribs (mm).

    Returns
    -------
    ndarray, shape (..., n_segments + 1, 2)
        ``P_0 = 0`` and ``P_{k+1} = P_k + s sinc(a_k/2) (cos, sin)(t_k + a_k/2)``.

    Examples
    --------
    >>> rib_centers([0.0, 0.0], 18.0).tolist()
    [[0.0, 0.0], [18.0, 0.0], [36.0, 0.0]]
    """
    return _rib_frames(angles_rad, spacing_mm)[0]


def cable_path(angles_rad, threading_mm, spacing_mm):
    """Positions (mm) of the threaded holes, one per rib, in the base frame.

    A hole at offset ``d`` on rib ``k`` sits at ``P_k + d (sin t_k, -cos t_k)``: positive
    ``d`` is the right side (-y at straight). The cable runs straight between
    consecutive holes, so the polyline length equals the sum of segment lengths.

    Parameters
    ----------
    angles_rad : array_like, shape (..., n_segments)
    threading_mm : array_like, shape (..., n_segments + 1)
        Hole offset on every rib (mm).
    spacing_mm : float

    Returns
    -------
    ndarray, shape (..., n_segments + 1, 2)
    """
    centers, theta = _rib_frames(angles_rad, spacing_mm)
    d = np.asarray(threading_mm, dtype=float)
    normal = np.stack([np.sin(theta), -np.cos(theta)], axis=-1)
    return centers + d[..., None] * normal
