"""Skeleton description of a SoftSnap module and threading conversion (pure Python/numpy).

A :class:`Skeleton` is immutable and hashable, so solvers may memoise per-skeleton data.
Every public entry point that takes a threading goes through
:meth:`Skeleton.threading_mm`, the single input-conversion helper.
"""
from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

__all__ = ['Skeleton', 'DEFAULT_HOLES_MM', 'DEFAULT_RIB_THICKNESS_MM', 'contact_angle']

#: Hole offsets of the authors' module (mm, positive = right of the spine), FACTS.md.
DEFAULT_HOLES_MM: Mapping[str, float] = MappingProxyType({
    'L0': -0.5, 'L1': -3.0, 'L2': -6.5, 'L3': -10.0,
    'R0': 0.5, 'R1': 3.0, 'R2': 6.5, 'R3': 10.0,
})

#: Rib thickness along the spine (mm) in the authors' CAD (``Passive skeleton.stl``:
#: 3.0 mm ribs at an 18 mm pitch, total length 201 mm = 11 x 18 + 3; FACTS.md).
DEFAULT_RIB_THICKNESS_MM = 3.0

# Offsets closer than this (mm) are the same hole when mapping offsets back to names.
_HOLE_MATCH_TOL_MM = 1e-9


def _finite_positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f'{name} must be a real number, got {value!r}')
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f'{name} must be finite and > 0, got {value!r}')
    return value


@dataclass(frozen=True)
class Skeleton:
    """Geometry and stiffness of one module.

    Parameters
    ----------
    n_ribs : int
        Number of ribs (>= 2); there are ``n_ribs - 1`` bending segments.
    spacing_mm : float
        Spine arc length between adjacent ribs (mm).
    rib_length_mm : float
        Rib length (mm); every hole must lie on the rib, ``|d| <= rib_length_mm / 2``.
    holes_mm : mapping of str to float
        Named hole offsets (mm, positive to the right of the spine).
    stiffness : sequence of float, optional
        Relative bending stiffness ``k_i`` per segment (energy ``sum k_i a_i^2``).
        None means all equal to 1, the paper's model.
    rib_thickness_mm : float
        Thickness of each rib along the spine (mm), ``0 <= t < spacing_mm``. The
        default 3.0 mm is the authors' CAD (``Passive skeleton.stl``: 3.0 mm ribs at an
        18 mm pitch, 201 mm = 11 x 18 + 3). It only sets the rib-contact angle
        (:attr:`contact_angle_rad`); ``rib_thickness_mm=0`` is the paper's idealised
        model (thin ribs).

    Examples
    --------
    >>> sk = Skeleton()
    >>> sk.n_segments, sk.straight_length_mm(['R3'] * 12)
    (11, 198.0)
    >>> round(sk.contact_angle_rad, 4), Skeleton(rib_thickness_mm=0).contact_angle_rad
    (1.2311, 1.44)
    """

    n_ribs: int = 12
    spacing_mm: float = 18.0
    rib_length_mm: float = 25.0
    holes_mm: Mapping[str, float] = field(default_factory=lambda: DEFAULT_HOLES_MM)
    stiffness: tuple[float, ...] | None = None
    rib_thickness_mm: float = DEFAULT_RIB_THICKNESS_MM

    def __post_init__(self):
        n = self.n_ribs
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 2:
            raise ValueError(f'n_ribs must be an integer >= 2, got {n!r}')
        object.__setattr__(self, 'n_ribs', int(n))
        object.__setattr__(self, 'spacing_mm', _finite_positive('spacing_mm', self.spacing_mm))
        object.__setattr__(self, 'rib_length_mm',
                           _finite_positive('rib_length_mm', self.rib_length_mm))
        t = self.rib_thickness_mm
        if isinstance(t, bool) or not isinstance(t, numbers.Real) or not math.isfinite(t) \
                or not 0.0 <= t < self.spacing_mm:
            raise ValueError(f'rib_thickness_mm must be a finite number in '
                             f'[0, spacing_mm = {self.spacing_mm}) mm, got {t!r}')
        object.__setattr__(self, 'rib_thickness_mm', float(t))
        if not isinstance(self.holes_mm, Mapping) or len(self.holes_mm) == 0:
            raise ValueError(f'holes_mm must be a non-empty mapping name -> offset mm, '
                             f'got {self.holes_mm!r}')
        half = 0.5 * self.rib_length_mm
        holes = {}
        for name, offset in self.holes_mm.items():
            if not isinstance(name, str) or not name:
                raise ValueError(f'hole names must be non-empty strings, got {name!r}')
            if isinstance(offset, bool) or not isinstance(offset, numbers.Real) \
                    or not math.isfinite(offset):
                raise ValueError(f'hole {name!r}: offset must be a finite number, '
                                 f'got {offset!r}')
            if abs(offset) > half:
                raise ValueError(f'hole {name!r}: offset {offset!r} mm is off the rib; '
                                 f'allowed [-{half}, {half}] mm')
            holes[name] = float(offset)
        object.__setattr__(self, 'holes_mm', MappingProxyType(holes))
        if self.stiffness is not None:
            try:
                k = np.asarray(self.stiffness, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ValueError(f'stiffness must be numbers, got {self.stiffness!r}') from exc
            if k.shape != (self.n_segments,):
                raise ValueError(f'expected {self.n_segments} stiffness values (one per '
                                 f'segment), got shape {k.shape}')
            if not np.all(np.isfinite(k)) or np.any(k <= 0.0):
                raise ValueError(f'stiffness must be finite and > 0, got {k.tolist()}')
            object.__setattr__(self, 'stiffness', tuple(float(v) for v in k))

    def __hash__(self):
        return hash((self.n_ribs, self.spacing_mm, self.rib_length_mm,
                     tuple(self.holes_mm.items()), self.stiffness, self.rib_thickness_mm))

    def __eq__(self, other):
        if not isinstance(other, Skeleton):
            return NotImplemented
        return (self.n_ribs, self.spacing_mm, self.rib_length_mm, dict(self.holes_mm),
                self.stiffness, self.rib_thickness_mm) == (
                    other.n_ribs, other.spacing_mm, other.rib_length_mm,
                    dict(other.holes_mm), other.stiffness, other.rib_thickness_mm)

    # -- derived quantities -------------------------------------------------------------
    @property
    def n_segments(self) -> int:
        """Number of bending segments, ``n_ribs - 1``."""
        return self.n_ribs - 1

    @property
    def stiffness_array(self) -> np.ndarray:
        """Per-segment stiffness ``k_i`` as a new float array of shape (n_segments,)."""
        if self.stiffness is None:
            return np.ones(self.n_segments)
        return np.array(self.stiffness, dtype=float)

    @property
    def contact_angle_rad(self) -> float:
        """Largest bending angle magnitude (rad) of one segment before the ribs touch.

        See :func:`contact_angle`: 1.2311 rad for the authors' 3.0 mm ribs,
        ``2 s / rib_length`` = 1.44 rad for thin ribs (``rib_thickness_mm=0``).
        """
        return contact_angle(self.spacing_mm, self.rib_length_mm, self.rib_thickness_mm)

    # -- threading conversion -------------------------------------------------------------
    def threading_mm(self, threading) -> np.ndarray:
        """Convert a threading (hole names and/or offsets in mm) to offsets in mm.

        Parameters
        ----------
        threading : sequence of str or float, length n_ribs
            One hole per rib, rib 0 first: a name from ``holes_mm`` or an offset in mm.

        Returns
        -------
        ndarray, shape (n_ribs,)

        Raises
        ------
        ValueError
            Wrong length, unknown hole name, non-finite or off-rib offset.

        Examples
        --------
        >>> Skeleton().threading_mm(['R3'] * 6 + ['L3'] * 6)[[0, -1]].tolist()
        [10.0, -10.0]
        """
        if isinstance(threading, str):
            threading = threading.split()
        if isinstance(threading, np.ndarray):
            if threading.ndim != 1:
                raise ValueError(f'expected a 1-D threading of {self.n_ribs} holes, '
                                 f'got shape {threading.shape}')
            if threading.dtype.kind in 'fiu':
                out = threading.astype(float)
                if out.shape[0] != self.n_ribs:
                    raise ValueError(f'expected {self.n_ribs} holes, got {out.shape[0]}')
                self._check_offsets(out)
                return out
        try:
            items = list(threading)
        except TypeError:
            raise ValueError(f'threading must be a sequence of hole names or offsets, '
                             f'got {threading!r}') from None
        if len(items) != self.n_ribs:
            raise ValueError(f'expected {self.n_ribs} holes, got {len(items)}')
        out = np.empty(self.n_ribs)
        for i, item in enumerate(items):
            if isinstance(item, str):
                try:
                    out[i] = self.holes_mm[item]
                except KeyError:
                    known = ', '.join(self.holes_mm)
                    raise ValueError(f'unknown hole {item!r} on rib {i}; known: {known}') \
                        from None
            elif isinstance(item, numbers.Real) and not isinstance(item, bool):
                out[i] = float(item)
            else:
                raise ValueError(f'rib {i}: expected a hole name or an offset in mm, '
                                 f'got {item!r}')
        self._check_offsets(out)
        return out

    def _check_offsets(self, offsets: np.ndarray) -> None:
        bad = ~np.isfinite(offsets)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f'rib {i}: hole offset must be finite, got {offsets[i]!r}')
        half = 0.5 * self.rib_length_mm
        off = np.abs(offsets) > half
        if off.any():
            i = int(np.argmax(off))
            raise ValueError(f'rib {i}: hole offset {offsets[i]!r} mm is off the rib; '
                             f'allowed [-{half}, {half}] mm')

    def hole_names(self, threading_mm) -> list:
        """Map offsets (mm) back to hole names; None where no named hole matches."""
        names = list(self.holes_mm)
        values = np.array([self.holes_mm[n] for n in names])
        out = []
        for d in np.asarray(threading_mm, dtype=float).ravel():
            j = int(np.argmin(np.abs(values - d)))
            out.append(names[j] if abs(values[j] - d) <= _HOLE_MATCH_TOL_MM else None)
        return out

    def straight_length_mm(self, threading) -> float:
        """Cable length (mm) of the straight module: ``sum sqrt(s^2 + (d_{i+1}-d_i)^2)``."""
        d = self.threading_mm(threading)
        return float(np.sum(np.hypot(self.spacing_mm, np.diff(d))))

    # -- serialisation ----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> 'Skeleton':
        """Build from a mapping with keys among the constructor arguments (validated).

        Unknown keys are an error, so a misspelt key is never silently ignored.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f'skeleton description must be a mapping, got {type(data).__name__}')
        allowed = {'n_ribs', 'spacing_mm', 'rib_length_mm', 'holes_mm', 'stiffness',
                   'rib_thickness_mm'}
        unknown = set(data) - allowed
        if unknown:
            raise ValueError(f'unknown skeleton keys {sorted(unknown)}; '
                             f'allowed: {sorted(allowed)}')
        kwargs = dict(data)
        if kwargs.get('stiffness') is not None and not isinstance(kwargs['stiffness'],
                                                                   (list, tuple)):
            raise ValueError(f'stiffness must be a list, got {kwargs["stiffness"]!r}')
        return cls(**kwargs)

    @classmethod
    def from_yaml(cls, path) -> 'Skeleton':
        """Load from a YAML file; the skeleton may sit under a top-level ``skeleton`` key."""
        import yaml
        text = Path(path).read_text()
        data = yaml.safe_load(text)
        if isinstance(data, Mapping) and set(data) == {'skeleton'}:
            data = data['skeleton']
        return cls.from_dict(data if data is not None else {})

    def to_dict(self) -> dict:
        """Plain-data form accepted by :meth:`from_dict`."""
        return {'n_ribs': self.n_ribs, 'spacing_mm': self.spacing_mm,
                'rib_length_mm': self.rib_length_mm, 'holes_mm': dict(self.holes_mm),
                'stiffness': None if self.stiffness is None else list(self.stiffness),
                'rib_thickness_mm': self.rib_thickness_mm}


@functools.lru_cache(maxsize=64)
def contact_angle(spacing_mm: float, rib_length_mm: float, rib_thickness_mm: float) -> float:
    """Bending angle magnitude (rad) at which the inner edges of two adjacent ribs meet.

    Geometry (the paper's Figure S1, FACTS.md): the spine between two rib centre lines
    is an arc of length ``s`` and radius ``R = s/|a|``, each rib's centre line is normal
    to it, and a rib is a rigid slab of thickness ``t`` along the spine (faces at
    ``+-t/2`` from its centre line) and length ``l`` across it. The two facing faces are
    the centre lines, each moved ``t/2`` towards the other; they converge towards the
    centre of curvature and, by the mirror symmetry about the bisector of the two
    centre lines, the inner corners (at ``l/2`` on the concave side) touch first, on the
    bisector, when::

        R - l/2 = (t/2) cot(|a|/2),   i.e.   s - (t/2) |a| cot(|a|/2) = (l/2) |a|

    For ``t = 0`` this is ``|a| = 2 s / l`` (1.44 rad for the authors' module: thin ribs
    meet at the centre of curvature). To first order ``|a| cot(|a|/2) = 2``, giving
    ``|a| = (s - t) / (l/2)`` (1.20 rad for 3.0 mm ribs): that value is exact only if
    the spine inside each rib stayed straight and the free part ``s - t`` alone bent,
    which is not the model's kinematics; within the model's own geometry the drawn
    ribs touch at the root of the equation above, 1.2311 rad (the first-order value
    leaves a 0.35 mm gap between the drawn inner corners). The result is capped at pi.

    Parameters
    ----------
    spacing_mm, rib_length_mm : float
        Spine arc length ``s`` between rib centre lines and rib length ``l`` (mm, > 0).
    rib_thickness_mm : float
        Rib thickness ``t`` along the spine (mm), ``0 <= t < s``.

    Examples
    --------
    >>> contact_angle(18.0, 25.0, 0.0)
    1.44
    >>> round(contact_angle(18.0, 25.0, 3.0), 6)
    1.231107
    """
    s, half, t = float(spacing_mm), 0.5 * float(rib_length_mm), float(rib_thickness_mm)
    if not (s > 0.0 and half > 0.0 and 0.0 <= t < s):
        raise ValueError(f'contact_angle needs spacing_mm > 0, rib_length_mm > 0 and '
                         f'0 <= rib_thickness_mm < spacing_mm; got {s!r}, {2 * half!r}, {t!r}')
    if t == 0.0:
        return min(s / half, math.pi)     # exactly the idealised value, no root finding

    def gap(a):
        # s - (t/2) a cot(a/2) - (l/2) a; finite on (0, pi] (cot(pi/2) = 0).
        x = 0.5 * a
        return s - t * x * math.cos(x) / math.sin(x) - half * a

    if gap(math.pi) >= 0.0:
        return math.pi
    # gap(0+) = s - t > 0: bracket the first sign change on a fine grid, then bisect to
    # rounding (64 halvings of a bracket shorter than pi/256).
    lo = hi = 0.0
    for j in range(1, 257):
        hi = math.pi * j / 256
        if gap(hi) < 0.0:
            break
        lo = hi
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if gap(mid) >= 0.0:
            lo = mid
        else:
            hi = mid
    return lo
