"""Work-precision benchmark of the forward solver (issue 3).

Compares, on the same problems and in the same run:
  (a) a re-implementation of the paper's Algorithm 1 procedure (scipy trust-constr over
      the segment lengths, each angle from a per-segment root find), with the exact
      cable-length formula so that only the procedure differs;
  (b) our solver: the bordered Newton capped at 0, 1, 2 iterations (no fallback) and
      the default (certified) solve;
  (c) batch mode (solve_forward_batch);
  (d) warm starts as the model node makes them (previous shape, 0.26 mm steps on the
      brittle star's modules) against cold solves of the same lengths;
  (e) the first solve of a threading (path table built), with the per-pair branch
      profiles shared from earlier threadings and with every cache empty.
Error = largest rib-centre distance (mm) to an mpmath reference (40 digits, KKT Newton
refined from our answer; see test/model/mp_reference.py).

Prints a table, writes docs/forward_work_precision.png. Runtime about 1-3 minutes.
Usage: .venv/bin/python benchmarks/forward_bench.py [--quick]
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import LinearConstraint, brentq, minimize

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test' / 'model'))
from mp_reference import kkt_reference, rib_centers_mp  # noqa: E402

import softsnap_model.forward as fwd  # noqa: E402
from benchlib import timed  # noqa: E402
from softsnap_model.reference import BRITTLE_STAR_MODULES, PAPER_THREADINGS  # noqa: E402
from softsnap_model import (Skeleton, reachable_range, rib_centers, segment_length,  # noqa: E402
                            solve_forward, solve_forward_batch, sweep)

SK = Skeleton(rib_thickness_mm=0.0)   # the idealised model (docs/bench-forward.md)
# The brittle star's five modules and a spread of the paper's threadings (FACTS.md).
BRITTLE_STAR = [' '.join(PAPER_THREADINGS[name]) for name in BRITTLE_STAR_MODULES]
THREADINGS = {name: ' '.join(PAPER_THREADINGS[name])
              for name in ('yellow', 'blue', 'red', 'snake', 'w')}


def problems(n_per):
    out = []
    for name, text in THREADINGS.items():
        t = text.split()
        lo, hi = reachable_range(SK, t)
        for frac in np.linspace(0.1, 0.6, n_per):
            out.append((name, t, hi - frac * min(hi - lo, 80.0)))
    return out


# -- (a) baseline: the paper's procedure ----------------------------------------------------
def baseline_solve(threading, length):
    """Algorithm 1: trust-constr over segment lengths L_i, angles by per-segment roots."""
    d = SK.threading_mm(threading)
    d1, d2, s = d[:-1], d[1:], SK.spacing_mm
    direction = np.where(d1 + d2 > 0, -1.0, np.where(d1 + d2 < 0, 1.0,
                                                     np.where(d1 >= 0, -1.0, 1.0)))
    straight = np.hypot(s, d2 - d1)
    # Segment length range on the bend side (the notebook bounds alpha to (-pi, pi]).
    a_max = SK.contact_angle_rad
    shortest = segment_length(direction * a_max, d1, d2, s)

    def length_to_angle(lengths):
        out = np.empty_like(lengths)
        for i, li in enumerate(lengths):
            li = min(max(li, shortest[i]), straight[i])
            f = lambda b: segment_length(direction[i] * b, d1[i], d2[i], s) - li  # noqa
            out[i] = 0.0 if f(0.0) <= 0 else direction[i] * brentq(f, 0.0, a_max,
                                                                   xtol=1e-14)
        return out

    def energy(lengths):
        a = length_to_angle(lengths)
        return float(a @ a)

    x0 = straight * (length / straight.sum())
    res = minimize(energy, x0, method='trust-constr',
                   constraints=[LinearConstraint(np.ones((1, d1.size)), length, length)],
                   bounds=list(zip(shortest, straight)),
                   options={'gtol': 1e-10, 'xtol': 1e-12, 'maxiter': 3000})
    return length_to_angle(res.x)


def clear_caches(profiles=False):
    """Forget every memoised threading (and, with ``profiles``, every pair profile)."""
    for name in ('_problem', '_single', '_threading_cached'):
        getattr(fwd, name).cache_clear()
    if profiles:
        fwd._PROFILE_CACHE.clear()


def warm_vs_cold(step_mm=0.26):
    """Median cold and warm (previous shape) solve times and mean Newton iterations."""
    cold, warm, it_cold, it_warm = [], [], [], []
    for text in BRITTLE_STAR:
        t = text.split()
        lo, hi = reachable_range(SK, t)
        prev = solve_forward(SK, t, hi - 0.01)
        for length in hi - step_mm * np.arange(1, 400):
            if length <= lo + 0.5:
                break
            t0 = time.perf_counter()
            rc = solve_forward(SK, t, length)
            t1 = time.perf_counter()
            rw = solve_forward(SK, t, length, initial=prev.angles)
            t2 = time.perf_counter()
            cold.append(t1 - t0)
            warm.append(t2 - t1)
            it_cold.append(rc.iterations)
            it_warm.append(rw.iterations)
            prev = rw
    return (statistics.median(cold), statistics.median(warm), float(np.mean(it_cold)),
            float(np.mean(it_warm)), len(cold))


def rib_error(angles, ref_centers):
    p = rib_centers(np.asarray(angles, float), SK.spacing_mm)
    return max(math.hypot(p[i, 0] - ref_centers[i][0], p[i, 1] - ref_centers[i][1])
               for i in range(len(ref_centers)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--quick', action='store_true', help='fewer problems and repeats')
    args = ap.parse_args()
    n_per = 2 if args.quick else 4
    probs = problems(n_per)

    # Reference shapes (mpmath), from our certified answer refined at 40 digits.
    refs = []
    for name, t, length in probs:
        r = solve_forward(SK, t, length)
        free = [i for i in range(11) if not r.at_contact[i]]
        a_ref, _ = kkt_reference(SK.threading_mm(t), [1.0] * 11, SK.spacing_mm, length,
                                 r.angles, r.tension, free=free)
        refs.append([(float(x), float(y)) for x, y in rib_centers_mp(a_ref, 18)])

    rows = []   # (label, median time s, median error mm, max error mm)

    # First call per threading (path tables built, then memoised): with the per-pair
    # profiles already built by earlier threadings, and with every cache empty.
    first, first_empty = [], []
    for name, text in THREADINGS.items():
        for out, profiles in ((first_empty, True), (first, False)):
            clear_caches(profiles)
            t0 = time.perf_counter()
            solve_forward(SK, text.split(), SK.straight_length_mm(text.split()) - 30.0)
            out.append(time.perf_counter() - t0)
            if profiles:    # rebuild the profiles shared by the other threadings
                for other in THREADINGS.values():
                    reachable_range(SK, other.split())

    # (b) ours, default (certified) cold solves: no initial guess; per-threading tables
    # are memoised pure data, built by the first calls above.
    reps = 50 if args.quick else 200
    times, errs = [], []
    for (name, t, length), ref in zip(probs, refs):
        dt, r = timed(lambda: solve_forward(SK, t, length), reps)
        times.append(dt)
        errs.append(rib_error(r.angles, ref))
    ours_time = statistics.median(times)
    rows.append(('ours, default (certified)', ours_time, statistics.median(errs), max(errs)))

    # (b') capped Newton without fallback: the work-precision knob.
    for cap in (0, 1, 2):
        times, errs = [], []
        for (name, t, length), ref in zip(probs, refs):
            _, _, S = fwd._single(SK, tuple(SK.threading_mm(t).tolist()))
            dt, out = timed(lambda: fwd._solve_single(S, length, max_iter=cap,
                                                      fallback=False), reps)
            times.append(dt)
            errs.append(rib_error(out['angles'], ref))
        rows.append((f'ours, Newton capped at {cap}', statistics.median(times),
                     statistics.median(errs), max(errs)))

    # (c) batch: all problems repeated to 20000 items.
    ts = [p[1] for p in probs]
    ls = [p[2] for p in probs]
    reps_b = 20000 // len(probs)
    big_t, big_l = ts * reps_b, ls * reps_b
    solve_forward_batch(SK, big_t, big_l)   # warm the stacking code
    dt, b = timed(lambda: solve_forward_batch(SK, big_t, big_l), 3)
    errs = [rib_error(b.angles[i], refs[i]) for i in range(len(probs))]
    batch_rate = len(big_l) / dt
    rows.append((f'ours, batch of {len(big_l)} (per solve)', dt / len(big_l),
                 statistics.median(errs), max(errs)))
    # Batch of a single threading (the model node's case: one module, many lengths).
    yl = np.linspace(130.0, 198.0, 20000)
    solve_forward_batch(SK, THREADINGS['yellow'].split(), yl)
    dt1, _ = timed(lambda: solve_forward_batch(SK, THREADINGS['yellow'].split(), yl), 3)

    # Warm starts: the model node's case.
    cold_t, warm_t, it_cold, it_warm, n_warm = warm_vs_cold()

    # Workspace sweep: 80 steps over 0-80 mm of the yellow module.
    c = np.linspace(0.0, 80.0, 80)
    sweep(SK, THREADINGS['yellow'].split(), c)
    sweep_time, _ = timed(lambda: sweep(SK, THREADINGS['yellow'].split(), c), 30)

    # (a) baseline, capped: a few problems, one repetition each (seconds per solve).
    n_base = 3 if args.quick else 5
    base_idx = np.linspace(0, len(probs) - 1, n_base).astype(int)
    times, errs = [], []
    for i in base_idx:
        name, t, length = probs[i]
        dt, a = timed(lambda: baseline_solve(t, length), 1)
        times.append(dt)
        errs.append(rib_error(a, refs[i]))
    base_time = statistics.median(times)
    rows.insert(0, ('baseline: paper Algorithm 1 (trust-constr)', base_time,
                    statistics.median(errs), max(errs)))

    # Table.
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan')
    print(f'# forward solver benchmark  ({platform.processor() or platform.machine()}, '
          f'{os.cpu_count()} cores, load {load:.2f}, numpy {np.__version__})')
    print(f'{"method":48s} {"median time":>14s} {"median err mm":>14s} {"max err mm":>11s}')
    for label, t, e_med, e_max in rows:
        unit = f'{t * 1e6:10.1f} us' if t < 0.1 else f'{t:10.3f} s '
        print(f'{label:48s} {unit:>14s} {e_med:14.2e} {e_max:11.2e}')
    print()
    print(f'single cold solve median: {ours_time * 1e6:.1f} us  (target <= 200 us)')
    print(f'baseline median: {base_time:.3f} s; speed-up: {base_time / ours_time:,.0f}x '
          f'(target >= 5000x)')
    print(f'batch (mixed threadings): {batch_rate:,.0f} solves/s; one threading: '
          f'{len(yl) / dt1:,.0f} solves/s  (target >= 50,000/s)')
    print(f'80-step workspace sweep: {sweep_time * 1e3:.2f} ms  (target < 10 ms)')
    print(f'brittle star modules, 0.26 mm steps ({n_warm} solves): cold {cold_t * 1e6:.1f} us '
          f'({it_cold:.2f} Newton iterations), warm from the previous shape '
          f'{warm_t * 1e6:.1f} us ({it_warm:.2f})')
    print(f'first call per threading (path table build): median '
          f'{statistics.median(first) * 1e3:.1f} ms with shared pair profiles, '
          f'{statistics.median(first_empty) * 1e3:.1f} ms with every cache empty')

    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    floor = 1e-16
    for label, t, e_med, e_max in rows:
        marker = 's' if label.startswith('baseline') else ('^' if 'batch' in label else 'o')
        ax.loglog(t, max(e_med, floor), marker, markersize=8, label=label)
        ax.plot([t, t], [max(e_med, floor), max(e_max, floor)], 'k-', lw=0.8)
    ax.set_xlabel('median time per solve (s)')
    ax.set_ylabel('rib-centre error vs mpmath (mm)\n(median, bar to max)')
    ax.set_title('SoftSnap forward solve, 12-rib module: work vs precision')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7, loc='best')
    fig.tight_layout()
    out = REPO / 'docs' / 'forward_work_precision.png'
    fig.savefig(out, dpi=120)
    print(f'wrote {out.relative_to(REPO)}')


if __name__ == '__main__':
    main()
