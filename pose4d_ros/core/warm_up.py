"""A synthetic RGB-D frame every stage runs once at start-up, so that numba's compilation is
not paid by the first camera frame."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics


def warm_up_frame(intrinsics: Intrinsics) -> tuple[NDArray[np.uint8], NDArray[np.float32],
                                                   NDArray[np.bool_]]:
    """A simple synthetic RGB-D frame to run a stage once before real frames come.

    The numba kernels compile (or load their cache) on their first call, which takes seconds;
    a node runs its stage on this frame at start-up so that the first camera frame is not the
    one that pays for it. A camera 1.1 m above a floor, a wall at 4.3 m and a textured 1.75 m
    "person" of slabs (head, torso, arms, legs) at 2.8 m, with Kinect-like depth noise, so that
    the foreground finds a person and every stage takes its usual path.

    Returns
    -------
    color : (H, W, 3) uint8; depth_m : (H, W) float32 metres; mask : (H, W) bool (the person).
    """
    h, w = intrinsics.height, intrinsics.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    ray_x = (u - intrinsics.cx) / intrinsics.fx
    ray_y = (v - intrinsics.cy) / intrinsics.fy
    depth = np.full((h, w), 4.3, np.float32)
    floor = np.where(ray_y > 0, 1.1 / np.maximum(ray_y, 1e-6), np.inf)
    depth = np.minimum(depth, floor).astype(np.float32)
    x, y = ray_x * 2.8, ray_y * 2.8  # where a ray meets the person's plane (y down from the eye)
    ax, top = np.abs(x), 1.1 - 1.75
    mask = ((ax < 0.2) & (y > top + 0.25) & (y < 0.25)                  # torso
            | (ax < 0.1) & (y >= top) & (y < top + 0.27)                # head and neck
            | (ax > 0.2) & (ax < 0.3) & (y > top + 0.28) & (y < 0.2)    # arms
            | (ax > 0.04) & (ax < 0.18) & (y >= 0.25) & (y < 1.1))      # legs
    depth[mask] = 2.8
    rng = np.random.default_rng(0)
    depth = (depth + rng.normal(0.0, 0.0015, depth.shape) * depth ** 2).astype(np.float32)
    depth[rng.random(depth.shape) < 0.02] = np.nan
    color = np.clip(80 + 60 * np.sin(u / 9)[..., None] + rng.normal(0, 8, (h, w, 3)), 0, 255)
    color[mask] = np.clip(160 + 50 * np.cos(v[mask] / 5)[:, None]
                          + rng.normal(0, 8, (int(mask.sum()), 3)), 0, 255)
    return color.astype(np.uint8), depth, mask
