"""Parameterised gait families: a point of the unit cube <-> a gait spec of a scene.

Pure numpy, no ROS, no MuJoCo. The optimiser (:mod:`softsnap_gaits.gait_search`) searches
the unit cube ``[0, 1]^d``; a family decodes each point into an ordinary ``pulse`` gait
spec (docs/gaits.md), so a winner is a plain scene gait that ``gait_node`` and the demo
play with no new code. Two families:

* ``pulse`` (alias ``walk``): every module its own phase (fraction of the period) and
  amplitude (mm), plus a common period, duty and rise time: ``2 n + 3`` numbers.
* ``wave`` (alias ``concertina``): the modules of a chain start one after another, a common
  ``lag`` of the period apart (head first; the lag may be negative, a wave running tail
  first), each with its own amplitude, plus period, duty and rise time: ``n + 4`` numbers.

The rise time is decoded as a fraction between two bounds: the shortest ramp the winches
can follow at the decoded amplitude (the gait library's speed rule, ``a * pi / (2 r)``
within ``WINCH_SPEED_MARGIN`` of ``winch_speed_mm_s``) and the longest the duty allows
(``min(duty, 1 - duty) * period``). When even the longest ramp is too fast for the
amplitude, the amplitudes are scaled down to fit and :attr:`DecodedGait.speed_excess`
says by how much (the objective penalises it), so every decoded spec is a gait
``make_gait`` accepts: the search never wastes a rollout on a refused gait.

Examples
--------
>>> from softsnap_model.scene import load_scene
>>> scene = load_scene('brittle_star')
>>> family = gait_family('walk', scene)
>>> family.dimension, family.names[:3]
(13, ('period_s', 'duty', 'rise'))
>>> decoded = family.decode([0.5] * family.dimension)
>>> decoded.spec['type'], decoded.speed_excess
('pulse', 0.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .gaits import MIN_PERIOD_S, WINCH_SPEED_MARGIN

__all__ = ['GaitFamily', 'DecodedGait', 'FAMILIES', 'FAMILY_ALIASES', 'gait_family',
           'FamilyBounds']


@dataclass(frozen=True)
class FamilyBounds:
    """Ranges the unit cube maps onto (linear in each)."""

    period_s: tuple[float, float] = (1.0, 4.0)
    duty: tuple[float, float] = (0.2, 0.8)
    amplitude_mm: tuple[float, float] = (0.0, 60.0)
    lag: tuple[float, float] = (-0.25, 0.25)


@dataclass(frozen=True)
class DecodedGait:
    """A point of the family's cube as a gait spec.

    Attributes
    ----------
    spec : dict
        A ``pulse`` gait spec (YAML-ready: floats rounded to 0.1 ms / 1 um / 1e-4 of a
        period, so the file and the rollout play the same numbers).
    speed_excess : float
        0 if the decoded amplitudes fit the winches; otherwise the factor (minus 1) by
        which they were scaled down to fit (the objective's penalty).
    """

    spec: dict
    speed_excess: float


def _lerp(u: float, bounds: tuple[float, float]) -> float:
    return float(bounds[0] + (bounds[1] - bounds[0]) * float(u))


class GaitFamily:
    """A family of pulse gaits for one scene (see the module docstring).

    Parameters
    ----------
    kind : str
        ``'pulse'`` or ``'wave'``.
    scene : softsnap_model.scene.Scene
    bounds : FamilyBounds, optional
    order : sequence of str, optional
        Module order of a wave (default: the scene's order, which is head first for the
        snake).
    """

    def __init__(self, kind: str, scene, bounds: FamilyBounds | None = None,
                 order: Sequence[str] | None = None):
        if kind not in FAMILIES:
            raise ValueError(f'unknown gait family {kind!r}; known: '
                             f'{", ".join(sorted(FAMILIES) + sorted(FAMILY_ALIASES))}')
        self.kind = kind
        self.scene = scene
        self.bounds = bounds or FamilyBounds()
        self.modules = tuple(order) if order is not None else tuple(scene.module_names)
        unknown = [m for m in self.modules if m not in scene.module_names]
        if unknown:
            raise ValueError(f'modules {unknown} are not in scene {scene.name!r}')
        speed = [WINCH_SPEED_MARGIN * scene.module(m).winch_speed_mm_s for m in self.modules]
        #: Cable speed each module may be commanded (mm/s), the gait library's rule.
        self.speed_limit_mm_s = float(min(speed))
        # Stay within the scene's own contraction limit (reachability is checked by
        # make_gait when the spec is built; 60 mm is below every paper threading's reach).
        top = min(scene.module(m).max_contraction_mm for m in self.modules)
        lo, hi = self.bounds.amplitude_mm
        self._amplitude_bounds = (lo, min(hi, top))

    @property
    def names(self) -> tuple[str, ...]:
        """Name of each coordinate of the cube."""
        head = ('period_s', 'duty', 'rise')
        amps = tuple(f'amplitude_mm.{m}' for m in self.modules)
        if self.kind == 'pulse':
            return head + tuple(f'phase.{m}' for m in self.modules) + amps
        return head + ('lag',) + amps

    @property
    def dimension(self) -> int:
        return len(self.names)

    def decode(self, x) -> DecodedGait:
        """The gait spec at point `x` of the unit cube (values outside are clipped)."""
        x = np.clip(np.asarray(x, dtype=float).ravel(), 0.0, 1.0)
        if x.size != self.dimension:
            raise ValueError(f'a {self.kind} point for {len(self.modules)} modules has '
                             f'{self.dimension} coordinates, got {x.size}')
        b = self.bounds
        period = round(max(MIN_PERIOD_S, _lerp(x[0], b.period_s)), 4)
        duty = round(_lerp(x[1], b.duty), 4)
        n = len(self.modules)
        if self.kind == 'pulse':
            phases = [round(float(p) % 1.0, 4) for p in x[3:3 + n]]
            amps = x[3 + n:3 + 2 * n]
        else:
            lag = _lerp(x[3], b.lag)
            phases = [round((k * lag) % 1.0, 4) for k in range(n)]
            amps = x[4:4 + n]
        amps = np.array([_lerp(a, self._amplitude_bounds) for a in amps])
        rise_max = min(duty, 1.0 - duty) * period
        peak = float(amps.max(initial=0.0))
        rise_min = peak * math.pi / (2.0 * self.speed_limit_mm_s)
        excess = 0.0
        if rise_min > rise_max:
            # Even the slowest ramp the duty allows is too fast: shrink the amplitudes.
            factor = rise_max / rise_min
            excess = 1.0 / factor - 1.0
            amps = amps * factor
            rise_min = rise_max
        rise = float(rise_min + (rise_max - rise_min) * float(x[2]))
        # Rounded so the YAML holds exactly what was scored; the rise time is rounded
        # up and the amplitude down (a gait exactly at the winch limit stays within it).
        rise = min(math.ceil(rise * 1e4) / 1e4, math.floor(rise_max * 1e4) / 1e4)
        amps = [math.floor(float(a) * 1e3) / 1e3 for a in amps]
        limit_amp = rise * 2.0 * self.speed_limit_mm_s / math.pi
        amps = [min(a, math.floor(limit_amp * 1e3) / 1e3) for a in amps]
        spec: dict[str, Any] = {
            'type': 'pulse', 'period_s': period,
            'phases': {m: p for m, p in zip(self.modules, phases)},
            'duty': duty, 'amplitude_mm': {m: a for m, a in zip(self.modules, amps)},
            'rise_time_s': rise}
        return DecodedGait(spec=spec, speed_excess=float(excess))

    def encode_hint(self, spec: Mapping) -> np.ndarray:
        """A cube point near a ``pulse``-like spec (a start point for the search).

        Reads ``period_s``, ``duty``, ``rise_time_s``, per-module ``phases`` (pulse) and
        ``amplitude_mm``; missing values take the middle of their range.
        """
        b = self.bounds
        inv = (lambda v, r: float(np.clip((v - r[0]) / (r[1] - r[0]), 0.0, 1.0)))
        period = float(spec.get('period_s', _lerp(0.5, b.period_s)))
        duty = float(spec.get('duty', _lerp(0.5, b.duty)))
        amp = spec.get('amplitude_mm', _lerp(0.5, self._amplitude_bounds))
        amps = {m: float(amp[m] if isinstance(amp, Mapping) else amp) for m in self.modules}
        rise_max = min(duty, 1.0 - duty) * period
        rise_min = max(amps.values()) * math.pi / (2.0 * self.speed_limit_mm_s)
        rise = float(spec.get('rise_time_s', 0.5 * (rise_min + rise_max)))
        u_rise = (rise - rise_min) / (rise_max - rise_min) if rise_max > rise_min else 0.5
        head = [inv(period, b.period_s), inv(duty, b.duty), float(np.clip(u_rise, 0, 1))]
        amp_u = [inv(amps[m], self._amplitude_bounds) for m in self.modules]
        if self.kind == 'pulse':
            phases = spec.get('phases', {})
            return np.array(head + [float(phases.get(m, 0.0)) for m in self.modules] + amp_u)
        return np.array(head + [inv(float(spec.get('lag', 0.0)), b.lag)] + amp_u)


#: Family kinds.
FAMILIES = ('pulse', 'wave')
#: Names the command line also accepts, after the paper's gaits.
FAMILY_ALIASES: Mapping[str, str] = {'walk': 'pulse', 'concertina': 'wave'}


def gait_family(name: str, scene, **kwargs) -> GaitFamily:
    """The family `name` (``pulse``, ``wave`` or an alias) for `scene`."""
    return GaitFamily(FAMILY_ALIASES.get(name, name), scene, **kwargs)
