"""``softsnap``: call a running robot's services and actions without the ``ros2`` command.

The ROS 2 wheels on PyPI have no ros2cli, so pip users get this instead (the bootstrap
puts it at ``.venv/bin/softsnap``; ``.venv/bin/python -m softsnap_gaits.command_line``
is the same). Requests are YAML mappings of the request's fields, as ``ros2 service call``
takes them, and responses are printed as YAML, field by field. Units are the messages'
(SI: m, rad, s)::

    softsnap forward --module yellow '{cable_length: 0.17}'      # ForwardShape
    softsnap inverse '{target_angles: [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1]}'
    softsnap design '{target_angles: [...], alternatives: 3}'       # DesignThreading action
    softsnap gait set walk --period 2.0      softsnap gait pause|resume|start|stop
    softsnap stop [MODULE ...]               softsnap calibrate MODULE ...
    softsnap call /brittle_star/gait_node/pause std_srvs/srv/Trigger

``--robot`` names the robot's namespace (default brittle_star, the demo's scene). The
exit status is 0 when every call answered with success, 1 when one answered with
success false, 2 when a service did not answer or the request was malformed.
"""
from __future__ import annotations

import argparse
import importlib
import sys
import time

import yaml

#: How long to wait for a service to appear and then for its answer (s): discovery of a
#: fresh process takes up to ~3 s here (ROS-PIP.md), an inverse design up to its timeout.
DEFAULT_TIMEOUT_S = 60.0


class CallError(Exception):
    """A call that could not be made (bad request, no service, no answer)."""


# ---------------------------------------------------------------- YAML <-> messages
def interface_type(name: str):
    """The class of ``pkg/srv/Name``, ``pkg/action/Name`` or ``pkg/msg/Name``."""
    try:
        package, kind, cls = name.split('/')
        return getattr(importlib.import_module(f'{package}.{kind}'), cls)
    except (ValueError, ImportError, AttributeError):
        raise CallError(f'unknown interface type {name!r} (expected pkg/srv/Name, '
                        f'pkg/action/Name or pkg/msg/Name of an installed package)') from None


def fill(msg, values) -> object:
    """Set `msg`'s fields from a mapping (nested messages from nested mappings, message
    arrays from lists of mappings); an unknown field is a CallError naming the fields."""
    if values is None:
        return msg
    if not isinstance(values, dict):
        raise CallError(f'{type(msg).__name__}: expected a mapping of fields, got {values!r}')
    fields = msg.get_fields_and_field_types()
    for key, value in values.items():
        if key not in fields:
            raise CallError(f'{type(msg).__name__} has no field {key!r}; fields: '
                            f'{", ".join(fields)}')
        current = getattr(msg, key)
        try:
            if hasattr(current, 'get_fields_and_field_types'):
                fill(current, value)
            elif isinstance(value, list) and value and isinstance(value[0], dict):
                element = _element_type(msg, key)
                setattr(msg, key, [fill(element(), v) for v in value])
            else:
                setattr(msg, key, value)
        except (TypeError, ValueError, AssertionError) as error:
            raise CallError(f'{type(msg).__name__}.{key}: {error}') from None
    return msg


def _element_type(msg, key: str):
    """Class of the elements of a message-array field (``geometry_msgs/Point[]``)."""
    spec = msg.get_fields_and_field_types()[key]       # 'sequence<geometry_msgs/Point>'
    inner = spec.split('<', 1)[1].split(',')[0].rstrip('>') if '<' in spec else spec.split('[')[0]
    package, cls = inner.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), cls)


def to_data(msg):
    """A message as plain lists, dicts and numbers (what is printed as YAML)."""
    if hasattr(msg, 'get_fields_and_field_types'):
        return {key: to_data(getattr(msg, key)) for key in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple)) or type(msg).__name__ in ('array', 'ndarray'):
        return [to_data(v) for v in msg]
    if hasattr(msg, 'item'):           # numpy scalars
        return msg.item()
    return msg


def parse_request(text: str | None) -> dict:
    if not text:
        return {}
    try:
        values = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise CallError(f'request is not YAML: {error}') from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise CallError(f'request must be a YAML mapping of fields, got {text!r}')
    return values


# ---------------------------------------------------------------- calls
class Caller:
    """One rclpy node in its own context that makes the calls."""

    def __init__(self, timeout_s: float):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from softsnap_ros.dds_profile import use_node_profile
        use_node_profile()
        self.rclpy = rclpy
        self.timeout_s = timeout_s
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[])
        self.node = rclpy.create_node(f'softsnap_cli_{_unique()}', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)

    def _spin_until(self, done, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if done():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return bool(done())

    def call(self, service: str, srv_type, request) -> object:
        client = self.node.create_client(srv_type, service)
        try:
            if not self._spin_until(client.service_is_ready, self.timeout_s):
                raise CallError(f'service {service} not available after {self.timeout_s:g} s '
                                f'(is the robot running, in this ROS domain?)')
            future = client.call_async(request)
            if not self._spin_until(future.done, self.timeout_s):
                raise CallError(f'service {service} did not answer within {self.timeout_s:g} s')
            return future.result()
        finally:
            self.node.destroy_client(client)

    def send_goal(self, name: str, action_type, goal, on_feedback) -> object:
        from rclpy.action import ActionClient
        client = ActionClient(self.node, action_type, name)
        try:
            if not self._spin_until(client.server_is_ready, self.timeout_s):
                raise CallError(f'action {name} not available after {self.timeout_s:g} s')
            sent = client.send_goal_async(goal, feedback_callback=lambda f: on_feedback(f.feedback))
            if not self._spin_until(sent.done, self.timeout_s):
                raise CallError(f'action {name} did not take the goal within {self.timeout_s:g} s')
            handle = sent.result()
            if not handle.accepted:
                raise CallError(f'action {name} rejected the goal (one design at a time)')
            result = handle.get_result_async()
            if not self._spin_until(result.done, self.timeout_s):
                handle.cancel_goal_async()
                raise CallError(f'action {name}: no result within {self.timeout_s:g} s '
                                f'(goal cancelled)')
            return result.result().result
        finally:
            client.destroy()


def _unique() -> str:
    import os
    return f'{os.getpid()}_{time.monotonic_ns() % 1_000_000}'


# ---------------------------------------------------------------- commands
def _print(label: str, response) -> bool:
    data = to_data(response)
    shown = {label: data} if label else data
    print(yaml.safe_dump(shown, default_flow_style=None, sort_keys=False, width=100), end='',
          flush=True)
    return bool(data.get('success', True)) if isinstance(data, dict) else True


def _module_holes(robot: str, module: str) -> list[str]:
    from softsnap_model.scene import load_scene
    try:
        return list(load_scene(robot).module(module).holes)
    except (KeyError, ValueError) as error:
        raise CallError(str(error).strip('"')) from None


def run(args, caller: Caller) -> bool:
    ns = '/' + args.robot.strip('/')
    from softsnap_interfaces.action import DesignThreading
    from softsnap_interfaces.srv import ForwardShape, InverseDesign, SetGait
    from std_srvs.srv import Trigger
    if args.command == 'forward':
        values = parse_request(args.request)
        if args.module:
            values.setdefault('holes', _module_holes(args.robot, args.module))
        request = fill(ForwardShape.Request(), values)
        return _print('', caller.call(f'{ns}/model_node/forward_shape', ForwardShape, request))
    if args.command == 'inverse':
        request = fill(InverseDesign.Request(), parse_request(args.request))
        return _print('', caller.call(f'{ns}/model_node/inverse_design', InverseDesign, request))
    if args.command == 'design':
        goal = fill(DesignThreading.Goal(), parse_request(args.request))

        def feedback(fb):
            print(f'feedback: {fb.stage} {100.0 * fb.fraction:.0f} % ({fb.elapsed:.1f} s)',
                  flush=True)
        return _print('result', caller.send_goal(f'{ns}/model_node/design_threading',
                                                 DesignThreading, goal, feedback))
    if args.command == 'gait':
        if args.action == 'set':
            if not args.name:
                raise CallError('gait set needs a gait name (see the scene file)')
            request = SetGait.Request(gait=args.name, period=args.period, amplitude=args.amplitude)
            return _print('', caller.call(f'{ns}/gait_node/set_gait', SetGait, request))
        return _print('', caller.call(f'{ns}/gait_node/{args.action}', Trigger, Trigger.Request()))
    if args.command in ('stop', 'calibrate', 'pause', 'resume'):
        modules = args.modules
        if not modules:
            if args.command == 'calibrate':
                raise CallError('calibrate needs the modules to calibrate (it moves them)')
            from softsnap_model.scene import load_scene
            modules = list(load_scene(args.robot).module_names)
        ok = True
        for module in modules:
            ok = _print(module, caller.call(f'{ns}/{module}/{args.command}', Trigger,
                                            Trigger.Request())) and ok
        return ok
    if args.command == 'call':
        srv_type = interface_type(args.type)
        request = fill(srv_type.Request(), parse_request(args.request))
        return _print('', caller.call(args.service, srv_type, request))
    raise CallError(f'unknown command {args.command!r}')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='softsnap', description="Call a running SoftSnap robot's services and actions "
        "(what `ros2 service call` and `ros2 action send_goal` do on a ROS install).",
        epilog='Requests are YAML mappings of the request fields (SI units), '
               'e.g. \'{cable_length: 0.17}\'. docs/command_line.md has every command.')
    parser.add_argument('--robot', default='brittle_star',
                        help="the robot's namespace, its scene name (default brittle_star)")
    parser.add_argument('--timeout', type=float, default=DEFAULT_TIMEOUT_S,
                        help=f'seconds to wait for the service and for its answer '
                             f'(default {DEFAULT_TIMEOUT_S:g})')
    sub = parser.add_subparsers(dest='command', required=True)
    forward = sub.add_parser('forward', help='model_node forward_shape: the shape of a '
                             'threading at a cable length (ForwardShape)')
    forward.add_argument('request', nargs='?', help="ForwardShape request, e.g. "
                         "'{holes: [R1, ...], cable_length: 0.17}'")
    forward.add_argument('--module', help="take holes from this module of the robot's scene")
    for name, text in (('inverse', 'model_node inverse_design: threadings for a target '
                                   'shape (InverseDesign)'),
                       ('design', 'model_node design_threading action: the same with '
                                  'progress feedback (DesignThreading)')):
        p = sub.add_parser(name, help=text)
        p.add_argument('request', help="request, e.g. '{target_angles: [0.1, ...]}'")
    gait = sub.add_parser('gait', help='gait_node: set the gait, start, stop, pause, resume')
    gait.add_argument('action', choices=['set', 'start', 'stop', 'pause', 'resume'])
    gait.add_argument('name', nargs='?', help='gait name (gait set)')
    gait.add_argument('--period', type=float, default=0.0, help='s; 0 keeps the default')
    gait.add_argument('--amplitude', type=float, default=0.0, help='m; 0 keeps the default')
    for name, text in (('stop', "drivers: stop the winches (every module's by default)"),
                       ('pause', 'drivers: hold position, ignore commands'),
                       ('resume', 'drivers: take commands again'),
                       ('calibrate', 'drivers: calibrate the named modules (moves them)')):
        p = sub.add_parser(name, help=text)
        p.add_argument('modules', nargs='*', help='module names (default: every module)')
    call = sub.add_parser('call', help='any service, as ros2 service call SERVICE TYPE REQUEST')
    call.add_argument('service', help='absolute service name')
    call.add_argument('type', help='e.g. std_srvs/srv/Trigger')
    call.add_argument('request', nargs='?', help='YAML request (default: empty)')
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    caller = None
    try:
        caller = Caller(args.timeout)
        return 0 if run(args, caller) else 1
    except CallError as error:
        print(f'softsnap: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        if caller is not None:
            caller.close()


if __name__ == '__main__':
    raise SystemExit(main())
