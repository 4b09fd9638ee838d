"""The person's mask (step 5 of `segment` and after): completed with the no-reading pixels along
its edges, brought back to full size from the working resolution, held through a frame without
a person, and applied to colour and depth."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.camera import MAX_DEPTH_M
from pose4d_ros.core.foreground.config import (
    REASON_NO_PERSON,
    ForegroundResult,
    MaskConfig,
    not_found,
)


def complete(mask: NDArray[np.bool_], no_reading: NDArray[np.bool_],
              box: tuple[int, int, int, int], config: MaskConfig) -> None:
    """Give the mask (in place) the no-reading pixels that belong to the person: those a
    morphological closing of `close_px` adds (Kinect drops readings in a ragged band along
    depth edges) and the holes of the mask made of them (dropouts on the clothes)."""
    if config.close_px > 1:
        h, w = mask.shape
        r = config.close_px
        x0, y0, x1, y1 = max(box[0] - r, 0), max(box[1] - r, 0), min(box[2] + r, w), \
            min(box[3] + r, h)
        crop = mask[y0:y1, x0:x1]
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (r, r))
        closed = cv2.morphologyEx(crop.view(np.uint8), cv2.MORPH_CLOSE, kernel,
                                  borderType=cv2.BORDER_CONSTANT, borderValue=0)
        crop |= closed.view(bool) & no_reading[y0:y1, x0:x1]
    if config.fill_holes:
        _fill_holes(mask, no_reading, box)


def grow_down(mask: NDArray[np.bool_], depth: NDArray[np.float32],
              above: NDArray[np.float32] | None, box: tuple[int, int, int, int],
              config: MaskConfig) -> tuple[int, int, int, int]:
    """Grow the mask (in place) down from its pixels less than `grow_max_above_m` above the
    floor into those below them whose depth runs on from theirs (within `grow_step_m`) and
    that stand at least `grow_min_above_m` above the floor, within the box's columns widened by
    `grow_px` each side; the grown mask's box. (From higher pixels, an arm held out over a
    person behind would grow down their body.)

    A leg seen from above runs into the floor's depth towards the foot, so the stable region
    of the depth's levels ends above it: on a real lab camera (`lab_walk`, pitched 30
    degrees) at the knees or mid-shin. Nothing grows without a floor (`above` None) or where
    the mask already reaches it (a person seen from the front, every render's)."""
    if above is None or config.grow_min_above_m <= 0:
        return box
    h, w = mask.shape
    x0, x1 = max(box[0] - config.grow_px, 0), min(box[2] + config.grow_px, w)
    bottom = _grow_down_kernel(mask, depth, above, box[1], box[3], x0, x1,
                               np.float32(config.grow_min_above_m),
                               np.float32(config.grow_max_above_m),
                               np.float32(config.grow_step_m))
    if bottom <= box[3] and x0 == box[0] and x1 == box[2]:
        return box
    cols = np.flatnonzero(np.logical_or.reduce(mask[box[1]:bottom], axis=0))
    return int(cols[0]), box[1], int(cols[-1]) + 1, max(bottom, box[3])


@njit(cache=True)
def _grow_down_kernel(mask: NDArray[np.bool_], depth: NDArray[np.float32],
                      above: NDArray[np.float32], y0: int, y1: int, x0: int, x1: int,
                      min_above: np.float32, max_above: np.float32, step: np.float32) -> int:
    """`grow_down`'s rows from the box's top (`y0`) down: a pixel joins when one of the three
    above it is in the mask, under `max_above`, with a depth within `step` of its own; below
    the box (`y1`), until a row where none does. Returns the row after the mask's last."""
    h, w = mask.shape
    bottom = y0
    for y in range(y0, h):
        joined = False
        for x in range(x0, x1):
            if mask[y, x]:
                joined = True
                continue
            z = depth[y, x]
            if y == y0 or not above[y, x] >= min_above:  # NaN: no reading, never joins
                continue
            for xx in range(max(x - 1, 0), min(x + 2, w)):
                if mask[y - 1, xx] and above[y - 1, xx] < max_above and \
                        abs(depth[y - 1, xx] - z) <= step:
                    mask[y, x] = True
                    joined = True
                    break
        if joined:
            bottom = y + 1
        elif y >= y1:
            break
    return bottom


def _fill_holes(mask: NDArray[np.bool_], fillable: NDArray[np.bool_],
                box: tuple[int, int, int, int]) -> None:
    """Fill, in place, the holes of `mask` (inside `box`) made only of `fillable` pixels."""
    x0, y0, x1, y1 = box
    crop = mask[y0:y1, x0:x1]
    pad = np.zeros((y1 - y0 + 2, x1 - x0 + 2), np.uint8)
    pad[1:-1, 1:-1] = crop
    ff = pad.copy()
    cv2.floodFill(ff, None, (0, 0), 1)
    holes = (ff[1:-1, 1:-1] == 0)
    if not holes.any():
        return
    n, lab = cv2.connectedComponents(holes.astype(np.uint8), connectivity=4)
    if n <= 1:
        return
    bad = np.bincount(lab[holes & ~fillable[y0:y1, x0:x1]], minlength=n) > 0
    bad[0] = True
    crop |= ~bad[lab]


@njit(cache=True)
def upsample_mask(small_mask: NDArray[np.bool_], small_depth: NDArray[np.float32],
                   depth: NDArray, scale: float, f: int, k: NDArray[np.float64],
                   floor: NDArray[np.float64], floor_tolerance: float, tolerance: float
                   ) -> NDArray[np.bool_]:
    """The full-size mask of a mask found on every f-th pixel of every f-th row.

    Inside and outside the mask a pixel takes its representative's value; along the mask's
    edge (a representative with neighbours on both sides) a pixel with depth is the person's
    when it is within `tolerance` of the depth of a neighbouring person pixel and, with a floor
    (nx, ny, nz, d; NaN = none), at least `floor_tolerance` above it. `depth` is the full-size
    image, `scale` metres per unit (uint16 millimetres: 0.001); 0 or NaN = no reading.
    """
    h, w = depth.shape
    sh, sw = small_mask.shape
    out = np.zeros((h, w), np.bool_)
    rows, cols = np.flatnonzero(small_mask.sum(axis=1)), np.flatnonzero(small_mask.sum(axis=0))
    if len(rows) == 0:
        return out
    for r in range(max(rows[0] - 1, 0), min(rows[-1] + 2, sh)):
        for c in range(max(cols[0] - 1, 0), min(cols[-1] + 2, sw)):
            inside = small_mask[r, c]
            edge = False
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < sh and 0 <= cc < sw and small_mask[rr, cc] != inside:
                        edge = True
            for y in range(r * f, min(r * f + f, h)):
                for x in range(c * f, min(c * f + f, w)):
                    if not edge:
                        out[y, x] = inside
                        continue
                    z = depth[y, x] * scale
                    if not (z > 0 and np.isfinite(z)):
                        out[y, x] = inside  # no reading: as its representative
                        continue
                    if np.isfinite(floor[0]):
                        height = (floor[0] * (x - k[2]) / k[0] * z
                                  + floor[1] * (y - k[3]) / k[1] * z + floor[2] * z + floor[3])
                        if height < floor_tolerance:
                            continue
                    for dr in range(-1, 2):
                        for dc in range(-1, 2):
                            rr, cc = r + dr, c + dc
                            if 0 <= rr < sh and 0 <= cc < sw and small_mask[rr, cc] and \
                                    abs(small_depth[rr, cc] - z) <= tolerance:
                                out[y, x] = True
    return out


def hold(previous: ForegroundResult, depth_m: NDArray[np.floating], *, grow_px: int = 3,
         depth_tol_m: float = 0.4, keep: float = 0.6) -> ForegroundResult:
    """The previous frame's person carried into a frame in which `segment` found none (its
    regions fail a rule for a frame or two, seen on held-out videos): the previous mask grown
    by `grow_px`, where this frame's depth lies within `depth_tol_m` of the previous person's
    median depth. Not found when that keeps less than `keep` of the previous mask's pixels.

    Parameters
    ----------
    previous : a found result of an earlier frame.
    depth_m : (H, W) float32 metres, NaN = no reading: this frame's depth.
    """
    k = 2 * grow_px + 1
    grown = cv2.dilate(previous.mask.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    with np.errstate(invalid='ignore'):
        mask = grown & (np.abs(np.asarray(depth_m) - previous.depth_m) <= depth_tol_m)
    if not np.count_nonzero(mask) >= keep * previous.area_px:
        return not_found(mask.shape, REASON_NO_PERSON)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return replace(previous, mask=mask, box=(int(cols[0]), int(rows[0]), int(cols[-1]) + 1,
                                             int(rows[-1]) + 1),
                   depth_m=float(np.nanmedian(np.asarray(depth_m)[mask])))


def apply_mask(color: NDArray[np.uint8], depth_m: NDArray[np.floating],
               mask: NDArray[np.bool_]) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """Blank colour and depth outside the person's mask.

    Parameters
    ----------
    color : (H, W, 3) or (H, W) uint8 image.
    depth_m : (H, W) float metres, NaN = no reading (uint16 millimetres accepted).
    mask : (H, W) bool, True = person.

    Returns
    -------
    color_masked : same shape and dtype as `color`, 0 outside the mask.
    depth_masked : (H, W) float32 metres, NaN outside the mask (and where there is no reading).
    New arrays; the inputs are not modified.
    """
    color = np.asarray(color)
    mask = np.asarray(mask)
    if mask.dtype != np.bool_:
        raise ValueError(f'mask must be bool, got dtype {mask.dtype}')
    if mask.ndim != 2 or color.shape[:2] != mask.shape:
        raise ValueError(f'colour shape {color.shape} does not match the mask {mask.shape}')
    depth = np.asarray(depth_m)
    if depth.dtype not in (np.uint16, np.float32, np.float64):
        raise ValueError(f'depth must be uint16 millimetres or float metres, '
                         f'got dtype {depth.dtype}')
    if depth.shape != mask.shape:
        raise ValueError(f'depth shape {depth.shape} does not match the mask {mask.shape}')
    # outside the mask zeros and NaN are written at memory speed, inside by one kernel pass
    color_masked = np.zeros(color.shape, color.dtype)
    depth_masked = np.empty(mask.shape, np.float32)
    depth_masked.fill(np.nan)
    h, w = mask.shape
    c = color.shape[2] if color.ndim == 3 else 1  # 0: no colour (`ForegroundStage`)
    _blank_outside(color.reshape(h, w, c), color_masked.reshape(h, w, c), depth,
                   depth_masked, mask, 0.001 if depth.dtype == np.uint16 else 1.0, MAX_DEPTH_M)
    return color_masked, depth_masked


@njit(cache=True)
def _blank_outside(color: NDArray[np.uint8], out: NDArray[np.uint8], depth: NDArray,
                   out_depth: NDArray[np.float32], mask: NDArray[np.bool_], scale: float,
                   max_m: float) -> None:
    """`apply_mask` inside the mask, in one pass: `out` = `color` inside the mask (it is 0
    elsewhere already); `out_depth` = the depth in metres (`depth` times `scale`) inside the
    mask where it is a reading (`camera.depth_to_metres`'s rule), NaN elsewhere already."""
    h, w, c = color.shape
    for r in range(h):
        for x in range(w):
            if mask[r, x]:
                for k in range(c):
                    out[r, x, k] = color[r, x, k]
                z = np.float32(depth[r, x]) * np.float32(scale)  # as depth_to_metres
                if z > 0 and z <= max_m:
                    out_depth[r, x] = z
