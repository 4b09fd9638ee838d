"""Pinhole camera model, depth units and robust depth look-up.

Frames: 3-D points are in the camera optical frame (x right, y down, z forward, metres), as in
`sensor_msgs/CameraInfo`. Pixel (u, v) is column, row, with (0, 0) the centre of the top-left
pixel. Depth images inside `core` are float32 metres with NaN where there is no reading; use
`depth_to_metres` at the boundary (REP-118: `16UC1` millimetres or `32FC1` metres, 0 or NaN =
no reading; a reading beyond `MAX_DEPTH_M` is no reading too).

Everything that enters a node is checked against physical sense here and in `core.joints`:
`Intrinsics` refuses a camera no lens makes (non-finite values, a field of view outside
`FOV_RANGE_DEG`, the principal point off the image), so that no later stage can be asked for a
pyramid of absurd size or a position of 1e300 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

# CAD-60 / OpenNI constants at 320x240 (the dataset's README; focal lengths double at 640x480).
CAD60_FX = 285.171
CAD60_FY = 285.117
CAD60_CX = 160.0
CAD60_CY = 120.0

# The farthest reading of the RGB-D cameras we serve (Kinect v1/v2, RealSense, Azure: <= 10 m),
# with a margin; 16UC1's 65535 mm and a 32FC1 1e30 are not distances.
MAX_DEPTH_M = 20.0
# Fields of view a camera lens gives (Kinect v1: 58 x 45 degrees).
FOV_RANGE_DEG = (10.0, 170.0)
# Largest image side: 4K cameras and below.
MAX_IMAGE_SIDE_PX = 8192


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an undistorted image (pixels)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        """Refuse intrinsics no camera has (ValueError naming the value and the rule)."""
        if not all(math.isfinite(v) for v in (self.fx, self.fy, self.cx, self.cy)):
            raise ValueError(f'intrinsics must be finite, got fx={self.fx}, fy={self.fy}, '
                             f'cx={self.cx}, cy={self.cy}')
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f'focal lengths must be positive, got fx={self.fx}, fy={self.fy}')
        if not (0 < self.width <= MAX_IMAGE_SIDE_PX and 0 < self.height <= MAX_IMAGE_SIDE_PX):
            raise ValueError(f'image size must be 1..{MAX_IMAGE_SIDE_PX} px a side, got '
                             f'{self.width}x{self.height}')
        lo, hi = FOV_RANGE_DEG
        for name, f, side in (('fx', self.fx, self.width), ('fy', self.fy, self.height)):
            fov = math.degrees(2 * math.atan(side / (2 * f)))
            if not lo <= fov <= hi:
                raise ValueError(f'{name}={f:.4g} px at {side} px gives a field of view of '
                                 f'{fov:.1f} degrees, outside {lo:g}..{hi:g}')
        if not (0 <= self.cx <= self.width and 0 <= self.cy <= self.height):
            raise ValueError(f'principal point ({self.cx:.4g}, {self.cy:.4g}) is off the '
                             f'{self.width}x{self.height} image')

    def check_size(self, shape: tuple[int, ...], what: str = 'image') -> None:
        """ValueError unless an image of `shape` (H, W, ...) is the size these intrinsics are
        calibrated for (a camera_info of another resolution would misplace every point)."""
        if tuple(shape[:2]) != (self.height, self.width):
            raise ValueError(f'camera_info is for {self.width}x{self.height} but the {what} is '
                             f'{shape[1]}x{shape[0]}')

    @property
    def k(self) -> NDArray[np.float64]:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera at another resolution."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)


def cad60_intrinsics(width: int = 320, height: int = 240) -> Intrinsics:
    """The OpenNI perspective model used by CAD-60, at `width` x `height`.

    Focal lengths scale with the height (the vertical field of view is the sensor's) and the
    principal point is the image centre: 640x480 is 320x240 with doubled focal lengths, and a
    wider image (848x480) sees more on the sides with the same square pixels, as cameras that
    offer both sizes do.
    """
    s = height / 240.0
    return Intrinsics(CAD60_FX * s, CAD60_FY * s, CAD60_CX * width / 320.0,
                      CAD60_CY * s, width, height)


def project(points: NDArray[np.floating], intrinsics: Intrinsics) -> NDArray[np.float64]:
    """Project 3-D points to pixels.

    Parameters
    ----------
    points : (N, 3) float, metres, optical frame.
    intrinsics : the camera.

    Returns
    -------
    (N, 2) float64 pixel (u, v); NaN for points that are NaN or not in front of the camera.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = p[:, 2]
    with np.errstate(invalid='ignore', divide='ignore'):
        front = z > 0
        u = np.where(front, intrinsics.cx + intrinsics.fx * p[:, 0] / z, np.nan)
        v = np.where(front, intrinsics.cy + intrinsics.fy * p[:, 1] / z, np.nan)
    return np.stack([u, v], axis=1)


def backproject(uv: NDArray[np.floating], depth_m: NDArray[np.floating],
                intrinsics: Intrinsics) -> NDArray[np.float64]:
    """Lift pixels with depth to 3-D points.

    Parameters
    ----------
    uv : (N, 2) float pixel (u, v).
    depth_m : (N,) float, metres along the optical axis (z); NaN or <= 0 = unknown.
    intrinsics : the camera.

    Returns
    -------
    (N, 3) float64 metres, optical frame; NaN rows where the depth is unknown.
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(depth_m, dtype=np.float64).reshape(-1)
    if len(z) != len(uv):
        raise ValueError(f'{len(uv)} pixels but {len(z)} depths')
    out = np.empty((len(z), 3))  # np.stack's result, without its Python wrapper
    out[:, 2] = z
    z = out[:, 2]
    z[~(z > 0)] = np.nan  # np.where(z > 0, z, np.nan)'s, in place
    out[:, 0] = (uv[:, 0] - intrinsics.cx) * z / intrinsics.fx
    out[:, 1] = (uv[:, 1] - intrinsics.cy) * z / intrinsics.fy
    return out


def depth_to_metres(depth: NDArray) -> NDArray[np.float32]:
    """Convert a depth image to float32 metres with NaN for no reading.

    Parameters
    ----------
    depth : (H, W) uint16 millimetres (0 = no reading), or float32/float64 metres (0 or NaN =
        no reading), as REP-118's `16UC1` and `32FC1`. Readings beyond `MAX_DEPTH_M` (REP-117's
        +inf = too far, 65535 mm, 1e30) and negative ones are no reading either.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f'depth image must be 2-D, got shape {depth.shape}')
    if depth.dtype == np.uint16:
        scale = np.float32(0.001)
    elif depth.dtype in (np.float32, np.float64):
        scale = np.float32(1.0)
    else:
        raise ValueError(f'depth must be uint16 millimetres or float metres, '
                         f'got dtype {depth.dtype}')
    out = np.empty(depth.shape, np.float32)
    _metres(depth, scale, np.float32(MAX_DEPTH_M), out)
    return out


@njit(cache=True)
def _metres(depth: NDArray, scale: np.float32, far: np.float32,
            out: NDArray[np.float32]) -> None:
    """`depth_to_metres` in one pass (numpy's took five): each pixel in float32 (1e300 in
    float64 is inf), times `scale`, NaN unless in (0, far]."""
    h, w = depth.shape
    for r in range(h):
        for c in range(w):
            z = np.float32(depth[r, c]) * scale
            out[r, c] = z if z > 0 and z <= far else np.nan


def depth_to_millimetres(depth_m: NDArray[np.floating]) -> NDArray[np.uint16]:
    """Convert float metres (NaN = no reading) to uint16 millimetres (0 = no reading; beyond
    65.535 m, 65535)."""
    d = np.asarray(depth_m)
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    out = np.empty(d.shape, np.uint16)
    _millimetres(np.ascontiguousarray(d).reshape(-1), out.reshape(-1))
    return out


@njit(cache=True)
def _millimetres(d: NDArray[np.floating], out: NDArray[np.uint16]) -> None:
    """`depth_to_millimetres` in one pass: rint(metres * 1000) in float64, clipped."""
    for i in range(d.size):
        v = np.float64(d[i])
        out[i] = np.uint16(min(np.rint(v * 1000.0), 65535.0)) if math.isfinite(v) and v > 0 \
            else 0


def robust_depth(depth_m: NDArray[np.floating], uv: NDArray[np.floating], *,
                 radius: int | NDArray[np.integer] = 3, mask: NDArray[np.bool_] | None = None,
                 quantile: float | NDArray[np.floating] = 0.5) -> NDArray[np.float64]:
    """Median (or another quantile) of the valid depths in a small window around each pixel.

    Holes (NaN) are ignored, and when a foreground `mask` is given only the person's pixels
    count, so that joints on an edge do not fall into the background.

    Parameters
    ----------
    depth_m : (H, W) float, metres, NaN = no reading.
    uv : (N, 2) float pixel (u, v); NaN rows give NaN.
    radius : half-size of the square window, pixels; one for all pixels or (N,) one each.
    mask : (H, W) bool, optional; True = person.
    quantile : which quantile of the window's depths, in [0, 1] (0.5: the median, 1: the
        farthest); one for all pixels or (N,) one each. Between two values it interpolates.

    Returns
    -------
    (N,) float64 metres; NaN where the window holds no valid pixel or uv is outside the image.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f'depth image must be 2-D, got shape {depth_m.shape}')
    mask = NO_MASK if mask is None else np.asarray(mask, dtype=bool)
    if mask is not NO_MASK and mask.shape != depth_m.shape:
        raise ValueError(f'mask {mask.shape} and depth {depth_m.shape} differ in shape')
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    radii = _per_pixel(radius, len(uv), np.int64, 'radius')
    q = _per_pixel(quantile, len(uv), np.float64, 'quantile')
    # ufuncs' reductions, without ndarray.any/all's Python wrappers (the per-frame path)
    if np.logical_or.reduce(radii < 0):
        raise ValueError(f'radius must be >= 0, got {radii.min()}')
    if not np.logical_and.reduce((q >= 0) & (q <= 1)):
        raise ValueError(f'quantile must be in [0, 1], got {np.asarray(quantile).tolist()}')
    return _robust_depth(depth_m, mask, uv, radii, q)


# No person mask, as the kernels that take one (`robust_depth`'s, the refiner's, the IK's
# depth search) read it: empty (left writable: numba compiles a read-only array as another
# type)
NO_MASK = np.zeros((0, 0), bool)


def _per_pixel(value: float | NDArray, n: int, dtype: type, what: str) -> NDArray:
    """`value` (one, or one per pixel) as a contiguous (n,) array of `dtype` (np.broadcast_to
    and np.ascontiguousarray's result, in two or three calls instead of a dozen)."""
    a = np.asarray(value, dtype=dtype)
    if a.shape == (n,):
        return np.ascontiguousarray(a)
    if a.size != 1:
        raise ValueError(f'{what} must be one value or one per pixel ({n}), got shape '
                         f'{a.shape}')
    out = np.empty(n, dtype)
    out.fill(a.flat[0])
    return out


# Largest window of `lift_depth`, half-size in pixels (a 41 x 41 window)
MAX_LIFT_RADIUS_PX = 20


def lift_depth(depth_m: NDArray[np.floating], uv: NDArray[np.floating], intrinsics: Intrinsics,
               radius_m: float | NDArray[np.floating], quantile: float | NDArray[np.floating],
               *, mask: NDArray[np.bool_] | None = None, probe_px: int = 3
               ) -> NDArray[np.float64]:
    """The depth at each pixel from a window of the same size on the body at any distance.

    The window's half-size is `radius_m` metres at the surface's depth (the median of a
    `probe_px` window: at least 1, at most `MAX_LIFT_RADIUS_PX` pixels), and it gives the
    `quantile` of its valid depths (`robust_depth`). A high quantile of a wide window finds the
    torso behind an arm crossing in front of a shoulder or a hip, where the median finds the arm.

    Returns (N,) float64 metres, NaN where nothing valid is near.
    """
    z0 = robust_depth(depth_m, uv, radius=probe_px, mask=mask)
    with np.errstate(invalid='ignore', divide='ignore'):
        r = np.rint(np.asarray(radius_m, dtype=np.float64) * intrinsics.fx / z0)
    r = np.clip(np.where(np.isfinite(r), r, probe_px), 1, MAX_LIFT_RADIUS_PX)
    return robust_depth(depth_m, uv, radius=r.astype(np.int64), mask=mask, quantile=quantile)


@njit(cache=True)
def _robust_depth(depth_m: NDArray, mask: NDArray[np.bool_], uv: NDArray[np.float64],
                  radii: NDArray[np.int64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    h, w = depth_m.shape
    out = np.full(len(uv), np.nan)
    buf = np.empty((2 * radii.max() + 1) ** 2 if len(radii) else 1, depth_m.dtype)
    for i in range(len(uv)):
        if np.isfinite(uv[i, 0]) and np.isfinite(uv[i, 1]):
            col, row = int(np.rint(uv[i, 0])), int(np.rint(uv[i, 1]))
            if 0 <= col < w and 0 <= row < h:
                out[i] = window_quantile_at(depth_m, mask, col, row, radii[i], q[i], buf)
    return out


@njit(cache=True)
def robust_depth_at(depth_m: NDArray, mask: NDArray[np.bool_], col: int, row: int,
                    radius: int, buf: NDArray) -> float:
    """`robust_depth` of one pixel (col, row) inside the image, for numba kernels.

    `mask` (H, W) bool, or empty for none; `buf` scratch of (2 radius + 1)^2 of the depth's
    dtype. The median of the valid values is taken in the image's dtype, as numpy's.
    """
    return window_quantile_at(depth_m, mask, col, row, radius, 0.5, buf)


@njit(cache=True)
def window_quantile_at(depth_m: NDArray, mask: NDArray[np.bool_], col: int, row: int,
                       radius: int, q: float, buf: NDArray) -> float:
    """The `q` quantile of the valid depths in the window of `robust_depth_at`."""
    h, w = depth_m.shape
    k = 0
    for r in range(max(row - radius, 0), min(row + radius + 1, h)):
        for c in range(max(col - radius, 0), min(col + radius + 1, w)):
            d = depth_m[r, c]
            if not (d > 0 and np.isfinite(d)) or (mask.size > 0 and not mask[r, c]):
                continue
            buf[k] = d
            k += 1
    if k == 0:
        return np.nan
    values = buf[:k]
    values.sort()
    pos = q * (k - 1)
    lo = int(pos)
    hi = min(lo + 1, k - 1)
    frac = pos - lo
    if frac == 0.0:
        return float(values[lo])
    if frac == 0.5:  # the median of an even count, in the image's dtype as numpy's
        return float((values[lo] + values[hi]) / 2)
    return float(values[lo]) + frac * (float(values[hi]) - float(values[lo]))
