"""Is this file a whole rerun recording? Checked before an ``.rrd`` is served or read.

``recording view`` served a truncated file, an empty one and 100 kB of random bytes
without a word, and ``rerun rrd stats`` read 377 of 633 chunks of a truncated file with
exit status 0. Here the file's framing is walked (rerun's RRF2 encoding as rerun-sdk 0.41
writes it: a 12-byte stream header ``RRF2`` + version + options, then frames of a
64-bit kind and a 64-bit length followed by that many bytes; kind 0 ends a stream, 1
starts a store, 2 is one chunk of data, 3 activates a blueprint; a closed file ends with
a footer whose last bytes are ``RRF2FOOT`` and a version), then rerun's own reader
decodes the chunks. The result says how many chunks were read and where reading stops.

:func:`check_rrd` returns an :class:`RrdCheck`; :func:`require_recording` raises
:class:`RecordingFileError` for a file that is not a recording (missing, empty, another
format) and warns (one line, to stderr by default) for one that is cut short or damaged.
"""
from __future__ import annotations

import dataclasses
import struct
import sys
from pathlib import Path

STREAM_MAGIC = b'RRF2'
FOOTER_MAGIC = b'RRF2FOOT'
STREAM_HEADER_BYTES = 12
FRAME_HEADER_BYTES = 16
FRAME_END, FRAME_STORE_INFO, FRAME_CHUNK, FRAME_BLUEPRINT = 0, 1, 2, 3


class RecordingFileError(ValueError):
    """The file is not a rerun recording (the reason names the path and what was found)."""


@dataclasses.dataclass(frozen=True)
class RrdCheck:
    """What a check of one ``.rrd`` file found.

    chunks : data chunks whose frames are whole; stores : stores started (a recording and
    its blueprint are two); complete : every stream ended and the footer is there;
    stopped_at : byte offset where reading stopped early (None: read to the end);
    problem : why it stopped or what is wrong (None: a whole recording).
    """

    path: Path
    size: int
    is_recording: bool
    chunks: int
    stores: int
    complete: bool
    stopped_at: int | None
    problem: str | None

    @property
    def ok(self) -> bool:
        return self.is_recording and self.problem is None

    def describe(self) -> str:
        if not self.is_recording:
            return f'{self.path} is not a rerun recording: {self.problem}'
        if self.problem is None:
            return f'{self.path}: a whole recording, {self.chunks} chunks in {self.size} B'
        where = f', stops at byte {self.stopped_at} of {self.size}' if self.stopped_at is not None else ''
        return f'{self.path}: {self.problem} ({self.chunks} chunks read{where})'


def _walk_frames(data: bytes) -> tuple[int, int, bool, int | None, str | None]:
    """(chunks, stores, complete, stopped_at, problem) of RRF2 data that starts right."""
    size, offset = len(data), 0
    chunks = stores = 0
    ended = False
    while offset < size:
        if data.startswith(STREAM_MAGIC, offset) and not data.startswith(FOOTER_MAGIC, offset):
            if offset + STREAM_HEADER_BYTES > size:
                return chunks, stores, False, offset, 'truncated: a stream header cut short'
            offset += STREAM_HEADER_BYTES
            ended = False
            continue
        if ended:   # after a stream's end: the footer, or another stream
            tail = data[offset:]
            if FOOTER_MAGIC in tail:
                return chunks, stores, True, None, None
            return chunks, stores, False, offset, 'no footer after the last stream'
        if offset + FRAME_HEADER_BYTES > size:
            return chunks, stores, False, offset, 'truncated: a frame header cut short'
        kind, length = struct.unpack_from('<QQ', data, offset)
        if kind not in (FRAME_END, FRAME_STORE_INFO, FRAME_CHUNK, FRAME_BLUEPRINT):
            return chunks, stores, False, offset, f'damaged: unknown frame kind {kind}'
        end = offset + FRAME_HEADER_BYTES + length
        if end > size:
            return chunks, stores, False, offset, (
                f'truncated: a frame of {length} B at byte {offset} ends past the file')
        chunks += kind == FRAME_CHUNK
        stores += kind == FRAME_STORE_INFO
        ended = kind == FRAME_END
        offset = end
    if ended:
        return chunks, stores, False, size, 'no footer after the last stream'
    return chunks, stores, False, size, 'truncated: the stream has no end (the writer did not close it)'


def _decoded_chunks(path: Path) -> tuple[int, str | None]:
    """(chunks rerun's reader decoded, its error or None)."""
    import warnings
    from rerun.chunk import RrdReader
    count = 0
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')   # "no footer": reported by the framing
            for _chunk in RrdReader(str(path)).stream().to_chunks():
                count += 1
    except Exception as error:  # noqa: BLE001 - rerun's reader raises RuntimeError and others
        return count, str(error).splitlines()[0]
    return count, None


def check_rrd(path: str | Path, decode: bool = True) -> RrdCheck:
    """Check one ``.rrd`` file (framing, then with `decode` rerun's own reader)."""
    path = Path(path)
    if not path.is_file():
        return RrdCheck(path, 0, False, 0, 0, False, 0, 'no such file')
    data = path.read_bytes()
    size = len(data)
    if size == 0:
        return RrdCheck(path, 0, False, 0, 0, False, 0, 'the file is empty')
    if not data.startswith(STREAM_MAGIC):
        return RrdCheck(path, size, False, 0, 0, False, 0,
                        f'expected the header {STREAM_MAGIC.decode()!r}, found {data[:4]!r}')
    chunks, stores, complete, stopped_at, problem = _walk_frames(data)
    if decode and problem is None:
        decoded, error = _decoded_chunks(path)
        if error is not None:
            return RrdCheck(path, size, True, decoded, stores, False, None,
                            f'damaged: rerun could not decode it after {decoded} chunks: {error}')
    return RrdCheck(path, size, True, chunks, stores, complete, stopped_at, problem)


def require_recording(path: str | Path, warn=None) -> RrdCheck:
    """The check of `path`; RecordingFileError if it is not a recording, and a one-line
    warning (``warn(text)``, default: stderr) if it is cut short or damaged."""
    check = check_rrd(path)
    if not check.is_recording:
        raise RecordingFileError(check.describe())
    if check.problem is not None:
        text = f'warning: {check.describe()}'
        if warn is None:
            print(text, file=sys.stderr, flush=True)
        else:
            warn(text)
    return check


def main(argv=None) -> int:
    """``python -m softsnap_model.rrd_check FILE ...``: one line per file; exit 0 if all
    are whole recordings, 1 if one is cut short or damaged, 2 if one is not a recording."""
    import argparse
    parser = argparse.ArgumentParser(prog='python -m softsnap_model.rrd_check',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('files', nargs='+', help='.rrd files')
    args = parser.parse_args(argv)
    status = 0
    for name in args.files:
        check = check_rrd(name)
        print(check.describe(), file=sys.stdout if check.ok else sys.stderr)
        status = max(status, 0 if check.ok else (1 if check.is_recording else 2))
    return status


if __name__ == '__main__':
    sys.exit(main())
