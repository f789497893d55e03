"""ROS 2 bags of a SoftSnap graph: record topics to a rosbag2 directory, play one back.

A bag is what ``ros2 bag record -s mcap`` writes: a directory holding ``metadata.yaml``
(rosbag2 format version 9, as Jazzy writes it) and one MCAP file with a ``ros2msg``
schema per message type. Each schema is the type's full definition, the ``.msg`` text of
the type followed by every type it uses (``std_msgs/Header``, ``geometry_msgs/Point``,
``builtin_interfaces/Time``, ...), read from the installed packages exactly as rosbag2
does it, so that tools without this project's packages (Foxglove, rerun, ``mcap_ros2``)
decode ``softsnap_interfaces`` messages. Messages are stored as the CDR bytes that came
over DDS (no re-serialisation), stamped with their receive time.

Command line (``ros2 run softsnap_gaits bag ...``, ``.venv/lib/softsnap_gaits/bag ...`` or
``python -m softsnap_gaits.bag ...``)::

    bag record -o DIR [TOPIC ...] [--namespace NS ...] [--all] [--exclude REGEX ...]
    bag play DIR [--rate R] [--topics TOPIC ...] [--loop] [--delay S] [--wait-for-subscribers S]
    bag info DIR
    bag reindex DIR

This module is the core: topic selection, message definitions, the writer, reading and
the playback schedule, with no rclpy. The ROS side (a recorder node subscribing with
``raw=True``, a player node publishing the stored bytes) is :mod:`softsnap_gaits.bag_node`,
imported only by the ``record`` and ``play`` commands.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
import sys
import time
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

__all__ = [
    'BagError', 'BagInfo', 'BagSummary', 'BagWriter', 'MessageDefinition', 'PlaybackClock',
    'TopicFilter', 'TopicInfo', 'bag_info', 'message_definition', 'playback_qos', 'read_messages',
    'recording_qos', 'main',
]

#: rosbag2 metadata format version written (Jazzy's rosbag2 writes and reads version 9).
ROSBAG2_VERSION = 9
#: Queue depth of the recorder's subscriptions (messages): a recorder that falls behind for
#: a few seconds on a loaded machine catches up instead of DDS overwriting its queue.
RECORD_DEPTH = 1000
#: The writer closes its current MCAP chunk (and hands it to the operating system) once
#: it is this old (s): a recorder killed (SIGKILL, out of memory) loses at most the
#: messages of the chunk it had open, and `bag reindex` recovers every closed one. The
#: rosbags writer alone closes a chunk only at 1 MiB, minutes of a small robot's topics.
CHUNK_PERIOD_S = 1.0
#: Queue depth the player publishes with when the bag does not know the publisher's own
#: (DDS discovery does not carry the history depth, so recorded profiles say 0).
PLAY_DEPTH = 100
#: Separator between the definitions of a schema (rosbag2's and the MCAP ros2msg profile's).
DEFINITION_SEPARATOR = '=' * 80
#: Field types of .msg files that are not messages.
PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'})


class BagError(ValueError):
    """A bag cannot be written or read: the reason names the path, topic or value."""


class DefinitionError(BagError):
    """A message type whose definition is not installed (or not a .msg type)."""


# ---------------------------------------------------------------- message definitions
@dataclasses.dataclass(frozen=True)
class MessageDefinition:
    """The full definition of a message type, as embedded in a bag's schema.

    Attributes
    ----------
    type_name : str
        ``package/msg/Type``.
    text : str
        ``ros2msg`` text: the type's .msg file, then each type it uses (transitively), each
        after a line of 80 ``=`` and a line ``MSG: package/Type``.
    type_hash : str
        The type's RIHS01 hash from its installed type description (``RIHS01_<hex>``).
    dependencies : tuple of str
        The ``package/msg/Type`` names of the types it uses, in the order of ``text``.
    """

    type_name: str
    text: str
    type_hash: str
    dependencies: tuple[str, ...]


def normalize_type_name(name: str, package: str | None = None) -> str:
    """``package/msg/Type`` of ``package/Type``, ``package/msg/Type`` or (with `package`)
    a bare ``Type``; BagError for anything else."""
    parts = name.split('/')
    if len(parts) == 1 and package:
        parts = [package, parts[0]]
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or parts[1] != 'msg' or not all(parts):
        raise DefinitionError(f"expected a message type 'package/msg/Type', got {name!r}")
    return '/'.join(parts)


def _field_types(text: str, package: str) -> list[str]:
    """Message types the fields of a .msg text use (``package/msg/Type``), in order."""
    found: list[str] = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        type_token = line.split()[0]  # constants (NAME=value) have primitive types
        base = re.sub(r'\[.*\]$', '', type_token)  # arrays: T[], T[3], T[<=3]
        base = re.sub(r'<=\d+$', '', base)  # bounded strings: string<=10
        if base in PRIMITIVE_TYPES:
            continue
        name = normalize_type_name(base, package)
        if name not in found:
            found.append(name)
    return found


def _share_directory(package: str) -> Path:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    try:
        return Path(get_package_share_directory(package))
    except PackageNotFoundError:
        raise DefinitionError(f'package {package!r} is not installed (not in the ament index '
                              'of AMENT_PREFIX_PATH)') from None


def _installed_files(type_name: str, share_directory: Callable[[str], Path]) -> tuple[str, str]:
    """(.msg text, RIHS01 hash) of an installed message type."""
    package, _, name = type_name.split('/')
    folder = share_directory(package) / 'msg'
    msg_path = folder / f'{name}.msg'
    if not msg_path.is_file():
        raise DefinitionError(f'no definition of {type_name}: {msg_path} does not exist '
                              '(only .msg types can be recorded)')
    type_hash = ''
    json_path = folder / f'{name}.json'
    if json_path.is_file():
        try:
            hashes = json.loads(json_path.read_text())['type_hashes']
            type_hash = next(h['hash_string'] for h in hashes if h['type_name'] == type_name)
        except (ValueError, KeyError, StopIteration, TypeError):
            type_hash = ''
    return msg_path.read_text(), type_hash


def message_definition(type_name: str,
                       share_directory: Callable[[str], Path] = _share_directory) -> MessageDefinition:
    """The full ``ros2msg`` definition of an installed message type, with its type hash.

    Parameters
    ----------
    type_name : str
        ``package/msg/Type`` (or ``package/Type``).
    share_directory : callable, optional
        Package name -> its share directory (default: the ament index).

    Raises
    ------
    DefinitionError
        The type, or a type it uses, has no installed .msg file.

    Examples
    --------
    >>> d = message_definition('softsnap_interfaces/msg/CableLength')  # doctest: +SKIP
    >>> d.dependencies  # doctest: +SKIP
    ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time')
    """
    root = normalize_type_name(type_name)
    texts: dict[str, str] = {}
    root_hash = ''
    pending = [root]
    while pending:  # depth first, each type once, in the order rosbag2 writes them
        current = pending.pop(0)
        if current in texts:
            continue
        text, type_hash = _installed_files(current, share_directory)
        if current == root:
            root_hash = type_hash
        texts[current] = text
        package = current.split('/')[0]
        pending = [t for t in _field_types(text, package) if t not in texts] + pending
    if not root_hash:
        root_hash = _computed_hash(root, texts)
    parts = [texts[root].rstrip('\n')]
    for name in list(texts)[1:]:
        package, _, short = name.split('/')
        parts.append(f'{DEFINITION_SEPARATOR}\nMSG: {package}/{short}\n{texts[name].rstrip(chr(10))}')
    return MessageDefinition(root, '\n'.join(parts) + '\n', root_hash, tuple(list(texts)[1:]))


def _computed_hash(type_name: str, texts: dict[str, str]) -> str:
    """RIHS01 hash of a type whose package installed no type description (rosbags)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.EMPTY)
    for name, text in texts.items():
        store.register(get_types_from_msg(text, name))
    return store.hash_rihs01(type_name)


# ---------------------------------------------------------------- topic selection
@dataclasses.dataclass(frozen=True)
class TopicFilter:
    """Which topics to record.

    A topic is taken when it is one of `topics`, or lies under one of `namespaces`, or
    `all` is set; and it matches none of `exclude` (regular expressions, searched in the
    absolute topic name). Hidden topics (a name part starting with ``_``) only when named
    in `topics`. ``matches`` compares absolute names (``/brittle_star/yellow/state``);
    ``resolved`` turns relative ones into absolute names the way a node does.
    """

    topics: tuple[str, ...] = ()
    namespaces: tuple[str, ...] = ()
    all: bool = False
    exclude: tuple[str, ...] = ()

    def __post_init__(self):
        for name in (*self.topics, *self.namespaces):
            if not name.strip('/'):
                raise BagError(f'empty topic or namespace name: {name!r}')
        for pattern in self.exclude:
            try:
                re.compile(pattern)
            except re.error as error:
                raise BagError(f'bad --exclude regular expression {pattern!r}: {error}') from None
        if not (self.topics or self.namespaces or self.all):
            raise BagError('nothing to record: name topics, a --namespace or --all')

    def resolved(self, resolve: Callable[[str], str]) -> 'TopicFilter':
        """The same filter with every name passed through `resolve` (for example a node's
        ``resolve_topic_name``: relative names under its namespace, remappings applied)."""
        return dataclasses.replace(self, topics=tuple(resolve(t) for t in self.topics),
                                   namespaces=tuple(resolve(n.rstrip('/')) for n in self.namespaces))

    def matches(self, topic: str) -> bool:
        if any(re.search(p, topic) for p in self.exclude):
            return False
        if topic in self.topics:
            return True
        if any(part.startswith('_') for part in topic.split('/')):
            return False
        if self.all:
            return True
        return any(topic.startswith(ns.rstrip('/') + '/') for ns in self.namespaces)


# ---------------------------------------------------------------- QoS
def _qos(**fields):
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    values = dict(history=QosHistory.KEEP_LAST, depth=10, reliability=QosReliability.RELIABLE,
                  durability=QosDurability.VOLATILE, deadline=QosTime(0, 0),
                  lifespan=QosTime(0, 0), liveliness=QosLiveliness.SYSTEM_DEFAULT,
                  liveliness_lease_duration=QosTime(0, 0), avoid_ros_namespace_conventions=False)
    values.update(fields)
    return Qos(**values)


def recording_qos(offered: Sequence) -> object:
    """The QoS (rosbags ``Qos``) to subscribe with to a topic whose publishers offer `offered`.

    Reliable only if every publisher is (a reliable subscription never matches a
    best-effort publisher), transient-local only if every publisher is (then their latched
    messages are recorded too), and a deep queue (RECORD_DEPTH).
    """
    from rosbags.interfaces import QosDurability, QosReliability
    reliable = all(q.reliability == QosReliability.RELIABLE for q in offered)
    latched = bool(offered) and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered)
    return _qos(depth=RECORD_DEPTH,
                reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
                durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE)


def playback_qos(offered: Sequence) -> object:
    """The QoS (rosbags ``Qos``) to play a topic with, from its recorded publishers' profiles.

    The recorded reliability and durability (best effort or transient local only if every
    recorded publisher was), and the recorded depth where the bag knows it, else
    PLAY_DEPTH.
    """
    from rosbags.interfaces import QosDurability, QosReliability
    best_effort = bool(offered) and all(q.reliability == QosReliability.BEST_EFFORT for q in offered)
    latched = bool(offered) and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered)
    depth = max([q.depth for q in offered] + [0]) or PLAY_DEPTH
    return _qos(depth=depth,
                reliability=QosReliability.BEST_EFFORT if best_effort else QosReliability.RELIABLE,
                durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE)


# ---------------------------------------------------------------- writing
@dataclasses.dataclass(frozen=True)
class BagSummary:
    """What a closed bag holds: path, messages per topic (count), first and last receive
    time (ns since the epoch; 0 when empty)."""

    path: Path
    message_counts: dict[str, int]
    start_ns: int
    end_ns: int

    @property
    def message_count(self) -> int:
        return sum(self.message_counts.values())


class BagWriter:
    """Writes one rosbag2 directory (MCAP storage, zstd-compressed chunks).

    ``add_topic`` once per topic (the schema embeds the type's full definition), then
    ``write`` the CDR bytes of each message with its receive time; ``close`` writes the
    MCAP summary and ``metadata.yaml``. Not thread-safe: one thread writes.

    Raises BagError if `path` exists (a bag is never overwritten).
    """

    def __init__(self, path: str | Path, *,
                 definition: Callable[[str], MessageDefinition] = message_definition):
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
        from rosbags.rosbag2.errors import WriterError
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path} exists: a bag is never overwritten, choose a new directory')
        self._definition = definition
        self._writer = Writer(self.path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
        # Compressed chunks, as rosbag2's MCAP plugin writes by default; every MCAP reader
        # (Foxglove, rerun, mcap_ros2) decompresses zstd.
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.set_custom_data('recorder', 'softsnap_gaits bag')
        try:
            self._writer.open()
        except (WriterError, OSError) as error:
            raise BagError(f'cannot create the bag {self.path}: {error}') from None
        self._connections: dict[str, object] = {}
        self._types: dict[str, str] = {}
        self.closed = False
        self.chunks_closed = 0
        self._chunk_opened_s: float | None = None   # monotonic s of the open chunk's first write

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> message type of every topic added."""
        return dict(self._types)

    def add_topic(self, topic: str, type_name: str, offered_qos: Sequence = ()) -> MessageDefinition:
        """Register a topic; its schema is `type_name`'s full definition. BagError if the
        topic is already there or the type's definition is not installed."""
        if self.closed:
            raise BagError(f'{self.path} is closed')
        if topic in self._connections:
            raise BagError(f'topic {topic} is already in the bag (as {self._types[topic]})')
        definition = self._definition(type_name)
        self._connections[topic] = self._writer.add_connection(
            topic, definition.type_name, msgdef=definition.text, rihs01=definition.type_hash,
            offered_qos_profiles=list(offered_qos))
        self._types[topic] = definition.type_name
        return definition

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Append one message (serialised CDR bytes) received at `timestamp_ns`."""
        connection = self._connections.get(topic)
        if connection is None:
            raise BagError(f'topic {topic} was not added to the bag')
        if self.closed:
            raise BagError(f'{self.path} is closed')
        self._writer.write(connection, int(timestamp_ns), data)
        if self._chunk_opened_s is None:
            self._chunk_opened_s = time.monotonic()
        self.flush_if_due()

    def flush_if_due(self, period_s: float = CHUNK_PERIOD_S) -> bool:
        """Close the open chunk and write it out if it is `period_s` old; True if it did.

        Also called by the recorder between messages, so a chunk closes on time when
        messages stop coming."""
        opened = self._chunk_opened_s
        if self.closed or opened is None or time.monotonic() - opened < period_s:
            return False
        storage = getattr(self._writer, 'storage', None)
        chunk = getattr(storage, 'chunk', None)
        if chunk is None or not hasattr(storage, 'close_chunk'):
            return False   # another rosbags layout: chunks close at its own size
        if chunk.bio.tell():
            storage.close_chunk()
            storage.bio.flush()   # in the kernel's hands: survives a SIGKILL of this process
            self.chunks_closed += 1
        self._chunk_opened_s = None
        return True

    def close(self) -> BagSummary:
        """Finish the MCAP file and write metadata.yaml (idempotent)."""
        counts = {topic: self._writer.counts[c.id] for topic, c in self._connections.items()}
        if not self.closed:
            self.closed = True
            self._writer.close()
        total = sum(counts.values())
        return BagSummary(self.path, counts, self._writer.min_timestamp if total else 0,
                          self._writer.max_timestamp if total else 0)


# ---------------------------------------------------------------- reading
@dataclasses.dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: name, type, message count and the recorded publishers' QoS."""

    name: str
    type_name: str
    message_count: int
    offered_qos: tuple


@dataclasses.dataclass(frozen=True)
class BagInfo:
    """A bag's metadata: storage file(s), duration and start (ns), topics."""

    path: Path
    storage_identifier: str
    files: tuple[str, ...]
    start_ns: int
    duration_ns: int
    message_count: int
    topics: tuple[TopicInfo, ...]


def _open_reader(path: Path):
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.errors import ReaderError
    path = Path(path)
    if not (path / 'metadata.yaml').is_file():
        raise BagError(f'{path} is not a bag: no metadata.yaml in it (a recording killed '
                       f'before it closed has none: `bag reindex {path}` rebuilds it)')
    try:
        reader = Reader(path)
        reader.open()
    except ReaderError as error:
        raise BagError(f'cannot read the bag {path}: {error}') from None
    return reader


def bag_info(path: str | Path) -> BagInfo:
    """The metadata of a bag (what ``ros2 bag info`` shows)."""
    reader = _open_reader(Path(path))
    try:
        topics = tuple(
            TopicInfo(c.topic, c.msgtype, c.msgcount, tuple(c.ext.offered_qos_profiles))
            for c in reader.connections)
        import yaml
        meta = yaml.safe_load((Path(path) / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        empty = reader.message_count == 0  # (an empty bag's start is 2^63 - 1)
        return BagInfo(Path(path), meta['storage_identifier'], tuple(meta['relative_file_paths']),
                       0 if empty else int(meta['starting_time']['nanoseconds_since_epoch']),
                       int(meta['duration']['nanoseconds']), reader.message_count, topics)
    finally:
        reader.close()


def bag_damage(path: str | Path) -> list[str]:
    """One line per damaged byte range of the bag's storage files (empty: the bag is
    whole): every chunk is decompressed and parsed (softsnap_gaits.bag_repair)."""
    from .bag_repair import DamagedBagError, scan_mcap
    lines = []
    for name in bag_info(path).files:
        try:
            lines += scan_mcap(Path(path) / name).problems()
        except (DamagedBagError, OSError) as error:
            lines.append(f'{name}: {error}')
    return lines


def read_messages(path: str | Path, topics: Iterable[str] | None = None,
                  on_damage: Callable[[list[str]], None] | None = None
                  ) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, receive time ns, CDR bytes) of every message, in receive-time order.

    A bag with damaged ranges (:func:`bag_damage`) is read from its intact chunks only,
    after ``on_damage(lines)`` (default: BagError, naming the ranges). A read failing
    in the middle anyway raises BagError, never the decoder's own exception."""
    damage = bag_damage(path)
    if damage:
        if on_damage is None:
            raise BagError(f'{path} is damaged: ' + '; '.join(damage))
        on_damage(damage)
        from .bag_repair import scan_messages
        wanted = None if topics is None else set(topics)
        for name in bag_info(path).files:
            for channel, stamp, data in scan_messages(Path(path) / name):
                if wanted is None or channel.topic in wanted:
                    yield channel.topic, channel.type_name, stamp, data
        return
    try:
        yield from _read_whole(path, topics)
    except BagError:
        raise
    except Exception as error:  # noqa: BLE001 - a decoder's error (zstd, CRC): one clear line
        raise BagError(f'cannot read {path} any further: {type(error).__name__}: {error}'
                       ) from None


def _read_whole(path: str | Path, topics: Iterable[str] | None
                ) -> Iterator[tuple[str, str, int, bytes]]:
    reader = _open_reader(Path(path))
    try:
        wanted = None if topics is None else set(topics)
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if connections:
            for connection, timestamp, data in reader.messages(connections=connections):
                yield connection.topic, connection.msgtype, timestamp, bytes(data)
    finally:
        reader.close()


@dataclasses.dataclass(frozen=True)
class PlaybackClock:
    """When to publish a recorded message: the recorded gaps divided by `rate`.

    `first_ns` is the receive time of the bag's first message, `start_s` the monotonic
    time it is published at. ``due(t)`` is the monotonic time of a message received at
    `t` ns.
    """

    rate: float
    first_ns: int
    start_s: float

    def __post_init__(self):
        if not (math.isfinite(self.rate) and 0.0 < self.rate <= 1000.0):
            raise BagError(f'rate must be > 0 and <= 1000, got {self.rate}')

    def due(self, timestamp_ns: int) -> float:
        return self.start_s + (timestamp_ns - self.first_ns) / 1e9 / self.rate


# ---------------------------------------------------------------- command line
def _absolute(names: Sequence[str]) -> tuple[str, ...]:
    return tuple(n if n.startswith('/') else '/' + n for n in names)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='bag', description='Record ROS 2 topics to a rosbag2 directory (MCAP), play one '
        'back, or show what one holds. ROS arguments (--ros-args ...) go last.')
    commands = parser.add_subparsers(dest='command', required=True)
    record = commands.add_parser('record', help='record topics until Ctrl-C (SIGINT/SIGTERM)')
    record.add_argument('topics', nargs='*',
                        help="topics to record (relative names are under the recorder's namespace)")
    record.add_argument('-o', '--output', required=True,
                        help='the bag directory to create (must not exist)')
    record.add_argument('-a', '--all', action='store_true', help='every topic of the ROS domain')
    record.add_argument('--namespace', action='append', default=[],
                        help='every topic under this namespace (repeatable)')
    record.add_argument('-x', '--exclude', action='append', default=[],
                        help='skip topics matching this regular expression (repeatable)')
    record.add_argument('--discovery-period', type=float, default=0.5,
                        help='how often to look for new topics, s (default 0.5)')
    play = commands.add_parser('play', help='publish the recorded messages with their timing')
    play.add_argument('bag', help='the bag directory')
    play.add_argument('-r', '--rate', type=float, default=1.0,
                      help='playback speed, 1 = as recorded (default 1)')
    play.add_argument('--topics', nargs='+', default=None, help='play only these topics')
    play.add_argument('-l', '--loop', action='store_true', help='play again from the start, until Ctrl-C')
    play.add_argument('-d', '--delay', type=float, default=1.0,
                      help='wait this long after creating the publishers, s, so that '
                           'subscribers match before the first message (default 1)')
    play.add_argument('-w', '--wait-for-subscribers', type=float, default=0.0, metavar='S',
                      help='first wait until every played topic has a subscriber, at most S '
                           'seconds (then play anyway, naming the topics without one; '
                           'default 0: do not wait)')
    info = commands.add_parser('info', help="print a bag's topics, types and counts; "
                                            'every chunk is checked (exit 1 if damaged)')
    info.add_argument('bag', help='the bag directory')
    info.add_argument('--json', action='store_true', help='print as JSON')
    reindex = commands.add_parser('reindex', help="rebuild a bag's metadata.yaml and index "
                                  'from the intact chunks of its MCAP file (a killed recorder)')
    reindex.add_argument('bag', help='the bag directory')
    return parser


def _print_info(info: BagInfo, as_json: bool) -> None:
    if as_json:
        print(json.dumps({
            'path': str(info.path), 'storage_identifier': info.storage_identifier,
            'files': list(info.files), 'start_ns': info.start_ns, 'duration_ns': info.duration_ns,
            'message_count': info.message_count,
            'topics': [{'name': t.name, 'type': t.type_name, 'message_count': t.message_count}
                       for t in info.topics]}, indent=2))
        return
    print(f'Files:      {", ".join(info.files)}\nStorage id: {info.storage_identifier}\n'
          f'Duration:   {info.duration_ns / 1e9:.3f} s\nMessages:   {info.message_count}\nTopics:')
    width = max((len(t.name) for t in info.topics), default=0)
    for t in sorted(info.topics, key=lambda t: t.name):
        print(f'  {t.name:{width}s}  {t.type_name}  {t.message_count}')


def _reindex(path: str) -> int:
    from .bag_repair import DamagedBagError, reindex
    try:
        result = reindex(path)
    except (DamagedBagError, OSError) as error:
        print(f'bag: {error}', file=sys.stderr)
        return 1
    seconds = (result.end_ns - result.start_ns) / 1e9 if result.messages else 0.0
    print(f'bag: reindexed {result.path}: {result.messages} messages in {result.chunks} '
          f'intact chunk(s), {seconds:.3f} s of receive time; original kept as {result.original}')
    for damaged in result.damaged:
        print(f'bag: warning: not recovered: {damaged.describe()}', file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``bag record|play|info|reindex``: see the module docstring. Exit 0, 1 on error, 2 on bad use."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if '--ros-args' in argv:
        index = argv.index('--ros-args')
        argv, ros_args = argv[:index], argv[index:]
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == 'info':
            _print_info(bag_info(args.bag), args.json)
            damage = bag_damage(args.bag)
            for line in damage:
                print(f'bag: warning: damaged: {line}', file=sys.stderr)
            return 1 if damage else 0
        if args.command == 'reindex':
            return _reindex(args.bag)
        if args.command == 'record':
            if not (math.isfinite(args.discovery_period) and 0.05 <= args.discovery_period <= 60):
                parser.error(f'--discovery-period must be 0.05-60 s, got {args.discovery_period}')
            selection = TopicFilter(tuple(args.topics), tuple(args.namespace), args.all,
                                    tuple(args.exclude))
            from .bag_node import record
            return record(Path(args.output), selection, args.discovery_period, ros_args)
        if not (math.isfinite(args.delay) and 0.0 <= args.delay <= 60.0):
            parser.error(f'--delay must be 0-60 s, got {args.delay}')
        if not (math.isfinite(args.wait_for_subscribers) and 0.0 <= args.wait_for_subscribers <= 3600.0):
            parser.error(f'--wait-for-subscribers must be 0-3600 s, got {args.wait_for_subscribers}')
        PlaybackClock(args.rate, 0, 0.0)  # validates the rate before ROS starts
        from .bag_node import play
        return play(Path(args.bag), args.rate, None if args.topics is None else _absolute(args.topics),
                    args.loop, args.delay, ros_args, wait_for_subscribers_s=args.wait_for_subscribers)
    except BagError as error:
        print(f'bag: {error}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
