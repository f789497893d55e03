"""Cable friction (issue 13): run time, accuracy and effect on the shape.

For mu in {0.05, 0.1, 0.2}, the paper's brittle-star threadings (yellow, blue, green,
red, orange) at 20, 40 and 60 mm contraction (clamped to 90% of the reachable range):
  - run time of `solve_friction` (pull branch) against `solve_forward` (frictionless),
    both measured in this run on the same problems: median and range over problems
    (each problem's time is the median of its repeats), and their ratio;
  - error: largest rib-centre distance (mm) to the independent slow reference
    (test/softsnap_model/friction_reference.py: own geometry, brentq per segment and on the
    winch tension);
  - effect: largest rib-centre distance (mm) between the friction shape and the
    frictionless one, and between the pull and release branches at the same length
    (the hysteresis loop's width).
Also the out-and-back sweep of the yellow module (0-60-0 mm, 1 mm steps) with
`friction_sweep` against the frictionless `sweep` of the same lengths.

Usage: .venv/bin/python benchmarks/friction_bench.py [--quick]
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test' / 'softsnap_model'))
import friction_reference as ref  # noqa: E402

from softsnap_model import Skeleton, reachable_range, solve_forward, sweep  # noqa: E402
from softsnap_model.friction import friction_sweep, solve_friction  # noqa: E402
from benchlib import timed  # noqa: E402
from softsnap_model.reference import BRITTLE_STAR_MODULES, PAPER_THREADINGS  # noqa: E402

SK = Skeleton()
MUS = (0.05, 0.1, 0.2)
CONTRACTIONS = (20.0, 40.0, 60.0)


def fmt_range(values, scale, unit):
    v = [x * scale for x in values]
    return f'{statistics.median(v):7.2f} {unit} [{min(v):.2f}-{max(v):.2f}]'


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--quick', action='store_true', help='fewer threadings and repeats')
    args = ap.parse_args()
    names = BRITTLE_STAR_MODULES[:2] if args.quick else BRITTLE_STAR_MODULES
    repeat = 3 if args.quick else 7
    load_start = os.getloadavg()
    print(f'# cable friction benchmark ({platform.machine()}, {os.cpu_count()} cores, '
          f'numpy {np.__version__}); load average at start {load_start[0]:.2f} '
          f'{load_start[1]:.2f} {load_start[2]:.2f}')
    print(f'# threadings: {", ".join(names)}; contractions {CONTRACTIONS} mm (at most 90% '
          f'of the reachable range); {repeat} repeats per problem')
    header = (f'{"mu":>5s} {"c mm":>5s} {"friction solve":>24s} {"frictionless":>22s} '
              f'{"ratio":>6s} {"err vs ref mm":>13s} {"moved mm":>9s} {"pull-release mm":>15s}')
    print(header)
    for mu in MUS:
        for c_nominal in CONTRACTIONS:
            t_fr, t_0, ratios, errs, moved, gap = [], [], [], [], [], []
            for name in names:
                t = list(PAPER_THREADINGS[name])
                lo, hi = reachable_range(SK, t)
                c = min(c_nominal, 0.9 * (hi - lo))
                L = hi - c
                solve_friction(SK, t, L, mu)           # first call builds the caches
                dt_f, r = timed(lambda: solve_friction(SK, t, L, mu), repeat)
                dt_0, f = timed(lambda: solve_forward(SK, t, L), repeat)
                if not r.converged:
                    print(f'  {name} {c:.1f} mm: NOT CONVERGED: {r.message}')
                t_fr.append(dt_f)
                t_0.append(dt_0)
                ratios.append(dt_f / dt_0)
                a_ref, _ = ref.reference_branch(SK.threading_mm(t), SK.spacing_mm,
                                                SK.stiffness_array, mu, SK.contact_angle_rad,
                                                L, -1)
                errs.append(float(np.max(np.linalg.norm(
                    r.rib_centers - ref.rib_centres(a_ref, SK.spacing_mm), axis=1))))
                moved.append(float(np.max(np.linalg.norm(r.rib_centers - f.rib_centers,
                                                         axis=1))))
                rel = solve_friction(SK, t, L, mu, 'release')
                gap.append(float(np.max(np.linalg.norm(r.rib_centers - rel.rib_centers,
                                                       axis=1))))
            print(f'{mu:5.2f} {c_nominal:5.0f} {fmt_range(t_fr, 1e3, "ms"):>24s} '
                  f'{fmt_range(t_0, 1e6, "us"):>22s} {statistics.median(ratios):6.1f} '
                  f'{max(errs):13.1e} {max(moved):9.1f} {max(gap):15.1f}', flush=True)

    # Out-and-back sweep of the yellow module.
    t = list(PAPER_THREADINGS['yellow'])
    L0 = SK.straight_length_mm(t)
    c = np.arange(0.0, 60.0 + 1e-9, 1.0)
    c = np.r_[c, c[-2::-1]]
    rows = []
    for mu in MUS:
        dt_s, sw = timed(lambda: friction_sweep(SK, t, L0 - c, mu), max(1, repeat // 3))
        dt_0, sw0 = timed(lambda: sweep(SK, t, c), repeat)
        half = len(c) // 2
        width = np.max(np.linalg.norm(sw.rib_centers[:half + 1]
                                      - sw.rib_centers[half:][::-1], axis=2))
        rows.append((mu, dt_s, dt_0, sw.converged, width))
    print()
    print(f'yellow module out and back, 0-60-0 mm in 1 mm steps ({len(c)} lengths):')
    print(f'{"mu":>5s} {"friction_sweep":>15s} {"sweep (frictionless)":>21s} {"ratio":>7s} '
          f'{"converged":>9s} {"loop width mm":>13s}')
    for mu, dt_s, dt_0, ok, width in rows:
        print(f'{mu:5.2f} {dt_s * 1e3:12.1f} ms {dt_0 * 1e3:18.2f} ms {dt_s / dt_0:7.0f} '
              f'{str(ok):>9s} {width:13.1f}')
    load_end = os.getloadavg()
    print(f'# load average at end {load_end[0]:.2f} {load_end[1]:.2f} {load_end[2]:.2f}')


if __name__ == '__main__':
    main()
