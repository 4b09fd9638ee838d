"""Message objects as arrays, read from their fields: the one reader of the message objects.

Live messages (rclpy's, in the nodes) and recorded ones (rosbags', in the bag readers) carry
the same fields, so this module reads both without importing either (duck-typed):

- `sensor_msgs/Image` -> numpy (`image_to_array`, through `pixels.decode`: row stride and
  endianness honoured); colour as RGB uint8 (`color_from_msg`); depth per REP-118
  (`depth_from_msg`): `16UC1`/`mono16` millimetres or `32FC1` metres, 0/NaN = no reading,
  returned in the core's convention (float32 metres, NaN = no reading);
- `sensor_msgs/CompressedImage` (image_transport's `compressed` and `compressedDepth`, as
  robots record their cameras) -> the same arrays (`color_from_compressed`,
  `depth_from_compressed`);
- `sensor_msgs/CameraInfo` -> `core.camera.Intrinsics`;
- `pose4d_msgs/JointArray` -> `core.joints.JointSet`; `pose4d_msgs/SkeletonArray` -> a tuple
  of them (their serialised bytes, without a message object per joint: `cdr`);
- `builtin_interfaces/Time` -> integer nanoseconds.

Messages are built from arrays in `nodes/convert.py` (rclpy objects), `cdr` (their bytes) and
`datasets/cad60_bag.py` (rosbags objects).
"""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, depth_to_metres
from pose4d_ros.core.joints import JointSet
from pose4d_ros.wire.pixels import decode


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
