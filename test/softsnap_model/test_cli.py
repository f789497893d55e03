"""softsnap-model command line."""
import json
import subprocess
import sys

import numpy as np
import pytest

from softsnap_model import Skeleton, solve_forward
from softsnap_model.cli import main, parse_threading

S_THREADING = 'R3 R3 R3 R3 R3 R3 L3 L3 L3 L3 L3 L3'


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_forward_json_matches_library(capsys):
    code, out, _ = run(capsys, 'forward', '--threading', S_THREADING, '--length', '150')
    assert code == 0
    data = json.loads(out)
    ref = solve_forward(Skeleton(), S_THREADING.split(), 150.0)
    assert np.allclose(data['angles_rad'], ref.angles, atol=1e-15)
    assert data['converged'] is True and len(data['rib_centers_mm']) == 12
    assert data['reachable_range_mm'][1] == pytest.approx(206.9072480941474)


def test_forward_contraction_and_offsets(capsys):
    code, out, _ = run(capsys, 'forward', '--threading', ','.join(['3'] * 12),
                       '--contraction', '10')
    assert code == 0
    assert json.loads(out)['cable_length_mm'] == pytest.approx(188.0)


def test_sweep_json(capsys):
    # The paper's 0-80 mm range on the green module (86.5 mm reachable with the CAD's
    # 3 mm ribs; the yellow one reaches only 70.4 mm).
    code, out, _ = run(capsys, 'sweep', '--threading',
                       'R1 R1 R1 R1 R1 R2 R2 R2 R2 R3 R3 R3', '--stop', '80', '--steps', '9')
    data = json.loads(out)
    assert code == 0 and len(data['angles_rad']) == 9 and all(data['converged'])
    assert data['contractions_mm'][-1] == 80.0


def test_errors_are_json_with_range(capsys):
    code, _, err = run(capsys, 'forward', '--threading', 'R1 ' * 12, '--contraction', '70')
    data = json.loads(err)
    assert code == 2 and data['type'] == 'InfeasibleLengthError'
    assert len(data['reachable_range_mm']) == 2
    code, _, err = run(capsys, 'forward', '--threading', 'R1 R9', '--length', '100')
    assert code == 2 and 'expected 12 holes' in json.loads(err)['error']


def test_parse_threading():
    assert parse_threading('R3, 2.5 L1') == ['R3', 2.5, 'L1']


def test_console_help_runs():
    proc = subprocess.run([sys.executable, '-m', 'softsnap_model.cli', '--help'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and 'forward' in proc.stdout and 'sweep' in proc.stdout


def test_parse_threading_expands_repeats():
    assert parse_threading('R3x6 L3x6') == ['R3'] * 6 + ['L3'] * 6
    assert parse_threading('r1x2, 2.5') == ['R1', 'R1', 2.5]


def test_record_subcommand_writes_a_sweep_recording(tmp_path, capsys, read_rrd):
    out = tmp_path / 'sweep.rrd'
    assert main(['record', 'sweep', '--threading', 'R3x12', '--max-contraction-mm', '30',
                 '--steps', '4', '--out', str(out)]) == 0
    answer = json.loads(capsys.readouterr().out)
    assert answer == {'recording': str(out.resolve()), 'steps': 4}
    rec = read_rrd(out)
    assert len(rec.values('robot/module/predicted/spine', 'LineStrips3D:strips')) == 4
