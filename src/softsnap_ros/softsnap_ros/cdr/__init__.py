"""The one CDR codec of the project's messages: readers, writers, rclpy fallback.

- :mod:`.primitives`: the format (plain CDR, XCDR1) and its shared pieces;
- :mod:`.readers`: ``CableLength``, ``RobotShape`` and ``ModuleState`` from bytes;
- :mod:`.state_writers`: the driver's ``ModuleState`` and ``CableLength`` as bytes;
- :mod:`.shape_writers`: the model's ``RobotShape`` and ``ModuleShape`` as bytes;
- :mod:`.fallback`: read with rclpy where our readers refuse; the start-up self-check.
"""
from .fallback import (WireMismatch, check_wire, read_cable_length, read_module_state,
                       read_robot_shape)
from .primitives import ENCAPSULATION_LE, HEADER_SIZE, REPRESENTATION_LE, CdrError
from .readers import (ModuleShapeCdr, RobotShapeCdr, decode_cable_length, decode_module_state,
                      decode_robot_shape, from_message)
from .shape_writers import ModuleShapeWire, RobotShapeWire
from .state_writers import CableLengthWire, ModuleStateFields, ModuleStateWire, fill_module_state

__all__ = ['CableLengthWire', 'CdrError', 'ENCAPSULATION_LE', 'HEADER_SIZE', 'ModuleShapeCdr',
           'ModuleShapeWire', 'ModuleStateFields', 'ModuleStateWire', 'REPRESENTATION_LE',
           'RobotShapeCdr', 'RobotShapeWire', 'WireMismatch', 'check_wire',
           'decode_cable_length', 'decode_module_state', 'decode_robot_shape',
           'fill_module_state', 'from_message', 'read_cable_length', 'read_module_state',
           'read_robot_shape']
