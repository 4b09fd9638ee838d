"""The wire's numba kernels compiled (or loaded from numba's cache) before a node's first
frame: `warm_up`."""

from __future__ import annotations

import numpy as np

from pose4d_ros.core.camera import depth_to_millimetres
from pose4d_ros.wire.cdr import CdrHeader, CdrStamp, image_from_cdr, image_to_cdr
from pose4d_ros.wire.msgs import depth_from_msg


def warm_up(width: int = 64, height: int = 48) -> None:
    """Read a small depth image in each encoding a camera sends (16UC1 millimetres, 32FC1
    metres) as a subscription hands it over (`image_from_cdr`: the pixels a read-only view of
    the message's bytes, a numba signature of their own) and write it back in millimetres, as
    the foreground republishes it. Each signature is compiled the first time it is met, which
    on a fresh install was the first camera frame's: 140-220 ms of the foreground's first
    frame (`make demo`'s latency tail), the detector's, tracker's and IK's loading it again."""
    header = CdrHeader(CdrStamp(0, 0), 'warm_up')
    metres = np.full((height, width), 2.5, np.float32)
    millimetres = depth_to_millimetres(metres)
    for img, encoding in ((millimetres, '16UC1'), (metres, '32FC1')):
        depth = depth_from_msg(image_from_cdr(image_to_cdr(img, encoding, header)))
    depth_to_millimetres(depth)
