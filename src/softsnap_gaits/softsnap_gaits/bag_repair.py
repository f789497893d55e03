"""Damaged bags: find what is readable in an MCAP file, chunk by chunk, and rebuild a bag.

A recorder killed before it closed its bag leaves an MCAP file without its summary and
footer and no ``metadata.yaml``; a disk error leaves bytes that no longer decompress.
Readers that trust the file's index (rosbags) refuse the first whole and die in the
middle of the second (an uncaught ``ZstdError`` after half the messages). Here the file
is read from its start, record by record (the MCAP format: an opcode byte, a 64-bit
length, the content): every chunk is decompressed and its records parsed on their own,
so a bad chunk is one damaged byte range, named with the receive times it covers, and
the chunks after it are still read. A record whose length runs past the end is where a
killed writer stopped (``truncated``); bytes that are not a record are skipped up to the
next byte sequence that is a consistent chunk header.

:func:`scan_mcap` says what a file holds; :func:`scan_messages` yields the messages of
its intact chunks; :func:`reindex` rebuilds a bag directory from them (the rosbag2
``reindex`` command: ``bag reindex DIR``), keeping the original file beside it.
No rclpy.
"""
from __future__ import annotations

import dataclasses
import heapq
import mmap
import struct
import zlib
from pathlib import Path
from typing import Iterator

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END = (
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F)
#: Opcodes of the MCAP specification (0x01-0x10); anything else is not a record.
KNOWN_OPCODES = frozenset(range(0x01, 0x11))
#: Reindexed bags keep the original file under its name plus this suffix.
ORIGINAL_SUFFIX = '.orig'


class DamagedBagError(ValueError):
    """A file is not an MCAP file at all (no magic), or holds no readable chunk."""


@dataclasses.dataclass(frozen=True)
class DamagedRange:
    """Bytes [start, end) of a file that could not be read, why, and the receive times
    (ns) of the messages lost there when its chunk header still said so (else 0)."""

    start: int
    end: int
    reason: str
    start_ns: int = 0
    end_ns: int = 0

    def describe(self) -> str:
        times = (f', messages received {self.start_ns / 1e9:.3f}-{self.end_ns / 1e9:.3f} s '
                 'since the epoch' if self.end_ns else '')
        return f'bytes {self.start}-{self.end} ({self.end - self.start} B{times}): {self.reason}'


@dataclasses.dataclass(frozen=True)
class ChunkSpan:
    """An intact chunk: where its record lies and how many messages it holds."""

    offset: int
    length: int
    start_ns: int
    end_ns: int
    messages: int


@dataclasses.dataclass(frozen=True)
class Channel:
    """A channel (topic) with its schema: type name, definition text, encoding and the
    recorded publishers' QoS (the channel's ``offered_qos_profiles`` metadata)."""

    id: int
    topic: str
    type_name: str
    definition: str
    encoding: str
    offered_qos_profiles: str


@dataclasses.dataclass(frozen=True)
class McapScan:
    """What a scan of one MCAP file found."""

    path: Path
    size: int
    chunks: tuple[ChunkSpan, ...]
    channels: dict
    damaged: tuple[DamagedRange, ...]
    complete: bool          # the writer finished it (data end and footer reached)
    orphaned: int = 0       # messages of a channel whose definition was lost

    @property
    def message_count(self) -> int:
        return sum(c.messages for c in self.chunks)

    @property
    def ok(self) -> bool:
        return self.complete and not self.damaged and not self.orphaned

    def problems(self) -> list[str]:
        """One line per damaged range (empty when the file is whole)."""
        lines = [f'{self.path.name}: {d.describe()}' for d in self.damaged]
        if not self.complete and not any(d.reason.startswith('truncated') for d in self.damaged):
            lines.append(f'{self.path.name}: no summary or footer (the writer did not close it)')
        if self.orphaned:
            lines.append(f'{self.path.name}: {self.orphaned} message(s) of a channel whose '
                         'definition was in a damaged range: skipped')
        return lines


def _u16(b, o): return struct.unpack_from('<H', b, o)[0]
def _u32(b, o): return struct.unpack_from('<I', b, o)[0]
def _u64(b, o): return struct.unpack_from('<Q', b, o)[0]


def _string(b, o) -> tuple[str, int]:
    n = _u32(b, o)
    if o + 4 + n > len(b):
        raise ValueError('string runs past its record')
    return bytes(b[o + 4:o + 4 + n]).decode('utf-8'), o + 4 + n


def _chunk_header(b, o: int, size: int):
    """(start ns, end ns, uncompressed size, crc, compression, data offset, data size) of
    the chunk record at `o` if its header is consistent, else None."""
    if o + 9 + 40 > size or b[o] != OP_CHUNK:
        return None
    length = _u64(b, o + 1)
    content = o + 9
    try:
        start_ns, end_ns, raw_size = struct.unpack_from('<QQQ', b, content)
        crc = _u32(b, content + 24)
        compression, p = _string(b, content + 28)
        data_size = _u64(b, p)
    except (ValueError, UnicodeDecodeError, struct.error):
        return None
    if compression not in ('', 'zstd', 'lz4') or p + 8 + data_size != content + length:
        return None
    if content + length > size:
        return None
    return start_ns, end_ns, raw_size, crc, compression, p + 8, data_size


def _decompress(data: bytes, compression: str, raw_size: int) -> bytes:
    if compression == '':
        return data
    if compression == 'zstd':
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=raw_size)
    import lz4.frame
    return lz4.frame.decompress(data)


def _records(b, schemas: dict, channels: dict, on_message, orphans: list) -> int:
    """Parse the records of a chunk's content; the number of messages. Messages of a
    channel not (yet) defined (its channel record was in a damaged chunk) are counted in
    ``orphans[0]``: they cannot be decoded."""
    o, n, count = 0, len(b), 0
    while o < n:
        if o + 9 > n:
            raise ValueError(f'record header cut at byte {o} of the chunk')
        op, length = b[o], _u64(b, o + 1)
        c, o = o + 9, o + 9 + length
        if o > n:
            raise ValueError(f'record of {length} B runs past the chunk')
        if op == OP_SCHEMA:
            sid = _u16(b, c)
            name, p = _string(b, c + 2)
            _encoding, p = _string(b, p)
            dlen = _u32(b, p)
            schemas[sid] = (name, bytes(b[p + 4:p + 4 + dlen]).decode('utf-8'))
        elif op == OP_CHANNEL:
            cid, sid = _u16(b, c), _u16(b, c + 2)
            topic, p = _string(b, c + 4)
            encoding, p = _string(b, p)
            qos, end = '', p + 4 + _u32(b, p)
            p += 4
            while p < end:
                key, p = _string(b, p)
                value, p = _string(b, p)
                if key == 'offered_qos_profiles':
                    qos = value
            name, definition = schemas.get(sid, ('', ''))
            channels[cid] = Channel(cid, topic, name, definition, encoding, qos)
        elif op == OP_MESSAGE:
            if length < 22:
                raise ValueError(f'message record of {length} B')
            count += 1
            if _u16(b, c) not in channels:
                orphans[0] += 1
            if on_message is not None:
                on_message(_u16(b, c), _u64(b, c + 6), bytes(b[c + 22:o]))
    return count


def _resync(b, o: int, size: int) -> int:
    """The offset of the next consistent chunk header after `o` (or `size`)."""
    while True:
        o = b.find(bytes([OP_CHUNK]), o + 1)
        if o < 0:
            return size
        if _chunk_header(b, o, size) is not None:
            return o


def _walk(path: Path, on_chunk_message=None) -> McapScan:
    path = Path(path)
    size = path.stat().st_size
    if size < len(MAGIC) or path.read_bytes()[:len(MAGIC)] != MAGIC:
        raise DamagedBagError(f'{path} is not an MCAP file (no MCAP magic at its start)')
    schemas: dict = {}
    channels: dict = {}
    chunks: list[ChunkSpan] = []
    damaged: list[DamagedRange] = []
    complete = False
    orphans = [0]
    with open(path, 'rb') as handle, mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as b:
        o = len(MAGIC)
        while o < size:
            if o + 9 > size:
                damaged.append(DamagedRange(o, size, 'truncated: a record header cut short'))
                break
            op, length = b[o], _u64(b, o + 1)
            end = o + 9 + length
            if op not in KNOWN_OPCODES:
                nxt = _resync(b, o, size)
                damaged.append(DamagedRange(o, nxt, f'not an MCAP record (opcode 0x{op:02x})'))
                o = nxt
                continue
            if end > size:
                nxt = _resync(b, o, size)
                if nxt < size:   # a broken length in the middle: read on after it
                    damaged.append(DamagedRange(o, nxt, f'a record length ({length} B) runs '
                                                'past the end of the file'))
                    o = nxt
                    continue
                # Where a killed writer stopped; a chunk header still gives the times.
                times = (struct.unpack_from('<QQ', b, o + 9) if op == OP_CHUNK
                         and o + 25 <= size else (0, 0))
                damaged.append(DamagedRange(o, size, f'truncated: a {length} B record '
                                            f'(opcode 0x{op:02x}) ends past the file',
                                            *times))
                break
            if op == OP_CHUNK:
                header = _chunk_header(b, o, size)
                if header is None:
                    nxt = _resync(b, o, size)
                    damaged.append(DamagedRange(o, nxt, 'chunk header inconsistent'))
                    o = nxt
                    continue
                start_ns, end_ns, raw_size, crc, compression, data_at, data_size = header
                try:
                    raw = _decompress(bytes(b[data_at:data_at + data_size]), compression, raw_size)
                    if len(raw) != raw_size:
                        raise ValueError(f'{len(raw)} B decompressed, the header says {raw_size}')
                    if crc and zlib.crc32(raw) != crc:
                        raise ValueError('CRC of the decompressed data does not match')
                    # Parse first, deliver after: a chunk is used whole or not at all.
                    found: list = []
                    count = _records(raw, schemas, channels,
                                     None if on_chunk_message is None else
                                     lambda *m: found.append(m), orphans)
                except Exception as error:  # noqa: BLE001 - any decoding failure is damage
                    damaged.append(DamagedRange(o, end, f'chunk does not decode: {error}',
                                                start_ns, end_ns))
                    o = end
                    continue
                if on_chunk_message is not None:
                    on_chunk_message(found)
                chunks.append(ChunkSpan(o, end - o, start_ns if count else 0,
                                        end_ns if count else 0, count))
            elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE):
                try:   # records outside chunks (an unchunked writer)
                    found = []
                    count = _records(bytes(b[o:end]), schemas, channels,
                                     None if on_chunk_message is None else
                                     lambda *m: found.append(m), orphans)
                except Exception as error:  # noqa: BLE001
                    damaged.append(DamagedRange(o, end, f'record does not decode: {error}'))
                    o = end
                    continue
                if count:
                    if on_chunk_message is not None:
                        on_chunk_message(found)
                    chunks.append(ChunkSpan(o, end - o, found[0][1] if found else 0,
                                            found[-1][1] if found else 0, count))
            elif op == OP_DATA_END:
                complete = True   # the summary after it indexes what we have read
                break
            elif op == OP_FOOTER:
                complete = True
                break
            o = end
    return McapScan(path, size, tuple(chunks), channels, tuple(damaged), complete, orphans[0])


def scan_mcap(path: str | Path) -> McapScan:
    """Read every chunk of an MCAP file; DamagedBagError if it is not MCAP at all."""
    return _walk(Path(path))


def scan_messages(path: str | Path) -> Iterator[tuple[Channel, int, bytes]]:
    """(channel, receive time ns, CDR bytes) of every message of the file's intact chunks,
    in receive-time order (chunks decoded one at a time, merged by time)."""
    per_chunk: list[list] = []
    scan = _walk(Path(path), per_chunk.append)
    streams = [sorted(((t, cid, data) for cid, t, data in found), key=lambda m: m[0])
               for found in per_chunk]
    for t, cid, data in heapq.merge(*streams, key=lambda m: m[0]):
        channel = scan.channels.get(cid)
        if channel is not None:
            yield channel, t, data


@dataclasses.dataclass(frozen=True)
class ReindexResult:
    """What ``reindex`` recovered: messages and chunks kept, what was damaged, the
    receive times covered (ns) and where the original file was kept."""

    path: Path
    messages: int
    chunks: int
    damaged: tuple[DamagedRange, ...]
    start_ns: int
    end_ns: int
    original: Path | None


def _mcap_files(bag: Path) -> list[Path]:
    meta = bag / 'metadata.yaml'
    if meta.is_file():
        try:
            import yaml
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            files = [bag / name for name in info['relative_file_paths']]
            if all(f.is_file() for f in files):
                return files
        except Exception:  # noqa: BLE001 - a broken metadata.yaml is what reindex replaces
            pass
    return sorted(p for p in bag.glob('*.mcap'))


def reindex(bag: str | Path) -> ReindexResult:
    """Rebuild the bag directory `bag` from the intact chunks of its MCAP file.

    Every message of every intact chunk is written, byte for byte with its receive time,
    to a new MCAP file with a summary and a new ``metadata.yaml`` (rosbag2 format); the
    original file is kept beside it as ``<name>.mcap.orig``. DamagedBagError when there
    is no MCAP file, or nothing readable in it.
    """
    from .bag import BagError, BagWriter, MessageDefinition, message_definition
    bag = Path(bag)
    files = _mcap_files(bag)
    if not bag.is_dir() or not files:
        raise DamagedBagError(f'{bag} holds no .mcap file to reindex')
    if len(files) > 1:
        raise DamagedBagError(f'{bag} holds {len(files)} .mcap files; reindex takes one')
    source = files[0]
    scan = scan_mcap(source)
    if not scan.chunks:
        raise DamagedBagError(f'nothing readable in {source}: ' + '; '.join(scan.problems()))
    original = source.with_name(source.name + ORIGINAL_SUFFIX)
    if original.exists():
        raise DamagedBagError(f'{original} exists: this bag was reindexed before')
    staging = bag / '.reindex'
    if staging.exists():
        import shutil
        shutil.rmtree(staging)

    def definition(type_name: str, text: str) -> MessageDefinition:
        try:
            type_hash = message_definition(type_name).type_hash
        except BagError:
            type_hash = ''
        return MessageDefinition(type_name, text, type_hash, ())

    texts = {c.type_name: c.definition for c in scan.channels.values()}
    writer = BagWriter(staging, definition=lambda t: definition(t, texts[t]))
    try:
        from rosbags.rosbag2.storage_mcap import get_qos
    except ImportError:  # pragma: no cover - another rosbags layout
        get_qos = None
    added: set[int] = set()
    try:
        for channel, stamp, data in scan_messages(source):
            if channel.id not in added:
                qos = []
                if get_qos is not None and channel.offered_qos_profiles:
                    meta = (struct.pack('<I', 20) + b'offered_qos_profiles'
                            + struct.pack('<I', len(channel.offered_qos_profiles.encode()))
                            + channel.offered_qos_profiles.encode())
                    try:
                        qos = get_qos(meta)
                    except Exception:  # noqa: BLE001 - QoS is informative; keep the messages
                        qos = []
                writer.add_topic(channel.topic, channel.type_name, qos)
                added.add(channel.id)
            writer.write(channel.topic, stamp, data)
    finally:
        summary = writer.close()
    new_files = sorted(staging.glob('*.mcap'))
    source.rename(original)
    new_files[0].rename(bag / source.name)
    import yaml
    meta = yaml.safe_load((staging / 'metadata.yaml').read_text())
    meta['rosbag2_bagfile_information']['relative_file_paths'] = [source.name]
    for entry in meta['rosbag2_bagfile_information'].get('files', []):
        entry['path'] = source.name
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(meta, sort_keys=False))
    (staging / 'metadata.yaml').unlink()
    staging.rmdir()
    return ReindexResult(bag, summary.message_count, len(scan.chunks), scan.damaged,
                         summary.start_ns, summary.end_ns, original)
