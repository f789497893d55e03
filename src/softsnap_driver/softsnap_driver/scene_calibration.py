"""A scene module's driver calibration: the one derivation used by the graph that
configures the drivers and by the simulated robot that must agree with them."""
from __future__ import annotations

from dataclasses import dataclass

from softsnap_ros.units import MM_PER_M

__all__ = ['ModuleCalibration', 'module_calibration']


@dataclass(frozen=True)
class ModuleCalibration:
    """What a module's driver is configured with, from its scene entry."""

    straight_length_mm: float   # cable length of the straight module, mm
    max_contraction_mm: float   # the most the driver contracts it, mm
    counts_per_mm: float        # encoder counts per mm of cable

    @property
    def straight_length_m(self) -> float:
        return self.straight_length_mm / MM_PER_M

    @property
    def max_contraction_m(self) -> float:
        return self.max_contraction_mm / MM_PER_M


def module_calibration(scene, module) -> ModuleCalibration:
    """The calibration of ``module`` (a scene's module entry) in ``scene``: the straight
    length is the model's, and the driver never commands beyond what the model can reach
    or the scene allows."""
    from softsnap_model.forward import reachable_range
    low_mm, straight_mm = reachable_range(scene.skeleton, module.threading_mm)
    return ModuleCalibration(straight_mm, min(module.max_contraction_mm, straight_mm - low_mm),
                             float(module.counts_per_mm))
