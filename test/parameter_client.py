"""The parameter services of a running node, called as ``ros2 param get/set`` call them
(tests of several packages read nodes' parameters back through this)."""
from __future__ import annotations


class ParameterClient:
    """The node's get/set_parameters services, as ``ros2 param get/set`` use them."""

    def __init__(self, ros_node, node_fqn: str):
        from rcl_interfaces.srv import GetParameters, SetParameters
        self.node = ros_node
        self.get_client = ros_node.create_client(GetParameters, f'{node_fqn}/get_parameters')
        self.set_client = ros_node.create_client(SetParameters, f'{node_fqn}/set_parameters')
        self.GetParameters, self.SetParameters = GetParameters, SetParameters

    def get(self, *names):
        """{name: (type, value)} of the node's parameters."""
        from rcl_interfaces.msg import ParameterType
        response = self.node.call(self.get_client, self.GetParameters.Request(names=list(names)), 30.0)
        out = {}
        for name, value in zip(names, response.values):
            field = {ParameterType.PARAMETER_DOUBLE: 'double_value',
                     ParameterType.PARAMETER_INTEGER: 'integer_value',
                     ParameterType.PARAMETER_STRING: 'string_value'}.get(value.type)
            out[name] = (value.type, getattr(value, field) if field else None)
        return out

    def set(self, name, **value):
        """Set one parameter the way ``ros2 param set`` does; returns SetParametersResult."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        kind = {'integer_value': ParameterType.PARAMETER_INTEGER,
                'string_value': ParameterType.PARAMETER_STRING,
                'double_value': ParameterType.PARAMETER_DOUBLE}[next(iter(value))]
        request = self.SetParameters.Request(parameters=[
            Parameter(name=name, value=ParameterValue(type=kind, **value))])
        return self.node.call(self.set_client, request, 30.0).results[0]
