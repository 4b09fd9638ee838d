"""What the detector's stage makes of the part model's poses: each part's pixel lifted to 3-D
as the model learned to read depth (`lift_parts`), the pose several person scales agree on
(`medoid_parts`), and the person's scale in the image from the parts' depths
(`person_scale_px`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, lift_depth, robust_depth
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.stats import median

# Half-size of the window of the robust depth look-up that lifts a detected joint to 3-D, pixels
# (the detector's default; `pose4d_ros.peer` lifts MediaPipe's joints with it too)
DEPTH_RADIUS_PX = 3


def valid_xyz(xyz: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Finite and in front of the camera."""
    # ufuncs only (a comparison with NaN raises no floating-point error): the per-frame path
    return np.logical_and.reduce(np.isfinite(xyz), axis=1) & (xyz[:, 2] > 0)


def lift_parts(model: PartModel, depth_m: NDArray[np.floating], uv: NDArray[np.floating],
               intrinsics: Intrinsics, mask: NDArray[np.bool_] | None = None
               ) -> NDArray[np.float64]:
    """The depth of each of the model's parts' joint centres at pixels `uv` (P, 2), as `model`
    learned to read it.

    Each part has its own look-up (`PartModel.depth_lookup`: a window of a size on the body and
    a quantile of its depths; without one, the median of a `DEPTH_RADIUS_PX` window) and lies
    its `depth_offset_m` behind the surface the camera sees.
    """
    if model.depth_lookup is None:
        z = robust_depth(depth_m, uv, radius=DEPTH_RADIUS_PX, mask=mask)
    else:
        z = lift_depth(depth_m, uv, intrinsics, model.depth_lookup[:, 0],
                       model.depth_lookup[:, 1], mask=mask)
    if model.depth_offset_m is not None:
        z = z + model.depth_offset_m
    return z


def medoid_parts(uvs: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """(P, 2): each part's position, among those of the poses `uvs` (each (P, 2) pixels), with
    the least summed distance to the others' (the medoid: a part one pose puts elsewhere
    while the others agree is not taken)."""
    p = np.stack(uvs)
    d = np.linalg.norm(p[:, None] - p[None], axis=3).sum(axis=1)
    return p[np.argmin(d, axis=0), np.arange(p.shape[1])]


# Metres of body per person scale: the tracker's pixel parameters are stated for a person of
# `slqe.REFERENCE_SCALE_PX` such scales (the part models' `scale_length_m`)
PERSON_SCALE_M = 0.5


def person_scale_px(xyz: NDArray[np.float64], intrinsics: Intrinsics | None) -> float | None:
    """The person's scale in the image, pixels per `PERSON_SCALE_M` of body, from the median
    depth of the parts' 3-D positions `xyz` (N, 3); None without a camera or a valid depth."""
    if intrinsics is None:
        return None
    z = xyz[valid_xyz(xyz), 2]
    return intrinsics.fx * PERSON_SCALE_M / median(z) if len(z) else None
