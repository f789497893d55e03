"""Driver core without ROS: cable length <-> encoder count, clamping, reboot detection.

Encoder convention: the module is calibrated at straight, so count 0 is the straight
cable length; with ``count_sign = +1`` positive counts shorten the cable (contract the
module)::

    contraction_mm = count_sign * count / counts_per_mm
    cable_length_m = straight_length_m - contraction_mm / 1000

Commands within ``clamp_margin_m`` of the allowed contraction range ``[min_contraction_m,
max_contraction_m]`` are clamped to it *in counts*, rounding towards the inside of the
range, so the target sent to the module can never lie outside it, whatever the rounding.
Non-physical commands are refused (ValueError), never clamped: a length <= 0, NaN or
infinite, or further than ``clamp_margin_m`` outside the range (a default-constructed
message holds 0.0 m: clamping it would drive the module to full contraction).

Examples
--------
>>> cal = CableCalibration(counts_per_mm=100.0, straight_length_m=0.2, max_contraction_m=0.08)
>>> cal.command(0.19)
TargetCommand(requested_length_m=0.19, length_m=0.19, count=1000, clamped=False)
>>> cal.command(0.118).count, cal.command(0.118).clamped
(8000, True)
>>> cal.command(0.0)
Traceback (most recent call last):
ValueError: cable length must be > 0 m, got 0.0
>>> round(cal.length_m(500), 6)
0.195
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

#: A command counts as clamped only when it lies outside the allowed cable-length range
#: by more than this (m): 1 nm, far below one encoder count, above float rounding.
RANGE_TOL_M = 1e-9

#: Default of :attr:`CableCalibration.clamp_margin_m` (m): commands at most this far
#: outside the allowed range are clamped (a planner's rounding, a slightly different
#: straight length); further out they are refused as non-physical.
DEFAULT_CLAMP_MARGIN_M = 0.005
#: Exit status of a driver process whose last stop was not confirmed (the module may
#: still move): a supervisor reports it as an error, never as a clean stop.
STOP_UNCONFIRMED_EXIT = 3


@dataclass(frozen=True)
class TargetCommand:
    """A cable-length command translated for the module.

    ``requested_length_m`` as received; ``length_m`` the length the count stands for
    (after clamping); ``count`` the encoder target; ``clamped`` whether the request was
    outside the allowed range.
    """

    requested_length_m: float
    length_m: float
    count: int
    clamped: bool


@dataclass(frozen=True)
class CableCalibration:
    """Geometry of one module's winch.

    Parameters
    ----------
    counts_per_mm : float
        Encoder counts per millimetre of cable wound (counts/mm), > 0.
    straight_length_m : float
        Cable length of the straight (calibrated) module, in metres (m), > 0.
    max_contraction_m : float
        Largest allowed contraction (straight length minus cable length), in metres.
    min_contraction_m : float
        Smallest allowed contraction, in metres (0: the straight module).
    count_sign : int
        +1 if positive counts shorten the cable, -1 if they lengthen it.
    clamp_margin_m : float
        Commands at most this far outside the allowed cable-length range are clamped to
        it, in metres (m), >= 0; further out they are refused.
    """

    counts_per_mm: float
    straight_length_m: float
    max_contraction_m: float
    min_contraction_m: float = 0.0
    count_sign: int = 1
    clamp_margin_m: float = DEFAULT_CLAMP_MARGIN_M

    def __post_init__(self):
        # bool is an int subclass: True would pass every check below as 1 (a 1 m
        # contraction, a +1 sign), so refuse it by name.
        for name in ('counts_per_mm', 'straight_length_m', 'max_contraction_m',
                     'min_contraction_m', 'clamp_margin_m'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f'{name} must be a number, got {value!r}')
        if not (math.isfinite(self.counts_per_mm) and self.counts_per_mm > 0):
            raise ValueError(f'counts_per_mm must be positive and finite, got {self.counts_per_mm!r}')
        if not (math.isfinite(self.straight_length_m) and self.straight_length_m > 0):
            raise ValueError(f'straight_length_m must be positive and finite, got {self.straight_length_m!r}')
        if not (math.isfinite(self.min_contraction_m) and self.min_contraction_m >= 0):
            raise ValueError(f'min_contraction_m must be >= 0, got {self.min_contraction_m!r}')
        if not (math.isfinite(self.max_contraction_m)
                and self.min_contraction_m <= self.max_contraction_m < self.straight_length_m):
            raise ValueError(
                f'max_contraction_m must be in [min_contraction_m={self.min_contraction_m}, '
                f'straight_length_m={self.straight_length_m}), got {self.max_contraction_m!r}')
        if not (math.isfinite(self.clamp_margin_m) and 0 <= self.clamp_margin_m <= 1.0):
            raise ValueError(f'clamp_margin_m must be in [0, 1] m, got {self.clamp_margin_m!r}')
        if type(self.count_sign) is not int or self.count_sign not in (1, -1):
            raise ValueError(f'count_sign must be +1 or -1, got {self.count_sign!r}')
        if self.count_range[0] > self.count_range[1]:
            raise ValueError(f'the contraction range [{self.min_contraction_m}, {self.max_contraction_m}] m '
                             f'holds no whole encoder count at {self.counts_per_mm} counts/mm')

    # Cached (the fields are frozen): read for every command the driver takes.
    @cached_property
    def count_range(self) -> tuple[int, int]:
        """Allowed encoder targets (lowest, highest), inclusive."""
        low = math.ceil(self.min_contraction_m * 1000.0 * self.counts_per_mm - 1e-9)
        high = math.floor(self.max_contraction_m * 1000.0 * self.counts_per_mm + 1e-9)
        if self.count_sign > 0:
            return low, high
        return -high, -low

    @cached_property
    def length_range_m(self) -> tuple[float, float]:
        """Allowed cable lengths (shortest, longest), in metres."""
        return (self.straight_length_m - self.max_contraction_m,
                self.straight_length_m - self.min_contraction_m)

    def length_m(self, count: int | float) -> float:
        """Cable length in metres for an encoder count."""
        return self.straight_length_m - self.count_sign * count / self.counts_per_mm / 1000.0

    def command(self, length_m: float) -> TargetCommand:
        """Translate a commanded cable length (m) to an encoder target, clamping near-range values.

        Raises ValueError, quoting the value and the accepted range, for a non-physical
        command: not a number, NaN, infinite, <= 0, or more than ``clamp_margin_m`` outside
        the allowed range.
        """
        if isinstance(length_m, bool) or not isinstance(length_m, (int, float)):
            raise ValueError(f'cable length must be a number in metres, got {length_m!r}')
        if not math.isfinite(length_m):
            raise ValueError(f'cable length must be finite, got {length_m!r}')
        if length_m <= 0:
            raise ValueError(f'cable length must be > 0 m, got {length_m!r}')
        shortest, longest = self.length_range_m
        margin = self.clamp_margin_m + RANGE_TOL_M
        if not shortest - margin <= length_m <= longest + margin:
            raise ValueError(
                f'cable length {length_m!r} m is more than clamp_margin_m={self.clamp_margin_m:g} m '
                f'outside the allowed range [{shortest:.6f}, {longest:.6f}] m')
        clamped = not (shortest - RANGE_TOL_M <= length_m <= longest + RANGE_TOL_M)
        bounded_m = min(max(float(length_m), shortest), longest)
        raw = self.count_sign * (self.straight_length_m - bounded_m) * 1000.0 * self.counts_per_mm
        low, high = self.count_range
        count = min(max(int(round(raw)), low), high)
        return TargetCommand(float(length_m), self.length_m(count), count, clamped)


def reboot_suspected(prev_count: int, prev_errors: int, count: int, errors: int, elapsed_s: float,
                     target_count: int | None, zero_band_counts: int, min_jump_counts: int,
                     max_speed_counts_per_s: float) -> str | None:
    """Decide whether two consecutive status replies show a module reboot.

    A reboot resets the firmware's encoder count (to 0) and its error counter. Signs:

    - the error counter went down (it only counts up while the module runs), or
    - the count is back within ``zero_band_counts`` of 0 although the last known count
      was at least ``min_jump_counts`` away, and either the module was not being driven
      towards 0 (its target is far from 0) or the jump is faster than the motor can move
      (``max_speed_counts_per_s`` over ``elapsed_s``).

    Returns a description of the evidence, or None.

    Examples
    --------
    >>> reboot_suspected(3000, 0, 0, 0, 0.1, 3000, 60, 300, 20000.0)
    'encoder count fell from 3000 to 0 while the target was 3000'
    >>> reboot_suspected(3000, 0, 20, 0, 1.0, 0, 60, 300, 20000.0) is None
    True
    """
    if errors < prev_errors:
        return f'encoder error counter fell from {prev_errors} to {errors}'
    if abs(count) > zero_band_counts or abs(prev_count) < min_jump_counts:
        return None
    if target_count is None or abs(target_count) > zero_band_counts:
        return (f'encoder count fell from {prev_count} to {count} while the target was '
                f'{target_count if target_count is not None else "unknown"}')
    if abs(prev_count - count) > max_speed_counts_per_s * max(elapsed_s, 0.0):
        return (f'encoder count fell from {prev_count} to {count} in {elapsed_s:.3f} s, '
                f'faster than {max_speed_counts_per_s:.0f} counts/s')
    return None
