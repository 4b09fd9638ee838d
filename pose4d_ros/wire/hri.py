"""The ROS4HRI (REP 155) body messages as their serialised bytes (little-endian CDR, as
`rclpy.serialization.serialize_message` gives them), written without the message classes, as
`wire.cdr` writes ours: `ids_list_to_cdr` (hri_msgs/IdsList), `skeleton2d_to_cdr`
(hri_msgs/Skeleton2D), `roi_to_cdr` (hri_msgs/NormalizedRegionOfInterest2D). The values come
from `core.hri`; the headers are any object with `stamp.sec`, `stamp.nanosec` and `frame_id`.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.wire.cdr import CDR_LE, CDR_U32, HeaderLike, _cdr_string, _header_cdr

_ROI = struct.Struct('<5f')  # xmin, ymin, xmax, ymax, c


def ids_list_to_cdr(ids: Sequence[str], header: HeaderLike) -> bytes:
    """hri_msgs/IdsList: the header and the ids."""
    out = bytearray()
    _header_cdr(out, header)
    out += bytes(-len(out) % 4)
    out += CDR_U32.pack(len(ids))
    for text in ids:
        _cdr_string(out, text)
    return CDR_LE + bytes(out)


def skeleton2d_to_cdr(points: NDArray[np.float32], header: HeaderLike) -> bytes:
    """hri_msgs/Skeleton2D: the header and its keypoints, (K, 3) rows (x, y, c) as
    `core.hri.skeleton2d` gives them (K = 18)."""
    rows = np.ascontiguousarray(points, dtype='<f4')
    if rows.ndim != 2 or rows.shape[1] != 3:
        raise ValueError(f'keypoints of shape {rows.shape}: expected (K, 3) rows x, y, c')
    out = bytearray()
    _header_cdr(out, header)
    out += bytes(-len(out) % 4)
    out += CDR_U32.pack(len(rows))
    return b''.join((CDR_LE, out, rows.tobytes()))


def roi_to_cdr(roi: tuple[float, float, float, float, float], header: HeaderLike) -> bytes:
    """hri_msgs/NormalizedRegionOfInterest2D: the header, then xmin, ymin, xmax, ymax, c."""
    out = bytearray()
    _header_cdr(out, header)
    out += bytes(-len(out) % 4)
    out += _ROI.pack(*roi)
    return CDR_LE + bytes(out)
