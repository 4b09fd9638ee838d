"""rosbag2 files (mcap or sqlite3) read and written with the pure-Python rosbags library.

The only module of the project that imports rosbags. Bags are standard rosbag2 directories,
readable by `ros2 bag`, `rosbags` and `mcap`. The typestore knows ROS 2 Jazzy's messages plus
pose4d_msgs, registered from the package's own .msg files, so the bags carry the full message
definitions and are self-describing.

Writing is atomic: a bag is built in a hidden temporary directory beside its destination and
renamed into place when closed, so a crash never leaves a half-written bag under the final name.
`BagWriter.flush` puts what was written so far on disk (an MCAP chunk, a SQLite commit); after a
crash (`kill -9`) `repair` turns the hidden partial recording into a bag of every flushed message.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import decompress, get_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pose4d_ros.datasets import bag_damage

MSG_PACKAGE = 'pose4d_msgs'
MSG_NAMES = ('Joint', 'JointArray', 'SkeletonArray')

_INFINITE = QosTime(0x7FFFFFFF, 0xFFFFFFFF)
# Hidden staging directory of a bag being written: .NAME.partial-PID
PARTIAL_MARK = '.partial-'


def make_qos(*, reliable: bool, depth: int, transient_local: bool = False) -> Qos:
    """An offered-QoS record for a bag's metadata (keep last `depth`)."""
    return Qos(QosHistory.KEEP_LAST, depth,
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               _INFINITE, _INFINITE, QosLiveliness.AUTOMATIC, _INFINITE, False)


# What a camera driver with default QoS offers, and the sensor-data profile.
QOS_RELIABLE = make_qos(reliable=True, depth=10)
QOS_SENSOR = make_qos(reliable=False, depth=5)


def msg_dir() -> Path:
    """Directory holding pose4d_msgs' .msg files.

    Looked up in the installed share/ of every prefix on AMENT_PREFIX_PATH, then in this
    interpreter's prefix, then in the source tree (a checkout used without installing).
    """
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    candidates = [Path(p) / 'share' / MSG_PACKAGE / 'msg' for p in [*prefixes, sys.prefix]]
    candidates.append(Path(__file__).resolve().parents[2] / MSG_PACKAGE / 'msg')
    for path in candidates:
        if all((path / f'{name}.msg').is_file() for name in MSG_NAMES):
            return path
    raise FileNotFoundError(
        f'{MSG_PACKAGE} .msg files not found in any of: {", ".join(map(str, candidates))}')


@cache
def typestore() -> Typestore:
    """ROS 2 Jazzy's message types plus pose4d_msgs."""
    store = get_typestore(Stores.ROS2_JAZZY)
    folder = msg_dir()
    types: dict[str, Any] = {}
    for name in MSG_NAMES:
        text = (folder / f'{name}.msg').read_text()
        types.update(get_types_from_msg(text, f'{MSG_PACKAGE}/msg/{name}'))
    store.register(types)
    return store


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag."""

    name: str
    msgtype: str
    count: int
    qos: tuple[Qos, ...]


@dataclass(frozen=True)
class BagMessage:
    """One recorded message: raw CDR bytes, as published."""

    topic: str
    msgtype: str
    timestamp_ns: int
    data: bytes
    bag: Path | None = None  # the bag it was read from, for errors


class BagWriter:
    """Write a rosbag2 directory atomically.

    Use as a context manager; on an exception the partial bag is removed. Messages are given as
    raw CDR bytes or as rosbags message objects (serialised with `typestore()`).

    Parameters
    ----------
    path : destination directory; must not exist.
    storage : 'mcap' (default) or 'sqlite3'.
    compress : zstd chunk compression (mcap only).
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap', compress: bool = True) -> None:
        self.path = Path(path)
        if storage not in ('mcap', 'sqlite3'):
            raise ValueError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
        if self.path.exists():
            raise FileExistsError(f'{self.path}: exists already, not overwriting')
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f'{self.path.parent}: no such directory')
        self.storage = storage
        self._staging = self.path.parent / f'.{self.path.name}{PARTIAL_MARK}{os.getpid()}'
        shutil.rmtree(self._staging, ignore_errors=True)
        self._staging.mkdir()
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._writer = Writer(self._staging / self.path.name, version=9, storage_plugin=plugin)
        if compress and storage == 'mcap':
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self._store = typestore()

    def add_topic(self, topic: str, msgtype: str, qos: Iterable[Qos] = (QOS_RELIABLE,)) -> None:
        """Declare a topic (once) with its message type and offered QoS profiles."""
        if topic in self._connections:
            raise ValueError(f'topic {topic} added twice')
        if msgtype not in self._store.types:
            raise ValueError(f'unknown message type {msgtype} for topic {topic}')
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._store, offered_qos_profiles=list(qos))
        self.counts[topic] = 0

    def write(self, topic: str, timestamp_ns: int, message: bytes | memoryview | object) -> None:
        """Write one message (raw CDR bytes, or a rosbags message object) at a receive time."""
        connection = self._connections.get(topic)
        if connection is None:
            raise ValueError(f'topic {topic} was not added to {self.path}')
        if not isinstance(message, bytes | bytearray | memoryview):
            message = self._store.serialize_cdr(message, connection.msgtype)
            # Fast DDS pads every payload to a multiple of 4 bytes on the wire, so a recorder
            # receives (and a bag of recorded data holds) the padded form; write that form.
            message = bytes(message) + bytes(-len(message) % 4)
        self._writer.write(connection, int(timestamp_ns), bytes(message))
        self.counts[topic] += 1

    def flush(self) -> None:
        """Put every message written so far on disk, where `repair` finds it after a crash.

        MCAP: the pending chunk is closed and the file flushed; SQLite: a commit. (rosbags'
        storage objects, at the pinned version, do both only on `close`.)
        """
        storage = self._writer.storage
        if self.storage == 'mcap':
            if storage.chunk.bio.tell():
                storage.close_chunk()
            storage.bio.flush()
        else:
            storage.conn.commit()

    def close(self) -> Path:
        """Finish the bag and move it into place; returns its path."""
        self._writer.close()
        os.replace(self._staging / self.path.name, self.path)
        self._staging.rmdir()
        return self.path

    def abort(self) -> None:
        """Drop the partial bag."""
        try:
            self._writer.abort()
        finally:
            shutil.rmtree(self._staging, ignore_errors=True)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: object, *_: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _open_reader(path: str | Path) -> Reader:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such bag')
    if not (path / 'metadata.yaml').is_file():
        hint = ''
        if PARTIAL_MARK in str(path) or any(path.glob('*.mcap')) or any(path.glob('*.db3')):
            hint = (': an unfinished recording (its recorder did not close it); '
                    f'`pose4d bag-repair {path}` recovers what it holds')
        raise ValueError(f'{path}: not a rosbag2 directory (no metadata.yaml){hint}')
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags, mcap, sqlite3: their own words for a damaged file
        raise ValueError(f'cannot read bag: {bag_damage.describe(path)}') from exc
    return reader


@contextmanager
def any_reader(path: str | Path) -> Iterator[AnyReader]:
    """An open reader of a rosbag2 (directory) or a ROS 1 bag (.bag file) of any camera's
    recording, closed at the end of the `with`; messages deserialised by `reader.deserialize`
    (types from the bag, else Jazzy's). ValueError naming the bag when it cannot be read."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such bag')
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as exc:  # rosbags' own words for what it cannot read
        raise ValueError(f'{path}: cannot read the bag ({exc})') from exc
    try:
        yield reader
    finally:
        reader.close()


def topics(path: str | Path) -> dict[str, TopicInfo]:
    """The bag's topics with type, message count and offered QoS."""
    reader = _open_reader(path)
    try:
        out: dict[str, TopicInfo] = {}
        for c in reader.connections:
            qos = tuple(getattr(c.ext, 'offered_qos_profiles', ()) or ())
            prev = out.get(c.topic)
            count = c.msgcount + (prev.count if prev else 0)
            out[c.topic] = TopicInfo(c.topic, c.msgtype, count, qos)
        return out
    finally:
        reader.close()


def read_messages(path: str | Path, topics: Iterable[str] | None = None,
                  *, start_ns: int | None = None) -> Iterator[BagMessage]:
    """Messages of a bag in timestamp order, as raw CDR bytes.

    Parameters
    ----------
    topics : only these topics (all if None). Unknown names raise ValueError.
    start_ns : skip messages before this bag timestamp (ns).
    """
    reader = _open_reader(path)
    try:
        connections = list(reader.connections)
        if topics is not None:
            wanted = set(topics)
            missing = wanted - {c.topic for c in connections}
            if missing:
                raise ValueError(f'{path}: no topic(s) {", ".join(sorted(missing))}; has '
                                 f'{", ".join(sorted({c.topic for c in connections}))}')
            connections = [c for c in connections if c.topic in wanted]
        n = 0
        messages = reader.messages(connections=connections, start=start_ns)
        while True:
            try:
                connection, timestamp, data = next(messages)
            except StopIteration:
                break
            except Exception as exc:  # rosbags, mcap, zstandard, sqlite3: a damaged file
                raise ValueError(f'damaged bag after {n} messages: '
                                 f'{bag_damage.describe(Path(path))}') from exc
            n += 1
            yield BagMessage(connection.topic, connection.msgtype, timestamp, bytes(data),
                             Path(path))
    finally:
        reader.close()


def deserialize(message: BagMessage) -> Any:
    """Decode a message's CDR bytes into a rosbags message object; ValueError naming the bag,
    topic and time when they are not a message of its type (damaged, or an unknown type)."""
    try:
        return typestore().deserialize_cdr(message.data, message.msgtype)
    except Exception as exc:  # rosbags raises whatever its decoder meets in damaged bytes
        known = message.msgtype in typestore().types
        raise ValueError(f'{message.bag or "bag"}: {message.topic} at {message.timestamp_ns} ns '
                         f'is not a valid {message.msgtype}: ' + (
                             f'its {len(message.data)} bytes do not decode as one (damaged)'
                             if known else 'a message type this reader does not know')
                         ) from exc


# ------------------------------------------------------------------ crash recovery
@dataclass(frozen=True)
class Repaired:
    """What `repair` saved: the new bag, its messages per topic, and what it had to skip."""

    path: Path
    counts: dict[str, int]
    skipped: str


def partial_recordings(directory: str | Path) -> list[Path]:
    """Unfinished recordings (`BagWriter`'s hidden staging directories) in `directory` whose
    writing process is gone: what a killed recorder leaves."""
    out = []
    for path in sorted(Path(directory).glob(f'.*{PARTIAL_MARK}*')):
        pid = path.name.rpartition(PARTIAL_MARK)[2]
        if path.is_dir() and not (pid.isdigit() and _alive(int(pid))):
            out.append(path)
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def repair(partial: str | Path, out: str | Path | None = None) -> Repaired:
    """Turn an unfinished recording (a recorder killed before it closed its bag) into a bag.

    Reads every complete record of the partial .mcap (the chunks the recorder flushed; one cut
    short by the crash or damaged is skipped and reported) or every committed row of the
    partial .db3, and writes them to a new bag, atomically like every bag.

    Parameters
    ----------
    partial : the hidden staging directory (.NAME.partial-PID), a directory in it, or the
        .mcap/.db3 file.
    out : the new bag; default: NAME beside the staging directory (the recording's name).
    """
    partial = Path(partial)
    if not partial.exists():
        raise FileNotFoundError(f'{partial}: no such file or directory')
    files = [partial] if partial.is_file() else sorted(
        f for pattern in ('*.mcap', '*.db3', '*/*.mcap', '*/*.db3') for f in partial.glob(pattern))
    if not files:
        raise ValueError(f'{partial}: no .mcap or .db3 file in it to repair')
    source = files[0]
    if out is None:
        staging = next((p for p in (partial, *partial.parents) if PARTIAL_MARK in p.name), None)
        if staging is None:
            raise ValueError(f'{partial}: not a partial recording (.NAME{PARTIAL_MARK}PID); '
                             'name the output')
        out = staging.parent / staging.name[1:].rpartition(PARTIAL_MARK)[0]
    sqlite = source.suffix == '.db3'
    skipped: list[str] = []
    with BagWriter(out, storage='sqlite3' if sqlite else 'mcap') as writer:
        for kind, *item in (_scan_sqlite(source) if sqlite else _scan_mcap(source, skipped)):
            (writer.add_topic if kind == 'topic' else writer.write)(*item)
    return Repaired(Path(out), dict(writer.counts), '; '.join(skipped))


def remove_partial(partial: str | Path) -> Path | None:
    """Delete an unfinished recording's staging directory (.NAME.partial-PID), whichever path
    inside it is given, and return it; None (nothing deleted) for any other path."""
    partial = Path(partial).resolve()
    staging = next((p for p in (partial, *partial.parents) if PARTIAL_MARK in p.name), None)
    if staging is not None:
        shutil.rmtree(staging)
    return staging


def _scan_sqlite(path: Path) -> Iterator[tuple]:
    """('topic', name, type, qos) and ('message', topic, time, data) of every committed row
    of a rosbag2 .db3."""
    try:
        con = sqlite3.connect(path)  # read-write: SQLite rolls back a crashed transaction
        try:
            names = {}
            for tid, name, msgtype, qos in con.execute(
                    'SELECT id, name, type, offered_qos_profiles FROM topics ORDER BY id'):
                names[tid] = name
                yield 'topic', name, msgtype, parse_qos(qos) if qos else [QOS_RELIABLE]
            for tid, stamp, data in con.execute(
                    'SELECT topic_id, timestamp, data FROM messages ORDER BY id'):
                yield 'message', names[tid], stamp, bytes(data)
        finally:
            con.close()
    except sqlite3.DatabaseError as exc:
        raise ValueError(f'{path}: not a readable rosbag2 SQLite file: {exc}') from None


def _scan_mcap(path: Path, skipped: list[str]) -> Iterator[tuple]:
    """('topic', name, type, qos) and ('message', topic, time, data) of every complete record
    of a rosbag2 .mcap, however it ends; what cannot be read is described in `skipped`."""
    data = memoryview(path.read_bytes())
    if bytes(data[:8]) != b'\x89MCAP0\r\n':
        raise ValueError(f'{path}: not an MCAP file (bad magic)')
    schemas: dict[int, str] = {}
    channels: dict[int, str] = {}

    def take(op: int, body: memoryview) -> Iterator[tuple]:
        f = _Fields(body)
        if op == 0x03:  # schema: id, name, encoding, data
            sid = f.int(2)  # (read before the name: an assignment evaluates its right first)
            schemas[sid] = f.bytes().decode()
        elif op == 0x04:  # channel: id, schema id, topic, message encoding, metadata
            cid, sid, topic = f.int(2), f.int(2), f.bytes().decode()
            f.bytes()
            if topic not in channels.values():
                yield 'topic', topic, schemas[sid], get_qos(f.bytes())
            channels[cid] = topic
        elif op == 0x05:  # message: channel, sequence, log time, publish time, data
            cid, _, log_time, _ = f.int(2), f.int(4), f.int(8), f.int(8)
            yield 'message', channels[cid], log_time, bytes(f.body[f.pos:])

    end = 8
    for op, body, end in _records(data, 8):
        try:
            if op == 0x06:  # chunk: start, end, size, crc, compression, records
                f = _Fields(body)
                f.int(16)
                size, crc, compression = f.int(8), f.int(4), f.bytes().decode()
                raw = decompress(f.bytes(8), compression, size, crc)
                for inner in _records(memoryview(raw), 0):
                    yield from take(*inner[:2])
            else:
                yield from take(op, body)
        except Exception as exc:  # noqa: BLE001 - zstd, CRC, decoding: the record is damaged
            skipped.append(f'record at byte {end - len(body) - 9} unreadable ({exc})')
    if end < len(data):
        skipped.append(f'the last {len(data) - end} bytes, cut short')


def _records(data: memoryview, pos: int) -> Iterator[tuple[int, memoryview, int]]:
    """(opcode, body, end offset) of each complete MCAP record from `pos` on, up to a cut."""
    while pos + 9 <= len(data):
        op, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], 'little')
        if pos + 9 + length > len(data):
            return  # the record a crash cut short
        yield op, data[pos + 9:pos + 9 + length], pos + 9 + length
        pos += 9 + length


class _Fields:
    """Little-endian fields of one MCAP record body, read in order."""

    def __init__(self, body: memoryview) -> None:
        self.body, self.pos = body, 0

    def int(self, size: int) -> int:
        return int.from_bytes(self._take(size), 'little')

    def bytes(self, size_bytes: int = 4) -> bytes:
        return bytes(self._take(self.int(size_bytes)))

    def _take(self, size: int) -> memoryview:
        if self.pos + size > len(self.body):
            raise ValueError('record shorter than its fields')
        self.pos += size
        return self.body[self.pos - size:self.pos]
