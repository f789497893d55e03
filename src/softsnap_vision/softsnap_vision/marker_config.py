"""Marker colours, sizes and layout (YAML, validated), with the paper's markers as defaults.

A marker file (all keys optional; docs/vision.md shows the layout to print)::

    rib_marker:               # one per rib, at the intersection of the rib and the middle rod
      color_rgb: [255, 64, 160]     # sRGB of the printed marker (the paper's pink)
      diameter_mm: 6.0
    base_marker:              # on the module's axis behind rib 0, on the case
      color_rgb: [255, 128, 0]      # the paper's orange
      diameter_mm: 6.0
      distance_to_first_rib_mm: 30.0
    tag:                      # marker_tracker: one ArUco tag per module instead of the orange
      dictionary: DICT_4X4_50
      size_mm: 20.0                 # black square edge
      distance_to_first_rib_mm: 35.0  # tag centre to rib 0, on the module's axis
    hue_tolerance_deg: 18.0   # hue window around each marker colour
    min_saturation: 0.35      # HSV saturation (0-1) a marker pixel needs
    min_value: 0.12           # HSV value (0-1): darker pixels have no reliable hue
    distance_tolerance_mm: 1.5        # rib-to-rib distance slack when ordering the ribs
    max_segment_angle_deg: 50.0       # largest bending between two ribs the ordering expects
    max_gap: 2                # ordering steps over at most this many hidden ribs in a row

Hue, saturation and value are used instead of RGB because a marker's hue and saturation
hardly change under uneven lighting, while its brightness does.
"""
from __future__ import annotations

import colorsys
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

__all__ = ['MarkerSpec', 'TagSpec', 'MarkerConfig', 'MarkerConfigError', 'load_marker_config',
           'PAPER_PINK_RGB', 'PAPER_ORANGE_RGB', 'ARUCO_DICTIONARIES']

#: The paper's marker colours as we print them (FACTS.md, camera measurement).
PAPER_PINK_RGB = (255, 64, 160)
PAPER_ORANGE_RGB = (255, 128, 0)
#: ArUco dictionaries a tag may come from (OpenCV names).
ARUCO_DICTIONARIES = ('DICT_4X4_50', 'DICT_4X4_100', 'DICT_5X5_50', 'DICT_5X5_100',
                      'DICT_6X6_50', 'DICT_APRILTAG_16h5', 'DICT_APRILTAG_36h11')


class MarkerConfigError(ValueError):
    """A marker file is missing or breaks a rule; the message names the key and the value."""


@dataclass(frozen=True)
class MarkerSpec:
    """One kind of round colour marker."""

    color_rgb: tuple[int, int, int]
    diameter_mm: float = 6.0
    distance_to_first_rib_mm: float = 0.0   # base marker only

    @property
    def hue_deg(self) -> float:
        r, g, b = (c / 255.0 for c in self.color_rgb)
        return colorsys.rgb_to_hsv(r, g, b)[0] * 360.0

    @property
    def area_mm2(self) -> float:
        return math.pi * (0.5 * self.diameter_mm) ** 2


@dataclass(frozen=True)
class TagSpec:
    """The per-module ArUco tag the marker tracker identifies modules by."""

    dictionary: str = 'DICT_4X4_50'
    size_mm: float = 20.0
    distance_to_first_rib_mm: float = 35.0


@dataclass(frozen=True)
class MarkerConfig:
    """Everything the detector needs to know about the markers (see the module docstring)."""

    rib_marker: MarkerSpec = MarkerSpec(PAPER_PINK_RGB)
    base_marker: MarkerSpec = MarkerSpec(PAPER_ORANGE_RGB, distance_to_first_rib_mm=30.0)
    tag: TagSpec = field(default_factory=TagSpec)
    hue_tolerance_deg: float = 18.0
    min_saturation: float = 0.35
    min_value: float = 0.12
    distance_tolerance_mm: float = 1.5
    max_segment_angle_deg: float = 50.0
    max_gap: int = 2


def _number(value: Any, key: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not low <= value <= high:
        raise MarkerConfigError(f'{key} must be a number in [{low:g}, {high:g}], got {value!r}')
    return float(value)


def _rgb(value: Any, key: str) -> tuple[int, int, int]:
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255
                       for c in value)):
        raise MarkerConfigError(f'{key} must be three integers 0-255 (sRGB), got {value!r}')
    r, g, b = (c / 255.0 for c in value)
    if colorsys.rgb_to_hsv(r, g, b)[1] < 0.4:
        raise MarkerConfigError(f'{key} {list(value)} is too grey to be told from the table by '
                                'its hue (HSV saturation below 0.4): print a saturated colour')
    return tuple(value)


def _keys(value: Any, key: str, allowed: set[str]) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise MarkerConfigError(f'{key} must be a mapping, got {value!r}')
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise MarkerConfigError(f'{key}: unknown key {unknown[0]!r} '
                                f'(known: {", ".join(sorted(allowed))})')
    return value


def _marker(value: Any, key: str, default: MarkerSpec, base: bool) -> MarkerSpec:
    allowed = {'color_rgb', 'diameter_mm'} | ({'distance_to_first_rib_mm'} if base else set())
    raw = _keys(value, key, allowed)
    spec = default
    if 'color_rgb' in raw:
        spec = replace(spec, color_rgb=_rgb(raw['color_rgb'], f'{key}.color_rgb'))
    if 'diameter_mm' in raw:
        spec = replace(spec, diameter_mm=_number(raw['diameter_mm'], f'{key}.diameter_mm', 1.0, 50.0))
    if 'distance_to_first_rib_mm' in raw:
        spec = replace(spec, distance_to_first_rib_mm=_number(
            raw['distance_to_first_rib_mm'], f'{key}.distance_to_first_rib_mm', 5.0, 200.0))
    return spec


def config_from_dict(data: Any, where: str = 'markers') -> MarkerConfig:
    """A MarkerConfig from parsed YAML (defaults for what is absent); MarkerConfigError if bad."""
    top = _keys(data, where, {'rib_marker', 'base_marker', 'tag', 'hue_tolerance_deg',
                              'min_saturation', 'min_value', 'distance_tolerance_mm',
                              'max_segment_angle_deg', 'max_gap'})
    cfg = MarkerConfig()
    rib = _marker(top.get('rib_marker'), 'rib_marker', cfg.rib_marker, base=False)
    base = _marker(top.get('base_marker'), 'base_marker', cfg.base_marker, base=True)
    raw_tag = _keys(top.get('tag'), 'tag', {'dictionary', 'size_mm', 'distance_to_first_rib_mm'})
    tag = cfg.tag
    if 'dictionary' in raw_tag:
        if raw_tag['dictionary'] not in ARUCO_DICTIONARIES:
            raise MarkerConfigError(f'tag.dictionary must be one of {", ".join(ARUCO_DICTIONARIES)},'
                                    f' got {raw_tag["dictionary"]!r}')
        tag = replace(tag, dictionary=raw_tag['dictionary'])
    if 'size_mm' in raw_tag:
        tag = replace(tag, size_mm=_number(raw_tag['size_mm'], 'tag.size_mm', 5.0, 200.0))
    if 'distance_to_first_rib_mm' in raw_tag:
        tag = replace(tag, distance_to_first_rib_mm=_number(
            raw_tag['distance_to_first_rib_mm'], 'tag.distance_to_first_rib_mm', 5.0, 300.0))
    hue_gap = abs((rib.hue_deg - base.hue_deg + 180.0) % 360.0 - 180.0)
    tol = _number(top.get('hue_tolerance_deg', cfg.hue_tolerance_deg), 'hue_tolerance_deg', 2.0, 60.0)
    if hue_gap < 2.0 * tol:
        raise MarkerConfigError(
            f'rib and base marker hues ({rib.hue_deg:.0f} and {base.hue_deg:.0f} deg) are '
            f'{hue_gap:.0f} deg apart, closer than twice hue_tolerance_deg ({tol:g}): '
            'they could not be told apart')
    max_gap = top.get('max_gap', cfg.max_gap)
    if isinstance(max_gap, bool) or not isinstance(max_gap, int) or not 0 <= max_gap <= 3:
        raise MarkerConfigError(f'max_gap must be an integer 0-3, got {max_gap!r}')
    return MarkerConfig(
        rib_marker=rib, base_marker=base, tag=tag, hue_tolerance_deg=tol,
        min_saturation=_number(top.get('min_saturation', cfg.min_saturation), 'min_saturation', 0.05, 0.95),
        min_value=_number(top.get('min_value', cfg.min_value), 'min_value', 0.0, 0.9),
        distance_tolerance_mm=_number(top.get('distance_tolerance_mm', cfg.distance_tolerance_mm),
                                      'distance_tolerance_mm', 0.1, 6.0),
        max_segment_angle_deg=_number(top.get('max_segment_angle_deg', cfg.max_segment_angle_deg),
                                      'max_segment_angle_deg', 5.0, 80.0),
        max_gap=max_gap)


def load_marker_config(path: str | os.PathLike | None) -> MarkerConfig:
    """The markers of a YAML file, or the paper's defaults for None."""
    if path is None:
        return MarkerConfig()
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise MarkerConfigError(f'{path}: cannot read: {exc}') from None
    except yaml.YAMLError as exc:
        raise MarkerConfigError(f'{path}: not valid YAML: {exc}') from None
    try:
        return config_from_dict(data)
    except MarkerConfigError as exc:
        raise MarkerConfigError(f'{path}: {exc}') from None
