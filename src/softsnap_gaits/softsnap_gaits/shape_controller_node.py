"""shape_controller: closes the loop from measured shapes to cable-length commands.

Run (``ros2 run softsnap_gaits shape_controller``)::

    .venv/lib/softsnap_gaits/shape_controller --ros-args -r __ns:=/gripper \\
        -p scene:=gripper -p measured_topic:=shape/ground_truth -p use_sim_time:=true

Topics (relative, so inside the node's namespace), per module M of the scene:
  ``M/<measured_topic>``         in:  softsnap_interfaces/MeasuredShape (m); default
                                 ``shape/measured`` (the camera tracker), or
                                 ``shape/ground_truth`` (sim_robot)
  ``M/cable_length/command``     out: softsnap_interfaces/CableLength (m), only while the
                                 controller has a target for M
  ``M/shape/target``, ``M/shape/predicted``  out: MeasuredShape (sources "target" and
                                 "model"): the target and the model's shape at the command
  ``/diagnostics``               out: one status per module, every second
Action ``~/reach_shape`` (softsnap_interfaces/ReachShape); services ``~/set_target``
(softsnap_interfaces/SetShapeTarget).

Hand-over with gait_node (docs/control.md): before commanding a module the node asks the
gait node (parameter ``gait_node``, '' for none) to release it through
``<gait_node>/release_modules`` and commands nothing until the gait node confirms; when
it stops controlling a module it hands it back. If no node of that name is in the graph
there is nobody to hand over from and the controller proceeds (logged); if the node is
there and does not confirm, the target is refused.

The control law, bounds and states are :mod:`softsnap_gaits.shape_control`; this node
only translates messages, parameters and timers.
"""
from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import asdict

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Point
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from softsnap_ros.diagnostics import key_values
from softsnap_ros.node import SoftSnapNode
from softsnap_ros.service_queues import action_qos_kwargs, create_queued_service
from softsnap_ros.spinning import run_node_main
from softsnap_ros.units import NS_PER_S, stamp_ns
from softsnap_interfaces.action import ReachShape
from softsnap_interfaces.msg import CableLength, MeasuredShape
from softsnap_interfaces.srv import ReleaseModules, SetShapeTarget

from softsnap_gaits.shape_control import (REACHED, STALE, TIMED_OUT, ControllerConfig,
                                          ShapeController, TargetError, make_target,
                                          module_model, named_shape_m)
from softsnap_model.scene import load_scene

#: How often the action's loop looks at the controllers (s, wall clock).
GOAL_POLL_S = 0.05
#: Feedback period of the action (s, wall clock).
FEEDBACK_PERIOD_S = 0.2
#: Period (s) at which the release of held modules is repeated to the gait node.
REASSERT_PERIOD_S = 2.0


def _points(msg_points) -> np.ndarray:
    return np.array([[p.x, p.y] for p in msg_points], dtype=float).reshape(-1, 2)


def _stamp_s(stamp) -> float:
    return stamp_ns(stamp) / NS_PER_S


class ShapeControllerNode(SoftSnapNode):
    """Per-module :class:`ShapeController` objects wired to topics, an action and services."""

    def __init__(self, **kwargs):
        super().__init__('shape_controller', **kwargs)
        d = self.declare_parameter
        d('scene', 'gripper', ParameterDescriptor(read_only=True, description='Scene name or '
          'path to a scene YAML file.'))
        d('modules', [''], ParameterDescriptor(read_only=True, description='Modules to '
          "control; [''] for every module of the scene."))
        d('measured_topic', 'shape/measured', ParameterDescriptor(read_only=True,
          description="Measured-shape topic per module: shape/measured (camera) or "
                      "shape/ground_truth (sim_robot)."))
        d('rate', 20.0, ParameterDescriptor(read_only=True, description='Control rate (Hz).'))
        d('integral_gain', 4.0, ParameterDescriptor(read_only=True, description='Integral '
          'gain on the length correction (1/s).'))
        d('stale_after', 0.5, ParameterDescriptor(read_only=True, description='A measurement '
          'older than this (s) holds the command.'))
        d('default_tolerance', 0.001, ParameterDescriptor(read_only=True, description='Target '
          'tolerance when a request gives 0 (m).'))
        d('default_timeout', 10.0, ParameterDescriptor(read_only=True, description='Target '
          'timeout when a request gives 0 (s).'))
        d('gait_node', 'gait_node', ParameterDescriptor(read_only=True, description='Name of '
          "the gait node to take modules from ('' for none)."))
        d('handover_timeout', 3.0, ParameterDescriptor(read_only=True, description='Wait for '
          "the gait node's confirmation at most this long (s, wall clock)."))
        d('bending_stiffness', 0.0, ParameterDescriptor(read_only=True, description="Model's "
          'bending stiffness K (N mm/rad^2); 0 for the default estimate.'))
        d('gravity', True, ParameterDescriptor(read_only=True, description='Model gravity '
          "in the module's frame from the scene pose."))
        d('correction_log', '', ParameterDescriptor(read_only=True, description='JSON-lines '
          "file the steady corrections are appended to ('' for the log only)."))
        d('rerun_recording', '', ParameterDescriptor(read_only=True, description='.rrd file '
          "for target, measured and predicted shapes and the error ('' for none)."))
        p = {n: self.get_parameter(n).value for n in (
            'scene', 'modules', 'measured_topic', 'rate', 'integral_gain', 'stale_after',
            'default_tolerance', 'default_timeout', 'gait_node', 'handover_timeout',
            'bending_stiffness', 'gravity', 'correction_log', 'rerun_recording')}
        self.params = p
        self.scene = load_scene(p['scene'])
        names = [m for m in p['modules'] if m] or list(self.scene.module_names)
        unknown = [n for n in names if n not in self.scene.module_names]
        if unknown:
            raise ValueError(f'scene {self.scene.name!r} has no module(s) '
                             f'{", ".join(map(repr, unknown))}; modules are '
                             f'{", ".join(self.scene.module_names)}')
        if not (1.0 <= p['rate'] <= 200.0):
            raise ValueError(f'rate must be from 1 to 200 Hz, got {p["rate"]!r}')
        self.lock = threading.RLock()
        self.group = ReentrantCallbackGroup()
        stiffness = p['bending_stiffness'] or None
        self.controllers: dict[str, ShapeController] = {}
        self.generation = {}
        self.command_pub, self.target_pub, self.predicted_pub = {}, {}, {}
        self.last_step = {}
        self.measurements = dict.fromkeys(names, 0)
        self.refused_measurements = dict.fromkeys(names, 0)
        for name in names:
            module = self.scene.module(name)
            config = ControllerConfig(
                integral_gain_per_s=p['integral_gain'], stale_after_s=p['stale_after'],
                max_speed_m_s=0.75 * module.winch_speed_mm_s * 1e-3)
            model = module_model(self.scene, name, gravity=p['gravity'],
                                 bending_stiffness_nmm=stiffness)
            self.controllers[name] = ShapeController(model, config)
            self.generation[name] = 0
            self.command_pub[name] = self.create_publisher(
                CableLength, f'{name}/cable_length/command', 50)
            self.target_pub[name] = self.create_publisher(MeasuredShape, f'{name}/shape/target', 5)
            self.predicted_pub[name] = self.create_publisher(
                MeasuredShape, f'{name}/shape/predicted', 5)
            self.create_subscription(
                MeasuredShape, f'{name}/{p["measured_topic"]}',
                lambda msg, n=name: self.measured_callback(n, msg), 20,
                callback_group=self.group)
        self.held: set[str] = set()      # modules the gait node released to us
        self.release_client = self.create_client(
            ReleaseModules, f'{p["gait_node"]}/release_modules', callback_group=self.group) \
            if p['gait_node'] else None
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.recorder = None
        if p['rerun_recording']:
            from softsnap_gaits.control_rerun import ControlRecorder
            self.recorder = ControlRecorder(p['rerun_recording'], self.scene.name)
        self.create_timer(1.0 / p['rate'], self.control_callback, callback_group=self.group)
        self.create_timer(1.0, self.diagnostics_callback, callback_group=self.group)
        # A restarted gait node has forgotten its releases: say them again now and then.
        self.create_timer(REASSERT_PERIOD_S, self.reassert_callback, callback_group=self.group)
        # Queues sized for bursts, lost requests counted (softsnap_ros.service_queues).
        create_queued_service(self, SetShapeTarget, '~/set_target', self.set_target_callback,
                              callback_group=self.group)
        self.action_server = ActionServer(
            self, ReachShape, '~/reach_shape', execute_callback=self.execute_callback,
            goal_callback=lambda goal: GoalResponse.ACCEPT,
            cancel_callback=lambda handle: CancelResponse.ACCEPT, callback_group=self.group,
            **action_qos_kwargs())
        self.get_logger().info(
            f'scene {self.scene.name!r}: controlling {", ".join(names)} from '
            f'<module>/{p["measured_topic"]}; hand-over with '
            f'{p["gait_node"] or "no gait node"}')

    # ------------------------------------------------------------------ helpers
    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _targets(self, modules, kind, points, shape_name, tolerance, timeout):
        """{module: (target, feedforward)} for a request, or raise TargetError."""
        if not modules:
            raise TargetError('no module given')
        unknown = [m for m in modules if m not in self.controllers]
        if unknown:
            raise TargetError(f'unknown module(s) {", ".join(map(repr, unknown))}; this '
                              f'controller has {", ".join(self.controllers)}')
        if len(set(modules)) != len(modules):
            raise TargetError('a module is named twice')
        tol = tolerance or self.params['default_tolerance']
        tmo = timeout or self.params['default_timeout']
        out = {}
        for m in modules:
            ctl = self.controllers[m]
            if kind == 'named':
                pts, k = named_shape_m(self.scene, ctl.model, shape_name), 'ribs'
            else:
                pts, k = _points(points), kind
            target = make_target(k, pts, ctl.model.n_ribs, tolerance_m=tol, timeout_s=tmo,
                                 name=shape_name if kind == 'named' else '')
            ff = ctl.plan(target)
            if not math.isfinite(ff.model_error_m) \
                    or ff.model_error_m > ctl.config.max_model_miss_m:
                raise TargetError(
                    f'{m}: unreachable: the closest shape the model predicts is '
                    f'{ff.model_error_m * 1e3:.1f} mm from the target (limit '
                    f'{ctl.config.max_model_miss_m * 1e3:g} mm)')
            out[m] = (target, ff)
        return out

    def _acquire(self, modules) -> tuple[bool, str]:
        """Ask the gait node to release `modules`; (ok, message)."""
        wanted = [m for m in modules if m not in self.held]
        if self.release_client is None or not wanted:
            return True, 'no hand-over needed'
        timeout = self.params['handover_timeout']
        name = self.params['gait_node']
        if not self.release_client.wait_for_service(timeout_sec=timeout):
            present = any(n == name for n, _ in self.get_node_names_and_namespaces())
            if present:
                return False, (f'gait node {name!r} is running but its release_modules '
                               f'service did not answer within {timeout:g} s')
            self.get_logger().warning(f'no gait node {name!r} in the graph: nobody to hand '
                                      f'{", ".join(wanted)} over from')
            return True, 'no gait node'
        request = ReleaseModules.Request(modules=wanted, release=True,
                                         requester=self.get_fully_qualified_name())
        done = threading.Event()
        future = self.release_client.call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout) or future.result() is None:
            return False, f'gait node {name!r} did not confirm the hand-over in {timeout:g} s'
        response = future.result()
        if not response.success or not set(wanted) <= set(response.released):
            return False, f'gait node {name!r} refused the hand-over: {response.message}'
        with self.lock:
            self.held.update(wanted)
        self.get_logger().info(f'gait node {name!r} released {", ".join(wanted)}')
        return True, response.message

    def reassert_callback(self) -> None:
        """Repeat the release of the modules held (idempotent for gait_node), so a gait
        node that restarted stops commanding them within REASSERT_PERIOD_S."""
        with self.lock:
            held = sorted(self.held)
        if held and self.release_client is not None and self.release_client.service_is_ready():
            self.release_client.call_async(ReleaseModules.Request(
                modules=held, release=True, requester=self.get_fully_qualified_name()))

    def _hand_back(self, modules) -> None:
        """Stop controlling `modules` and return them to the gait node (no wait)."""
        with self.lock:
            for m in modules:
                self.controllers[m].clear_target()
            back = [m for m in modules if m in self.held]
            self.held.difference_update(back)
        if back and self.release_client is not None and self.release_client.service_is_ready():
            self.release_client.call_async(ReleaseModules.Request(
                modules=back, release=False, requester=self.get_fully_qualified_name()))
            self.get_logger().info(f'handed {", ".join(back)} back to the gait node')

    def _apply(self, targets) -> dict:
        """Set the targets (all modules at once); returns the generation per module."""
        now = self.now_s()
        with self.lock:
            for m, (target, ff) in targets.items():
                self.controllers[m].set_target(target, now, ff)
                self.generation[m] += 1
                self._publish_shape(self.target_pub[m], m, target.points_m, 'target')
                self._publish_shape(self.predicted_pub[m], m, ff.predicted_ribs_m, 'model')
            return {m: self.generation[m] for m in targets}

    def _publish_shape(self, pub, module, points, source) -> None:
        msg = MeasuredShape()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = module
        msg.module, msg.source = module, source
        msg.rib_centers = [Point(x=float(x), y=float(y), z=0.0) for x, y in points]
        msg.visible = [True] * len(points)
        msg.residual, msg.cable_length, msg.rmse_to_model = 0.0, math.nan, math.nan
        pub.publish(msg)

    # ------------------------------------------------------------------ callbacks
    def measured_callback(self, module: str, msg: MeasuredShape) -> None:
        pts = _points(msg.rib_centers)
        try:
            with self.lock:
                self.controllers[module].observe(pts, _stamp_s(msg.header.stamp),
                                                 list(msg.visible) or None)
                self.measurements[module] += 1
        except ValueError as exc:
            self.refused_measurements[module] += 1
            self.get_logger().warning(f'{module}: measurement refused: {exc}',
                                      throttle_duration_sec=5.0)
            return
        if self.recorder is not None:
            self.recorder.measured(module, _stamp_s(msg.header.stamp), pts)

    def control_callback(self) -> None:
        now = self.get_clock().now()
        if now.nanoseconds <= 0:
            return   # use_sim_time before the first /clock
        t = now.nanoseconds * 1e-9
        records = []
        with self.lock:
            for m, ctl in self.controllers.items():
                if ctl.target is None:
                    continue
                before = len(ctl.corrections)
                step = ctl.step(t)
                self.last_step[m] = step
                if step.command_m is not None:
                    msg = CableLength()
                    msg.header.stamp = now.to_msg()
                    msg.cable_length = float(step.command_m)
                    self.command_pub[m].publish(msg)
                records += [(m, r) for r in ctl.corrections[before:]]
                if self.recorder is not None and step.command_m is not None:
                    self.recorder.step(m, t, ctl.target.points_m, step,
                                       ctl.predicted_ribs_m())
        for m, r in records:
            self._log_correction(m, r)

    def _log_correction(self, module, record) -> None:
        self.get_logger().info(
            f'{module}: target reached; steady correction {record.correction_m * 1e3:+.2f} mm '
            f'(model {record.feedforward_m * 1e3:.2f} mm, robot {record.command_m * 1e3:.2f} '
            f'mm, error {record.error_m * 1e3:.2f} mm)')
        path = self.params['correction_log']
        if path:
            try:
                with open(path, 'a', encoding='utf-8') as f:
                    f.write(json.dumps({'robot': self.scene.name, 'module': module,
                                        **asdict(record)}) + '\n')
            except OSError as exc:
                self.get_logger().warning(f'correction log {path!r}: {exc}')

    def diagnostics_callback(self) -> None:
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        robot = self.get_namespace().strip('/') or self.scene.name
        with self.lock:
            for m, ctl in self.controllers.items():
                step = self.last_step.get(m)
                status = DiagnosticStatus(name=f'softsnap/{robot}/{m}/shape_controller',
                                          hardware_id=m)
                state = ctl.state
                if state in (STALE, TIMED_OUT):
                    status.level = DiagnosticStatus.WARN
                    status.message = step.reason if step else state
                else:
                    status.level = DiagnosticStatus.OK
                    status.message = state if ctl.target else 'no target'
                values = {'state': state, 'measurements': self.measurements[m],
                          'measurements_refused': self.refused_measurements[m],
                          'handed_over': m in self.held}
                if step is not None and ctl.target is not None:
                    values.update(error_mm=round(step.error_m * 1e3, 3),
                                  command_mm=round((step.command_m or math.nan) * 1e3, 3),
                                  correction_mm=round(step.correction_m * 1e3, 3),
                                  measurement_age_s=round(step.measurement_age_s, 3),
                                  saturated=step.saturated)
                status.values = key_values(values)
                array.status.append(status)
        self.diagnostics_pub.publish(array)

    def set_target_callback(self, request, response):
        modules = list(request.modules)
        if request.target_kind == 'clear':
            unknown = [m for m in modules if m not in self.controllers]
            if unknown:
                response.success, response.message = False, f'unknown module(s) {unknown}'
                return response
            self._hand_back(modules)
            response.success, response.message = True, f'cleared {", ".join(modules)}'
            return response
        try:
            targets = self._targets(modules, request.target_kind, request.target_points,
                                    request.shape_name, request.tolerance, request.timeout)
        except (TargetError, ValueError) as exc:
            response.success, response.message = False, f'refused: {exc}'
            self.get_logger().warning(response.message)
            return response
        ok, message = self._acquire(modules)
        if not ok:
            response.success, response.message = False, f'refused: {message}'
            self.get_logger().warning(response.message)
            return response
        self._apply(targets)
        response.success = True
        response.feedforward_cable_length = [targets[m][1].cable_length_m for m in modules]
        response.message = 'standing target set for ' + ', '.join(modules)
        return response

    def execute_callback(self, goal_handle):
        goal = goal_handle.request
        modules = list(goal.modules)
        started = self.now_s()
        result = ReachShape.Result(modules=modules)

        def finish(reason, message, success=False):
            result.success, result.stop_reason, result.message = success, reason, message
            result.elapsed = self.now_s() - started
            with self.lock:
                for m in modules:
                    ctl = self.controllers.get(m)
                    step = self.last_step.get(m)
                    result.final_error.append(step.error_m if step else math.nan)
                    result.final_tip_error.append(step.tip_error_m if step else math.nan)
                    result.cable_length.append(ctl.command_m if ctl and ctl.command_m
                                               is not None else math.nan)
                    result.correction.append(step.correction_m if step else math.nan)
            return result

        try:
            targets = self._targets(modules, goal.target_kind, goal.target_points,
                                    goal.shape_name, goal.tolerance, goal.timeout)
        except (TargetError, ValueError) as exc:
            goal_handle.abort()
            return finish('refused', str(exc))
        ok, message = self._acquire(modules)
        if not ok:
            goal_handle.abort()
            return finish('refused', message)
        generations = self._apply(targets)
        last_feedback = 0.0
        while rclpy.ok():
            if goal_handle.is_cancel_requested:
                self._hand_back(modules)
                goal_handle.canceled()
                return finish('canceled', 'canceled; the last command is held until the '
                                          'gait node takes the modules back')
            with self.lock:
                if any(self.generation[m] != generations[m] for m in modules):
                    goal_handle.abort()
                    return finish('preempted', 'another goal or target took a module')
                states = {m: self.controllers[m].state for m in modules}
                steps = {m: self.last_step.get(m) for m in modules}
            if time.monotonic() - last_feedback >= FEEDBACK_PERIOD_S:
                last_feedback = time.monotonic()
                fb = ReachShape.Feedback(modules=modules, elapsed=self.now_s() - started)
                fb.error = [s.error_m if s else math.nan for s in steps.values()]
                fb.cable_length = [s.command_m if s and s.command_m is not None else math.nan
                                   for s in steps.values()]
                fb.state = list(states.values())
                goal_handle.publish_feedback(fb)
            if all(s == REACHED for s in states.values()):
                if not goal.hold:
                    self._hand_back(modules)
                goal_handle.succeed()
                return finish('reached', 'every module within its tolerance', True)
            timed = [m for m, s in states.items() if s == TIMED_OUT]
            if timed:
                stale = [m for m in timed if steps[m] and ('stale after' in steps[m].reason
                                                            or 'no measurement' in steps[m].reason)]
                if not goal.hold:
                    self._hand_back(modules)
                goal_handle.abort()
                reason = 'stale' if stale else 'timed_out'
                return finish(reason, '; '.join(
                    f'{m}: {steps[m].reason if steps[m] else "timed out"}' for m in timed))
            time.sleep(GOAL_POLL_S)
        goal_handle.abort()
        return finish('canceled', 'node shutting down')

    def destroy_node(self):
        if self.recorder is not None:
            self.recorder.close()
        super().destroy_node()


def main(args=None) -> int:
    # Several threads: the action's loop waits on the controllers while the timer,
    # measurements and the gait node's reply keep arriving (one lock guards the
    # controllers).
    return run_node_main(args, 'shape_controller', ShapeControllerNode,
                         lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == '__main__':
    raise SystemExit(main())
