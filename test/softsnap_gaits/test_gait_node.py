"""gait_node in its own process: publishing rate, services, gait switching and refusals."""
import math
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

NS = '/brittle_star'
TIMEOUT_S = 20.0          # discovery on a loaded 2-core machine can take seconds


def straight_length_m(module):
    from softsnap_model.scene import load_scene
    return load_scene('brittle_star').module(module).straight_length_mm / 1000.0


def subscribe(node, topic, msg_type, depth=200):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    received = []
    qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(msg_type, topic, lambda m: received.append((time.monotonic(), m)), qos)
    return received


def stamp_s(msg) -> float:
    """Header stamp of a message in seconds (the publishing node's clock)."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def measure_rate(node, received, window_s):
    """Messages received during the next `window_s` seconds and their mean rate (Hz).

    The rate is taken from the header stamps, i.e. it is the rate at which the node
    published them: arrival times in this process also carry its own scheduling (a test
    process starved for 100 ms takes the backlog in a burst, which says nothing about the
    publisher).
    """
    start = len(received)
    deadline = time.monotonic() + window_s
    node.spin_until(lambda: time.monotonic() >= deadline, window_s + 1.0)
    window = received[start:]
    assert len(window) >= 3, f'only {len(window)} messages in {window_s} s'
    stamps = [stamp_s(m) for _, m in window]
    return (len(stamps) - 1) / (stamps[-1] - stamps[0]), window


def wait_for_period(node, received, period_s):
    """Spin until two consecutive messages are stamped about `period_s` apart.

    After a rate change, commands from the old timer may still be queued here; the
    measurement window starts once the new timer's spacing shows up.
    """
    def new_spacing():
        if len(received) < 2:
            return False
        dt = stamp_s(received[-1][1]) - stamp_s(received[-2][1])
        return abs(dt - period_s) < 0.2 * period_s

    assert node.spin_until(new_spacing, TIMEOUT_S), 'the new rate never showed up'


def check_rate(node, received, rate_hz, window_s=1.5):
    """Assert the node publishes at `rate_hz`; returns (mean rate, messages).

    The machine is shared (2 cores, other engineers' tests): a starved process misses
    timer periods, which lowers the mean rate but not the typical interval. So the median
    interval of the header stamps must match the period closely and the mean rate (also
    from the stamps) must lie between 60 % and 110 % of the target. Delivery is checked
    by count: the window must hold at least 60 % of the messages the rate implies.
    """
    mean, window = measure_rate(node, received, window_s)
    stamps = np.array([stamp_s(m) for _, m in window])
    median_stamp_hz = 1.0 / np.median(np.diff(stamps))
    print(f'target {rate_hz:g} Hz: mean {mean:.1f} Hz, median interval {median_stamp_hz:.1f} Hz '
          f'(stamps), {len(window)} messages received in {window_s} s')
    assert median_stamp_hz == pytest.approx(rate_hz, rel=0.05)
    assert 0.6 * rate_hz <= mean <= 1.1 * rate_hz
    assert len(window) >= 0.6 * rate_hz * window_s
    return mean, window


def set_parameters(node, client, **values):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    request = SetParameters.Request(
        parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
    return node.call(client, request, TIMEOUT_S).results


def test_gait_node_publishes_at_the_configured_rate(start_node, ros_node):
    from rcl_interfaces.srv import SetParameters
    from softsnap_interfaces.msg import CableLength, GaitPhase

    proc = start_node('softsnap_gaits', 'gait_node', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', 'gait:=walk', '-p', 'rate:=50')
    yellow = subscribe(ros_node, f'{NS}/yellow/cable_length/command', CableLength)
    blue = subscribe(ros_node, f'{NS}/blue/cable_length/command', CableLength)
    phases = subscribe(ros_node, f'{NS}/gait/phase', GaitPhase)
    assert ros_node.spin_until(lambda: len(yellow) > 5 and len(phases) > 5, TIMEOUT_S), \
        proc.output()

    _, window = check_rate(ros_node, yellow, 50.0, window_s=3.5)
    # Commands follow the walk: over a 3 s cycle yellow holds straight and 30 mm contracted.
    lengths = [m.cable_length for _, m in window]
    straight = straight_length_m('yellow')
    assert max(lengths) == pytest.approx(straight, abs=1e-9)
    assert min(lengths) == pytest.approx(straight - 0.030, abs=1e-9)
    assert all(straight - 0.030 - 1e-9 <= v <= straight + 1e-9 for v in lengths)
    assert min(m.cable_length for _, m in blue) == pytest.approx(
        straight_length_m('blue') - 0.030, abs=1e-9)
    phase = phases[-1][1]
    assert phase.gait == 'walk' and phase.running and not phase.paused
    assert phase.period == 3.0 and 0.0 <= phase.phase <= 1.0 and phase.cycle >= 1
    # Its own counts: one command per module per tick, at least as many as arrived here
    # with a stamp up to this phase's (a phase is published after its tick's commands).
    assert list(phase.modules) == ['yellow', 'blue', 'green', 'red', 'orange']
    sent = dict(zip(phase.modules, phase.commands_sent))
    assert len(set(sent.values())) == 1, sent
    stamp = stamp_s(phase)
    assert sent['yellow'] >= sum(1 for _, m in yellow if stamp_s(m) <= stamp) > 5

    # Change the rate at run time, then refuse an out-of-range one.
    client = ros_node.create_client(SetParameters, f'{NS}/gait_node/set_parameters')
    assert set_parameters(ros_node, client, rate=20.0)[0].successful
    wait_for_period(ros_node, yellow, 1.0 / 20.0)        # let the new timer settle
    check_rate(ros_node, yellow, 20.0)
    result = set_parameters(ros_node, client, rate=5000.0)[0]
    assert not result.successful and 'rate' in result.reason
    assert proc.alive()


def test_gait_node_services_start_stop_pause_resume_switch(start_node, ros_node):
    from rcl_interfaces.srv import SetParameters
    from softsnap_interfaces.msg import CableLength, GaitPhase
    from softsnap_interfaces.srv import SetGait
    from std_srvs.srv import Trigger

    proc = start_node('softsnap_gaits', 'gait_node', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', 'autostart:=false', '-p', 'rate:=50',
                      '-p', 'transition_time:=0.1')
    yellow = subscribe(ros_node, f'{NS}/yellow/cable_length/command', CableLength)
    phases = subscribe(ros_node, f'{NS}/gait/phase', GaitPhase)
    trigger = {name: ros_node.create_client(Trigger, f'{NS}/gait_node/{name}')
               for name in ('start', 'stop', 'pause', 'resume')}
    set_gait = ros_node.create_client(SetGait, f'{NS}/gait_node/set_gait')
    params = ros_node.create_client(SetParameters, f'{NS}/gait_node/set_parameters')

    def last_phase():
        return phases[-1][1] if phases else None

    def wait_phase(pred):
        n = len(phases)
        ok = ros_node.spin_until(lambda: len(phases) > n and pred(phases[-1][1]), TIMEOUT_S)
        assert ok, f'phase never matched; last {last_phase()}\n{proc.output()}'

    # Not started: phase says stopped, and no commands are published.
    wait_phase(lambda p: not p.running and not p.paused and p.gait == 'walk')
    assert yellow == []
    assert not ros_node.call(trigger['pause'], Trigger.Request(), TIMEOUT_S).success

    response = ros_node.call(trigger['start'], Trigger.Request(), TIMEOUT_S)
    assert response.success and 'walk' in response.message
    wait_phase(lambda p: p.running)
    assert ros_node.spin_until(lambda: len(yellow) > 10, TIMEOUT_S)
    assert not ros_node.call(trigger['start'], Trigger.Request()).success   # already running

    # Pause: commands keep coming but hold still; resume: they move again.
    assert ros_node.call(trigger['pause'], Trigger.Request()).success
    wait_phase(lambda p: p.paused and not p.running)
    # Select the held commands by stamp, not by arrival: commands published just before
    # the pause can still be in this process's queue when the paused phase is taken (the
    # executor serves the two topics independently), and they differ from the held value.
    # Every tick stamped at or after this paused phase message ran while paused.
    paused_at = stamp_s(phases[-1][1])
    measure_rate(ros_node, yellow, 0.6)
    held = [m.cable_length for _, m in yellow if stamp_s(m) >= paused_at]
    assert len(held) >= 3, f'only {len(held)} commands while paused'
    assert len(set(held)) == 1, sorted(set(held))
    assert ros_node.call(trigger['resume'], Trigger.Request()).success
    wait_phase(lambda p: p.running and not p.paused)
    _, moving = measure_rate(ros_node, yellow, 3.2)            # a whole 3 s cycle
    assert len({round(m.cable_length, 9) for _, m in moving}) > 2

    # Switch gait and period through the service.
    response = ros_node.call(set_gait, SetGait.Request(gait='walk_reverse', period=2.0))
    assert response.success, response.message
    wait_phase(lambda p: p.gait == 'walk_reverse' and p.period == 2.0 and p.running)
    # Unknown gait and out-of-range amplitude are refused with a reason; the gait stays.
    response = ros_node.call(set_gait, SetGait.Request(gait='fly'))
    assert not response.success
    assert "unknown gait 'fly'" in response.message and 'walk_reverse' in response.message
    response = ros_node.call(set_gait, SetGait.Request(gait='walk', amplitude=0.09))
    # (yellow reaches 70.374 mm with the CAD's 3 mm ribs, below the scene's 80 mm)
    assert not response.success and '70.374 mm' in response.message
    result = set_parameters(ros_node, params, gait='hop')[0]
    assert not result.successful and "unknown gait 'hop'" in result.reason
    wait_phase(lambda p: p.gait == 'walk_reverse' and p.period == 2.0)
    # Too fast for the winches (60 mm on walk_reverse's 0.95 s ramps: 99.2 mm/s > 69.3
    # mm/s): refused with the numbers. With time_scale auto the node slows the gait just
    # enough: 99.21 / 69.3 = 1.432 times the 2 s period.
    result = set_parameters(ros_node, params, amplitude=0.06)[0]
    assert not result.successful and 'needs 99.2 mm/s' in result.reason, result.reason
    result = set_parameters(ros_node, params, time_scale='fast')[0]
    assert not result.successful and "got 'fast'" in result.reason
    assert set_parameters(ros_node, params, time_scale='auto')[0].successful
    assert set_parameters(ros_node, params, amplitude=0.06)[0].successful
    scaled = 2.0 * (60.0 * math.pi / 1.9) / (0.75 * 92.4)
    wait_phase(lambda p: p.gait == 'walk_reverse' and abs(p.period - scaled) < 1e-6)

    # Stop: the modules relax to straight, then the node stops commanding them.
    response = ros_node.call(trigger['stop'], Trigger.Request())
    assert response.success
    wait_phase(lambda p: not p.running and not p.paused)
    # Judge by the node's clock (header stamps), not by this process's wall clock: under
    # load either process can be starved for a while, and commands published during the
    # relax blend may arrive late. The stop happened at or before `stopped_at`; the blend
    # (transition_time 0.1 s) is over by stopped_at + 0.1, the first tick after that
    # publishes the straight length and later ticks publish no command, only the phase.
    stopped_at = stamp_s(phases[-1][1])

    def node_time_passed(dt):
        return lambda: phases and stamp_s(phases[-1][1]) >= stopped_at + dt

    assert ros_node.spin_until(node_time_passed(1.0), TIMEOUT_S), proc.output()
    count = len(yellow)
    last_command = max((m for _, m in yellow), key=stamp_s)
    assert last_command.cable_length == pytest.approx(straight_length_m('yellow'), abs=1e-9)
    after_blend = [stamp_s(m) - stopped_at for _, m in yellow if stamp_s(m) >= stopped_at + 0.1]
    assert len(after_blend) <= 1, f'commands after the relax blend at +{after_blend} s'
    # Another half second of node time (phases keep coming): still no command.
    assert ros_node.spin_until(node_time_passed(1.5), TIMEOUT_S), proc.output()
    assert len(yellow) == count
    assert proc.alive()


@pytest.mark.parametrize('args, reason', [
    (['-p', 'scene:=dragon'], "unknown scene 'dragon'; known scenes:"),
    (['-p', 'scene:=brittle_star', '-p', 'gait:=fly'],
     "unknown gait 'fly'; known gaits: walk, walk_reverse"),
    (['-p', 'scene:=brittle_star', '-p', 'amplitude:=0.06'], "needs 125.7 mm/s of cable"),
    (['-p', 'scene:=brittle_star', '-p', 'time_scale:=1000'], 'time scale override: expected auto'),
])
def test_gait_node_refuses_invalid_scene_or_gait_at_start(start_node, args, reason):
    proc = start_node('softsnap_gaits', 'gait_node', '--ros-args', *args)
    proc.proc.wait(TIMEOUT_S)
    assert proc.proc.returncode == 2
    assert reason in proc.output()
