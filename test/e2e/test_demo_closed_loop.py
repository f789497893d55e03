"""End to end: `make demo ARGS="--physics --closed-loop"` (the shape controller on a MuJoCo
gripper finger) settles its cases and leaves its recording and correction log."""
import json

import pytest

from test_demo import run_demo

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_closed_loop_demo_reaches_its_targets(tmp_path, read_rrd):
    run_dir = tmp_path / 'run'
    proc = run_demo('--physics', '--closed-loop', '--run-dir', str(run_dir), '--json',
                    timeout=360)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index('{'):])
    cases = {c['name']: c for c in summary['cases']}
    assert set(cases) == {'payload_20g_tip', 'stiffness_minus_20pct'}
    assert cases['payload_20g_tip']['open_loop_tip_error_mm'] > 3.0
    for case in cases.values():
        assert case['stable'] and case['closed_loop_tip_error_mm'] < 1.0, case
        assert case['settle_time_s'] is not None and case['stop_reason'] == 'reached', case
    records = [json.loads(line) for line in
               (run_dir / 'corrections.jsonl').read_text().splitlines()]
    assert len(records) >= 2 and all(r['module'] == 'front_left' for r in records)
    rec = read_rrd(run_dir / 'control.rrd')
    assert 'control/front_left/error_mm' in rec.entities
