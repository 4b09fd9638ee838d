"""rosbag2 files (mcap or sqlite3) read and written with the pure-Python rosbags library.

The only module of the project that imports rosbags. Bags are standard rosbag2 directories,
readable by `ros2 bag`, `rosbags` and `mcap`. The typestore knows ROS 2 Jazzy's messages plus
pose4d_msgs, registered from the package's own .msg files, so the bags carry the full message
definitions and are self-describing.

Writing is atomic: a bag is built in a hidden temporary directory beside its destination and
renamed into place when closed, so a crash never leaves a half-written bag under the final name.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
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
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pose4d_ros.core.joints import JointSet

MSG_PACKAGE = 'pose4d_msgs'
MSG_NAMES = ('Joint', 'JointArray')

_INFINITE = QosTime(0x7FFFFFFF, 0xFFFFFFFF)


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
        self._staging = self.path.parent / f'.{self.path.name}.partial-{os.getpid()}'
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
        raise ValueError(f'{path}: not a rosbag2 directory (no metadata.yaml)')
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError family
        raise ValueError(f'{path}: cannot read bag: {exc}') from exc
    return reader


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
        for connection, timestamp, data in reader.messages(connections=connections,
                                                           start=start_ns):
            yield BagMessage(connection.topic, connection.msgtype, timestamp, bytes(data))
    finally:
        reader.close()


def deserialize(message: BagMessage) -> Any:
    """Decode a message's CDR bytes into a rosbags message object."""
    return typestore().deserialize_cdr(message.data, message.msgtype)


def joint_set(msg: Any) -> JointSet:
    """A `pose4d_msgs/JointArray` read from a bag (rosbags object) as a core JointSet."""
    js = msg.joints
    n = len(js)
    return JointSet(
        tuple(j.name for j in js),
        np.array([[j.u, j.v] for j in js], np.float64).reshape(n, 2),
        np.array([[j.position.x, j.position.y, j.position.z] for j in js],
                 np.float64).reshape(n, 3),
        confidence=np.array([j.confidence for j in js], np.float32),
        source=np.array([j.source for j in js], np.uint8),
        covariance=np.array([np.asarray(j.position_covariance, np.float64) for j in js]
                            ).reshape(n, 3, 3),
        score=float(msg.score), track_id=int(msg.track_id))


def stamp_ns(msg: Any) -> int:
    """Header stamp of a message read from a bag, nanoseconds."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
