"""Which rib each marker is: the module base frame and the walk along the spine.

The paper's frame: the first rib marker (rib 0, the one next to the base marker) is the
origin, the line from the base marker through it is the x-axis, y is x turned 90 degrees
counter-clockwise seen from above. Here rib 0 must also lie at the layout's distance from
the base marker: if it is hidden, the nearest rib marker is rib 1, 18 mm farther, and the
frame would be wrong, so the frame is refused instead.

Then the ribs are taken in order, each from the last one found: the next rib lies one
chord (``s sinc(a/2)``, 16.9-18 mm for the authors' module) further along, turned by at
most the rib-contact angle; over ``k`` hidden ribs in a row the distance window grows to
what ``k + 1`` segments bent by at most ``max_segment_angle_deg`` reach. A candidate is
taken only if it is the only one in the nearest window and fits no other window (then it
could be a different rib); otherwise the walk stops there and the remaining ribs are
missing. A marker is never guessed.

Pure numpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ['BaseFrame', 'FrameError', 'base_frame', 'order_ribs', 'RibOrder']


#: Several rib markers near rib 0's distance from the base marker: the one within this of
#: the layout's distance (mm) is rib 0, if it is the only one.
FIRST_RIB_SURE_MM = 1.0


#: Slack on the largest turn between successive chords (rad): markers at rib contact
#: measured with noise.
TURN_MARGIN_RAD = 0.15


class FrameError(ValueError):
    """The module base frame cannot be set up from what is seen (message says why)."""


@dataclass(frozen=True)
class BaseFrame:
    """The module base frame on the plane (mm, seen from above)."""

    origin_mm: np.ndarray           # rib 0's marker
    x_axis: np.ndarray              # unit vector, base marker -> rib 0
    first_rib_index: int            # which of the candidate points is rib 0

    def to_base(self, points_mm: np.ndarray) -> np.ndarray:
        """Plane points (N, 2) -> base-frame points (N, 2) (mm)."""
        d = np.asarray(points_mm, dtype=float) - self.origin_mm
        x = self.x_axis
        return np.column_stack([d @ x, d @ np.array([-x[1], x[0]])])

    def to_plane(self, base_mm: np.ndarray) -> np.ndarray:
        """Base-frame points (N, 2) -> plane points (mm)."""
        b = np.asarray(base_mm, dtype=float).reshape(-1, 2)
        x = self.x_axis
        y = np.array([-x[1], x[0]])
        return self.origin_mm + b[:, :1] * x + b[:, 1:] * y


def base_frame(anchor_mm, rib_points_mm: np.ndarray, distance_mm: float, tolerance_mm: float,
               axis_hint=None, max_hint_deg: float = 25.0) -> BaseFrame:
    """The base frame from the base marker (or tag centre) ``anchor_mm`` and rib markers.

    Rib 0 is the rib marker nearest the anchor; it must be ``distance_mm`` away within
    ``tolerance_mm``, and be the only one there. ``axis_hint`` (a unit vector, e.g. a tag's
    x-axis) restricts rib 0 to within ``max_hint_deg`` of that direction.
    """
    pts = np.asarray(rib_points_mm, dtype=float).reshape(-1, 2)
    anchor = np.asarray(anchor_mm, dtype=float)
    if pts.shape[0] == 0:
        raise FrameError('no rib marker seen')
    d = pts - anchor
    dist = np.hypot(d[:, 0], d[:, 1])
    ok = np.abs(dist - distance_mm) <= tolerance_mm
    if axis_hint is not None:
        hint = np.asarray(axis_hint, dtype=float)
        cosine = (d @ hint) / np.maximum(dist, 1e-9)
        ok &= cosine >= math.cos(math.radians(max_hint_deg))
    near = np.flatnonzero(ok)
    if near.size > 1:
        # A curled module can bring a later rib near the case; rib 0 sits on the rigid
        # base at the layout's distance, to within the measurement's accuracy.
        near = near[np.abs(dist[near] - distance_mm) <= FIRST_RIB_SURE_MM]
    if near.size == 0 and ok.any():
        raise FrameError(f'{int(ok.sum())} rib markers near the distance of rib 0 from the base '
                         'marker, none of them at it: which is rib 0 is ambiguous')
    if near.size == 0:
        nearest = float(dist.min())
        raise FrameError(f'rib 0 marker not found: the nearest rib marker is {nearest:.1f} mm '
                         f'from the base marker, expected {distance_mm:g} +- {tolerance_mm:g} mm '
                         '(rib 0 hidden?): the module frame is undefined')
    if near.size > 1:
        raise FrameError(f'{near.size} rib markers at the distance of rib 0 from the base '
                         'marker: which is rib 0 is ambiguous')
    i = int(near[0])
    return BaseFrame(origin_mm=pts[i].copy(), x_axis=d[i] / dist[i], first_rib_index=i)


@dataclass(frozen=True)
class RibOrder:
    """Result of :func:`order_ribs`."""

    point_index: tuple[int | None, ...]     # per rib: index into the candidate points, or None
    stopped: str                            # why the walk ended ('' when every rib was found)


def _windows(spacing_mm: float, max_angle_rad: float, contact_angle_rad: float, max_gap: int,
             tol_mm: float):
    """Per step k (1 = next rib): (min, max) chord distance (mm) over k segments."""
    out = []
    for k in range(1, max_gap + 2):
        a = max_angle_rad
        # k segments all bent by the largest angle the same way: the shortest chord
        # (while k a < pi; beyond, the shortest is taken as 0: no window is trusted).
        if k * a < math.pi:
            shortest = 2.0 * (spacing_mm / a) * math.sin(0.5 * k * a)
        else:
            shortest = 0.0
        if k == 1:
            # One segment: its angle is bounded by rib contact, not by the walk's setting.
            half = 0.5 * contact_angle_rad
            shortest = min(shortest, spacing_mm * math.sin(half) / half)
        out.append((shortest - tol_mm, k * spacing_mm + tol_mm))
    return out


def order_ribs(base_points_mm: np.ndarray, first_index: int, n_ribs: int, spacing_mm: float,
               contact_angle_rad: float, max_segment_angle_rad: float, max_gap: int,
               tolerance_mm: float, used=()) -> RibOrder:
    """Assign candidate points (base frame, mm) to ribs 0..n_ribs-1 by walking the spine.

    ``first_index`` is rib 0; ``used`` are candidate indices that belong elsewhere.
    """
    pts = np.asarray(base_points_mm, dtype=float).reshape(-1, 2)
    windows = _windows(spacing_mm, max_segment_angle_rad, contact_angle_rad, max_gap,
                       tolerance_mm)
    taken = set(used) | {first_index}
    order: list[int | None] = [first_index] + [None] * (n_ribs - 1)
    rib, position, heading = 0, pts[first_index], 0.0
    first = True
    while rib < n_ribs - 1:
        free = np.array([j for j in range(len(pts)) if j not in taken], dtype=int)
        if free.size == 0:
            return RibOrder(tuple(order), 'no more rib markers')
        d = pts[free] - position
        dist = np.hypot(d[:, 0], d[:, 1])
        turn = np.abs((np.arctan2(d[:, 1], d[:, 0]) - heading + math.pi) % (2 * math.pi) - math.pi)
        fits = []   # per candidate: the steps k whose window it fits
        for j in range(free.size):
            ks = []
            for k, (lo, hi) in enumerate(windows, start=1):
                if rib + k > n_ribs - 1:
                    break
                # chord of k segments turns by at most (k - 1/2) contact angles from the
                # previous chord (from the x-axis, which is rib 0's tangent, at the start)
                limit = ((k - 0.5) if first else k) * contact_angle_rad + TURN_MARGIN_RAD
                if lo <= dist[j] <= hi and turn[j] <= limit + 1e-9:
                    ks.append(k)
            fits.append(ks)
        steps = [min(ks) for ks in fits if ks and min(ks) <= max_gap + 1]
        if not steps:
            return RibOrder(tuple(order), f'no rib marker after rib {rib}')
        k = min(steps)
        if k > max_gap + 1:
            return RibOrder(tuple(order), f'more than {max_gap} hidden ribs after rib {rib}')
        chosen = [j for j, ks in enumerate(fits) if ks and min(ks) == k]
        if len(chosen) > 1:
            return RibOrder(tuple(order), f'{len(chosen)} candidates for rib {rib + k}: ambiguous')
        j = chosen[0]
        lo1, hi1 = windows[0]
        if k > 1 and np.any((dist >= lo1) & (dist <= hi1)):
            # a marker one rib away that turns too far: a gap here would be a guess
            return RibOrder(tuple(order), f'a marker one rib after rib {rib} turns more than '
                            'rib contact allows: ambiguous')
        if len(fits[j]) > 1:
            return RibOrder(tuple(order), f'the marker after rib {rib} could be rib '
                            + ' or '.join(str(rib + q) for q in fits[j]) + ': ambiguous')
        index = int(free[j])
        order[rib + k] = index
        taken.add(index)
        heading = math.atan2(d[j, 1], d[j, 0])
        position = pts[index]
        rib += k
        first = False
    return RibOrder(tuple(order), '')
