"""One closed-loop reach over the ROS graph, open loop first: for the benchmark, the demo
and the tests.

The shape_controller node runs in its own process; this process hosts the physics plant
(:mod:`softsnap_gaits.physics_plant`) and a client. A case:

1. the target: where the physics module's tip rests at a cable length (so the robot can
   reach it; the controller's model cannot, exactly);
2. open loop: the model's feedforward length for that target (the same model the node
   uses, :func:`softsnap_gaits.shape_control.module_model`) is commanded directly and the
   plant left to settle; the tip error is the open-loop error;
3. closed loop: a ReachShape goal for the same target; the noise-free tip error is
   followed for ``observe_s`` after the goal was sent.

Errors are the plant's noise-free tip (the measured one may carry noise and latency),
averaged over a trailing :data:`AVERAGE_S`: the hanging finger with a 20 g load swings by
up to ~1 mm at 3-4 Hz in the physics with the cable held fixed (its damping is estimated
for 1 g ribs), open loop as much as closed loop, which no cable command removes. The
swing's size is logged as ``swing``. ``stable`` means the loop settled: the averaged error
stays within the tolerance and the winch's length within :data:`STEADY_LENGTH_M` over the
last 2 s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Tip error (m) a case must settle within.
SETTLE_TOLERANCE_M = 0.001
#: Trailing window (s) the tip is averaged over.
AVERAGE_S = 0.5
#: Largest spread (m) of the winch's length over the last 2 s of a stable case.
STEADY_LENGTH_M = 0.0005


@dataclass(frozen=True)
class CaseResult:
    """One case (SI units inside; the benchmark prints mm)."""

    name: str
    open_loop_tip_error_m: float
    closed_loop_tip_error_m: float
    settle_time_s: float
    stable: bool
    stop_reason: str
    message: str

    def as_json(self) -> dict:
        return {'name': self.name,
                'open_loop_tip_error_mm': round(self.open_loop_tip_error_m * 1e3, 3),
                'closed_loop_tip_error_mm': round(self.closed_loop_tip_error_m * 1e3, 3),
                'settle_time_s': (round(self.settle_time_s, 3)
                                  if math.isfinite(self.settle_time_s) else None),
                'stable': self.stable}


def spin_for(executor, seconds: float, until=None) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if until is not None and until():
            return True
        executor.spin_once(timeout_sec=0.02)
    return bool(until()) if until is not None else True


def averaged(history, window_s: float = AVERAGE_S) -> list:
    """`history` with each tip replaced by its mean over the trailing window."""
    times = np.array([h[0] for h in history])
    tips = np.array([h[1] for h in history])
    start = np.searchsorted(times, times - window_s)
    cumulative = np.vstack([np.zeros(2), np.cumsum(tips, axis=0)])
    counts = (np.arange(len(times)) + 1 - start)[:, None]
    means = (cumulative[1:] - cumulative[start]) / counts
    return [(t, m, h[2]) for t, m, h in zip(times, means, history)]


def settle_time_s(history, start_s: float, target, tolerance_m: float) -> float:
    """Time after `start_s` from which the tip error stays within the tolerance to the
    end of `history` (inf if it never does)."""
    inside_since = None
    for t, tip, _ in history:
        if t < start_s:
            continue
        if np.linalg.norm(tip - target) <= tolerance_m:
            if inside_since is None:
                inside_since = t
        else:
            inside_since = None
    return math.inf if inside_since is None else inside_since - start_s


def run_case(node, executor, scene, module: str, name: str, *, contraction_m: float,
             physics: dict, latency_s: float = 0.0, noise_m: float = 0.0,
             open_loop_s: float = 3.0, observe_s: float = 6.0, timeout_s: float = 10.0,
             seed: int = 0, camera_rate_hz: float = 0.0, on_plant=None,
             log=print) -> CaseResult:
    """Run one case against a shape_controller serving `module` of `scene`.

    With `camera_rate_hz` the plant also publishes camera images (the marker tracker's
    input); ``on_plant(plant)`` runs once the plant is up, before the open loop (the
    benchmark starts the tracker and the controller there)."""
    from rclpy.action import ActionClient
    from softsnap_interfaces.action import ReachShape
    from softsnap_interfaces.msg import CableLength
    from geometry_msgs.msg import Point

    from softsnap_gaits.physics_plant import MujocoModulePlant, settled_tip_m
    from softsnap_gaits.shape_control import make_target, module_model

    model = module_model(scene, module)
    length_true = model.range_m[1] - contraction_m
    target = settled_tip_m(scene, module, length_true, **physics)
    feedforward, _ = model.closest_length(make_target('tip', target, model.n_ribs))
    plant = MujocoModulePlant(node, scene, module, latency_s=latency_s, noise_m=noise_m,
                              seed=seed, initial_length_m=model.range_m[1],
                              camera_rate_hz=camera_rate_hz, **physics)
    try:
        if on_plant is not None:
            on_plant(plant)
        command = node.create_publisher(CableLength, f'{module}/cable_length/command', 10)
        # Open loop: the feedforward commanded directly (the controller has no target).
        t_open = time.monotonic()
        while time.monotonic() - t_open < open_loop_s:
            msg = CableLength()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.cable_length = feedforward
            command.publish(msg)
            spin_for(executor, 0.05)
        tail = [h for h in plant.history() if h[0] >= time.monotonic() - AVERAGE_S]
        open_err = float(np.mean([np.linalg.norm(tip - target) for _, tip, _ in tail]))
        node.destroy_publisher(command)
        client = ActionClient(node, ReachShape, 'shape_controller/reach_shape')
        if not spin_for(executor, 30.0, client.server_is_ready):
            raise RuntimeError('shape_controller/reach_shape not available')
        goal = ReachShape.Goal(modules=[module], target_kind='tip',
                               target_points=[Point(x=float(target[0]), y=float(target[1]))],
                               tolerance=SETTLE_TOLERANCE_M, timeout=timeout_s,
                               hold=True)
        t_goal = time.monotonic()
        sent = client.send_goal_async(goal)
        spin_for(executor, 30.0, sent.done)
        handle = sent.result()
        if handle is None or not handle.accepted:
            raise RuntimeError('goal not accepted')
        result_future = handle.get_result_async()
        spin_for(executor, observe_s, lambda: time.monotonic() - t_goal >= observe_s)
        spin_for(executor, 30.0, result_future.done)
        result = result_future.result().result if result_future.done() else None
        # The target is held after the goal: the tail shows it stays there.
        raw = plant.history()
        history = averaged(raw)
        settle = settle_time_s(history, t_goal, target, SETTLE_TOLERANCE_M)
        end = history[-1][0]
        last = [np.linalg.norm(tip - target) for t, tip, _ in history if t >= end - 1.0]
        final = [np.linalg.norm(tip - target) for t, tip, _ in history if t >= end - 2.0]
        lengths = [length for t, _, length in history if t >= end - 2.0]
        swing = max(np.linalg.norm(r[1] - a[1]) for r, a in zip(raw, history)
                    if r[0] >= end - 2.0)
        stable = bool(final) and max(final) <= SETTLE_TOLERANCE_M and math.isfinite(settle) \
            and float(np.ptp(lengths)) <= STEADY_LENGTH_M
        client.destroy()
        out = CaseResult(name, open_err, float(np.mean(last)), settle, stable,
                         result.stop_reason if result else 'no result',
                         result.message if result else '')
        log(f'{name}: target tip ({target[0] * 1e3:.1f}, {target[1] * 1e3:.1f}) mm, true length '
            f'{length_true * 1e3:.2f} mm, feedforward {feedforward * 1e3:.2f} mm; open loop '
            f'{open_err * 1e3:.2f} mm; closed loop {out.closed_loop_tip_error_m * 1e3:.3f} mm, '
            f'settled {settle:.2f} s, stable {stable} (winch spread {np.ptp(lengths) * 1e3:.3f} '
            f'mm, swing {swing * 1e3:.2f} mm); goal {out.stop_reason}: {out.message}')
        return out
    finally:
        plant.close()


def tagged_scene_file(scene: str, module: str, tag_id: int, directory) -> Path:
    """A copy of `scene` (name or path) in `directory` with ArUco tag `tag_id` on
    `module`'s case, for the marker tracker of a camera filming that module (the
    shipped gripper has no tags: a top-down camera sees no hanging finger's face)."""
    import yaml
    from softsnap_model.scene import find_scene
    source = Path(find_scene(scene))
    data = yaml.safe_load(source.read_text())
    names = [m['name'] for m in data['modules']]
    if module not in names:
        raise ValueError(f'no module {module!r} in scene {scene!r} (modules: {names})')
    for entry in data['modules']:
        if entry['name'] == module:
            entry['markers'] = {'tag_id': int(tag_id)}
    path = Path(directory) / f'{source.stem}_tag{int(tag_id)}_{module}.yaml'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def camera_tracker_args(namespace: str, scene_file, plane_distance_m: float) -> list[str]:
    """The ``--ros-args`` of the marker_tracker that measures the plant's camera images
    (in `namespace`, the tagged scene, reliable images: a lost 1 MB frame is a lost
    measurement)."""
    return ['-r', f'__ns:={namespace}', '-p', f'scene:={scene_file}',
            '-p', f'plane_distance:={plane_distance_m:.6f}', '-p', 'reliable_images:=true',
            '-r', 'image_raw:=camera/image_raw', '-r', 'camera_info:=camera/camera_info']
