"""The floor plane (step 1 of `segment`): RANSAC on the 3-D points of the lower part of the
image, planes through three points whose normal is within `floor_max_tilt_deg` of the optical
"up" (-y) and that pass `floor_min_height_m`-`floor_max_height_m` below the camera; the plane
with most inliers (tolerance growing with z^2, as Kinect noise does) is refined by weighted
least squares."""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit
from numpy.linalg import _umath_linalg
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.foreground.config import FloorConfig

DEFAULT = FloorConfig()  # the defaults, one instance (frozen)
# how far below a plane a point must lie to count as below it (besides the inlier tolerance)
FLOOR_BELOW_M = 0.1
# reductions without their Python wrappers (the per-frame path)
_sum, _any, _all = np.add.reduce, np.logical_or.reduce, np.logical_and.reduce
# np.linalg.eigh's LAPACK call (lower triangle), without its wrapper's checks and casts
_eigh_lo = _umath_linalg.eigh_lo


_RAYS: dict[Intrinsics, tuple[NDArray[np.float32], NDArray[np.float32]]] = {}


def _rays(intrinsics: Intrinsics) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Per-column (u - cx) / fx (1, W) and per-row (v - cy) / fy (H, 1), float32."""
    rays = _RAYS.get(intrinsics)
    if rays is None:
        rx = ((np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx)
        ry = ((np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy)
        rays = (rx.astype(np.float32)[None, :], ry.astype(np.float32)[:, None])
        if len(_RAYS) > 16:
            _RAYS.clear()
        _RAYS[intrinsics] = rays
    return rays


@functools.lru_cache(maxsize=64)
def _ransac_draws(seed: int, n_pts: int, iterations: int) -> NDArray[np.int64]:
    """The RANSAC sample: (iterations, 3) point indices (read-only), a function of its
    arguments, drawn once (seeding a generator costs more than the fit's arithmetic)."""
    idx = np.random.default_rng(seed).integers(0, n_pts, size=(iterations, 3))
    idx.setflags(write=False)
    return idx


def fit_floor(depth_m: NDArray[np.floating], intrinsics: Intrinsics, *,
              config: FloorConfig = DEFAULT,
              previous: NDArray[np.floating] | None = None) -> NDArray[np.float64] | None:
    """RANSAC fit of the floor plane in the lower part of a depth image.

    Parameters
    ----------
    depth_m : (H, W) float32 metres, NaN = no reading.
    intrinsics : the camera, of the same size.
    config : uses the `floor_*` fields and `seed`.
    previous : (4,) plane from an earlier frame, tried as one more hypothesis.

    Returns
    -------
    (4,) float64 plane (nx, ny, nz, d), optical frame, unit normal pointing up (ny < 0), so that
    ``n . p + d`` is the height above the floor in metres; None when no plane has
    `floor_min_inliers` inliers.
    """
    h, w = depth_m.shape
    step = config.floor_sample_step
    r0 = int(h * (1.0 - config.floor_rows_fraction))
    sub = depth_m[r0::step, ::step]
    rx, ry = _rays(intrinsics)
    ok = np.isfinite(sub)
    # numpy's Python-level wrappers (np.stack, np.einsum, np.where, np.linalg.eigh, ...) are
    # written out here as the operations they call: the same arithmetic in the same order,
    # a fraction of the interpreter's work per frame
    rr, cc = ok.nonzero()
    n_pts = len(rr)
    if n_pts < config.floor_min_inliers or n_pts < 3:
        return None
    z = sub[ok].astype(np.float64)
    pts = np.empty((n_pts, 3))
    pts[:, 0] = rx[0, cc * step] * z
    pts[:, 1] = ry[r0 + rr * step, 0] * z
    pts[:, 2] = z
    # Kinect v1 depth error grows with z^2 (disparity quantisation)
    tol = config.floor_inlier_m * np.maximum(z, 1.0) ** 2

    idx = _ransac_draws(config.seed, n_pts, config.floor_iterations)
    p0, p1, p2 = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    normal = _cross(p1 - p0, p2 - p0)
    norm = np.sqrt(_sum(normal * normal, axis=1))
    good = norm > 1e-9
    normal = normal[good] / norm[good, None]
    p0 = p0[good]
    normal[normal[:, 1] > 0] *= -1.0  # point up (optical -y)
    d = -_sum(normal * p0, axis=1)
    if previous is not None:
        prev = np.asarray(previous, dtype=np.float64).reshape(4)
        if _all(np.isfinite(prev)):
            normal = np.concatenate((normal, prev[None, :3]))
            d = np.concatenate((d, prev[3:]))
    cos_tilt = math.cos(config.floor_max_tilt_deg * (math.pi / 180.0))  # math.radians's
    plausible = ((-normal[:, 1] >= cos_tilt) & (d >= config.floor_min_height_m)
                 & (d <= config.floor_max_height_m))
    if not _any(plausible):
        return None
    normal, d = normal[plausible], d[plausible]
    counts = _support(pts @ normal.T, d, tol, config.floor_max_below)
    best = int(counts.argmax())
    if counts[best] < config.floor_min_inliers:
        return None
    plane = np.empty(4)
    plane[:3], plane[3] = normal[best], d[best]
    for _ in range(2):  # least-squares refinement on the inliers
        inl = np.abs(pts @ plane[:3] + plane[3]) < tol
        if _sum(inl, dtype=np.intp) < 3:
            break
        # weighted total least squares, weights 1 / sigma^2 with sigma ~ z^2
        q = pts[inl]
        wt = 1.0 / np.maximum(q[:, 2], 1.0) ** 4
        c = (wt @ q) / _sum(wt)
        qc = q - c
        # the normal: the weighted scatter's eigenvector of the smallest eigenvalue (the
        # LAPACK routine np.linalg.eigh calls, without its checks: NaN if it fails)
        _, vecs = _eigh_lo((qc * wt[:, None]).T @ qc, signature='d->dd')
        n = vecs[:, 0] * (-1.0 if vecs[1, 0] > 0 else 1.0)
        if not -n[1] >= cos_tilt:  # NaN too
            break
        plane = np.empty(4)
        plane[:3], plane[3] = n, -float(n @ c)
    return plane


@njit(cache=True)
def _support(products: NDArray[np.float64], d: NDArray[np.float64], tol: NDArray[np.float64],
             max_below: float) -> NDArray[np.intp]:
    """Each plane's inliers: the points within `tol` of it, where `products` (N points x M
    planes) are the points' dot products with the planes' normals and `d` the planes' offsets.
    A floor has nothing below it: a table top or a seat (a horizontal plane above the floor,
    often with more points on it in the lower image than the floor shows) has the floor and
    the legs below it, so a plane with more than `max_below` (> 0) times its inliers below it
    (by over the tolerance and `FLOOR_BELOW_M`) counts none. One pass over the products,
    where the array expressions it replaces made five N x M arrays a frame."""
    n, m = products.shape
    counts = np.zeros(m, np.intp)
    below = np.zeros(m, np.intp)
    for i in range(n):
        t = tol[i]
        under = -max(t, FLOOR_BELOW_M)
        for j in range(m):
            s = products[i, j] + d[j]
            if abs(s) < t:
                counts[j] += 1
            if s < under:
                below[j] += 1
    if max_below > 0:
        for j in range(m):
            if below[j] > max_below * counts[j]:
                counts[j] = 0
    return counts


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """np.cross of (N, 3) rows: the same products and differences, without its wrapper."""
    out = np.empty(a.shape)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def floor_height(depth_m: NDArray[np.floating], intrinsics: Intrinsics,
                 plane: NDArray[np.floating]) -> NDArray[np.float32]:
    """Height of every pixel's 3-D point above a plane.

    Parameters
    ----------
    depth_m : (H, W) float32 metres, NaN = no reading.
    intrinsics : the camera.
    plane : (4,) (nx, ny, nz, d) as returned by `fit_floor`.

    Returns
    -------
    (H, W) float32 metres; NaN where the depth is NaN.
    """
    if depth_m.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f'depth image of shape {depth_m.shape} but the intrinsics are '
                         f'{intrinsics.width}x{intrinsics.height}')
    rx, ry = _rays(intrinsics)
    n = np.asarray(plane, dtype=np.float32)
    out = np.empty(depth_m.shape, np.result_type(depth_m.dtype, np.float32))
    _height(depth_m, rx[0], ry[:, 0], n, out)
    return out


@njit(cache=True)
def _height(depth_m: NDArray[np.floating], rx: NDArray[np.float32], ry: NDArray[np.float32],
            n: NDArray[np.float32], out: NDArray[np.floating]) -> None:
    """`floor_height` in one pass (numpy's took five), the same float32 operations in the same
    order: z (n . ray) + d, n . ray = n_x rx + n_y ry + n_z."""
    h, w = depth_m.shape
    for r in range(h):
        for c in range(w):
            along = n[0] * rx[c] + n[1] * ry[r] + n[2]
            out[r, c] = depth_m[r, c] * along + n[3]
