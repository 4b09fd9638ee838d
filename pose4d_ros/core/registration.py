"""How well a camera's depth image is registered to its colour image; the depth moved onto it.

A depth image "registered to colour" has each reading at the colour pixel that sees the same
point. When the camera's depth-to-colour calibration is off, the depth lies some pixels beside
the colour image: a person's depth silhouette, and so the foreground's mask of them, covers
the wall on one side and misses their arm on the other, and every part read through the mask
or looked up in depth is read off the person (the real Xtion recording `lab_walk`: 8-12 px
to the left at 2-4 m; docs/NOTES.md).

`edge_shift` measures it: the shift (dx, dy) that lays the depth image's edges (depth steps)
on the colour image's (Canny), by the mean distance from a depth edge to the nearest colour
edge (chamfer, each capped at `CAP_PX`: a mean, not a median, so that the few horizontal
edges of upright people weigh in dy), over frames, searched on a grid and refined.
`shift_image` moves a depth image by it, what `pose4d eval --depth-shift` does to every
frame. A constant shift is right at one distance only (the parallax of a misplaced baseline
falls with depth); it is what one recording of people at 2-4 m needs.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

DEPTH_STEP_M = 0.3  # a depth edge: a step of at least this between neighbouring readings
CANNY = (50, 150)  # the colour edges' hysteresis thresholds (8-bit grey levels)
CAP_PX = 10.0  # a depth edge farther than this from any colour edge counts as this far
MAX_POINTS = 5000  # depth edge pixels read a frame at most (evenly spread)


@dataclass(frozen=True)
class Shift:
    """The shift that lays the depth edges on the colour edges, in pixels (x right, y down),
    with the mean distance (px, capped at `CAP_PX`, over edges and frames) of a depth edge
    to the nearest colour edge there and unshifted, and the frames measured."""

    dx: int
    dy: int
    chamfer_px: float
    unshifted_px: float
    frames: int


def depth_edges(depth_m: NDArray[np.floating]) -> NDArray[np.bool_]:
    """(H, W) bool: the pixels where the depth steps by at least `DEPTH_STEP_M` to a neighbour
    (3x3 Sobel; no reading counts as 0 m, so a silhouette against missing readings is an
    edge too)."""
    d = np.nan_to_num(np.asarray(depth_m, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    step = (np.abs(cv2.Sobel(d, cv2.CV_32F, 1, 0, ksize=3))
            + np.abs(cv2.Sobel(d, cv2.CV_32F, 0, 1, ksize=3)))
    return step > DEPTH_STEP_M * 8.0  # a Sobel 3x3 weighs a unit step 4 + 4


def _colour_distance(color: NDArray[np.uint8]) -> NDArray[np.float32]:
    """(H, W) distance of every pixel to the nearest colour edge, capped at `CAP_PX`."""
    grey = cv2.cvtColor(color, cv2.COLOR_RGB2GRAY) if color.ndim == 3 else color
    edges = cv2.Canny(np.ascontiguousarray(grey, np.uint8), *CANNY) > 0
    far = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3)
    return np.minimum(far, CAP_PX)


def edge_shift(frames: Iterable[tuple[NDArray[np.uint8], NDArray[np.floating]]],
               max_dx: int = 30, max_dy: int = 10) -> Shift:
    """The shift within +-`max_dx`, +-`max_dy` px that lays the depth edges of `frames`
    ((colour RGB uint8, depth metres) pairs of one camera) nearest the colour edges: the
    smallest mean chamfer distance, on a 2-px grid, then refined to the pixel around the best
    (to about a pixel: a depth step's edge is two pixels wide). ValueError when no frame has
    depth edges to measure."""
    points, distances = [], []
    for color, depth_m in frames:
        if color.shape[:2] != np.shape(depth_m):
            raise ValueError(f'colour {color.shape[:2]} and depth {np.shape(depth_m)} differ in '
                             'size: depth must be registered to the colour image')
        ys, xs = np.nonzero(depth_edges(depth_m))
        # not along the image's borders, where a shifted image's empty strip makes edges
        h, w = color.shape[:2]
        inside = ((xs > max_dx + 1) & (xs < w - max_dx - 2)
                  & (ys > max_dy + 1) & (ys < h - max_dy - 2))
        xs, ys = xs[inside], ys[inside]
        if len(xs) < 50:
            continue
        keep = np.linspace(0, len(xs) - 1, min(len(xs), MAX_POINTS)).astype(int)
        points.append((xs[keep], ys[keep]))
        distances.append(_colour_distance(color))
    if not points:
        raise ValueError('no frame has depth edges to measure the registration by')

    def cost(dx: int, dy: int) -> float:
        per_frame = []
        for (xs, ys), far in zip(points, distances, strict=True):
            x, y = xs + dx, ys + dy
            ok = (x >= 0) & (x < far.shape[1]) & (y >= 0) & (y < far.shape[0])
            if ok.any():
                per_frame.append(float(np.mean(far[y[ok], x[ok]])))
        return float(np.mean(per_frame)) if per_frame else CAP_PX

    grid = [(dx, dy) for dx in range(-max_dx, max_dx + 1, 2)
            for dy in range(-max_dy, max_dy + 1, 2)]
    best = min(grid, key=lambda s: (cost(*s), abs(s[0]) + abs(s[1])))
    near = [(best[0] + i, best[1] + j) for i in (-1, 0, 1) for j in (-1, 0, 1)
            if abs(best[0] + i) <= max_dx and abs(best[1] + j) <= max_dy]
    dx, dy = min(near, key=lambda s: (cost(*s), abs(s[0]) + abs(s[1])))
    return Shift(dx, dy, round(cost(dx, dy), 3), round(cost(0, 0), 3), len(points))


def shift_image(image: NDArray, dx: int, dy: int) -> NDArray:
    """`image` moved by (dx, dy) pixels (x right, y down), NaN (0 for integers) where nothing
    moved in: a depth image laid onto its colour image by `edge_shift`'s shift."""
    image = np.asarray(image)
    fill = np.nan if np.issubdtype(image.dtype, np.floating) else 0
    out = np.full_like(image, fill)
    h, w = image.shape[:2]
    if abs(dx) >= w or abs(dy) >= h:
        return out
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        image[max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)]
    return out
