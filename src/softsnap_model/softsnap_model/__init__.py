"""softsnap_model: quasi-static model of SoftSnap modules (pure numpy/scipy core).

Core modules (no rclpy): :mod:`.geometry` (exact cable length and rib poses),
:mod:`.skeleton` (module description), :mod:`.forward` (quasi-static forward solver).
"""
from .forward import (CONSTRAINT_TOL_MM, STATIONARITY_TOL_RAD, BatchResult, ForwardResult,
                      InfeasibleLengthError, SegmentBranch, SnapThroughError, SweepResult,
                      reachable_range, segment_angle_at_tension, segment_branch,
                      solve_forward, solve_forward_batch, sweep)
from .inverse import DesignResult, DesignSensitivity, design_sensitivity, design_threading
from .geometry import cable_path, rib_centers, segment_length, segment_length_derivatives
from .skeleton import Skeleton

__all__ = [
    'design_threading', 'DesignResult', 'design_sensitivity', 'DesignSensitivity',
    'Skeleton', 'solve_forward', 'solve_forward_batch', 'sweep', 'reachable_range',
    'ForwardResult', 'BatchResult', 'SweepResult', 'InfeasibleLengthError',
    'SnapThroughError', 'SegmentBranch', 'segment_branch', 'segment_angle_at_tension',
    'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD',
    'segment_length', 'segment_length_derivatives', 'rib_centers', 'cable_path',
]
