"""gait_node: plays a scene's gait, publishing every module's commanded cable length.

Run (``ros2 run softsnap_gaits gait_node`` or the installed script directly)::

    .venv/lib/softsnap_gaits/gait_node --ros-args -r __ns:=/brittle_star \\
        -p scene:=brittle_star -p gait:=walk

Topics (relative, so inside the node's namespace):
  ``<module>/cable_length/command`` softsnap_interfaces/CableLength, metres
  ``gait/phase``                    softsnap_interfaces/GaitPhase (with the commands
                                    published per module since start)
Services (private): ``~/start``, ``~/stop``, ``~/pause``, ``~/resume`` (std_srvs/Trigger),
``~/set_gait`` (softsnap_interfaces/SetGait), ``~/release_modules``
(softsnap_interfaces/ReleaseModules: the hand-over to the shape controller; released
modules get no command from this node until taken back, docs/control.md).
Parameters: scene, gait, rate, autostart, period, amplitude, time_scale, transition_time
(docs/gaits.md).

The node is a thin shell: the gait library (gaits.py) computes contractions and the
player (player.py) keeps the start/stop/pause state; here they are wired to ROS.

Time: the gait runs on the node's ROS clock (its timer and every stamp). With
``use_sim_time:=true`` that is ``/clock`` (a simulated robot, ``sim_robot``): the gait then
plays at the simulation's pace, however fast the simulation runs against the wall clock.
Until the first ``/clock`` arrives the ROS time is 0: an autostart waits for it, and the
trigger services refuse with that reason (a gait started at time 0 would jump ahead by
the whole simulated time when the clock arrives).
"""
from __future__ import annotations

import math

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.parameter import Parameter
from softsnap_ros.node import SoftSnapNode
from softsnap_ros.service_queues import create_queued_service
from softsnap_ros.spinning import run_node_main
from softsnap_interfaces.msg import CableLength, GaitPhase
from softsnap_interfaces.srv import ReleaseModules, SetGait
from std_srvs.srv import Trigger

from softsnap_gaits.gaits import GaitError, make_gait
from softsnap_gaits.player import PAUSED, RUNNING, GaitPlayer
from softsnap_model.scene import load_scene

#: Publishing rate limits (Hz).
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 1000.0
#: Largest period override (s) and amplitude override (m) the parameters accept.
MAX_PERIOD_S, MAX_AMPLITUDE_M = 3600.0, 0.2
MAX_TRANSITION_S = 10.0
#: Parameters that define the gait: a change rebuilds it (and may be refused).
GAIT_PARAMETERS = ('gait', 'period', 'amplitude', 'time_scale')


def _time_scale(text) -> float | str | None:
    """The time_scale parameter for make_gait: None (''), 'auto', or a number.

    Raises GaitError (a ValueError) quoting the value for anything else (make_gait
    checks the range).
    """
    if not isinstance(text, str):
        raise GaitError(f"time_scale must be text ('', 'auto' or a number), got {text!r}")
    text = text.strip()
    if not text:
        return None
    if text.lower() == 'auto':
        return 'auto'
    try:
        return float(text)
    except ValueError:
        raise GaitError(f"time_scale must be '', 'auto' or a number from 0.01 to 100, "
                        f'got {text!r}') from None


def _float_range(low: float, high: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=low, to_value=high, step=0.0)]


class GaitNode(SoftSnapNode):
    """Publishes the commanded cable length of each module of a scene at a fixed rate."""

    def __init__(self, **kwargs):
        super().__init__('gait_node', **kwargs)
        self.declare_parameter('scene', 'brittle_star', ParameterDescriptor(
            description='Scene name (brittle_star, starfish, snake, gripper, ring) or path '
                        'to a scene YAML file; fixed at start-up.', read_only=True))
        self.declare_parameter('gait', '', ParameterDescriptor(
            description="Gait name from the scene's gaits; empty: the scene's default gait."))
        self.declare_parameter('rate', 50.0, ParameterDescriptor(
            description='Publishing rate of commands and phase, in Hz.',
            floating_point_range=_float_range(MIN_RATE_HZ, MAX_RATE_HZ)))
        self.declare_parameter('autostart', True, ParameterDescriptor(
            description='Start the gait as soon as the node is up (otherwise call ~/start).'))
        self.declare_parameter('period', 0.0, ParameterDescriptor(
            description="Gait period override in s; 0 keeps the gait's own period.",
            floating_point_range=_float_range(0.0, MAX_PERIOD_S)))
        self.declare_parameter('amplitude', 0.0, ParameterDescriptor(
            description='Override of the largest cable contraction, in m (every module is '
                        "scaled alike); 0 keeps the gait's own amplitude.",
            floating_point_range=_float_range(0.0, MAX_AMPLITUDE_M)))
        self._accept_number_as_text('time_scale')
        self.declare_parameter('time_scale', '', ParameterDescriptor(
            description="Slow a gait down for the winches: '' keeps the gait's own "
                        "time_scale (1 unless its spec says otherwise; a gait faster than "
                        "75 % of a winch's speed is refused), 'auto' slows it just enough, "
                        'a number from 0.01 to 100 multiplies every duration.'))
        self.declare_parameter('transition_time', 0.3, ParameterDescriptor(
            description='Blend time in s from the last command to a new target on start, '
                        'stop and gait switches (0: jump).',
            floating_point_range=_float_range(0.0, MAX_TRANSITION_S)))

        # Scene and initial gait: a failure here is a configuration error the caller sees
        # (SceneError / GaitError propagate to main, which exits with the reason).
        self.scene = load_scene(self.get_parameter('scene').value)
        gait = self._build_gait(self._gait_config({}))
        self.player = GaitPlayer(gait, transition_s=self.get_parameter('transition_time').value)

        self.command_publishers = {
            # Depth 100 (2 s at 50 Hz, as the drivers' command queues): a reliable writer
            # keeps unacknowledged commands that long, so a subscriber starved for a moment
            # loses none. 1 s was too short for a 50-module driver container on a busy
            # 2-core machine (1 command of 193 lost under a load average of 30).
            m.name: self.create_publisher(CableLength, f'{m.name}/cable_length/command', 100)
            for m in self.scene.modules}
        # Depth 50 like the commands: the phase carries the sent counts a subscriber matches
        # its received counts against (by stamp), so a starved subscriber should miss none.
        self.phase_publisher = self.create_publisher(GaitPhase, 'gait/phase', 50)
        # Commands published per module since start (count), reported in every GaitPhase.
        self.commands_sent = {m.name: 0 for m in self.scene.modules}
        create_queued_service(self, Trigger, '~/start', self.start_callback)
        create_queued_service(self, Trigger, '~/stop', self.stop_callback)
        create_queued_service(self, Trigger, '~/pause', self.pause_callback)
        create_queued_service(self, Trigger, '~/resume', self.resume_callback)
        create_queued_service(self, SetGait, '~/set_gait', self.set_gait_callback)
        # Modules handed over to another commander (the shape controller): no commands.
        self.released: set[str] = set()
        create_queued_service(self, ReleaseModules, '~/release_modules', self.release_callback)
        self.timer = self.create_timer(1.0 / self.get_parameter('rate').value,
                                       self.timer_callback)
        self.add_on_set_parameters_callback(self.parameters_callback)

        # An autostart waits for a valid time (see "Time" above).
        self._autostart_pending = bool(self.get_parameter('autostart').value)
        self._start_if_pending()
        self.get_logger().info(
            f'scene {self.scene.name!r} ({self.scene.path}), modules '
            f'{", ".join(self.scene.module_names)}; gait {gait.name!r} ({gait.type}, period '
            f'{gait.period_s:g} s, amplitude {gait.amplitude_mm:g} mm); publishing '
            f'{self.get_parameter("rate").value:g} Hz on '
            f'{self.resolve_topic_name("gait/phase").rsplit("/", 2)[0]}/<module>/cable_length/command; '
            f'{"running" if self.player.state == RUNNING else "waiting for /clock (use_sim_time)" if self._autostart_pending else "waiting for ~/start"}')

    # ------------------------------------------------------------------ helpers
    def _accept_number_as_text(self, name: str) -> None:
        """Let ``-p time_scale:=2`` (typed as a number) mean the text '2'."""
        overrides = getattr(self, '_parameter_overrides', None)
        p = overrides.get(name) if isinstance(overrides, dict) else None
        if p is not None and p.type_ in (Parameter.Type.INTEGER, Parameter.Type.DOUBLE):
            overrides[name] = Parameter(name, Parameter.Type.STRING, str(p.value))

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _start_if_pending(self, now_s: float | None = None) -> None:
        """Start an autostart once the clock has a time (> 0; with use_sim_time, the
        first /clock)."""
        now_s = self._now_s() if now_s is None else now_s
        if self._autostart_pending and now_s > 0.0:
            self._autostart_pending = False
            self.player.start(now_s)

    def _gait_config(self, changes: dict) -> dict:
        """Current gait, period and amplitude parameters with `changes` applied."""
        config = {k: self.get_parameter(k).value for k in GAIT_PARAMETERS}
        config.update(changes)
        return config

    def _build_gait(self, config: dict):
        """Gait from parameter values (period s, amplitude m; 0 = the gait's own)."""
        name = config['gait'] or self.scene.default_gait
        period = config['period'] or None
        amplitude = config['amplitude'] * 1000.0 if config['amplitude'] else None
        return make_gait(name, self.scene, period_s=period, amplitude_mm=amplitude,
                         time_scale=_time_scale(config['time_scale']))

    # ------------------------------------------------------------------ callbacks
    def parameters_callback(self, parameters: list[Parameter]) -> SetParametersResult:
        """Validate a parameter change and apply it; refuse it with the reason otherwise."""
        changes = {p.name: p.value for p in parameters}
        gait_changes = {k: v for k, v in changes.items() if k in GAIT_PARAMETERS}
        new_gait = None
        if gait_changes:
            try:
                new_gait = self._build_gait(self._gait_config(gait_changes))
            except (GaitError, ValueError) as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        if 'rate' in changes and not (isinstance(changes['rate'], float)
                                      and MIN_RATE_HZ <= changes['rate'] <= MAX_RATE_HZ):
            return SetParametersResult(
                successful=False, reason=f'rate must be a number from {MIN_RATE_HZ:g} to '
                                         f'{MAX_RATE_HZ:g} Hz, got {changes["rate"]!r}')
        if 'transition_time' in changes:
            value = changes['transition_time']
            if not (isinstance(value, float) and 0.0 <= value <= MAX_TRANSITION_S):
                return SetParametersResult(
                    successful=False, reason=f'transition_time must be from 0 to '
                                             f'{MAX_TRANSITION_S:g} s, got {value!r}')
        # Everything checked: apply.
        now = self._now_s()
        if new_gait is not None:
            ok, message = self.player.switch(new_gait, now)
            if not ok:
                return SetParametersResult(successful=False, reason=message)
            self.get_logger().info(message)
        if 'transition_time' in changes:
            self.player.transition_s = changes['transition_time']
        if 'rate' in changes:
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(1.0 / changes['rate'], self.timer_callback)
        return SetParametersResult(successful=True)

    def timer_callback(self) -> None:
        now = self.get_clock().now()
        if now.nanoseconds <= 0:
            return   # no time yet (use_sim_time before the first /clock): nothing to stamp
        self._start_if_pending(now.nanoseconds * 1e-9)
        out = self.player.tick(now.nanoseconds * 1e-9)
        stamp = now.to_msg()
        if out.cable_length_mm is not None:
            for name, length_mm in zip(self.player.gait.module_names, out.cable_length_mm):
                if name in self.released:
                    continue
                msg = CableLength()
                msg.header.stamp = stamp
                msg.cable_length = float(length_mm) / 1000.0
                self.command_publishers[name].publish(msg)
                self.commands_sent[name] += 1
        phase = GaitPhase()
        phase.header.stamp = stamp
        phase.gait = self.player.gait.name
        phase.running = out.state == RUNNING
        phase.paused = out.state == PAUSED
        phase.phase = min(max(out.phase, 0.0), 1.0)
        phase.cycle = out.cycle
        phase.period = float(self.player.gait.period_s)
        phase.modules = list(self.commands_sent)
        phase.commands_sent = list(self.commands_sent.values())
        self.phase_publisher.publish(phase)

    def _trigger(self, action, response: Trigger.Response) -> Trigger.Response:
        now = self._now_s()
        if now <= 0.0:
            response.success = False
            response.message = 'no time yet: waiting for the first /clock (use_sim_time is set)'
            self.get_logger().warning(response.message)
            return response
        self._autostart_pending = False   # a service call takes over from the autostart
        response.success, response.message = action(now)
        self.get_logger().info(response.message)
        return response

    def start_callback(self, request, response):
        return self._trigger(self.player.start, response)

    def stop_callback(self, request, response):
        return self._trigger(self.player.stop, response)

    def pause_callback(self, request, response):
        return self._trigger(self.player.pause, response)

    def resume_callback(self, request, response):
        return self._trigger(self.player.resume, response)

    def set_gait_callback(self, request: SetGait.Request, response: SetGait.Response):
        """Switch gait through the parameters, so parameters and the running gait agree."""
        values = {'gait': request.gait or self.get_parameter('gait').value,
                  'period': float(request.period), 'amplitude': float(request.amplitude)}
        for key, value in (('period', request.period), ('amplitude', request.amplitude)):
            if not math.isfinite(value) or value < 0.0:
                response.success = False
                response.message = f'{key} must be >= 0 (0 keeps the default), got {value!r}'
                return response
        result = self.set_parameters_atomically(
            [Parameter(k, value=v) for k, v in values.items()])
        response.success = result.successful
        if not result.successful:
            response.message = result.reason
        else:
            gait = self.player.gait
            response.message = (f'gait {gait.name!r}: period {gait.period_s:g} s, amplitude '
                                f'{gait.amplitude_mm:g} mm, {self.player.state}')
        return response


    def release_callback(self, request: ReleaseModules.Request,
                         response: ReleaseModules.Response):
        """Release modules to another commander, or take them back (all or nothing)."""
        unknown = [m for m in request.modules if m not in self.command_publishers]
        if unknown:
            response.success = False
            response.message = (f'unknown module(s) {", ".join(map(repr, unknown))}; '
                                f'modules are {", ".join(self.command_publishers)}')
        else:
            before = set(self.released)
            if request.release:
                self.released.update(request.modules)
            else:
                self.released.difference_update(request.modules)
            response.success = True
            verb = 'released to' if request.release else 'taken back from'
            response.message = (f'{", ".join(request.modules) or "no module"} {verb} '
                                f'{request.requester or "a caller"}')
            if self.released != before:   # the controller repeats its releases: log changes
                self.get_logger().info(response.message)
        response.released = sorted(self.released)
        return response


def main(args=None) -> int:
    # One thread: the timer, services and parameter callbacks all touch the player, and
    # serial execution keeps them consistent without locks.
    return run_node_main(args, 'gait_node', GaitNode)


if __name__ == '__main__':
    raise SystemExit(main())
