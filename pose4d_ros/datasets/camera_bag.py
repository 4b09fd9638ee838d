"""Any recording of an RGB-D camera's topics, rosbag2 (mcap or sqlite3) or ROS 1 (.bag): the
frames a real camera's driver published, read by `datasets.bag.any_reader`.

Topics are picked by what they carry: the `sensor_msgs/Image` topics' first messages tell colour
(rgb8, bgr8, rgba8, bgra8, mono8) from depth (16UC1, mono16, 32FC1), and image_transport's
`sensor_msgs/CompressedImage` ones `compressed` colour from `compressedDepth`; of several, a
name with 'depth_registered' or 'aligned' is preferred for depth (registered to the colour
image, which the stages need), and 'color' or 'rgb' for colour; the `sensor_msgs/CameraInfo`
topic beside the colour image (sharing its namespace) gives the intrinsics. `color_topic`,
`depth_topic`, `info_topic` pick them by name instead. Colour and depth are paired by header
stamp, exactly or the nearest within `slop_ns` (drivers stamp the two streams apart); the
latest camera_info is used. A bag with our own topics and ground truth is read by
`datasets.cad60_bag`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pose4d_ros.core.sync import StampSync
from pose4d_ros.datasets.bag import any_reader
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.wire import (
    color_from_compressed,
    color_from_msg,
    depth_from_compressed,
    depth_from_msg,
    intrinsics_from_msg,
    is_compressed_depth,
    stamp_to_ns,
)

IMAGE = 'sensor_msgs/msg/Image'
COMPRESSED = 'sensor_msgs/msg/CompressedImage'
INFO = 'sensor_msgs/msg/CameraInfo'
COLOR_ENCODINGS = ('rgb8', 'bgr8', 'rgba8', 'bgra8', 'mono8')
DEPTH_ENCODINGS = ('16UC1', 'mono16', '32FC1')
# Colour and depth stamps at most this far apart are one frame (half a 30 fps period)
DEFAULT_SLOP_NS = 16_000_000


def _first_encoding(reader: Any, connection: Any) -> str | None:
    # an Image's encoding; a CompressedImage's codec, 'compressedDepth' or 'compressed'
    for conn, _, raw in reader.messages(connections=[connection]):
        msg = reader.deserialize(raw, conn.msgtype)
        if conn.msgtype == COMPRESSED:
            return 'compressedDepth' if is_compressed_depth(msg) else 'compressed'
        return str(msg.encoding)
    return None


def _color(msg: Any) -> Any:
    return color_from_compressed(msg) if hasattr(msg, 'format') else color_from_msg(msg)


def _depth(msg: Any) -> Any:
    return depth_from_compressed(msg) if hasattr(msg, 'format') else depth_from_msg(msg)


def _prefer(topics: list[str], words: tuple[str, ...]) -> str:
    return min(topics, key=lambda t: (not any(w in t for w in words), t))


def pick_topics(path: str | Path, *, color_topic: str | None = None,
                depth_topic: str | None = None, info_topic: str | None = None
                ) -> tuple[str, str, str]:
    """The (colour, depth, camera_info) topics of a camera recording (module docstring);
    ValueError naming the bag and what it lacks."""
    path = Path(path)
    with any_reader(path) as reader:
        by_topic = {c.topic: c for c in reader.connections}
        for flag, topic, kinds in (('color', color_topic, (IMAGE, COMPRESSED)),
                                   ('depth', depth_topic, (IMAGE, COMPRESSED)),
                                   ('info', info_topic, (INFO,))):
            if topic is not None and (topic not in by_topic
                                      or by_topic[topic].msgtype not in kinds):
                raise ValueError(f'{path}: no {" or ".join(kinds)} topic {topic!r} for '
                                 f'--{flag}-topic (has {", ".join(sorted(by_topic))})')
        encodings = {t: _first_encoding(reader, c) for t, c in by_topic.items()
                     if c.msgtype in (IMAGE, COMPRESSED) and t not in (color_topic, depth_topic)}
    colours = [t for t, e in encodings.items() if e in (*COLOR_ENCODINGS, 'compressed')]
    depths = [t for t, e in encodings.items() if e in (*DEPTH_ENCODINGS, 'compressedDepth')]
    color = color_topic or (_prefer(colours, ('color', 'rgb')) if colours else None)
    depth = depth_topic or (_prefer(depths, ('depth_registered', 'aligned')) if depths else None)
    if color is None or depth is None:
        raise ValueError(f'{path}: no {"colour" if color is None else "depth"} image topic '
                         f'(images: {encodings or "none"}); name it with --'
                         f'{"color" if color is None else "depth"}-topic')
    infos = [t for t, c in by_topic.items() if c.msgtype == INFO]
    if info_topic is None:
        space = color.rsplit('/', 1)[0]
        near = [t for t in infos if t.rsplit('/', 1)[0] == space]
        info_topic = (near or infos or [None])[0]
    if info_topic is None:
        raise ValueError(f'{path}: no sensor_msgs/CameraInfo topic (the intrinsics)')
    return color, depth, info_topic


def read_frames(path: str | Path, *, color_topic: str | None = None,
                depth_topic: str | None = None, info_topic: str | None = None,
                slop_ns: int = DEFAULT_SLOP_NS) -> Iterator[Frame]:
    """The RGB-D frames of a camera recording in stamp order, without ground truth (frames
    before the first camera_info are skipped)."""
    path = Path(path)
    color, depth, info = pick_topics(path, color_topic=color_topic, depth_topic=depth_topic,
                                     info_topic=info_topic)
    sync = StampSync(2, slop_ns=slop_ns)
    intrinsics = None
    with any_reader(path) as reader:
        wanted = [c for c in reader.connections if c.topic in (color, depth, info)]
        for conn, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == info:
                intrinsics = intrinsics_from_msg(msg)
                continue
            stamp = stamp_to_ns(msg.header.stamp)
            for pivot, (c, d) in sync.push(0 if conn.topic == color else 1, stamp, msg):
                if intrinsics is None:
                    continue
                try:
                    rgb, depth_m = _color(c), _depth(d)
                    intrinsics.check_size(rgb.shape, f'colour image on {color}')
                    intrinsics.check_size(depth_m.shape, f'depth image on {depth}')
                except ValueError as exc:
                    raise ValueError(f'{path}@{pivot}: {exc}') from exc
                yield Frame(pivot, rgb, depth_m, intrinsics, None, key=f'{path.name}/{pivot}',
                            video=path.name)
