"""Work-precision benchmark of the forward solver (issues 3 and 17).

Every speed figure is also given as a ratio against a baseline measured in the same run
(the machine is shared: absolute times vary 2-4x with its load, ratios much less), the
load average is printed at the start and the end, and the timed figures are repeated
(rounds) to give the median and the range over rounds.

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
      profiles shared from earlier threadings and with every cache empty;
  (f) a plain reference solver (benchmarks/accuracy_check.py: bracketing on the tension
      and on every segment's angle, no tables), the second baseline;
  (g) 192-rib batches (iterations per row, rows at the iteration cap) and a loop over
      2187 threadings (3^7: the path-table caches must not rebuild per solve);
  (h) a plain loop of cold solves over the paper's nine threadings at six contractions
      each (the issue-17 target, <= 100 us per solve), and with --before the same loop
      on the old solver, interleaved round by round.
Error = largest rib-centre distance (mm) to an mpmath reference (40 digits, KKT Newton
refined from our answer; see test/softsnap_model/mp_reference.py).

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
sys.path.insert(0, str(REPO / 'test' / 'softsnap_model'))
from mp_reference import kkt_reference, rib_centers_mp  # noqa: E402

import softsnap_model.forward as fwd  # noqa: E402
from accuracy_check import reference_solve  # noqa: E402
from benchlib import fmt_spread, load_line, timed  # noqa: E402
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
    if profiles:
        fwd.clear_caches()
    else:
        for cached in (fwd._problem, fwd._single, fwd._single_named, fwd._threading_cached):
            cached.cache_clear()


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


def single_round(probs, reps, clock=time.perf_counter):
    """Median over problems of each problem's median cold solve time (s)."""
    return statistics.median(timed(lambda: solve_forward(SK, t, length), reps, clock)[0]
                             for _, t, length in probs)


def long_batch(n_rows=4000):
    """192-rib batch: (s per solve, max iterations, rows at the cap, all converged)."""
    sk = Skeleton(n_ribs=192)
    t = ['R1', 'R2', 'R3', 'R2'] * 48
    lo, hi = reachable_range(sk, t)
    lengths = np.linspace(hi - 0.01, lo + 0.02 * (hi - lo), n_rows)
    solve_forward_batch(sk, t, lengths[:10])
    dt, r = timed(lambda: solve_forward_batch(sk, t, lengths), 1)
    return (dt / n_rows, int(r.iterations.max()), int(np.sum(r.iterations >= fwd.MAX_ITER)),
            bool(r.converged.all()))


def threading_loop(n_lengths=2):
    """Solve every threading of 3^7 (the last 7 ribs R1/R2/R3) at a few lengths, twice,
    length-major; (first pass s per solve, second pass s per solve, peak RSS MiB)."""
    import itertools
    import resource
    ts = [['R1'] * 5 + list(tail) for tail in itertools.product(('R1', 'R2', 'R3'), repeat=7)]
    ranges = [reachable_range(SK, t) for t in ts]   # builds every table (first pass)
    passes = []
    for _ in range(2):
        t0 = time.perf_counter()
        for frac in np.linspace(0.2, 0.6, n_lengths):
            for t, (lo, hi) in zip(ts, ranges):
                solve_forward(SK, t, hi - frac * (hi - lo))
        passes.append((time.perf_counter() - t0) / (len(ts) * n_lengths))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return passes[0], passes[1], rss, len(ts)


#: Contractions of the paper loop, as fractions of each threading's reachable range.
PAPER_LOOP_FRACTIONS = (0.05, 0.2, 0.4, 0.6, 0.8, 0.95)


def paper_loop(mods, rounds):
    """(h): cold ``solve_forward`` over the nine paper threadings at
    :data:`PAPER_LOOP_FRACTIONS`, a plain loop, for each solver module in ``mods``.

    The modules take turns every round (the order alternating), so a change of the
    machine's load hits both alike. Returns ``{name: (wall s per solve, CPU s per
    solve) per round}``.
    """
    cases = []
    for t in PAPER_THREADINGS.values():
        t = list(t)
        lo, hi = reachable_range(SK, t)
        cases += [(t, hi - frac * (hi - lo)) for frac in PAPER_LOOP_FRACTIONS]
    for mod in mods.values():         # tables built, code paths warm
        for t, length in cases:
            mod.solve_forward(SK, t, length)
    out = {name: [] for name in mods}
    for r in range(rounds):
        for name in (list(mods) if r % 2 == 0 else list(mods)[::-1]):
            solve = mods[name].solve_forward
            w0, c0 = time.perf_counter(), time.thread_time()
            for t, length in cases:
                solve(SK, t, length)
            c1, w1 = time.thread_time(), time.perf_counter()
            out[name].append(((w1 - w0) / len(cases), (c1 - c0) / len(cases)))
    return out


def load_before(rev):
    """The forward solver of git revision ``rev`` as a module next to the current one, so
    that both run side by side in this process on the same problems: the subpackage
    ``softsnap_model/forward/`` (issue 17 on), or the single file ``forward.py`` of
    revisions before its split (e.g. b3d97c3). Its relative imports (``..geometry``)
    resolve to the installed ``softsnap_model``."""
    import importlib.util
    import subprocess
    import tempfile
    base = 'src/softsnap_model/softsnap_model/forward'
    root = Path(tempfile.mkdtemp()) / 'forward_before'
    root.mkdir()
    names = subprocess.run(['git', '-C', str(REPO), 'ls-tree', '--name-only', f'{rev}:{base}'],
                           capture_output=True, text=True)
    if names.returncode == 0:
        for name in names.stdout.split():
            if name.endswith('.py'):
                (root / name).write_text(subprocess.run(
                    ['git', '-C', str(REPO), 'show', f'{rev}:{base}/{name}'], check=True,
                    capture_output=True, text=True).stdout)
        spec = importlib.util.spec_from_file_location(
            'softsnap_model._forward_before', root / '__init__.py',
            submodule_search_locations=[str(root)])
    else:
        (root / 'forward.py').write_text(subprocess.run(
            ['git', '-C', str(REPO), 'show', f'{rev}:{base}.py'], check=True,
            capture_output=True, text=True).stdout)
        spec = importlib.util.spec_from_file_location('softsnap_model._forward_before',
                                                      root / 'forward.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def first_solve_cpu(mods, reps=5):
    """Median CPU time (s) of the first solve of each benchmark threading, per solver
    module of ``mods``, its per-threading tables forgotten before each (pair profiles
    kept). The modules take turns solve by solve, ``reps`` times over the threadings
    (a load burst then hits both, not one module's whole round)."""
    out = [[] for _ in mods]
    for _ in range(reps):
        for text in THREADINGS.values():
            t = text.split()
            length = SK.straight_length_mm(t) - 30.0
            for mod, times in zip(mods, out):
                for name in ('_problem', '_single', '_single_named', '_threading_cached'):
                    cached = getattr(mod, name, None)
                    if cached is not None:
                        cached.cache_clear()
                times.append(timed(lambda: mod.solve_forward(SK, t, length), 1,
                                   time.thread_time)[0])
    return [statistics.median(times) for times in out]


def certified_starts(mod, n_lengths):
    """(cold solves that took no Newton step, solves): the path table's start certified
    as it is, over the paper's nine threadings with and without rib thickness."""
    zero = total = 0
    for sk in (SK, Skeleton()):
        for t in PAPER_THREADINGS.values():
            lo, hi = mod.reachable_range(sk, list(t))
            for length in np.linspace(lo + 1e-6, hi - 1e-6, n_lengths):
                zero += mod.solve_forward(sk, list(t), length).iterations == 0
                total += 1
    return zero, total


def side_by_side(before, probs, reps, rounds):
    """CPU times of the solver of ``before`` and of this one, interleaved round by round:
    single cold solve (median over problems), batch of one threading and of mixed
    threadings, first solve of a threading. Returns ``{figure: (before s, now s) per
    round}`` and the largest angle difference between the two solvers."""
    yellow = THREADINGS['yellow'].split()
    yl = np.linspace(130.0, 198.0, 20000)
    ts = [p[1] for p in probs] * (20000 // len(probs))
    ls = [p[2] for p in probs] * (20000 // len(probs))
    diff = max(float(np.max(np.abs(before.solve_forward(SK, t, length).angles
                                   - solve_forward(SK, t, length).angles)))
               for _, t, length in probs)
    figures = {'single cold solve': [], 'batch, one threading (20,000)': [],
               'batch, mixed (20,000)': [], 'first solve of a threading': []}
    for _ in range(rounds):
        times = {}
        firsts = dict(zip(('before', 'now'), first_solve_cpu((before, fwd))))
        for label, mod in (('before', before), ('now', fwd)):
            first = firsts[label]
            # Tables back for the timed solves (built in full by a batch: since issue
            # 17 a single solve or reachable_range builds only what it reads).
            mod.solve_forward_batch(SK, [p[1] for p in probs], [p[2] for p in probs])
            times[label] = (
                statistics.median(timed(lambda: mod.solve_forward(SK, t, length), reps,
                                        time.thread_time)[0] for _, t, length in probs),
                timed(lambda: mod.solve_forward_batch(SK, yellow, yl), 1, time.thread_time)[0],
                timed(lambda: mod.solve_forward_batch(SK, ts, ls), 1, time.thread_time)[0],
                first)
        for key, b, n in zip(figures, times['before'], times['now']):
            figures[key].append((b, n))
    return figures, diff


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--quick', action='store_true', help='fewer problems and repeats')
    ap.add_argument('--rounds', type=int, default=5, help='repeats of each timed figure')
    ap.add_argument('--before', metavar='REV', help='also time the single-file solver of '
                    'this git revision side by side (e.g. b3d97c3, before issue 17)')
    args = ap.parse_args()
    print(load_line('start'))
    n_per = 2 if args.quick else 4
    rounds = 3 if args.quick else args.rounds
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
    first, first_empty, first_cpu = [], [], []
    for _ in range(2 if args.quick else 3):
        for name, text in THREADINGS.items():
            for out, profiles in ((first_empty, True), (first, False)):
                clear_caches(profiles)
                length = SK.straight_length_mm(text.split()) - 30.0
                t0, c0 = time.perf_counter(), time.thread_time()
                solve_forward(SK, text.split(), length)
                out.append(time.perf_counter() - t0)
                if not profiles:
                    first_cpu.append(time.thread_time() - c0)
                if profiles:    # rebuild the profiles shared by the other threadings
                    for other in THREADINGS.values():
                        reachable_range(SK, other.split())

    # (b) ours, default (certified) cold solves: no initial guess; per-threading tables
    # are memoised pure data, built by the first calls above. Repeated in rounds.
    reps = 50 if args.quick else 200
    errs = []
    for (name, t, length), ref in zip(probs, refs):
        errs.append(rib_error(solve_forward(SK, t, length).angles, ref))
    single_rounds = [single_round(probs, reps) for _ in range(rounds)]
    single_cpu = [single_round(probs, reps, time.thread_time) for _ in range(rounds)]
    ours_time = statistics.median(single_rounds)
    rows.append(('ours, default (certified)', ours_time, statistics.median(errs), max(errs)))

    # (b') capped Newton without fallback: the work-precision knob.
    for cap in (0, 1, 2):
        times, errs = [], []
        for (name, t, length), ref in zip(probs, refs):
            _, S = fwd._single(SK, tuple(SK.threading_mm(t).tolist()))
            dt, out = timed(lambda: fwd._solve_single(S, length, max_iter=cap,
                                                      fallback=False), reps)
            times.append(dt)
            errs.append(rib_error(out['angles'], ref))
        rows.append((f'ours, Newton capped at {cap}', statistics.median(times),
                     statistics.median(errs), max(errs)))

    # (c) batch: all problems repeated to 20000 items, and one threading.
    ts = [p[1] for p in probs]
    ls = [p[2] for p in probs]
    reps_b = 20000 // len(probs)
    big_t, big_l = ts * reps_b, ls * reps_b
    solve_forward_batch(SK, big_t, big_l)   # warm the stacking code
    mixed, mixed_cpu = [], []
    for _ in range(rounds):
        dt, b = timed(lambda: solve_forward_batch(SK, big_t, big_l), 1)
        mixed.append(len(big_l) / dt)
        mixed_cpu.append(len(big_l) / timed(lambda: solve_forward_batch(SK, big_t, big_l), 1,
                                            time.thread_time)[0])
    errs = [rib_error(b.angles[i], refs[i]) for i in range(len(probs))]
    rows.append((f'ours, batch of {len(big_l)} (per solve)', 1.0 / statistics.median(mixed),
                 statistics.median(errs), max(errs)))
    yl = np.linspace(130.0, 198.0, 20000)
    solve_forward_batch(SK, THREADINGS['yellow'].split(), yl)
    one, one_cpu = [], []
    for _ in range(rounds):
        for out, clock in ((one, time.perf_counter), (one_cpu, time.thread_time)):
            out.append(len(yl) / timed(lambda: solve_forward_batch(
                SK, THREADINGS['yellow'].split(), yl), 1, clock)[0])

    # Warm starts: the model node's case.
    cold_t, warm_t, it_cold, it_warm, n_warm = warm_vs_cold()

    # Workspace sweep: 80 steps over 0-80 mm of the yellow module.
    c = np.linspace(0.0, 80.0, 80)
    sweep(SK, THREADINGS['yellow'].split(), c)
    sweep_time, _ = timed(lambda: sweep(SK, THREADINGS['yellow'].split(), c), 30)

    # (g) 192 ribs, and a loop over 2187 threadings.
    long_dt, long_max_it, long_capped, long_ok = long_batch(1000 if args.quick else 4000)
    loop = None if args.quick else threading_loop()

    # (a) baseline, capped: a few problems, one repetition each (seconds per solve), and
    # (f) the plain reference solver on the same problems; ours on exactly those too.
    n_base = 3 if args.quick else 5
    base_idx = np.linspace(0, len(probs) - 1, n_base).astype(int)
    times, errs, plain, ours_same = [], [], [], []
    for i in base_idx:
        name, t, length = probs[i]
        dt, a = timed(lambda: baseline_solve(t, length), 1)
        times.append(dt)
        errs.append(rib_error(a, refs[i]))
        plain.append(timed(lambda: reference_solve(SK, t, length), 1)[0])
        ours_same.append(timed(lambda: solve_forward(SK, t, length), reps)[0])
    base_time = statistics.median(times)
    plain_time = statistics.median(plain)
    rows.insert(0, ('baseline: paper Algorithm 1 (trust-constr)', base_time,
                    statistics.median(errs), max(errs)))

    # Table.
    print(f'# forward solver benchmark  ({platform.processor() or platform.machine()}, '
          f'{os.cpu_count()} cores, numpy {np.__version__}, {rounds} rounds)')
    print(f'{"method":48s} {"median time":>14s} {"median err mm":>14s} {"max err mm":>11s}')
    for label, t, e_med, e_max in rows:
        unit = f'{t * 1e6:10.1f} us' if t < 0.1 else f'{t:10.3f} s '
        print(f'{label:48s} {unit:>14s} {e_med:14.2e} {e_max:11.2e}')
    print()
    print('ratios (same run; median over the same problems):')
    ours_base = statistics.median(ours_same)
    print(f'  speed-up over the paper procedure: {base_time / ours_base:,.0f}x '
          f'(target >= 10,000x; paper {base_time:.3f} s, ours {ours_base * 1e6:.1f} us)')
    print(f'  speed-up over the plain reference solver: {plain_time / ours_base:,.0f}x '
          f'(reference {plain_time * 1e3:.1f} ms)')
    print(f'  batch (one threading) per solve vs a single cold solve: '
          f'{ours_time * statistics.median(one):.1f}x faster')
    print('absolute (median (range) over rounds, on the load printed above and below; wall '
          'time, and CPU time of this thread, which does not count waiting for a core):')
    print(f'  single cold solve: {fmt_spread(single_rounds, 1e6)} us wall, '
          f'{fmt_spread(single_cpu, 1e6)} us CPU  (target <= 100 us)')
    print(f'  batch, one threading: {fmt_spread(one, 1, 0)} solves/s wall, '
          f'{fmt_spread(one_cpu, 1, 0)} CPU  (target >= 150,000/s)')
    print(f'  batch, mixed threadings: {fmt_spread(mixed, 1, 0)} solves/s wall, '
          f'{fmt_spread(mixed_cpu, 1, 0)} CPU  (target >= 100,000/s)')
    print(f'  first solve of a new threading: {fmt_spread(first, 1e3, 2)} ms wall, '
          f'{fmt_spread(first_cpu, 1e3, 2)} ms CPU with shared pair profiles (target <= 1 ms), '
          f'{fmt_spread(first_empty, 1e3, 2)} ms wall with every cache empty')
    print(f'  80-step workspace sweep: {sweep_time * 1e3:.2f} ms  (target < 10 ms)')
    print(f'  brittle star modules, 0.26 mm steps ({n_warm} solves): cold {cold_t * 1e6:.1f} us '
          f'({it_cold:.2f} Newton iterations), warm from the previous shape '
          f'{warm_t * 1e6:.1f} us ({it_warm:.2f})')
    print(f'  192-rib batch: {long_dt * 1e6:.1f} us per solve, max {long_max_it} Newton '
          f'iterations, {long_capped} rows at the {fwd.MAX_ITER}-iteration cap, '
          f'all converged: {long_ok}')
    n_cert = 100 if args.quick else 300
    zero, total = certified_starts(fwd, n_cert)
    print(f'  cold solves with a certified start (no Newton step), nine paper threadings, '
          f'with and without rib thickness: {zero} of {total} ({100.0 * zero / total:.1f} %)')
    if loop is not None:
        print(f'  loop over {loop[3]} threadings, length-major: {loop[0] * 1e6:.0f} us per '
              f'solve (first pass), {loop[1] * 1e6:.0f} us (second pass; no table rebuilt); '
              f'peak RSS {loop[2]:.0f} MiB')
    if args.before:
        before = load_before(args.before)
        for t in THREADINGS.values():     # build its tables before timing
            before.reachable_range(SK, t.split())
        figures, diff = side_by_side(before, probs, reps, rounds)
        print(f'side by side with the solver of {args.before} (CPU time of this thread, '
              f'median (range) over {rounds} interleaved rounds; angles agree to {diff:.1e} rad):')
        for key, pairs in figures.items():
            ratio = [b / n for b, n in pairs]
            scale, unit = (1e3, 'ms') if 'first' in key else (1e6, 'us')
            note = (f' (each round the median of {5 * len(THREADINGS)} first solves per '
                    f'solver, the two taking turns solve by solve)' if 'first' in key else '')
            print(f'  {key}: ratio before/now {fmt_spread(ratio, 1, 2)}x; before '
                  f'{fmt_spread([b for b, _ in pairs], scale, 1 + ("first" in key))} {unit}, '
                  f'now {fmt_spread([n for _, n in pairs], scale, 1 + ("first" in key))} {unit}'
                  f'{note}')
        zero_b, total_b = certified_starts(before, n_cert)
        print(f'  cold solves with a certified start (no Newton step): before {zero_b} of '
              f'{total_b} ({100.0 * zero_b / total_b:.1f} %), now {zero} of {total} '
              f'({100.0 * zero / total:.1f} %)')
    # (h) the paper loop, last: with --before, the old solver takes turns with this one.
    mods = {'now': fwd}
    if args.before:
        mods = {'before': before, 'now': fwd}
    loop_rounds = 15 if args.quick else 40
    paper = paper_loop(mods, loop_rounds)
    n_cases = len(PAPER_THREADINGS) * len(PAPER_LOOP_FRACTIONS)
    wall = [w for w, _ in paper['now']]
    cpu = [c for _, c in paper['now']]
    print(f'paper loop: cold solve_forward over the {len(PAPER_THREADINGS)} paper threadings at '
          f'{len(PAPER_LOOP_FRACTIONS)} contractions ({n_cases} solves a round, '
          f'{loop_rounds} rounds; median (range) per solve):')
    print(f'  now: {fmt_spread(wall, 1e6)} us wall, {fmt_spread(cpu, 1e6)} us CPU  '
          '(target <= 100 us on a quiet machine)')
    if args.before:
        ratio = [b[1] / n[1] for b, n in zip(paper['before'], paper['now'])]
        print(f'  {args.before}: {fmt_spread([w for w, _ in paper["before"]], 1e6)} us wall, '
              f'{fmt_spread([c for _, c in paper["before"]], 1e6)} us CPU; ratio before/now '
              f'(CPU, round by round) {fmt_spread(ratio, 1, 2)}x')
    print(load_line('end'))

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
