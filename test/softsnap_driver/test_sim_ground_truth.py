"""sim_robot's ground truth: every module's simulated rib centres as MeasuredShape.

Over real DDS and real loopback HTTP: a sim_robot process (the brittle star floating,
gravity off, so a leg settles on the quasi-static shape), one leg hauled in through its
firmware's ``set`` request, and the published ground truth compared with the exact
quasi-static model (``solve_forward``, an independent solver) at the cable length the
message reports.
"""
from __future__ import annotations

import math
import urllib.request

import numpy as np
import pytest

from softsnap_driver.protocol import encode_set_request
from softsnap_driver.sim_observation import ObservationWorker, TickSchedule

NS = '/gt'
TIMEOUT_S = 120.0    # a model build and a simulation slower than real time on a busy machine


def test_tick_schedules_with_dividing_rates_fire_on_the_same_ticks():
    ticks = [k * 0.02 for k in range(500)]            # the 50 Hz /clock grid, 10 s
    fast, slow = TickSchedule(30.0), TickSchedule(15.0)
    fast_ticks = {t for t in ticks if fast.due(t)}
    slow_ticks = {t for t in ticks if slow.due(t)}
    assert slow_ticks <= fast_ticks
    # 15 Hz on a 50 Hz grid: 150 frames in 10 s, never two on one tick.
    assert len(slow_ticks) == 150 and len(fast_ticks) == 300
    assert not TickSchedule(10.0).due(-0.5)
    with pytest.raises(ValueError, match='rate'):
        TickSchedule(0.0)


def test_the_observation_worker_reports_a_failure_and_goes_on_and_drops_when_full():
    import threading
    failures, handled = [], []
    gate = threading.Event()

    def handle(item):
        gate.wait(10.0)
        if item == 'bad':
            raise RuntimeError('boom')
        handled.append(item)

    worker = ObservationWorker('test', handle, lambda item, exc: failures.append((item, exc)),
                               depth=2)
    assert worker.offer('bad')
    # The thread may have taken 'bad' already: fill the queue until an offer is refused.
    offered = ['a', 'b', 'c', 'd']
    accepted = [item for item in offered if worker.offer(item)]
    assert worker.dropped == len(offered) - len(accepted) >= 1
    gate.set()
    worker.stop()
    assert handled == accepted and not worker.alive
    assert len(failures) == 1 and failures[0][0] == 'bad' and 'boom' in str(failures[0][1])


def _http_set(port: int, count: int) -> None:
    head = encode_set_request(count, 200).decode('ascii').split(' ')[1]   # '/?set=...'
    with urllib.request.urlopen(f'http://127.0.0.1:{port}{head}', timeout=10.0) as reply:
        assert reply.status == 200


@pytest.mark.ros
def test_ground_truth_over_dds_matches_the_quasi_static_model_of_a_settled_leg(
        start_node, ros_node, slot_port):
    from softsnap_interfaces.msg import MeasuredShape
    from softsnap_model import solve_forward
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    names = [m.name for m in scene.modules]
    port_base = slot_port(len(names))
    proc = start_node('softsnap_driver', 'sim_robot', '--ros-args', '-r', f'__ns:={NS}',
                      '-p', 'scene:=brittle_star', '-p', 'gravity:=false',
                      '-p', f'port_base:={port_base}', '-p', 'links_per_segment:=2',
                      '-p', 'ground_truth_rate_hz:=10.0')
    got = {n: [] for n in names}
    for n in names:
        ros_node.create_subscription(MeasuredShape, f'{NS}/{n}/shape/ground_truth',
                                     got[n].append, 50)
    assert ros_node.spin_until(lambda: all(got.values()), TIMEOUT_S), proc.output()[-3000:]
    first = got[names[0]][-1]
    assert first.module == names[0] and first.source == 'simulator'
    assert first.header.frame_id == f'brittle_star/{names[0]}'
    assert len(first.rib_centers) == 12 and list(first.visible) == [True] * 12
    assert first.residual == 0.0 and math.isnan(first.rmse_to_model)
    # The straight module at start: rib 0 at the origin, ribs 18 mm apart along +x.
    straight = np.array([[p.x, p.y] for p in first.rib_centers])
    assert np.allclose(straight[:, 0], np.arange(12) * 0.018, atol=5e-4)
    assert np.allclose(straight[:, 1], 0.0, atol=5e-4)

    # Haul 20 mm of the first leg's cable in through the firmware protocol (real HTTP).
    leg = names[0]
    counts = int(round(20.0 * scene.modules[0].counts_per_mm))
    straight_m = got[leg][-1].cable_length
    _http_set(port_base, counts)

    def settled():
        shapes = got[leg]
        if len(shapes) < 5 or straight_m - shapes[-1].cable_length < 0.019:
            return False
        last = [np.array([[p.x, p.y] for p in s.rib_centers]) for s in shapes[-5:]]
        # The tip still by less than 0.05 mm over the last five samples (0.4 s).
        return max(np.linalg.norm(a[-1] - last[-1][-1]) for a in last) < 5e-5

    assert ros_node.spin_until(settled, TIMEOUT_S), proc.output()[-3000:]
    shape = got[leg][-1]
    ref = solve_forward(scene.skeleton, scene.modules[0].threading_mm, shape.cable_length * 1e3)
    measured_mm = np.array([[p.x, p.y] for p in shape.rib_centers]) * 1e3
    error_mm = np.linalg.norm(measured_mm - ref.rib_centers[:, :2], axis=1)
    assert error_mm.max() < 0.5, error_mm          # the physics' fidelity contract
    assert np.linalg.norm(measured_mm[-1] - straight[-1] * 1e3) > 10.0   # it did bend
    # Stamps are simulation time, increasing; the other legs stayed straight.
    stamps = [s.header.stamp.sec + 1e-9 * s.header.stamp.nanosec for s in got[leg]]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    other = np.array([[p.x, p.y] for p in got[names[1]][-1].rib_centers])
    assert np.allclose(other, straight, atol=5e-4)
    assert proc.alive(), proc.output()[-3000:]
    assert proc.stop() == 0, proc.output()[-3000:]


@pytest.mark.ros
def test_a_ground_truth_rate_above_the_clock_rate_is_refused_with_the_reason(start_node):
    proc = start_node('softsnap_driver', 'sim_robot', '--ros-args', '-p', 'scene:=gripper',
                      '-p', 'ground_truth_rate_hz:=80.0')
    assert proc.proc.wait(120) == 2, proc.output()
    assert 'ground_truth_rate_hz must be in [0, clock_rate_hz = 50]' in proc.output()
    assert 'Traceback' not in proc.output()
