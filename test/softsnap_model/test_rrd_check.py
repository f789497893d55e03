"""Recordings checked when read (softsnap_model.rrd_check, ``recording view``).

Real .rrd files written by rerun-sdk (the sweep recorder), then cut short, emptied or
replaced with random bytes. Whether a file is whole is also asked of rerun's own reader
(RrdReader), which the check does not use for its framing walk.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from softsnap_model.recording import parse_threading, record_sweep
from softsnap_model.rrd_check import RecordingFileError, check_rrd, require_recording


@pytest.fixture(scope='module')
def whole_rrd(tmp_path_factory):
    path = tmp_path_factory.mktemp('rrd') / 'sweep.rrd'
    record_sweep(path, parse_threading('R3x12'), [float(c) for c in range(0, 60, 2)])
    return path


def _rerun_chunks(path) -> int:
    from rerun.chunk import RrdReader
    return sum(1 for _ in RrdReader(str(path)).stream().to_chunks())


def test_a_whole_recording_is_whole_and_counts_rerun_s_chunks(whole_rrd):
    check = check_rrd(whole_rrd)
    assert check.ok and check.complete and check.stopped_at is None, check.describe()
    # Every store's chunks (the blueprint's too): at least those of the recording's store.
    assert check.chunks >= _rerun_chunks(whole_rrd) > 0


def test_a_truncated_recording_says_how_many_chunks_and_where_it_stops(whole_rrd, tmp_path):
    data = whole_rrd.read_bytes()
    cut = tmp_path / 'cut.rrd'
    cut.write_bytes(data[:len(data) // 3])
    check = check_rrd(cut)
    assert check.is_recording and not check.ok and not check.complete
    assert check.problem.startswith('truncated')
    assert 0 < check.stopped_at <= len(data) // 3
    assert 0 <= check.chunks < check_rrd(whole_rrd).chunks
    with pytest.raises(RuntimeError):   # rerun's reader refuses it (independent check)
        _rerun_chunks(cut)
    warnings = []
    require_recording(cut, warn=warnings.append)
    assert len(warnings) == 1 and f'stops at byte {check.stopped_at}' in warnings[0]


@pytest.mark.parametrize('content', [b'', os.urandom(100_000), b'RRF'])
def test_a_file_that_is_not_a_recording_is_refused(tmp_path, content):
    path = tmp_path / 'not.rrd'
    path.write_bytes(content)
    check = check_rrd(path)
    assert not check.is_recording
    with pytest.raises(RecordingFileError, match='not a rerun recording'):
        require_recording(path)


def test_damaged_bytes_in_the_middle_are_reported(whole_rrd, tmp_path):
    data = bytearray(whole_rrd.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 4096] = bytes(4096)
    path = tmp_path / 'damaged.rrd'
    path.write_bytes(bytes(data))
    check = check_rrd(path)
    assert check.is_recording and not check.ok, check.describe()


def _view(path, tmp_path, slot_port):
    return subprocess.Popen([sys.executable, '-m', 'softsnap_model.recording', 'view', str(path),
                             '--web-port', str(slot_port()), '--grpc-port', str(slot_port())],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def test_recording_view_refuses_a_non_recording_with_one_line_and_exit_2(tmp_path, slot_port):
    path = tmp_path / 'random.rrd'
    path.write_bytes(os.urandom(100_000))
    proc = _view(path, tmp_path, slot_port)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, (out, err)
    assert 'Traceback' not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and 'not a rerun recording' in lines[0], err


def test_recording_view_warns_about_a_truncated_file_and_serves_the_rest(whole_rrd, tmp_path,
                                                                         slot_port):
    data = whole_rrd.read_bytes()
    cut = tmp_path / 'cut.rrd'
    cut.write_bytes(data[:len(data) // 2])
    proc = _view(cut, tmp_path, slot_port)
    try:
        first = proc.stderr.readline()
        assert 'truncated' in first and 'chunks read' in first, first
        deadline = time.monotonic() + 120
        line = ''
        while 'open http' not in line and time.monotonic() < deadline and proc.poll() is None:
            line = proc.stdout.readline()
        assert 'open http' in line
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)
