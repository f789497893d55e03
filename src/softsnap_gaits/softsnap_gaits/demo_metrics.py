"""The demo's metrics, from what the observer saw: shape and tip errors, travel, the
grasp, command counts (plain functions of recorded samples; no ROS)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np


from .demo_config import (PAYLOAD_HOLD_TOL_MM, PHYSICS_PAYLOADS, SETTLED_HOLD_TOL_M,
                          SETTLED_SNAPSHOTS)
from .demo_observer import ModuleStats, Observer


def simulated_shape_errors_mm(s: ModuleStats, skeleton, threading_mm) -> tuple[list, list]:
    """Simulated versus predicted shape, one value per simulated shape, mm: the root mean
    square over the rib centres of their distances (the paper's measure against its
    experiments), the predicted shape being ``solve_forward``'s for the cable length of
    that very snapshot, so what remains is gravity, contact and dynamics.

    (Pairing a snapshot with the latest predicted shape received instead compared shapes
    of different cable lengths while a winch moved: the measured length, its solve and
    the snapshot reach the demo at different times.)

    Returns the errors and, parallel to them, whether the snapshot's winch had been at
    rest (the same cable length) for ``SETTLED_SNAPSHOTS`` snapshots before it.
    """
    from softsnap_model.forward import solve_forward
    errors, settled = [], []
    cache: dict[float, np.ndarray] = {}
    run = 0
    previous = None
    for centres_m, length_m in s.simulated_shapes:
        run = run + 1 if length_m == previous else 0
        previous = length_m
        if length_m not in cache:
            try:
                planar = np.asarray(solve_forward(skeleton, threading_mm, length_m * 1000.0).rib_centers)
            except ValueError:   # a length the model refuses: no predicted shape to compare
                planar = np.empty((0, 2))
            cache[length_m] = np.column_stack((planar, np.zeros(len(planar))))
        predicted = cache[length_m]
        if len(predicted) != len(centres_m):
            continue
        distance = np.linalg.norm(centres_m * 1000.0 - predicted, axis=1)
        errors.append(float(np.sqrt(np.mean(distance ** 2))))
        settled.append(run >= SETTLED_SNAPSHOTS)
    return errors, settled


def travel(samples, window_ns) -> dict | None:
    """Straight-line travel in the ground plane between the first and last position
    sample stamped inside `window_ns`: distance (mm), heading (deg), over seconds."""
    inside = [x for x in samples if window_ns[0] <= x[0] <= window_ns[1]]
    if len(inside) < 2:
        return None
    (t0, x0, y0, _), (t1, x1, y1, _) = inside[0], inside[-1]
    dx, dy = (x1 - x0) * 1000.0, (y1 - y0) * 1000.0
    return {'distance_mm': float(math.hypot(dx, dy)),
            'heading_deg': float(math.degrees(math.atan2(dy, dx))),
            'seconds': (t1 - t0) * 1e-9}


def first_grasp_hold(scene, gait_name: str, phases, payload_samples) -> dict | None:
    """Did the gripper hold its payload through the first grasp? None if not observed.

    The hold of cycle 0 runs from phase ``close_s / period`` to ``(close_s + hold_s) /
    period`` of a ``grasp`` gait (its spec in the scene); the payload holds if it sank
    less than PAYLOAD_HOLD_TOL_MM over it and ends clear of the ground.
    """
    spec = scene.gaits.get(gait_name, {})
    if spec.get('type') != 'grasp' or not phases or not payload_samples:
        return None
    period = sum(float(spec.get(k, 0.0)) for k in ('close_s', 'hold_s', 'open_s', 'rest_s'))
    start_phase = float(spec['close_s']) / period
    end_phase = (float(spec['close_s']) + float(spec['hold_s'])) / period
    hold = [t for t, cycle, phase in phases if cycle == 0 and start_phase <= phase <= end_phase]
    if len(hold) < 2:
        return None
    stamps = [x[0] for x in payload_samples]

    def z_at(t):
        i = int(np.searchsorted(stamps, t, side='right')) - 1
        return payload_samples[i][3] if i >= 0 else None

    z0, z1 = z_at(hold[0]), z_at(hold[-1])
    if z0 is None or z1 is None:
        return None
    size_m = PHYSICS_PAYLOADS.get(scene.name, {}).get('payload_size_m', 0.0)
    drop_mm = (z0 - z1) * 1000.0
    clear_mm = (z1 - size_m) * 1000.0
    return {'held': bool(drop_mm < PAYLOAD_HOLD_TOL_MM and clear_mm > PAYLOAD_HOLD_TOL_MM),
            'drop_mm': float(drop_mm), 'height_mm': float(z1 * 1000.0)}


def physics_summary(scene, gait_name: str, observer: Observer, window_ns, sim_log: str) -> dict:
    """The --physics part of the summary (distances in mm, per gait cycle).

    Stamps and `window_ns` are simulated time (every node runs on sim_robot's /clock), so
    a cycle is the gait's period of simulated time, whatever the real-time factor;
    ``gait_cycles`` counts the cycles the gait node reported playing in the window.
    """
    from .gaits import make_gait
    period = make_gait(gait_name, scene).period_s
    base = travel(observer.base_positions, window_ns)
    payload = travel(observer.payload_positions, window_ns)
    per_cycle = (lambda t: None if t is None or t['seconds'] <= 0
                 else t['distance_mm'] * period / t['seconds'])
    shape_error = {}
    for name, s in observer.stats.items():
        module = scene.module(name)
        errors, settled = simulated_shape_errors_mm(s, scene.skeleton, module.threading_mm)
        at_rest = [e for e, ok in zip(errors, settled) if ok]
        shape_error[name] = ({'mean': float(np.mean(errors)), 'max': float(np.max(errors)),
                              'n': len(errors),
                              'settled_mean': float(np.mean(at_rest)) if at_rest else None,
                              'settled_n': len(at_rest)} if errors else None)
    factor = None
    for line in sim_log.splitlines():
        if 'real-time factor' in line:
            try:
                factor = float(line.split('real-time factor')[1].split()[0])
            except (IndexError, ValueError):
                pass
    # Gait cycles played inside the window, by the gait's own phase (simulated time).
    played = [(t, c + ph) for t, c, ph in observer.phases if window_ns[0] <= t <= window_ns[1]]
    cycles = float(played[-1][1] - played[0][1]) if len(played) > 1 else None
    # The simulated seconds those cycles took (a gait node started late on a loaded
    # machine plays fewer cycles in the window, but each still takes its period).
    gait_seconds = (played[-1][0] - played[0][0]) * 1e-9 if len(played) > 1 else None
    return {'gait': gait_name, 'gait_period_s': period, 'gait_cycles': cycles,
            'gait_seconds': gait_seconds,
            'base_travel': base, 'base_mm_per_cycle': per_cycle(base),
            'payload_travel': payload, 'payload_mm_per_cycle': per_cycle(payload),
            'payload_first_grasp': first_grasp_hold(scene, gait_name, observer.phases,
                                                    observer.payload_positions),
            'shape_error_mm': shape_error, 'real_time_factor': factor,
            'gait_phases_observed': len(observer.phases)}


def in_window(stamps_ns, window_ns) -> list:
    return sorted(t for t in stamps_ns if window_ns[0] <= t <= window_ns[1])


def running_tip_errors_mm(s: ModuleStats, tip_mm=lambda x: x) -> list:
    """Tip error at every predicted shape, mm: its tip against the tip of the commanded
    shape that was the latest when it arrived. `tip_mm` maps a stored shape (angles) to
    its tip point."""
    c_tips, p_tips = {}, {}
    errors = []
    for p, c in s.tip_error_pairs:
        if c not in c_tips:
            c_tips[c] = tip_mm(s.commanded_tips[c][2])
        if p not in p_tips:
            p_tips[p] = tip_mm(s.predicted_tips[p][2])
        errors.append(float(np.linalg.norm(p_tips[p] - c_tips[c])))
    return errors


def settled_tip_errors_mm(s: ModuleStats, window_ns, tip_mm=lambda x: x) -> list:
    """Tip error at the end of every step the gait held, mm (the "settled" error).

    A step ends at the last command of a hold: a command equal (within
    `SETTLED_HOLD_TOL_M`) to the one before it, followed by one that differs, i.e. the
    last commanded sample before the commanded contraction changes again; only ends
    stamped inside `window_ns` count. There, the error is the distance between the tip
    of the commanded shape (the latest commanded shape stamped at or before that command,
    solved for the held length) and the tip of the predicted shape (the latest predicted
    shape whose measured length was stamped at or before it). The winch has had the whole
    hold to get there, so this measures the model and the motor at rest, not the lag.
    `tip_mm` maps a stored shape (the observer stores angles) to its tip point.
    """
    if len(s.command_stamps_ns) < 3:
        return []
    order = np.argsort(s.command_stamps_ns, kind='stable')
    t = np.asarray(s.command_stamps_ns, dtype=np.int64)[order]
    length = np.asarray(s.command_lengths_m, dtype=float)[order]
    held = np.abs(np.diff(length)) <= SETTLED_HOLD_TOL_M        # held[i]: i -> i + 1 equal
    ends = np.nonzero(held[:-1] & ~held[1:])[0] + 1             # held into i, changes after
    commanded = sorted(s.commanded_tips, key=lambda e: e[0])
    predicted = sorted(s.predicted_tips, key=lambda e: e[0])
    c_stamps = [e[0] for e in commanded]
    p_stamps = [e[0] for e in predicted]
    errors = []
    for i in ends:
        if not window_ns[0] <= t[i] <= window_ns[1]:
            continue
        c = np.searchsorted(c_stamps, t[i], side='right') - 1
        p = np.searchsorted(p_stamps, t[i], side='right') - 1
        if c < 0 or p < 0 or abs(commanded[c][1] - length[i]) > SETTLED_HOLD_TOL_M:
            continue   # no shape solved for this hold (model node starved): no sample
        errors.append(float(np.linalg.norm(tip_mm(commanded[c][2]) - tip_mm(predicted[p][2]))))
    return errors


@dataclasses.dataclass(frozen=True)
class CommandCounts:
    """Commands of one module over one stretch of tick stamps, by each party's own count.

    The stretch runs from the latest command a driver state reported early in the run
    (exclusive) to the latest one it reported by the end (inclusive): over it the gait
    node's counts (GaitPhase of those ticks) and the driver's (ModuleState) are exact, so
    `lost` is what left the gait node and never reached the driver.
    """

    sent: int            # published by the gait node (count)
    received: int        # taken by the driver (count)
    observed: int        # taken by the demo's observer (count)
    from_ns: int         # stamps (ns of ROS time) of the stretch: (from_ns, to_ns]
    to_ns: int

    @property
    def lost(self) -> int:
        return self.sent - self.received

    @property
    def observer_shortfall(self) -> int:
        """What the observer missed: its own problem (starved by load), not a lost command."""
        return self.sent - self.observed


def commands_counted(name: str, s: ModuleStats, gait_sent: dict[int, dict[str, int]],
                     window_ns: tuple[int, int]) -> CommandCounts | None:
    """The gait node's, the driver's and the observer's counts of `name`'s commands.

    A driver state says "commands_received, the latest stamped T"; the gait node's
    GaitPhase stamped T says how many it had sent up to and including T. Two such pairs,
    the first and last whose T lies in `window_ns`, bound the stretch. None when there is
    no such pair (driver states or gait phases not observed).
    """
    usable = [(received, last) for _, received, last in s.driver_counts
              if window_ns[0] <= last <= window_ns[1] and name in gait_sent.get(last, {})]
    if len(usable) < 2:
        return None
    (r0, t0), (r1, t1) = usable[0], max(usable, key=lambda u: (u[1], u[0]))
    if t1 <= t0:
        return None
    observed = sum(1 for t in s.command_stamps_ns if t0 < t <= t1)
    return CommandCounts(sent=gait_sent[t1][name] - gait_sent[t0][name], received=r1 - r0,
                         observed=observed, from_ns=t0, to_ns=t1)


def percentiles(values) -> dict:
    if not values:
        return {'median': math.nan, 'p99': math.nan, 'n': 0}
    v = np.asarray(values)
    return {'median': float(np.median(v)), 'p99': float(np.percentile(v, 99)), 'n': int(v.size)}
