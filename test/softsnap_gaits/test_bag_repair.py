"""Bags that survive their recorder, and damaged bags read with one clear message.

Real bags: written by BagWriter (rosbags' MCAP writer) with real CDR messages, or by a
real ``bag record`` process killed with SIGKILL while a real publisher runs. What is
recovered is compared with what was written, and whole files with an independent MCAP
reader (the ``mcap`` library).
"""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time

import pytest
import yaml

from softsnap_gaits.bag import BagWriter, bag_damage, bag_info, read_messages
from softsnap_gaits.bag_repair import DamagedBagError, reindex, scan_mcap

TOPIC = '/repair/yellow/state'
TYPE = 'softsnap_interfaces/msg/ModuleState'


def _state(i: int) -> bytes:
    from rclpy.serialization import serialize_message
    from softsnap_interfaces.msg import ModuleState
    msg = ModuleState(module='yellow', online=True, commands_received=i)
    msg.header.stamp.sec = i
    return serialize_message(msg)


def _write(path, batches: int, per_batch: int, close: bool = True):
    """A bag of `batches` chunks of `per_batch` messages each (message i at i ms)."""
    writer = BagWriter(path)
    writer.add_topic(TOPIC, TYPE)
    i = 0
    for _ in range(batches):
        for _ in range(per_batch):
            writer.write(TOPIC, 1_000_000_000 + i * 1_000_000, _state(i))
            i += 1
        assert writer.flush_if_due(period_s=0.0)   # the chunk is closed and on disk
    if close:
        writer.close()
    return writer


def _counts(path) -> list[int]:
    from rclpy.serialization import deserialize_message
    from softsnap_interfaces.msg import ModuleState
    return [deserialize_message(data, ModuleState).commands_received
            for _, _, _, data in read_messages(path, on_damage=lambda lines: None)]


def test_a_killed_writer_s_bag_is_reindexed_with_every_closed_chunk(tmp_path):
    bag = tmp_path / 'killed'
    writer = _write(bag, batches=4, per_batch=50, close=False)
    writer.write(TOPIC, 5_000_000_000, _state(999))   # in the open chunk: lost with the writer
    # What a SIGKILL leaves: the file as the operating system has it, no metadata.yaml.
    killed = tmp_path / 'as_killed'
    killed.mkdir()
    shutil.copy(bag / 'killed.mcap', killed / 'killed.mcap')
    writer.close()
    assert not (killed / 'metadata.yaml').exists()
    with pytest.raises(ValueError, match='bag reindex'):
        bag_info(killed)
    scan = scan_mcap(killed / 'killed.mcap')
    assert not scan.complete and len(scan.chunks) == 4 and scan.message_count == 200
    result = reindex(killed)
    assert (result.messages, result.chunks) == (200, 4)
    assert result.original.exists() and (killed / 'metadata.yaml').is_file()
    info = bag_info(killed)
    assert info.message_count == 200 and [t.name for t in info.topics] == [TOPIC]
    assert bag_damage(killed) == []
    assert _counts(killed) == list(range(200))   # every message, in order, byte for byte
    with pytest.raises(DamagedBagError, match='reindexed before'):
        reindex(killed)


def _damage_middle(bag, size: int = 4096) -> tuple[int, int]:
    path = bag / f'{bag.name}.mcap'
    data = bytearray(path.read_bytes())
    start = len(data) // 2
    data[start:start + size] = bytes(size)
    path.write_bytes(bytes(data))
    return start, start + size


def test_a_damaged_bag_names_the_range_and_the_rest_is_read(tmp_path):
    bag = tmp_path / 'damaged'
    _write(bag, batches=8, per_batch=400)
    total = bag_info(bag).message_count
    start, end = _damage_middle(bag)
    damage = bag_damage(bag)
    assert damage and 'bytes' in damage[0]
    got = _counts(bag)
    # Whole chunks are lost, never single messages: what is left is consecutive runs of
    # 400, in order, and fewer than all.
    assert 0 < len(got) < total and len(got) % 400 == 0
    assert got == sorted(got) and len(set(got)) == len(got)
    with pytest.raises(ValueError, match='damaged'):
        list(read_messages(bag))   # no skipping unless the caller says so


def test_bag_info_of_a_damaged_bag_warns_and_exits_1_without_a_traceback(tmp_path):
    bag = tmp_path / 'damaged'
    _write(bag, batches=8, per_batch=400)
    _damage_middle(bag)
    proc = subprocess.run([sys.executable, '-m', 'softsnap_gaits.bag', 'info', str(bag)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    assert 'Traceback' not in proc.stderr and 'damaged' in proc.stderr and 'bytes' in proc.stderr
    assert 'Messages:' in proc.stdout   # the metadata is still shown


def test_bag_reindex_cli_and_a_file_that_is_not_mcap(tmp_path):
    bag = tmp_path / 'junk'
    bag.mkdir()
    (bag / 'junk.mcap').write_bytes(b'not an mcap file at all' * 100)
    proc = subprocess.run([sys.executable, '-m', 'softsnap_gaits.bag', 'reindex', str(bag)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and 'Traceback' not in proc.stderr
    assert proc.stderr.count('\n') == 1 and 'not an MCAP file' in proc.stderr


def test_an_intact_bag_reads_the_same_through_the_scan_as_through_mcap(tmp_path):
    """The scanner, checked against the mcap library on a whole file."""
    from mcap.reader import make_reader
    from softsnap_gaits.bag_repair import scan_messages
    bag = tmp_path / 'whole'
    _write(bag, batches=3, per_batch=30)
    with open(bag / 'whole.mcap', 'rb') as f:
        reference = [(m.log_time, bytes(m.data)) for _, _, m in make_reader(f).iter_messages()]
    ours = [(t, data) for _, t, data in scan_messages(bag / 'whole.mcap')]
    assert ours == reference and len(ours) == 90
    assert scan_mcap(bag / 'whole.mcap').ok


# ------------------------------------------------------------ a real killed recorder
@pytest.mark.ros
@pytest.mark.slow
def test_a_sigkilled_recorder_loses_at_most_its_open_chunk(tmp_path, start_node, ros_node):
    from softsnap_interfaces.msg import CableLength
    bag = tmp_path / 'killed'
    recorder = start_node('softsnap_gaits', 'bag', 'record', '-o', str(bag), '/repair/length',
                          '--discovery-period', '0.1')
    publisher = ros_node.create_publisher(CableLength, '/repair/length', 100)
    assert ros_node.spin_until(lambda: publisher.get_subscription_count() > 0, 60.0), \
        recorder.output()[-2000:]
    sent = []   # (monotonic s, index)
    period = 0.02
    next_at = time.monotonic()
    while len(sent) < 250:   # 5 s at 50 Hz
        msg = CableLength(cable_length=float(len(sent)))
        publisher.publish(msg)
        sent.append((time.monotonic(), len(sent)))
        next_at += period
        ros_node.spin_until(lambda: time.monotonic() >= next_at, 1.0)
    killed_at = time.monotonic()
    recorder.proc.send_signal(signal.SIGKILL)
    recorder.proc.wait(30)
    assert not (bag / 'metadata.yaml').exists()
    proc = subprocess.run([sys.executable, '-m', 'softsnap_gaits.bag', 'reindex', str(bag)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    from rclpy.serialization import deserialize_message
    got = [int(deserialize_message(d, CableLength).cable_length)
           for _, _, _, d in read_messages(bag)]
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] == len(got) > 0
    # A prefix of what was sent, nothing missing in between (the recorder subscribed
    # before the first message: it was matched).
    assert got == list(range(got[0], got[0] + len(got))) and got[0] == 0
    last_sent_at = dict((i, t) for t, i in sent)[got[-1]]
    lost_s = killed_at - last_sent_at
    chunks = len(scan_mcap(bag / 'killed.mcap.orig').chunks)   # as the recorder left it
    print(f'\nSIGKILLed recorder: {len(got)} of {len(sent)} messages recovered in {chunks} '
          f'chunks; the last {lost_s:.2f} s before the kill lost')
    assert chunks >= 2   # chunks closed by time, not only at 1 MiB


@pytest.mark.ros
def test_bag_play_of_a_damaged_bag_plays_the_intact_chunks_and_says_so(tmp_path, start_node,
                                                                      ros_node):
    from softsnap_interfaces.msg import ModuleState
    bag = tmp_path / 'damaged'
    _write(bag, batches=8, per_batch=400)
    _damage_middle(bag)
    intact = len(_counts(bag))
    received = []
    ros_node.create_subscription(ModuleState, TOPIC, received.append, 5000)
    player = start_node('softsnap_gaits', 'bag', 'play', str(bag), '--rate', '100',
                        '--wait-for-subscribers', '60')
    assert ros_node.spin_until(lambda: not player.alive(), 300.0), player.output()[-2000:]
    ros_node.spin_until(lambda: len(received) >= intact, 10.0)
    out = player.output()
    assert player.proc.returncode == 1, out[-2000:]
    assert 'Traceback' not in out and 'damaged, skipped' in out and 'bytes' in out
    # The player's own count (a subscriber in this process may fall behind 100x speed).
    assert f'played {intact} messages' in out and intact < 3200, out[-2000:]
    assert received
