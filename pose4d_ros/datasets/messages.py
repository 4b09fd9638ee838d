"""Messages as arrays, read from their fields: the one reader of the project's messages.

Live messages (rclpy, through `nodes/convert.py`) and recorded ones (rosbags objects, through the
bag readers) carry the same fields, so this module reads both without importing either:

- `sensor_msgs/Image` -> numpy (`decode`): row stride (`step`) and endianness honoured; colour
  as RGB uint8; depth per REP-118: `16UC1`/`mono16` millimetres or `32FC1` metres, 0/NaN = no
  reading, returned in the core's convention (float32 metres, NaN = no reading);
- `sensor_msgs/CompressedImage` (image_transport's `compressed` and `compressedDepth`, as
  robots record their cameras) -> the same arrays (`color_from_compressed`,
  `depth_from_compressed`);
- `sensor_msgs/CameraInfo` -> `core.camera.Intrinsics`;
- `pose4d_msgs/JointArray` -> `core.joints.JointSet`; `pose4d_msgs/SkeletonArray` -> a tuple
  of them; both also straight from their serialised bytes (`cdr_header`, `skeletons_from_cdr`,
  `joints_from_cdr`: little-endian CDR, as Fast DDS and `nodes.convert.skeletons_to_cdr` write
  it), without a message object per joint;
- `builtin_interfaces/Time` -> integer nanoseconds.

Messages are built from arrays in `nodes/convert.py` (rclpy) and `cad60_bag.py` (rosbags).
"""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, depth_to_metres
from pose4d_ros.core.joints import MISSING, JointSet

# encoding -> (dtype, channels)
ENCODINGS: dict[str, tuple[str, int]] = {
    'rgb8': ('u1', 3), 'bgr8': ('u1', 3), 'rgba8': ('u1', 4), 'bgra8': ('u1', 4),
    'mono8': ('u1', 1), '8UC1': ('u1', 1), '8UC3': ('u1', 3),
    'mono16': ('u2', 1), '16UC1': ('u2', 1), '32FC1': ('f4', 1),
}


def decode(data: object, height: int, width: int, step: int, encoding: str,
           bigendian: bool) -> NDArray:
    """(H, W) or (H, W, C) array (native byte order, a copy) of an image's pixel buffer.

    Raises ValueError naming the encoding, the size or the stride that is wrong.
    """
    if encoding not in ENCODINGS:
        raise ValueError(f'unsupported image encoding {encoding!r} '
                         f'(supported: {", ".join(ENCODINGS)})')
    kind, channels = ENCODINGS[encoding]
    dtype = np.dtype(kind).newbyteorder('>' if bigendian else '<')
    h, w, step = int(height), int(width), int(step)
    row = w * channels * dtype.itemsize
    if h == 0 or w == 0:
        raise ValueError(f'empty image ({w}x{h})')
    if step < row:
        raise ValueError(f'image step {step} is smaller than a row ({row} bytes, {w}x{channels} '
                         f'{encoding})')
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size < step * h:
        raise ValueError(f'image data has {buf.size} bytes, expected {step * h} '
                         f'({h} rows of {step})')
    rows = buf[: step * h].reshape(h, step)[:, :row]
    out = np.ascontiguousarray(rows).view(dtype)
    out = out.reshape((h, w, channels) if channels > 1 else (h, w))
    return out if dtype.isnative else out.astype(dtype.newbyteorder('='))


def stamp_to_ns(stamp: Any) -> int:
    """A `builtin_interfaces/Time` as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def image_to_array(msg: Any) -> NDArray:
    """Pixels of an Image as a (H, W) or (H, W, C) array (a copy), in the message's encoding.

    Raises ValueError naming the encoding or size that is wrong.
    """
    return decode(msg.data, msg.height, msg.width, msg.step, msg.encoding, msg.is_bigendian)


def color_from_msg(msg: Any) -> NDArray[np.uint8]:
    """Colour image as (H, W, 3) uint8 RGB."""
    img = image_to_array(msg)
    enc = msg.encoding
    if enc in ('rgb8', '8UC3'):
        return img
    if enc == 'bgr8':
        return np.ascontiguousarray(img[..., ::-1])
    if enc == 'rgba8':
        return np.ascontiguousarray(img[..., :3])
    if enc == 'bgra8':
        return np.ascontiguousarray(img[..., 2::-1])
    if enc in ('mono8', '8UC1'):
        return np.repeat(img[..., None], 3, axis=2)
    raise ValueError(f'colour image has a depth encoding {enc!r}')


# compressed_depth_image_transport's header before the PNG: the format (int32: 0 = inverse
# depth, 1 = as is) and the two quantisation parameters of inverse depth (float32 a, b)
COMPRESSED_DEPTH_HEADER = struct.Struct('<iff')


def is_compressed_depth(msg: Any) -> bool:
    """Whether a CompressedImage is image_transport's `compressedDepth` (its format says so)."""
    return 'compresseddepth' in str(msg.format).lower()


def _imdecode(data: Any, flags: int, what: str) -> NDArray:
    img = cv2.imdecode(np.frombuffer(bytes(data), np.uint8), flags)
    if img is None:
        raise ValueError(f'{what}: its bytes do not decode as an image')
    return img


def color_from_compressed(msg: Any) -> NDArray[np.uint8]:
    """A `compressed` CompressedImage (JPEG or PNG; format 'bgr8; jpeg compressed bgr8',
    'rgb8; jpeg compressed bgr8' or plain 'jpeg') as (H, W, 3) uint8 RGB: the codec holds
    BGR whatever the raw image's encoding was."""
    if is_compressed_depth(msg):
        raise ValueError(f'colour image is a compressedDepth image ({msg.format!r})')
    img = _imdecode(msg.data, cv2.IMREAD_COLOR, f'compressed image ({msg.format!r})')
    return np.ascontiguousarray(img[:, :, ::-1])


def depth_from_compressed(msg: Any) -> NDArray[np.float32]:
    """A `compressedDepth` CompressedImage ('16UC1; compressedDepth png': millimetres;
    '32FC1; compressedDepth png': metres quantised as inverse depth, a / (v - b)) as (H, W)
    float32 metres, NaN = no reading."""
    fmt = str(msg.format)
    if not is_compressed_depth(msg):
        raise ValueError(f'depth image must be compressedDepth, got format {fmt!r}')
    data = bytes(msg.data)
    if len(data) <= COMPRESSED_DEPTH_HEADER.size:
        raise ValueError(f'compressedDepth image of {len(data)} bytes holds no image')
    kind, a, b = COMPRESSED_DEPTH_HEADER.unpack_from(data)
    img = _imdecode(data[COMPRESSED_DEPTH_HEADER.size:], cv2.IMREAD_UNCHANGED,
                    f'compressedDepth image ({fmt!r})')
    if img.dtype != np.uint16 or img.ndim != 2:
        raise ValueError(f'compressedDepth image ({fmt!r}) must hold 16-bit single-channel '
                         f'pixels, got {img.dtype} {img.shape}')
    if fmt.split(';')[0].strip().upper() == '32FC1':
        if kind != 0:
            raise ValueError(f'32FC1 compressedDepth must be inverse depth (0), got {kind}')
        v = img.astype(np.float32)
        with np.errstate(divide='ignore'):
            depth = np.where(img > 0, np.float32(a) / (v - np.float32(b)), np.float32(np.nan))
        return depth_to_metres(depth.astype(np.float32))
    return depth_to_metres(img)


def depth_from_msg(msg: Any) -> NDArray[np.float32]:
    """Depth image as (H, W) float32 metres, NaN = no reading (16UC1/mono16 mm or 32FC1 m)."""
    if msg.encoding not in ('16UC1', 'mono16', '32FC1'):
        raise ValueError(f'depth image encoding must be 16UC1 (mm) or 32FC1 (m), '
                         f'got {msg.encoding!r}')
    return depth_to_metres(image_to_array(msg))


def intrinsics_from_msg(msg: Any) -> Intrinsics:
    """Pinhole intrinsics from CameraInfo's K (ROS 2 `k`, ROS 1 `K`; rectified images
    assumed)."""
    k = msg.k if hasattr(msg, 'k') else msg.K
    if k[0] <= 0 or k[4] <= 0:
        raise ValueError(f'camera_info K has non-positive focal length (fx={k[0]}, fy={k[4]}); '
                         'is the camera calibrated?')
    return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(msg.width),
                      int(msg.height))


def joints_from_msg(msg: Any) -> JointSet:
    """A `pose4d_msgs/JointArray` as a JointSet."""
    js = msg.joints
    n = len(js)
    uv = np.array([[j.u, j.v] for j in js], dtype=np.float64).reshape(n, 2)
    xyz = np.array([[j.position.x, j.position.y, j.position.z] for j in js],
                   dtype=np.float64).reshape(n, 3)
    cov = np.array([np.asarray(j.position_covariance, dtype=np.float64) for j in js]
                   ).reshape(n, 3, 3)
    return JointSet(tuple(j.name for j in js), uv, xyz,
                    confidence=np.array([j.confidence for j in js], dtype=np.float32),
                    source=np.array([j.source for j in js], dtype=np.uint8), covariance=cov,
                    score=float(msg.score), track_id=int(msg.track_id))


def skeletons_from_msg(msg: Any) -> tuple[JointSet, ...]:
    """A `pose4d_msgs/SkeletonArray` as JointSets, in the message's order."""
    return tuple(joints_from_msg(m) for m in msg.skeletons)


# --------------------------------------------------------------------------- serialised (CDR)

# The layout the readers below and `nodes.convert`'s writers share
CDR_LE = b'\x00\x01\x00\x00'  # encapsulation: plain CDR, little-endian
CDR_U32 = struct.Struct('<I')     # a sequence's or string's length
CDR_TIME = struct.Struct('<iI')   # builtin_interfaces/Time
CDR_TRACK = struct.Struct('<If')  # JointArray's track_id, score
# a Joint after its name, from an 8-byte boundary: u, v, position x, y, z, confidence, source,
# 3 bytes to the covariance's 8-byte boundary, position_covariance
_JOINT = np.dtype([('uv', '<f8', 2), ('xyz', '<f8', 3), ('confidence', '<f4'), ('source', 'u1'),
                   ('pad', 'V3'), ('covariance', '<f8', 9)])
_SPAN = np.arange(_JOINT.itemsize)
_JOINT_MIN = 4 + 1 + _JOINT.itemsize  # the fewest bytes a joint takes (a name of no characters)


def _string(buf: memoryview, at: int) -> tuple[str, int]:
    """The CDR string at payload offset `at` (aligned to 4 first) and the offset after it."""
    at += -at % 4
    (n,) = CDR_U32.unpack_from(buf, at)
    end = at + 4 + n
    if n < 1 or end > len(buf) or buf[end - 1] != 0:
        raise ValueError(f'bad string at byte {at}: length {n}, {len(buf)} bytes in all')
    return str(buf[at + 4:end - 1], 'utf-8'), end


def cdr_header(data: bytes) -> tuple[int, int, str, int]:
    """A serialised message that starts with a `std_msgs/Header` (little-endian CDR): its
    stamp's (sec, nanosec), frame_id, and the payload offset after it. ValueError for bytes
    that are not such a message (other encapsulations included: the caller deserialises those
    the general way)."""
    if len(data) < 16 or data[:4] != CDR_LE:
        raise ValueError(f'{len(data)} bytes that are not little-endian CDR')
    buf = memoryview(data)[4:]
    sec, nanosec = CDR_TIME.unpack_from(buf, 0)
    frame_id, at = _string(buf, 8)
    return sec, nanosec, frame_id, at


def _joints_at(buf: memoryview, at: int) -> tuple[JointSet, int]:
    """The JointArray at payload offset `at` (its header first) and the offset after it."""
    _, at = _string(buf, at + (-at % 4) + 8)  # header: stamp, frame_id
    at += -at % 4
    track_id, score = CDR_TRACK.unpack_from(buf, at)
    (n,) = CDR_U32.unpack_from(buf, at + 8)
    at += 12
    if n * _JOINT_MIN > len(buf) - at:
        raise ValueError(f'{n} joints announced, {len(buf) - at} bytes left')
    names, starts = [], []
    for _ in range(n):
        name, at = _string(buf, at)
        at += -at % 8
        names.append(name)
        starts.append(at)
        at += _JOINT.itemsize
    if at > len(buf):
        raise ValueError(f'{n} joints need {at} bytes, {len(buf)} in all')
    # every joint's fields in one gather (names end where they end: the offsets vary)
    rows = np.array(starts, np.intp)[:, None] + _SPAN
    v = np.frombuffer(buf, np.uint8)[rows].view(_JOINT).reshape(n)
    source = v['source'].copy()  # each field contiguous, as the stages' arrays are
    if n and source.max() > MISSING:
        raise ValueError(f'unknown joint source code(s) {sorted(set(source[source > MISSING]))}')
    return JointSet.of_arrays(tuple(names), v['uv'].copy(), v['xyz'].copy(),
                              v['confidence'].copy(), source,
                              v['covariance'].reshape(n, 3, 3).copy(),
                              score=score, track_id=track_id), at


def _read(data: bytes, what: str, read: Any) -> Any:
    if data[:4] != CDR_LE:
        raise ValueError(f'{what}: {len(data)} bytes that are not little-endian CDR')
    try:
        return read(memoryview(data)[4:])
    except struct.error as exc:
        raise ValueError(f'{what}: {len(data)} bytes end too soon ({exc})') from None


def skeletons_from_cdr(data: bytes, at: int) -> tuple[JointSet, ...]:
    """The people of a serialised `pose4d_msgs/SkeletonArray` (little-endian CDR), read from
    payload offset `at` (after its header, `cdr_header`), as `skeletons_from_msg` gives them.
    ValueError for bytes that do not hold one."""
    def read(buf: memoryview) -> tuple[JointSet, ...]:
        start = at + (-at % 4)
        (n,) = CDR_U32.unpack_from(buf, start)
        if n * 20 > len(buf) - start:
            raise ValueError(f'{n} skeletons announced, {len(buf) - start} bytes left')
        people, where = [], start + 4
        for _ in range(n):
            joints, where = _joints_at(buf, where)
            people.append(joints)
        return tuple(people)
    return _read(data, 'SkeletonArray', read)


def joints_from_cdr(data: bytes) -> JointSet:
    """A serialised `pose4d_msgs/JointArray` (little-endian CDR) as `joints_from_msg` gives it.
    ValueError for bytes that do not hold one."""
    return _read(data, 'JointArray', lambda buf: _joints_at(buf, 0)[0])
