"""End to end: the demo runs a whole simulated robot for a few seconds in separate processes."""
import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.mark.parametrize('scene', ['brittle_star'])
def test_demo_runs_the_robot_and_records_it(scene, tmp_path, read_rrd):
    run_dir = tmp_path / 'run'
    proc = subprocess.run(
        [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', scene, '--seconds', '4',
         '--run-dir', str(run_dir), '--json'],
        capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index('{'):])
    assert summary['scene'] == scene
    assert set(summary['modules']) == {'yellow', 'blue', 'green', 'red', 'orange'}
    for name, m in summary['modules'].items():
        # 50 Hz gait for ~4 s; on a loaded 2-core machine allow a slower timer.
        assert m['commands_received'] > 100, (name, m)
        assert m['messages_lost'] == 0, (name, m)
        assert m['measured_lengths'] > 20, (name, m)  # drivers poll the simulated modules
        assert m['commanded_shapes'] > 5 and m['predicted_shapes'] > 5, (name, m)
        assert m['online'], (name, m)
        assert 3.0 < m['battery_v'] < 4.3, (name, m)
        assert m['tip_error_mm_mean'] >= 0.0 and m['tip_error_mm_max'] < 400.0, (name, m)
    assert summary['model']['solves'] > 10
    # Every process stopped on SIGINT (no kill, no crash, no orphan).
    assert all(code in (0, -2) for code in summary['exit_codes'].values()), summary['exit_codes']
    assert len(summary['exit_codes']) == 5 * 2 + 3
    recording = run_dir / f'{scene}.rrd'
    assert summary['recording'] == str(recording.resolve())
    assert recording.stat().st_size > 10_000
    rec = read_rrd(recording)  # also checks the file was closed properly (footer)
    for module in summary['modules']:
        for source in ('commanded', 'predicted'):
            spines = rec.values(f'robot/{module}/{source}/spine', 'LineStrips3D:strips')
            assert len(spines) >= 3, (module, source)
            # 12 rib centres, in metres, within a module length of the base.
            points = spines[-1][0]
            assert len(points) == 12
            assert max(abs(c) for p in points for c in p) < 0.25
        assert len(rec.scalars(f'plots/cable_length_mm/{module}/commanded')) >= 3


def test_demo_reports_a_bad_scene(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'softsnap_gaits.demo', '--scene', 'no_such_robot',
                           '--seconds', '1', '--run-dir', str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'no_such_robot' in proc.stderr
