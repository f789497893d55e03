"""softsnap_model: quasi-static model of SoftSnap modules (pure numpy/scipy core).

Core modules (no rclpy): :mod:`.geometry` (exact cable length and rib poses),
:mod:`.skeleton` (module description), :mod:`.forward` (quasi-static forward solver).
"""
from .geometry import cable_path, rib_centers, segment_length, segment_length_derivatives
from .skeleton import Skeleton

__all__ = ['Skeleton', 'segment_length', 'segment_length_derivatives', 'rib_centers',
           'cable_path']
