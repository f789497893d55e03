"""The demo's report: the summary dictionary (also written as JSON) and its printed
tables."""
from __future__ import annotations

from pathlib import Path

import numpy as np


from .supervision import shutdown_problems
from .demo_config import SETTLED_SNAPSHOTS, SNAPSHOT_RATE_HZ
from .demo_metrics import (commands_counted, in_window, percentiles, running_tip_errors_mm,
                           settled_tip_errors_mm)
from .demo_observer import Observer


def print_physics(p: dict) -> None:
    print(f"physics (sim_robot, MuJoCo; real-time factor while stepping: "
          f"{_cell(p['real_time_factor'], '.2f')}), gait {p['gait']} ({p['gait_period_s']:g} s cycle):")
    base = p['base_travel']
    if base is None:
        print('  robot travel: not observed')
    else:
        print(f"  robot travelled {base['distance_mm']:.1f} mm (heading {base['heading_deg']:.0f} deg) "
              f"in {base['seconds']:.1f} s of simulated time: {p['base_mm_per_cycle']:.1f} mm "
              'per gait cycle')
    grasp = p['payload_first_grasp']
    if p['payload_travel'] is not None:
        pay = p['payload_travel']
        if grasp is not None:
            # A grasp is not locomotion: say what the number is (where the payload ended,
            # seen from above, against where it started), not a travel per cycle.
            print(f"  payload {pay['distance_mm']:.1f} mm from where it started, in the ground "
                  f"plane, after {pay['seconds']:.1f} s (first to last sample of the run)")
        else:
            print(f"  payload travelled {pay['distance_mm']:.1f} mm: "
                  f"{p['payload_mm_per_cycle']:.1f} mm per cycle")
    if grasp is not None:
        print(f"  payload {'HELD' if grasp['held'] else 'NOT held'} through the first grasp "
              f"(sank {grasp['drop_mm']:.1f} mm during the hold, centre {grasp['height_mm']:.0f} mm "
              'above the ground at its end)')
    cells = ', '.join(f"{name} {e['mean']:.1f}/{e['max']:.1f} ({_cell(e['settled_mean'], '.1f')})"
                      if e else f'{name} -' for name, e in p['shape_error_mm'].items())
    print('  simulated vs predicted shape at the same cable length, rib-centre RMS mean/max mm '
          f'(mean with the winch at rest >= {SETTLED_SNAPSHOTS / SNAPSHOT_RATE_HZ:g} s): {cells}')


def summarise(scene, observer: Observer, seconds: float, recording: Path | None,
              exit_codes: dict[str, int | None], window_ns: tuple[int, int] = (0, 2**63)) -> dict:
    """The demo's summary as a plain dict (printed as a table, or JSON with --json).

    Commands and measured lengths count the messages stamped inside `window_ns` (the
    run, in ns of ROS time); the command rate is taken from their stamps.
    """
    modules = {}
    for name, s in observer.stats.items():
        commands = in_window(s.command_stamps_ns, window_ns)
        span = (commands[-1] - commands[0]) * 1e-9 if len(commands) > 1 else 0.0
        running = running_tip_errors_mm(s, observer._tip_mm)
        errors = np.asarray(running) if running else None
        settled = settled_tip_errors_mm(s, window_ns, observer._tip_mm)
        state = s.state
        counted = commands_counted(name, s, observer.gait_sent, window_ns)
        measured = in_window(s.measured_stamps_ns, window_ns)
        # What the observer never saw is None ("not observed"), never a 0 or NaN that
        # would read as a measurement.
        # (With 'robot' streams the observer takes no command or measured-length stream.)
        streams = [] if getattr(observer, 'streams', 'modules') == 'robot' else [
            ('gait commands', s.command_stamps_ns), ('measured lengths', s.measured_stamps_ns)]
        unobserved = [what for what, seen in (
            *streams,
            ('commanded shapes', s.commanded_shapes), ('predicted shapes', s.predicted_shapes),
            ('driver state', state is not None),
            ('command counters', counted is not None)) if not seen]
        modules[name] = {
            # The nodes' own counts over the same stretch of commands (CommandCounts).
            'commands_sent': counted.sent if counted else None,
            'driver_received': counted.received if counted else None,
            'commands_lost': counted.lost if counted else None,
            'observer_commands': counted.observed if counted else None,
            'observer_shortfall': counted.observer_shortfall if counted else None,
            'counted_seconds': (counted.to_ns - counted.from_ns) * 1e-9 if counted else None,
            # The driver's counts since it started (its latest state).
            'driver_refused': int(state.commands_refused) if state is not None else None,
            'driver_targets_sent': int(state.targets_sent) if state is not None else None,
            # What the observer took inside the run window, and its rate from the stamps.
            'commands_observed': len(commands) if s.command_stamps_ns else None,
            'command_rate_hz': ((len(commands) - 1) / span if span > 0 else 0.0)
                               if s.command_stamps_ns else None,
            'observer_dds_lost': s.lost,
            'measured_lengths': len(measured) if s.measured_stamps_ns else None,
            'commanded_shapes': s.commanded_shapes or None,
            'predicted_shapes': s.predicted_shapes or None,
            'tip_error_mm_mean': float(np.mean(errors)) if errors is not None else None,
            'tip_error_mm_max': float(np.max(errors)) if errors is not None else None,
            'settled_tip_error_mm_mean': float(np.mean(settled)) if settled else None,
            'settled_tip_error_mm_max': float(np.max(settled)) if settled else None,
            'settled_samples': len(settled),
            'solve_time_us_mean': float(np.mean(s.solve_times_s) * 1e6) if s.solve_times_s else None,
            'command_to_shape_ms': percentiles(s.command_to_shape_ms),
            'measured_to_shape_ms': percentiles(s.measured_to_shape_ms),
            'online': bool(state.online) if state is not None else None,
            'battery_v': float(state.battery_voltage) if state is not None else None,
            'request_failures': int(state.request_failures) if state is not None else None,
            'not_observed': unobserved,
        }
    diag = observer.diagnostics
    return {
        'scene': scene.name, 'seconds': seconds, 'modules': modules,
        'observer_streams': getattr(observer, 'streams', 'modules'),
        'model': None if diag is None else {
            'solves': diag.solves, 'skipped_unchanged': diag.skipped_unchanged,
            'skipped_duplicate': diag.skipped_duplicate, 'refused': diag.refused,
            # Length messages the model node took per module since it started (counts).
            'lengths_taken': {m: {'commanded': int(c), 'measured': int(r)} for m, c, r in zip(
                diag.modules, diag.commanded_lengths, diag.measured_lengths)}},
        'recording': None if recording is None else str(recording),
        'recording_bytes': recording.stat().st_size if recording and recording.exists() else 0,
        'exit_codes': exit_codes,
    }


def _cell(value, spec: str) -> str:
    """`value` formatted with `spec`, or '-' (right-aligned to its width) when None."""
    if value is None:
        width = int(''.join(c for c in spec.split('.')[0] if c.isdigit()) or 1)
        return '-'.rjust(width) if not spec.startswith('<') else '-'.ljust(width)
    return format(str(value) if spec.endswith('s') else value, spec)


def print_summary(summary: dict) -> None:
    clock = (f" of simulated time ({summary['wall_seconds']:g} s of wall time)"
             if summary.get('sim_time') else '')
    print(f"\nSoftSnap demo: {summary['scene']}, {summary['seconds']:g} s of gait{clock} "
          "(tip error: commanded shape versus the shape predicted from the measured length, "
          "all the time (running) and at the end of each step (settled: last command before "
          "the commanded contraction changes, n steps); "
          "commands by each node's own count: sent by the gait node, rcvd by the driver, "
          "lost = sent - rcvd; seen by this demo's observer, short = sent - seen (the "
          "observer's own shortfall under load, not a lost command))")
    header = (f"{'module':10s} {'sent':>5s} {'rcvd':>5s} {'lost':>4s} {'seen':>5s} {'short':>5s} {'Hz':>5s} "
              f"{'measured':>8s} {'shapes c/p':>11s} "
              f"{'tip err mean/max mm':>20s} {'settled mean/max mm (n)':>24s} {'solve µs':>9s} {'online':>6s} {'batt V':>6s}")
    print(header)
    print('-' * len(header))
    for name, m in summary['modules'].items():
        print(f"{name:10s} {_cell(m['commands_sent'], '5d')} {_cell(m['driver_received'], '5d')} "
              f"{_cell(m['commands_lost'], '4d')} {_cell(m['observer_commands'], '5d')} "
              f"{_cell(m['observer_shortfall'], '5d')} {_cell(m['command_rate_hz'], '5.1f')} "
              f"{_cell(m['measured_lengths'], '8d')} "
              f"{_cell(m['commanded_shapes'], '5d')}/{_cell(m['predicted_shapes'], '<5d')} "
              f"{_cell(m['tip_error_mm_mean'], '9.2f')}/{_cell(m['tip_error_mm_max'], '<9.2f')} "
              f"{_cell(m['settled_tip_error_mm_mean'], '9.2f')}/{_cell(m['settled_tip_error_mm_max'], '<7.2f')}"
              f"({m['settled_samples']:3d}) "
              f"{_cell(m['solve_time_us_mean'], '10.0f')} {_cell(m['online'], '>6s')} "
              f"{_cell(m['battery_v'], '6.2f')}")
    for name, m in summary['modules'].items():
        if m.get('not_observed'):
            print(f"{name}: not observed (shown as -): {', '.join(m['not_observed'])}")
    lost = {name: m['commands_lost'] for name, m in summary['modules'].items() if m['commands_lost']}
    if lost:
        print(f'WARNING: commands lost between the gait node and the drivers: {lost}')
    dds_lost = {name: m['observer_dds_lost'] for name, m in summary['modules'].items()
                if m['observer_dds_lost']}
    if dds_lost:
        print(f'observer: DDS reported messages lost to the observer: {dds_lost}')
    if summary['model']:
        d = summary['model']
        print(f"model node: {d['solves']} solves, {d['skipped_unchanged']} unchanged lengths and "
              f"{d['skipped_duplicate']} duplicate modules skipped, {d['refused']} refused")
        if d.get('lengths_taken'):
            taken = ', '.join(f"{name} {n['commanded']}/{n['measured']}"
                              for name, n in d['lengths_taken'].items())
            print(f'model node took commanded/measured lengths (since its start): {taken}')
    latency = [m['command_to_shape_ms']['median'] for m in summary['modules'].values()
               if m['command_to_shape_ms']['n']]
    if summary.get('physics'):
        # Stamps and the observer's clock are both sim_robot's /clock, which advances in
        # steps: the difference is 0 within a step, not a latency.
        print('gait command -> commanded shape: not measured on simulated time')
    elif latency:
        print(f"gait command -> commanded shape: median {np.median(latency):.2f} ms over modules")
    if summary.get('processes'):
        usage = ', '.join(f"{name} {u['cpu_percent']:.0f}%" for name, u in summary['processes'].items()
                          if not name.startswith('sim_'))
        print(f'CPU (% of one core): {usage}')
    if summary.get('physics'):
        print_physics(summary['physics'])
    problems = summary.get('shutdown_problems')
    if problems is None:   # a summary without the shutdown's account: judge by exit codes
        problems = shutdown_problems(summary['exit_codes'])
    print('processes: all stopped cleanly (in order: gait, drivers, then simulators, model '
          'and recorders)' if not problems else
          'processes with errors: ' + '; '.join(f'{k}: {v}' for k, v in problems.items()))
    if summary['recording']:
        print(f"recording: {summary['recording']} ({summary['recording_bytes'] / 1024:.0f} KiB); "
              f"open it with: .venv/bin/rerun {summary['recording']}")
    if summary.get('bag'):
        print(f"bag: {summary['bag']} ({summary['bag_messages']} messages on "
              f"{len(summary['bag_topics'])} topics, {summary['bag_bytes'] / 1024:.0f} KiB); "
              f"replay it with: .venv/lib/softsnap_gaits/bag play {summary['bag']}")
    elif summary.get('bag_error'):
        print(f"bag: {summary['bag_error']}")


def bag_summary(bag: Path | None) -> dict:
    """The bag's path, message counts per topic and size, read back from its metadata."""
    if bag is None:
        return {'bag': None}
    from .bag import BagError, bag_info
    try:
        info = bag_info(bag)
    except BagError as error:
        return {'bag': None, 'bag_error': str(error)}
    return {'bag': str(bag), 'bag_messages': info.message_count,
            'bag_topics': {t.name: t.message_count for t in info.topics},
            'bag_bytes': sum(f.stat().st_size for f in bag.iterdir())}
