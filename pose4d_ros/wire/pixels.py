"""The pixel buffer of a `sensor_msgs/Image`, both ways: its encodings (`ENCODINGS`), the buffer
as an array (`decode`: row stride and endianness honoured) and an array as the packed pixels of
an encoding (`as_encoding`, what `cdr.image_to_cdr` and `nodes.convert.array_to_image` write).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

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


def as_encoding(img: NDArray, encoding: str) -> tuple[NDArray, int]:
    """`img` as the C-contiguous pixels of `encoding` (native byte order), and its channels;
    ValueError when it cannot be."""
    if encoding not in ENCODINGS:
        raise ValueError(f'unsupported image encoding {encoding!r}')
    kind, channels = ENCODINGS[encoding]
    img = np.ascontiguousarray(img, dtype=np.dtype(kind))
    if img.ndim != (3 if channels > 1 else 2) or (channels > 1 and img.shape[2] != channels):
        raise ValueError(f'array of shape {img.shape} does not fit encoding {encoding}')
    return img, channels
