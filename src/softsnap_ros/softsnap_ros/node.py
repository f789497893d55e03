"""The base class of every SoftSnap node: double parameters also take integer values.

Users type ``-p rate:=50``, ``rate: 50`` in a ``--params-file`` and ``ros2 param set
/ns/node rate 50``. The command line, YAML and ``ros2 param`` all make those INTEGER
values, and rclpy refuses an integer for a parameter declared as a double: at start-up
``declare_parameter`` raises ``InvalidParameterTypeException`` (the node dies), at run time
the set is refused with "Wrong parameter type". :class:`SoftSnapNode` converts such
integers to doubles in both places and changes nothing else: a string, a bool or an array
for a double parameter is still refused with rclpy's reason (at start-up as a
:class:`StartupParameterError`, a ValueError every node's ``main`` reports in one line,
like an override outside its descriptor's range).

How, in rclpy (Jazzy):

- Run time: a *pre-set* callback (``add_pre_set_parameters_callback``) may rewrite the
  list of parameters before they are checked against their descriptors; it turns an
  INTEGER for a declared DOUBLE parameter into the same value as a DOUBLE. Then the
  descriptor's range check and the node's own on-set callback see a float.
- Start-up: ``declare_parameters`` does *not* run pre-set callbacks (rclpy documents
  this), and it takes the value from the overrides that ``--params-file`` and ``-p``
  produced. So :meth:`SoftSnapNode.declare_parameters` converts the integer override of a
  double parameter before declaring it. rclpy keeps those overrides only in the
  ``_parameter_overrides`` dict (Humble to Rolling; no public accessor); if a future rclpy
  drops it, integers are refused again rather than anything going wrong silently, and
  ``test/softsnap_ros/test_parameters.py`` says so.

Also here: the parameter descriptors every node declares (:func:`float_range`,
:func:`integer_range`, :func:`read_only`, :func:`table_descriptor`).

Why in softsnap_ros: it is the bottom of our ROS packages (rclpy and message packages
only), so every node package stands on it without a cycle, and a driver process does not
import numpy and scipy with softsnap_model (~1 s and ~30 MB per driver, five per robot).
"""
from __future__ import annotations

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

__all__ = ['StartupParameterError', 'SoftSnapNode', 'float_range', 'integer_as_double',
           'integer_range', 'read_only', 'table_descriptor']


def float_range(description: str, low: float, high: float, step: float = 0.0,
                read_only: bool = False) -> ParameterDescriptor:
    """A double parameter's descriptor with its range [low, high] (step 0: any value)."""
    return ParameterDescriptor(description=description, read_only=read_only,
                               floating_point_range=[FloatingPointRange(
                                   from_value=float(low), to_value=float(high),
                                   step=float(step))])


def integer_range(description: str, low: int, high: int, step: int = 1,
                  read_only: bool = False) -> ParameterDescriptor:
    """An integer parameter's descriptor with its range [low, high] in steps of step."""
    return ParameterDescriptor(description=description, read_only=read_only,
                               integer_range=[IntegerRange(from_value=int(low),
                                                           to_value=int(high), step=int(step))])


def read_only(description: str) -> ParameterDescriptor:
    """A parameter fixed at start-up (its description says so)."""
    return ParameterDescriptor(description=description + ' (fixed at start-up)',
                               read_only=True)


def table_descriptor(kind: type, description: str, bounds: tuple | None = None,
                     runtime: bool = False) -> ParameterDescriptor:
    """The descriptor of one row of a simulator's option table: its type, its range
    (``bounds`` (low, high) or None) and whether it may change while running."""
    text = description if runtime else description + ' (fixed at start-up)'
    if bounds is not None and kind is int:
        return integer_range(text, *bounds, read_only=not runtime)
    if bounds is not None and kind is float:
        return float_range(text, *bounds, read_only=not runtime)
    return ParameterDescriptor(description=text, read_only=not runtime)


class StartupParameterError(ValueError):
    """A start-up parameter value of the wrong type or refused (names parameter and value)."""


def integer_as_double(parameter: Parameter) -> Parameter:
    """`parameter` as a DOUBLE if it holds an INTEGER, else `parameter` itself."""
    if parameter.type_ == Parameter.Type.INTEGER:
        return Parameter(parameter.name, Parameter.Type.DOUBLE, float(parameter.value))
    return parameter


def _declared_double(entry: tuple) -> bool:
    """Whether a ``declare_parameters`` entry (name, value or type, descriptor) is a double."""
    if len(entry) < 2:
        return False
    descriptor = entry[2] if len(entry) > 2 else None
    if isinstance(descriptor, ParameterDescriptor) and descriptor.dynamic_typing:
        return False
    value = entry[1]
    if isinstance(value, Parameter.Type):
        return value == Parameter.Type.DOUBLE
    return isinstance(value, float)


class SoftSnapNode(Node):
    """An rclpy ``Node`` whose double parameters also accept integer values.

    Use it as the base class instead of ``Node``; declare parameters as usual
    (``declare_parameter`` goes through :meth:`declare_parameters`).

    Only one pre-set callback may be registered on such a node: rclpy concatenates the
    lists that several pre-set callbacks return.
    """

    def __init__(self, node_name: str, **kwargs):
        super().__init__(node_name, **kwargs)
        self.add_pre_set_parameters_callback(self._integers_as_doubles_callback)

    def declare_parameters(self, namespace, parameters, ignore_override: bool = False):
        parameters = list(parameters)  # read twice: here and by rclpy
        overrides = getattr(self, '_parameter_overrides', None)
        if not ignore_override and isinstance(overrides, dict):
            for entry in parameters:
                name = f'{namespace}.{entry[0]}' if namespace else entry[0]
                if name in overrides and _declared_double(entry):
                    overrides[name] = integer_as_double(overrides[name])
        try:
            return super().declare_parameters(namespace, parameters, ignore_override)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            # rclpy's message names the parameter, the value and the expected type or range.
            raise StartupParameterError(str(exc)) from exc

    def _integers_as_doubles_callback(self, parameters: list[Parameter]) -> list[Parameter]:
        """Pre-set callback: an INTEGER for a declared DOUBLE parameter becomes a DOUBLE."""
        converted = []
        for parameter in parameters:
            if (self.has_parameter(parameter.name) and self.describe_parameter(
                    parameter.name).type == ParameterType.PARAMETER_DOUBLE):
                parameter = integer_as_double(parameter)
            converted.append(parameter)
        return converted
