"""A Kinect v1 (structured light) depth sensor model for the synthetic renderer.

Applied to the renderer's exact depth z (metres along the optical axis), in this order:

1. Projector shadow: the infrared projector sits `baseline_m` (7.5 cm) beside the camera, so
   surfaces it cannot light have no reading: a band `f b (1/z_near - 1/z_far)` pixels wide
   beside the left of foreground edges (`raycast.projector_shadow`).
2. Axial noise growing with z^2: sigma_z = 1.2 mm + 1.9 mm (z - 0.4)^2 (Nguyen, Izadi and Lovell,
   "Modeling Kinect sensor noise for improved 3D reconstruction and tracking", 3DIMPVT 2012),
   part of it spatially correlated (the sensor matches 9x9 blocks, so neighbours err together).
3. Disparity quantisation: the sensor measures disparity in 1/8 pixel steps, so depth comes
   in steps of `quant * z^2` (2.85e-3 / m: 1/8 px at f = 580 px, b = 7.5 cm at 640x480; Khoshelham
   and Elberink, Sensors 2012): z_q = 1 / (round(1 / (quant z)) quant).
4. Holes: at depth discontinuities (the block matcher fails on mixed windows), at grazing
   angles, on infrared-absorbing materials (dark hair, black fabric), a few random speckles,
   and outside the working range (< 0.5 m, > 4.5 m): all written as 0.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.synth.raycast import projector_shadow


@dataclass(frozen=True)
class KinectModel:
    """Kinect v1 depth model parameters (defaults from the references in the module docstring).

    Attributes
    ----------
    baseline_m : projector-camera baseline, metres.
    quant : disparity quantisation, depth step = quant * z^2 (1/m).
    noise_a_m, noise_b : axial noise sigma = noise_a_m + noise_b (z - 0.4)^2, metres.
    correlated : fraction of the noise variance that is spatially correlated.
    min_range_m, max_range_m : working range; outside it the sensor gives 0.
    edge_jump_m, edge_rel : a neighbour differing by more than edge_jump_m + edge_rel * z is a
        discontinuity.
    edge_drop, edge_ring_drop : probability of a hole on a discontinuity pixel / on its
        neighbours.
    grazing_cos : below this |cos| between ray and normal, readings start to drop out.
    speckle : probability of an isolated hole anywhere.
    """

    baseline_m: float = 0.075
    quant: float = 2.85e-3
    noise_a_m: float = 0.0012
    noise_b: float = 0.0019
    correlated: float = 0.6
    min_range_m: float = 0.5
    max_range_m: float = 4.5
    edge_jump_m: float = 0.05
    edge_rel: float = 0.02
    edge_drop: float = 0.55
    edge_ring_drop: float = 0.15
    grazing_cos: float = 0.2
    speckle: float = 0.002

    def axial_noise_m(self, z: NDArray[np.floating]) -> NDArray[np.floating]:
        """Standard deviation of the axial noise at depth z (metres), metres."""
        return self.noise_a_m + self.noise_b * (z - 0.4) ** 2


def kinect_depth(depth_m: NDArray[np.float32], normal: NDArray[np.float32],
                 intrinsics: Intrinsics, rng: np.random.Generator, *,
                 dropout: NDArray[np.float32] | None = None,
                 model: KinectModel | None = None) -> NDArray[np.uint16]:
    """Turn exact depth into a Kinect v1 measurement.

    Parameters
    ----------
    depth_m : (H, W) float32 exact depth z, metres, inf = nothing hit.
    normal : (H, W, 3) float32 unit surface normals, optical frame.
    intrinsics : the depth camera (the same grid as the depth image).
    rng : the noise source.
    dropout : (H, W) float32 per-pixel probability of no reading from the material, optional.
    model : the sensor parameters (default `KinectModel()`).

    Returns
    -------
    (H, W) uint16 millimetres, 0 = no reading.
    """
    m = model or KinectModel()
    z = np.asarray(depth_m, dtype=np.float32)
    h, w = z.shape
    valid = np.isfinite(z) & (z > 0)
    zc = np.where(valid, z, np.float32(0.0))

    if (h, w) != (intrinsics.height, intrinsics.width):
        raise ValueError(f'depth image is {w}x{h} but the intrinsics are '
                         f'{intrinsics.width}x{intrinsics.height}')
    shadow = projector_shadow(np.where(valid, z, np.inf).astype(np.float32),
                              float(intrinsics.fx * m.baseline_m))

    # noise, as a fraction of sigma: correlated (smooth, upsampled) plus white
    sigma = m.axial_noise_m(zc)
    coarse = rng.standard_normal((max(h // 6, 2), max(w // 6, 2))).astype(np.float32)
    smooth = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)
    smooth /= max(float(smooth.std()), 1e-6)
    white = rng.standard_normal((h, w)).astype(np.float32)
    noise = np.sqrt(m.correlated) * smooth + np.sqrt(1.0 - m.correlated) * white
    zn = zc + sigma * noise

    # disparity quantisation: 1/z in steps of quant
    with np.errstate(divide='ignore', invalid='ignore'):
        level = np.rint(1.0 / (np.maximum(zn, 1e-3) * m.quant))
        zq = 1.0 / (np.maximum(level, 1.0) * m.quant)

    # holes at discontinuities: compare with the 4 neighbours (nothing hit = far away)
    zf = np.where(valid, z, np.float32(1e3))
    jump = np.zeros((h, w), bool)
    thr = m.edge_jump_m + m.edge_rel * zc
    dx = np.abs(np.diff(zf, axis=1)) > thr[:, 1:]
    dy = np.abs(np.diff(zf, axis=0)) > thr[1:, :]
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:, :] |= dy
    jump[:-1, :] |= dy
    ring = cv2.dilate(jump.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~jump
    u = rng.random((h, w), dtype=np.float32)
    p_drop = np.full((h, w), m.speckle, np.float32)
    p_drop[jump] = m.edge_drop
    p_drop[ring] = np.maximum(p_drop[ring], m.edge_ring_drop)
    # grazing angles: the pattern is smeared out
    cos = np.abs(np.einsum('hwc,hwc->hw', normal, unit_rays(intrinsics)))
    graze = np.clip((m.grazing_cos - cos) / m.grazing_cos, 0.0, 1.0)
    p_drop = np.maximum(p_drop, graze)
    if dropout is not None:
        p_drop = np.maximum(p_drop, dropout)
    holes = (u < p_drop) | shadow | ~valid | (zq < m.min_range_m) | (zq > m.max_range_m)
    mm = np.where(holes, 0.0, np.rint(zq * 1000.0))
    return np.clip(mm, 0, 65535).astype(np.uint16)


@functools.cache
def unit_rays(intrinsics: Intrinsics) -> NDArray[np.float32]:
    """(H, W, 3) float32 unit ray directions through the pixel centres, optical frame."""
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64),
                       np.arange(intrinsics.height, dtype=np.float64))
    d = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy,
                  np.ones_like(u)], axis=-1)
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)
    d.flags.writeable = False  # shared by every caller through the cache
    return d


def ideal_depth(depth_m: NDArray[np.float32]) -> NDArray[np.uint16]:
    """Exact depth as uint16 millimetres (0 where nothing was hit), no sensor effects."""
    z = np.asarray(depth_m, dtype=np.float32)
    ok = np.isfinite(z) & (z > 0)
    return np.clip(np.where(ok, np.rint(z * 1000.0), 0.0), 0, 65535).astype(np.uint16)
