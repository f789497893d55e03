"""The angle the cable wraps through each hole, from the exact straight-line cable path."""
from __future__ import annotations

import numpy as np

from ..geometry import half_angle_functions
from ..skeleton import Skeleton

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
