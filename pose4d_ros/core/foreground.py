"""Person foreground from the depth image: floor removal and MSER (first stage of the paper).

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", section 3 (foreground extraction): maximally
stable extremal regions (MSER, Matas et al. 2002) are found on the depth image, regions larger
than a trained area threshold are background (walls, floor), and the person's region masks the
colour and depth images before the part detector runs. The paper gives no more detail; the rest
of this module is our design, measured on the synthetic CAD-60-format sets.

Steps of `segment` (one depth frame, float32 metres, NaN = no reading):

1. Floor plane. RANSAC on the 3-D points of the lower part of the image: planes through three
   points whose normal is within `floor_max_tilt_deg` of the optical "up" (-y) and that pass
   `floor_min_height_m`-`floor_max_height_m` below the camera; the plane with most inliers
   (tolerance growing with z^2, as Kinect noise does) is refined by weighted least squares.
   Pixels less than `floor_tolerance_m` above it are dropped. Without this, the floor in front
   of the person is nearer than the person and joins the feet at every depth threshold, so
   the person's region leaks into the floor (no person-sized region is left at all).
2. 8-bit depth. Depth in [`depth_near_m`, `depth_far_m`] maps linearly to 255..1 (near is
   bright); no reading, floor and out-of-range pixels are 0. A connected component of
   ``{g >= t}`` (an extremal region) is a set of connected pixels nearer than level t.
3. Extremal regions and their stability. The component tree of all levels is built by
   union-find (numba, on every `tree_step`-th pixel). A region R(t)'s stability score is
   ``(|R(t - delta)| - |R(t)|) / |R(t)|``, its growth when the threshold moves `mser_delta`
   levels (``delta * (far - near) / 254`` metres) further away; regions with a score above
   `mser_max_variation` or larger than `max_region_area_px` (the trained background area
   threshold) are dropped. This is MSER's criterion, but not OpenCV's MSER: OpenCV keeps a
   region only when it is more stable than its parent, and the parent of a free-standing
   person (the person merged with the wall behind) is usually more stable, so OpenCV never
   reports the whole person.
4. Person rules, in two stages. Stage 1 uses the tree's statistics (box, mean depth) and
   examines the best `max_candidates` regions (score ``log(area) - stability_weight *
   variation - border_penalty * touches_side``; regions within the person bounds first).
   Stage 2 traces each at full resolution (flood fill), splits it at empty depth gaps wider
   than `occluder_gap_m` (an occluder in front, furniture behind) and, when a part is deeper
   than `person_max_extent_m`, also at Otsu's threshold of its depth histogram (a table whose
   top recedes towards the person). Every part must pass the person-size rules: box height
   ``h_px z / fy`` and width ``w_px z / fx`` at its median depth z, surface
   ``n_px z^2 / (fx fy)``, fill of its box, depth extent, and, with a floor, the height above
   the floor of its top rows (head or hands) and bottom rows (feet or the occluder's top).
   The best-scoring part wins; with `previous`, a part overlapping the previous box gets
   `previous_bonus`. A person nearer than the camera sees whole (1.2 m away, head to thighs)
   is cut by the image's bottom edge and shorter than a whole person may be: when no part
   passes the rules, parts cut by that edge get smaller lower bounds on height and surface
   and no rule on their bottom rows (`person_min_cut_height_m`); the best few such regions
   are examined besides the best few others, never in their place.
5. Completion. No-reading pixels that a small closing of the mask adds (Kinect loses the
   readings in a ragged band along depth edges) join the mask; optionally, holes of no-reading
   pixels are filled.

Defaults were tuned on the synthetic training set only (UTKinect subjects s01-s06 rendered in
random rooms by `pose4d synth`, 1536 frames): a coordinate search over the parameters
maximising the mean mask IoU against the rendered person masks, the person rules searched on
the stored candidate parts of every frame. The test set (s07-s08, unseen bodies and rooms) was
used only to report. The tuning script is kept with the project notes
(``foreground_tune.py``); its results are in `ForegroundConfig`'s docstring.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.camera import MAX_DEPTH_M, Intrinsics, depth_to_metres
from pose4d_ros.core.stats import median

# Reasons given when no person is found.
REASON_OK = ''
REASON_TOO_SMALL = 'image too small'
REASON_NO_DEPTH = 'no valid depth'
REASON_NO_REGION = 'no stable region'
REASON_NO_PERSON = 'no region of person size'


@dataclass(frozen=True)
class ForegroundConfig:
    """Parameters of `segment`; defaults tuned on the synthetic training set.

    Tuning (``foreground_tune.py`` in the project notes; synthetic training set, 1536 frames of
    UTKinect subjects s01-s06 in random rooms, 320x240): coordinate search of one parameter at
    a time over a grid, every second frame, maximising the mean mask IoU, until no change
    helped; then the person rules and score weights were searched on the stored candidate
    parts of all frames, and one more coordinate round changed nothing. Mean IoU on the
    training set 0.932 (median 0.947, 96.2 % of frames above 0.8); on the unseen test set
    (s07-s08, 400 frames) 0.912 (median 0.944, 86.0 % above 0.8). What mattered: floor
    removal (without it 0.38), a thin floor band (`floor_tolerance_m` 2 cm: 5 cm loses the
    shoes, 0.925), the closing into no-reading edge pixels (`close_px` 0: 0.883), the depth
    splits (`occluder_gap_m` 0 and no extent rule: 0.859), and `person_max_area_m2` (0.7 was
    best on the training set, 0.80 is kept for a margin above the largest training person,
    0.73 m^2, at a cost of 0.004 IoU there; 0.9 and above: 0.915). Flat on the training set:
    `max_region_area_px` 15000-40000 (30000 keeps people nearer than 2 m), `mser_max_variation`
    0.25-2, `stability_weight` 10-50, `mser_delta` 6-8 (4: 0.931, 2: 0.918; grid runs on every
    second frame). `tree_step` 2 costs 0.002 IoU and saves about 40 % of the time.

    Attributes
    ----------
    depth_near_m, depth_far_m : depth range mapped to the 8-bit image, metres (near -> 255,
        far -> 1, everything else 0).
    mser_delta : MSER stability step, 8-bit levels (one level = (far - near) / 254 metres;
        6 levels = 10 cm with the defaults).
    mser_min_area_px : smallest region, pixels (at the input resolution).
    max_region_area_px : the trained background area threshold: larger regions are
        background, pixels (at the input resolution).
    mser_max_variation : the paper's stability score: largest relative area growth over
        `mser_delta` levels further away for a region to be stable.
    connectivity : pixel neighbourhood of the regions, 4 or 8.
    tree_step : the region tree is built on every `tree_step`-th pixel of each row and
        column (1 = all; 2 = four times faster); chosen regions are traced at full
        resolution.
    person_min_height_m, person_max_height_m : height of a person region, metres (box height
        times median depth over fy).
    person_min_cut_height_m : smallest height of a region cut by the image's bottom edge (a
        person nearer than the camera sees whole: head and shoulders down to the edge),
        metres; its smallest surface is `person_min_area_m2` in the same proportion, and its
        bottom rows are the edge, not its feet, so the bottom rule does not apply to it.
    person_min_width_m, person_max_width_m : width, metres (box width times depth over fx).
    person_min_area_m2, person_max_area_m2 : surface of a person region seen from the
        camera, square metres (pixels times depth squared over fx fy).
    person_max_fill : largest fraction of its box a person region fills (furniture and wall
        pieces fill their boxes).
    border_penalty : score taken from a region that touches the left or right image border.
    merge_slack : factor on the upper person bounds for whole regions, before they are split
        at depth gaps (a region may hold an occluder or furniture besides the person).
    max_candidates : regions (best first) whose pixels are examined.
    person_min_top_m, person_max_top_m : height above the floor of a person part's top rows
        (head, or hands raised), metres; only with a floor.
    person_max_bottom_m : largest height above the floor of its bottom rows (feet, or the top
        of an occluder hiding them), metres; only with a floor.
    person_max_extent_m : largest depth extent of a person part (5th to 95th percentile of
        its depths), metres; deeper regions are also split in two at Otsu's threshold.
    edge_rows : rows at the top and bottom of a part whose median height is its top/bottom.
    floor_remove : fit and drop the floor plane before MSER.
    floor_rows_fraction : lower fraction of the image rows searched for the floor.
    floor_sample_step : pixel stride of the RANSAC sample grid.
    floor_iterations : RANSAC hypotheses per frame.
    floor_inlier_m : RANSAC inlier distance at 1 m, metres; grows with depth squared (Kinect
        depth noise and quantisation do).
    floor_tolerance_m : pixels less than this above the floor plane are floor, metres.
    floor_max_tilt_deg : largest angle between the floor normal and the optical -y axis.
    floor_min_height_m, floor_max_height_m : range of camera heights above the floor, metres.
    floor_min_inliers : fewest RANSAC inliers for a floor to be accepted.
    occluder_gap_m : an empty depth gap wider than this inside the chosen region separates a
        nearer object (an occluder) from the person, metres; 0 disables the cut.
    close_px : size of the closing (ellipse, pixels) whose no-reading pixels join the mask;
        0 or 1 = none.
    fill_holes : fill holes of the mask that have no depth reading.
    stability_weight : a region's score is ``log(area) - stability_weight * variation -
        border_penalty * touches_side``.
    previous_bonus : with `previous`, score added to a region whose box overlaps the previous
        box by more than 0.3 (intersection over union); 0 = no temporal preference.
    seed : RANSAC random seed (the result is a function of the input).
    working_height_px : larger depth images are segmented on every f-th pixel of every f-th
        row, f the largest integer factor that keeps at least this many rows (640x480 and
        848x480 at 320x240 and 424x240), and the mask is brought back to full size: the
        parameters in pixels hold at the resolution they were tuned at (CAD-60's 240 rows)
        and the cost does not grow with the camera's resolution.
    """

    depth_near_m: float = 0.4
    depth_far_m: float = 4.5
    mser_delta: int = 6
    mser_min_area_px: int = 60
    max_region_area_px: int = 30000
    mser_max_variation: float = 0.5
    connectivity: int = 8
    tree_step: int = 2
    person_min_height_m: float = 0.8
    person_max_height_m: float = 2.3
    person_min_cut_height_m: float = 0.4
    person_min_width_m: float = 0.15
    person_max_width_m: float = 2.0
    person_min_area_m2: float = 0.1
    person_max_area_m2: float = 0.8
    person_max_fill: float = 0.7
    border_penalty: float = 2.0
    merge_slack: float = 2.0
    person_min_top_m: float = 0.9
    person_max_top_m: float = 2.5
    person_max_bottom_m: float = 1.0
    person_max_extent_m: float = 1.0
    edge_rows: int = 3
    max_candidates: int = 6
    floor_remove: bool = True
    floor_rows_fraction: float = 0.5
    floor_sample_step: int = 4
    floor_iterations: int = 64
    floor_inlier_m: float = 0.004
    floor_tolerance_m: float = 0.02
    floor_max_tilt_deg: float = 30.0
    floor_min_height_m: float = 0.3
    floor_max_height_m: float = 3.0
    floor_min_inliers: int = 40
    occluder_gap_m: float = 0.3
    close_px: int = 5
    fill_holes: bool = False
    stability_weight: float = 50.0
    previous_bonus: float = 0.5
    seed: int = 0
    working_height_px: int = 240

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == 'int' and (not isinstance(value, int) or isinstance(value, bool)):
                raise ValueError(f'{f.name} must be an integer, got {value!r}')
        if not (math.isfinite(self.depth_near_m) and math.isfinite(self.depth_far_m)
                and 0.0 <= self.depth_near_m < self.depth_far_m):
            raise ValueError(f'need 0 <= depth_near_m < depth_far_m, got depth_near_m='
                             f'{self.depth_near_m}, depth_far_m={self.depth_far_m}')
        if not 1 <= self.mser_delta <= 64:
            raise ValueError(f'mser_delta must be in [1, 64] levels, got {self.mser_delta}')
        if not 1 <= self.mser_min_area_px < self.max_region_area_px:
            raise ValueError(f'need 1 <= mser_min_area_px < max_region_area_px, got '
                             f'mser_min_area_px={self.mser_min_area_px}, '
                             f'max_region_area_px={self.max_region_area_px}')
        if not self.mser_max_variation > 0:
            raise ValueError(f'mser_max_variation must be positive, got {self.mser_max_variation}')
        if self.tree_step not in (1, 2, 3, 4):
            raise ValueError(f'tree_step must be 1, 2, 3 or 4, got {self.tree_step}')
        if self.connectivity not in (4, 8):
            raise ValueError(f'connectivity must be 4 or 8, got {self.connectivity}')
        for lo, hi in (('person_min_height_m', 'person_max_height_m'),
                       ('person_min_cut_height_m', 'person_max_height_m'),
                       ('person_min_area_m2', 'person_max_area_m2'),
                       ('person_min_top_m', 'person_max_top_m'),
                       ('person_min_width_m', 'person_max_width_m'),
                       ('floor_min_height_m', 'floor_max_height_m')):
            a, b = getattr(self, lo), getattr(self, hi)
            if not 0.0 <= a < b:
                raise ValueError(f'need 0 <= {lo} < {hi}, got {lo}={a}, {hi}={b}')
        if not 0.0 < self.floor_rows_fraction <= 1.0:
            raise ValueError(f'floor_rows_fraction must be in (0, 1], got '
                             f'{self.floor_rows_fraction}')
        if not self.person_max_extent_m > 0:
            raise ValueError(f'person_max_extent_m must be positive, got '
                             f'{self.person_max_extent_m}')
        if not self.person_max_bottom_m >= 0:
            raise ValueError(f'person_max_bottom_m must be >= 0, got {self.person_max_bottom_m}')
        if not self.merge_slack >= 1.0:
            raise ValueError(f'merge_slack must be >= 1, got {self.merge_slack}')
        for name in ('floor_sample_step', 'floor_iterations', 'floor_min_inliers',
                     'max_candidates', 'edge_rows', 'working_height_px'):
            if getattr(self, name) < 1:
                raise ValueError(f'{name} must be >= 1, got {getattr(self, name)}')
        for name in ('floor_inlier_m', 'floor_tolerance_m'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')
        if not 0.0 < self.floor_max_tilt_deg < 90.0:
            raise ValueError(f'floor_max_tilt_deg must be in (0, 90), got '
                             f'{self.floor_max_tilt_deg}')
        if not 0 <= self.close_px <= 31:
            raise ValueError(f'close_px must be in [0, 31], got {self.close_px}')
        if not self.occluder_gap_m >= 0:
            raise ValueError(f'occluder_gap_m must be >= 0, got {self.occluder_gap_m}')
        if not 0.0 < self.person_max_fill <= 1.0:
            raise ValueError(f'person_max_fill must be in (0, 1], got {self.person_max_fill}')
        for name in ('stability_weight', 'previous_bonus', 'border_penalty'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')

    @property
    def min_cut_area_m2(self) -> float:
        """Smallest surface of a region cut by the image's bottom edge, square metres."""
        return self.person_min_area_m2 * self.person_min_cut_height_m / self.person_min_height_m

    @property
    def metres_per_level(self) -> float:
        """Depth step of one 8-bit level, metres."""
        return (self.depth_far_m - self.depth_near_m) / 254.0


@dataclass(frozen=True)
class ForegroundResult:
    """The person's foreground in one frame.

    Attributes
    ----------
    mask : (H, W) bool, True = person.
    box : (x0, y0, x1, y1) int pixels of the mask's bounding box, x1/y1 exclusive; None when
        nothing was found.
    depth_m : median depth of the person's pixels, metres; NaN when nothing was found.
    found : whether a person region was found.
    reason : why nothing was found ('' when found).
    stability : the MSER stability score of the region the person was found in (its area
        growth over `mser_delta` levels further away, relative; smaller = more stable); NaN
        when nothing was found.
    level : the lowest 8-bit level of the person's pixels (the extremal region's threshold,
        or the far end of the depth part cut from it); -1 if none.
    floor : (4,) float64 plane (nx, ny, nz, d), optical frame, n unit and pointing up, so
        that ``n . p + d`` is the height of point p above the floor (metres); None if no floor
        was found.
    """

    mask: NDArray[np.bool_]
    box: tuple[int, int, int, int] | None = None
    depth_m: float = math.nan
    found: bool = False
    reason: str = REASON_OK
    stability: float = math.nan
    level: int = -1
    floor: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def area_px(self) -> int:
        """Number of person pixels."""
        return int(np.count_nonzero(self.mask))


def _not_found(shape: tuple[int, ...], reason: str,
               floor: NDArray[np.float64] | None = None) -> ForegroundResult:
    return ForegroundResult(mask=np.zeros(shape, dtype=bool), found=False, reason=reason,
                            floor=floor)


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
              config: ForegroundConfig = ForegroundConfig(),
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
    if np.count_nonzero(ok) < max(config.floor_min_inliers, 3):
        return None
    z = sub[ok].astype(np.float64)
    rr, cc = np.nonzero(ok)
    x = rx[0, cc * step] * z
    y = ry[r0 + rr * step, 0] * z
    pts = np.stack([x, y, z], axis=1)
    n_pts = len(pts)
    # Kinect v1 depth error grows with z^2 (disparity quantisation)
    tol = config.floor_inlier_m * np.maximum(z, 1.0) ** 2

    idx = _ransac_draws(config.seed, n_pts, config.floor_iterations)
    p0, p1, p2 = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    norm = np.linalg.norm(normal, axis=1)
    good = norm > 1e-9
    normal = normal[good] / norm[good, None]
    p0 = p0[good]
    normal *= np.where(normal[:, 1] > 0, -1.0, 1.0)[:, None]  # point up (optical -y)
    d = -np.einsum('ij,ij->i', normal, p0)
    if previous is not None:
        prev = np.asarray(previous, dtype=np.float64).reshape(4)
        if np.all(np.isfinite(prev)):
            normal = np.vstack([normal, prev[:3]])
            d = np.append(d, prev[3])
    cos_tilt = math.cos(math.radians(config.floor_max_tilt_deg))
    plausible = ((-normal[:, 1] >= cos_tilt) & (d >= config.floor_min_height_m)
                 & (d <= config.floor_max_height_m))
    if not plausible.any():
        return None
    normal, d = normal[plausible], d[plausible]
    dist = np.abs(pts @ normal.T + d[None, :])
    counts = np.count_nonzero(dist < tol[:, None], axis=0)
    best = int(np.argmax(counts))
    if counts[best] < config.floor_min_inliers:
        return None
    plane = np.append(normal[best], d[best])
    for _ in range(2):  # least-squares refinement on the inliers
        inl = np.abs(pts @ plane[:3] + plane[3]) < tol
        if np.count_nonzero(inl) < 3:
            break
        # weighted total least squares, weights 1 / sigma^2 with sigma ~ z^2
        q = pts[inl]
        wt = 1.0 / np.maximum(q[:, 2], 1.0) ** 4
        c = (wt @ q) / wt.sum()
        qc = q - c
        # the normal: the weighted scatter's eigenvector of the smallest eigenvalue
        _, vecs = np.linalg.eigh((qc * wt[:, None]).T @ qc)
        n = vecs[:, 0] * (-1.0 if vecs[1, 0] > 0 else 1.0)
        if -n[1] < cos_tilt:
            break
        plane = np.append(n, -float(n @ c))
    return plane


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
    rx, ry = _rays(intrinsics)
    n = np.asarray(plane, dtype=np.float32)
    along = n[0] * rx + n[1] * ry + n[2]  # n . ray, (H, W) by broadcasting
    return depth_m * along + n[3]


def depth_to_levels(depth_m: NDArray[np.floating], *,
                    config: ForegroundConfig = ForegroundConfig(),
                    drop: NDArray[np.bool_] | None = None) -> NDArray[np.uint8]:
    """Depth as the 8-bit image MSER runs on: near bright, no reading 0.

    Parameters
    ----------
    depth_m : (H, W) float metres, NaN = no reading.
    config : uses `depth_near_m`, `depth_far_m`.
    drop : (H, W) bool, pixels to set to 0 (e.g. the floor).

    Returns
    -------
    (H, W) uint8: ``255 - round(254 (z - near) / (far - near))`` for z in [near, far], else 0.
    """
    scale = np.float32(254.0 / (config.depth_far_m - config.depth_near_m))
    with np.errstate(invalid='ignore'):
        g = np.float32(255.5) - (depth_m - np.float32(config.depth_near_m)) * scale
        valid = (g >= 1.0) & (g < 256.0)
    if drop is not None:
        valid &= ~drop
    return np.where(valid, g, 0).astype(np.uint8)


def _complete(mask: NDArray[np.bool_], no_reading: NDArray[np.bool_],
              box: tuple[int, int, int, int], config: ForegroundConfig) -> None:
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


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Intersection over union of two boxes."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return inter / float((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


# ------------------------------------------------------------------------------------------
# Component tree of the upper level sets {g >= t} (union-find, Najman & Couprie 2006)
# ------------------------------------------------------------------------------------------

@njit(cache=True)
def _find(parent: NDArray[np.int32], p: int) -> int:
    while parent[p] != p:
        parent[p] = parent[parent[p]]  # path halving
        p = parent[p]
    return p


@njit(cache=True)
def _component_tree(g: NDArray[np.uint8], conn8: bool, pix: NDArray[np.int32],
                    nodes: NDArray[np.int32], pend: NDArray[np.int32]) -> tuple:
    """Every extremal region of `g` (components of ``{g >= t}``, t = 255..1) as tree nodes.

    A node is recorded for each component at each level at which it gains pixels; its parent
    is the node that holds it at the next lower level at which that component changes. Nodes
    come out in order of decreasing level, so a parent's index is larger than its children's.
    Pixels at level 0 (no reading, floor) belong to no region.

    `pix` (10, (H + 2) (W + 2)), `nodes` (10, H W) and `pend` (H W,) int32 are workspaces
    (`_workspace`); the returned arrays are views into `nodes`.

    Returns
    -------
    level, size, x0, y0, x1, y1 (box, x1/y1 exclusive), gsum (sum of the levels of its
    pixels), seed (flat index into `g` of one of its pixels), parent (-1 for a top node);
    each (M,) int32.
    """
    h, w = g.shape
    # a border of level-0 pixels spares the bounds checks
    wp = w + 2
    counts = np.zeros(256, np.int64)
    for y in range(h):
        for x in range(w):
            counts[g[y, x]] += 1
    start = np.zeros(256, np.int64)
    pos = 0
    for lv in range(255, 0, -1):
        start[lv] = pos
        pos += counts[lv]
    m = pos
    order = np.empty(m, np.int32)
    fill = start.copy()
    for y in range(h):
        for x in range(w):
            lv = g[y, x]
            if lv > 0:
                order[fill[lv]] = (y + 1) * wp + x + 1
                fill[lv] += 1

    # workspace rows, reused between calls (fresh pages cost more than the whole tree)
    parent, size, bx0, by0, bx1, by1, gs, last, stamp, newnode = pix
    parent[:] = -1
    stamp[:] = 0
    n_level, n_size, n_x0, n_y0, n_x1, n_y1, n_gsum, n_seed, n_parent, pend_node = nodes
    pend_root = pend
    if conn8:
        offsets = np.array([-wp - 1, -wp, -wp + 1, -1, 1, wp - 1, wp, wp + 1])
    else:
        offsets = np.array([-wp, -1, 1, wp])
    nn = 0
    for lv in range(255, 0, -1):
        s = start[lv]
        e = s + counts[lv]
        if s == e:
            continue
        npend = 0
        for k in range(s, e):
            p = order[k]
            y = p // wp - 1
            x = p - (y + 1) * wp - 1
            parent[p] = p
            size[p] = 1
            bx0[p] = x
            by0[p] = y
            bx1[p] = x + 1
            by1[p] = y + 1
            gs[p] = lv
            last[p] = -1
            newnode[p] = -1
            rp = p
            for off in offsets:
                q = p + off
                if parent[q] < 0:
                    continue
                rq = _find(parent, q)
                if rq == rp:
                    continue
                if size[rp] < size[rq]:
                    rp, rq = rq, rp
                parent[rq] = rp
                size[rp] += size[rq]
                bx0[rp] = min(bx0[rp], bx0[rq])
                by0[rp] = min(by0[rp], by0[rq])
                bx1[rp] = max(bx1[rp], bx1[rq])
                by1[rp] = max(by1[rp], by1[rq])
                gs[rp] += gs[rq]
                if last[rq] >= 0:  # the loser's history hangs under the merged node
                    pend_node[npend] = last[rq]
                    pend_root[npend] = rp
                    npend += 1
                    last[rq] = -1
        for k in range(s, e):
            r = _find(parent, order[k])
            if stamp[r] == lv:
                continue
            stamp[r] = lv
            n_level[nn] = lv
            n_size[nn] = size[r]
            n_x0[nn] = bx0[r]
            n_y0[nn] = by0[r]
            n_x1[nn] = bx1[r]
            n_y1[nn] = by1[r]
            n_gsum[nn] = gs[r]
            ry = r // wp - 1
            n_seed[nn] = ry * w + (r - (ry + 1) * wp - 1)
            n_parent[nn] = -1
            if last[r] >= 0:
                n_parent[last[r]] = nn
            last[r] = nn
            newnode[r] = nn
            nn += 1
        for j in range(npend):
            n_parent[pend_node[j]] = newnode[_find(parent, pend_root[j])]
    return (n_level[:nn], n_size[:nn], n_x0[:nn], n_y0[:nn], n_x1[:nn], n_y1[:nn],
            n_gsum[:nn], n_seed[:nn], n_parent[:nn])


_LOCAL = threading.local()


def _tree(g: NDArray[np.uint8], conn8: bool) -> tuple:
    """`_component_tree` with this thread's workspace for the image size."""
    h, w = g.shape
    ws = getattr(_LOCAL, 'workspace', None)
    if ws is None or ws[0] != (h, w):
        ws = ((h, w), np.empty((10, (h + 2) * (w + 2)), np.int32),
              np.empty((10, h * w), np.int32), np.empty(h * w, np.int32))
        _LOCAL.workspace = ws
    return _component_tree(g, conn8, ws[1], ws[2], ws[3])


@njit(cache=True)
def _variation(level: NDArray[np.int32], size: NDArray[np.int32], parent: NDArray[np.int32],
               delta: int, min_size: int) -> NDArray[np.float64]:
    """(|R(t - delta)| - |R(t)|) / |R(t)| per node; NaN for nodes under `min_size` pixels."""
    m = level.shape[0]
    out = np.full(m, np.nan)
    for i in range(m):
        if size[i] < min_size:
            continue
        a = i
        lo = level[i] - delta
        while parent[a] >= 0 and level[parent[a]] >= lo:
            a = parent[a]
        out[i] = (size[a] - size[i]) / size[i]
    return out


def segment(depth_m: NDArray[np.floating], intrinsics: Intrinsics, *,
            config: ForegroundConfig = ForegroundConfig(),
            previous: ForegroundResult | None = None) -> ForegroundResult:
    """Find the person in a depth image (floor removal, MSER, person-size rules).

    Parameters
    ----------
    depth_m : (H, W) float32 metres, NaN (or 0) = no reading, optical frame; uint16
        millimetres (0 = no reading) is accepted too.
    intrinsics : the depth camera, same size as `depth_m`.
    config : parameters (module docstring).
    previous : the result of the previous frame, optional: its floor plane is tried as a
        RANSAC hypothesis and regions overlapping its box are preferred.

    Returns
    -------
    ForegroundResult. When no person is found, ``found`` is False, the mask is empty and
    ``reason`` says why (image too small, no valid depth, no stable region, no region of
    person size).

    Raises
    ------
    ValueError : `depth_m` is not 2-D, or its size differs from the intrinsics'.
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2:
        raise ValueError(f'depth image must be 2-D, got shape {depth.shape}')
    h, w = depth.shape
    if h < 8 or w < 8:
        return _not_found((h, w), REASON_TOO_SMALL)
    if (intrinsics.width, intrinsics.height) != (w, h):
        raise ValueError(f'depth image is {w}x{h} but the intrinsics are '
                         f'{intrinsics.width}x{intrinsics.height}')
    f = max(h // config.working_height_px, 1)
    if f > 1:
        return _subsampled_segment(depth, intrinsics, f, config, previous)
    depth = depth_to_metres(depth)  # new float32 array: inputs are never touched
    valid = np.isfinite(depth)
    if not valid.any():
        return _not_found((h, w), REASON_NO_DEPTH)

    floor, parts, reason = _examine(depth, intrinsics, config, previous)
    if not parts:
        return _not_found((h, w), reason, floor)
    prev_box = previous.box if previous is not None and previous.found else None
    scores = [part_score(pt, config, prev_box) for pt in parts]
    ok = [k for k, pt in enumerate(parts) if person_rules(pt, config)]
    if not ok:  # a person too near to be seen whole, only when no whole one is in view
        ok = [k for k, pt in enumerate(parts) if person_rules(pt, config, near=True)]
    if not ok:
        return _not_found((h, w), REASON_NO_PERSON, floor)
    best = parts[max(ok, key=lambda k: scores[k])]
    mask = np.zeros((h, w), dtype=bool)
    x0, y0 = best.origin
    mask[y0:y0 + best.crop.shape[0], x0:x0 + best.crop.shape[1]] = best.crop
    _complete(mask, ~valid, best.box, config)
    zr = depth[mask]
    zr = zr[np.isfinite(zr)]
    return ForegroundResult(mask=mask, box=best.box, depth_m=median(zr), found=True,
                            reason=REASON_OK, stability=best.variation, level=best.lo,
                            floor=floor)


def _subsampled_segment(depth: NDArray, intrinsics: Intrinsics, f: int,
                        config: ForegroundConfig, previous: ForegroundResult | None
                        ) -> ForegroundResult:
    """`segment` on every f-th pixel of every f-th row, its mask brought back to full size
    (each pixel takes the value of the one it was represented by)."""
    h, w = depth.shape
    small = np.ascontiguousarray(depth[::f, ::f])
    k = intrinsics
    small_k = Intrinsics(k.fx / f, k.fy / f, k.cx / f, k.cy / f, small.shape[1], small.shape[0])
    if previous is not None and previous.box is not None:
        x0, y0, x1, y1 = previous.box
        previous = replace(previous, box=(x0 // f, y0 // f, -(-x1 // f), -(-y1 // f)))
    out = segment(small, small_k, config=config, previous=previous)
    if not out.found:
        return replace(out, mask=np.zeros((h, w), bool))
    floor = np.full(4, np.nan) if out.floor is None else out.floor
    depth = np.asarray(depth)
    mask = _upsample_mask(out.mask, depth_to_metres(small), depth,
                          0.001 if depth.dtype == np.uint16 else 1.0, f,
                          np.array([k.fx, k.fy, k.cx, k.cy]), floor,
                          config.floor_tolerance_m, config.mser_delta * config.metres_per_level)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    box = (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)
    return replace(out, mask=mask, box=box)


@njit(cache=True)
def _upsample_mask(small_mask: NDArray[np.bool_], small_depth: NDArray[np.float32],
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


@dataclass(frozen=True)
class Part:
    """A depth part of a stable region: a candidate person (internal; for tuning).

    crop : (h, w) bool pixels over the part's region box, whose top-left pixel is `origin`.
    box : (x0, y0, x1, y1) of the part, x1/y1 exclusive. lo, hi : its 8-bit level range.
    n : pixels; z : median depth, m; height_m, width_m : box size at depth z; area_m2 :
    surface seen from the camera; fill : n over box area; variation : the region's MSER
    variation; side : touches the left or right image border; cut : touches the bottom one
    (a person too near to be seen whole); top_m, bottom_m : height
    above the floor of its top and bottom rows (NaN without a floor); extent_m : depth
    between its 5th and 95th percentiles.
    """

    crop: NDArray[np.bool_] = field(repr=False)
    origin: tuple[int, int]
    box: tuple[int, int, int, int]
    lo: int
    hi: int
    n: int
    z: float
    height_m: float
    width_m: float
    area_m2: float
    fill: float
    variation: float
    side: bool
    cut: bool
    top_m: float
    bottom_m: float
    extent_m: float


def _examine(depth: NDArray[np.float32], intrinsics: Intrinsics, config: ForegroundConfig,
             previous: ForegroundResult | None
             ) -> tuple[NDArray[np.float64] | None, list[Part], str]:
    """Floor, stable regions and their depth parts (the candidates `segment` chooses from).

    Returns the floor plane (or None), the parts, and the reason when there are none.
    """
    h, w = depth.shape
    floor = None
    drop = None
    above = None
    if config.floor_remove:
        floor = fit_floor(depth, intrinsics, config=config,
                          previous=None if previous is None else previous.floor)
        if floor is not None:
            above = floor_height(depth, intrinsics, floor)
            with np.errstate(invalid='ignore'):
                drop = above < config.floor_tolerance_m
    g = depth_to_levels(depth, config=config, drop=drop)

    # the tree on every `tree_step`-th pixel (a person is ~100 px tall even at the
    # subsampled resolution); the chosen regions are then traced at full resolution
    st = config.tree_step
    gs = g if st == 1 else np.ascontiguousarray(g[::st, ::st])
    level, size, x0, y0, x1, y1, gsum, seed, parent = _tree(gs, config.connectivity == 8)
    var = _variation(level, size, parent, config.mser_delta,
                     max(config.mser_min_area_px // (st * st), 1))
    area_px = size.astype(np.float64) * (st * st)
    with np.errstate(invalid='ignore'):
        stable = (var <= config.mser_max_variation) & (area_px <= config.max_region_area_px)
    cand = np.flatnonzero(stable)
    if cand.size == 0:
        return floor, [], REASON_NO_REGION

    # Stage 1, on the tree's statistics (box, mean depth): a region may still hold an occluder
    # or a piece of furniture besides the person, so only the person's lower size bounds
    # apply, and the upper ones with `merge_slack`.
    z = config.depth_near_m + (255.0 - gsum[cand] / size[cand]) * config.metres_per_level
    height_m = (y1[cand] - y0[cand]) * st * z / intrinsics.fy
    width_m = (x1[cand] - x0[cand]) * st * z / intrinsics.fx
    area_m2 = area_px[cand] * z * z / (intrinsics.fx * intrinsics.fy)
    slack = config.merge_slack
    # a region cut by the bottom edge may be a person too near to be seen whole, whose
    # lower bounds are smaller; such regions come after every other (see `segment`)
    whole_size = ((height_m >= config.person_min_height_m)
                  & (area_m2 >= config.person_min_area_m2))
    near = ((y1[cand] == gs.shape[0]) & (height_m >= config.person_min_cut_height_m)
            & (area_m2 >= config.min_cut_area_m2))
    ok = ((whole_size | near) & (width_m >= config.person_min_width_m)
          & (height_m <= slack * config.person_max_height_m)
          & (width_m <= slack * config.person_max_width_m)
          & (area_m2 <= slack * config.person_max_area_m2))
    # regions within the strict bounds first: an isolated person is one, and big merged
    # regions (a room's worth of furniture) must not take all the places
    strict = ((height_m <= config.person_max_height_m) & (width_m <= config.person_max_width_m)
              & (area_m2 <= config.person_max_area_m2))[ok]
    only_near = ~whole_size[ok]
    cand = cand[ok]
    if cand.size == 0:
        return floor, [], REASON_NO_PERSON
    side = (x0[cand] == 0) | (x1[cand] == gs.shape[1])
    score = (np.log(area_px[cand]) - config.stability_weight * var[cand]
             - config.border_penalty * side + 1000.0 * strict)
    rank = np.argsort(-score, kind='stable')
    # the best few regions that may hold a whole person, and the best few near ones
    order = np.concatenate([_distinct(cand[rank[only_near[rank] == near]], x0, y0, x1, y1, size,
                                      config.max_candidates) for near in (False, True)])

    # Stage 2, on the full-resolution pixels of the best few regions: split each at empty
    # depth gaps (an occluder in front, furniture behind); every part is a candidate.
    parts = []
    gap_levels = config.occluder_gap_m / config.metres_per_level
    extent_levels = config.person_max_extent_m / config.metres_per_level
    ws = gs.shape[1]
    for i in order.tolist():
        sy, sx = divmod(int(seed[i]), ws)
        crop, bx = _region(g, int(level[i]), (sy * st, sx * st), config.connectivity)
        gl = g[bx[1]:bx[3], bx[0]:bx[2]]
        hl = None if above is None else above[bx[1]:bx[3], bx[0]:bx[2]]
        hist = np.bincount(gl[crop], minlength=256)
        present = np.flatnonzero(hist)
        for lo, hi in _depth_parts(hist, gap_levels):
            ranges = [(lo, hi)]
            if _extent_levels(hist[lo:hi + 1]) > extent_levels:
                # too deep for one person, but no empty gap: an occluder whose top surface
                # recedes towards the person (a table); split at Otsu's threshold
                cut = lo + _otsu(hist[lo:hi + 1])
                ranges += [(lo, cut), (cut + 1, hi)]
            for a, b in ranges:
                whole = a <= present[0] and b >= present[-1]
                part = crop if whole else crop & (gl >= a) & (gl <= b)
                pt = _describe(part, hist[a:b + 1], a, b, bx, float(var[i]), hl, intrinsics,
                               (w, h), config)
                if pt is not None:
                    parts.append(pt)
    return floor, parts, REASON_NO_PERSON


def _distinct(order: NDArray[np.int64], x0: NDArray, y0: NDArray, x1: NDArray, y1: NDArray,
              size: NDArray, n: int) -> NDArray[np.int64]:
    """The first `n` regions of `order` (best first) that are not nested copies of one picked
    before: the regions of one chain are often the same pixels at several levels."""
    picked: list[int] = []
    for i in order[:8 * n].tolist():
        if any(_overlap((x0[i], y0[i], x1[i], y1[i]), (x0[j], y0[j], x1[j], y1[j])) > 0.9
               and min(size[i], size[j]) > 0.9 * max(size[i], size[j]) for j in picked):
            continue
        picked.append(i)
        if len(picked) == n:
            break
    return np.array(picked, np.int64)


def _describe(part: NDArray[np.bool_], hist: NDArray[np.int64], lo: int, hi: int,
              origin: tuple[int, int, int, int], var: float, above: NDArray[np.float32] | None,
              intrinsics: Intrinsics, size: tuple[int, int], config: ForegroundConfig
              ) -> Part | None:
    """Measure one depth part; None when it is too small to be anything."""
    n = int(hist.sum())
    if n < config.mser_min_area_px:
        return None
    # median level -> depth; level l is at depth near + (255 - l) * metres_per_level
    med = lo + int(np.searchsorted(np.cumsum(hist), (n + 1) // 2))
    z = config.depth_near_m + (255.0 - med) * config.metres_per_level
    rows = np.flatnonzero(part.any(axis=1))
    cols = np.flatnonzero(part.any(axis=0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    bh, bw = r1 - r0, c1 - c0
    box = (origin[0] + c0, origin[1] + r0, origin[0] + c1, origin[1] + r1)
    cut = box[3] == size[1]
    height_m, width_m = bh * z / intrinsics.fy, bw * z / intrinsics.fx
    area, fill = n * z * z / (intrinsics.fx * intrinsics.fy), n / (bh * bw)
    extent = _extent_levels(hist) * config.metres_per_level
    top = bottom = math.nan
    # the heights above the floor decide only among parts of a person's size
    if above is not None and size_rules(height_m, width_m, area, fill, extent, cut, config):
        k = config.edge_rows
        t = above[r0:r0 + k][part[r0:r0 + k]]
        b = above[max(r1 - k, 0):r1][part[max(r1 - k, 0):r1]]
        top, bottom = median(t[np.isfinite(t)]), median(b[np.isfinite(b)])
    return Part(crop=part, origin=(origin[0], origin[1]), box=box, lo=lo, hi=hi, n=n, z=z,
                height_m=height_m, width_m=width_m, area_m2=area, fill=fill, variation=var,
                side=box[0] == 0 or box[2] == size[0], cut=cut, top_m=top, bottom_m=bottom,
                extent_m=extent)


def size_rules(height_m: float, width_m: float, area_m2: float, fill: float, extent_m: float,
               cut: bool, config: ForegroundConfig) -> bool:
    """Whether a part has a person's height, width, surface, fill and depth extent (`cut`:
    the smaller height and surface of a person cut by the image's bottom edge)."""
    c = config
    min_height = c.person_min_cut_height_m if cut else c.person_min_height_m
    min_area = c.min_cut_area_m2 if cut else c.person_min_area_m2
    return (min_height <= height_m <= c.person_max_height_m
            and c.person_min_width_m <= width_m <= c.person_max_width_m
            and min_area <= area_m2 <= c.person_max_area_m2
            and fill <= c.person_max_fill and extent_m <= c.person_max_extent_m)


def person_rules(part: Part, config: ForegroundConfig, near: bool = False) -> bool:
    """Whether a part passes the person-size rules of `config` (tops and bottoms only when
    the floor is known); `near`: the rules of a person cut by the image's bottom edge
    (`ForegroundConfig.person_min_cut_height_m`), which only such a part can pass."""
    c = config
    if near and not part.cut:
        return False
    if not size_rules(part.height_m, part.width_m, part.area_m2, part.fill, part.extent_m,
                      near, c):
        return False
    if math.isfinite(part.top_m) and not c.person_min_top_m <= part.top_m <= c.person_max_top_m:
        return False
    if not near and math.isfinite(part.bottom_m) and part.bottom_m > c.person_max_bottom_m:
        return False
    return True


def part_score(part: Part, config: ForegroundConfig,
               prev_box: tuple[int, int, int, int] | None = None) -> float:
    """``log(area) - stability_weight * variation - border_penalty * touches_side``
    (+ `previous_bonus` when the part's box overlaps `prev_box`).

    Stable beats large: an object standing free is stable over many levels (variation ~ 0),
    a slanted wall grows steadily; among equally stable nested regions the largest is the
    whole person rather than a part of it. A region cut by the left or right image border is
    more often furniture or a wall than a person (the camera is aimed at the person).
    """
    score = (math.log(part.n) - config.stability_weight * part.variation
             - config.border_penalty * part.side)
    if prev_box is not None and _overlap(prev_box, part.box) > 0.3:
        score += config.previous_bonus
    return score


def _extent_levels(hist: NDArray[np.int64]) -> int:
    """Levels between the 5th and 95th percentiles of a histogram."""
    cum = np.cumsum(hist)
    n = cum[-1]
    return int(np.searchsorted(cum, 0.95 * n) - np.searchsorted(cum, 0.05 * n))


def _otsu(hist: NDArray[np.int64]) -> int:
    """Otsu's threshold of a histogram: the last bin of the lower class."""
    p = hist.astype(np.float64)
    k = np.arange(p.size)
    w0 = np.cumsum(p)[:-1]
    w1 = p.sum() - w0
    m0 = np.cumsum(p * k)[:-1]
    m1 = (p * k).sum() - m0
    with np.errstate(invalid='ignore', divide='ignore'):
        between = w0 * w1 * (m0 / w0 - m1 / w1) ** 2
    return int(np.nanargmax(between)) if np.isfinite(between).any() else p.size // 2


def _depth_parts(hist: NDArray[np.int64], gap_levels: float) -> list[tuple[int, int]]:
    """Level ranges [lo, hi] of a region's histogram separated by more than `gap_levels`
    empty levels (all of it when `gap_levels` is 0)."""
    levels = np.flatnonzero(hist)
    if levels.size == 0:
        return []
    if gap_levels <= 0:
        return [(int(levels[0]), int(levels[-1]))]
    cuts = np.flatnonzero(np.diff(levels) > gap_levels).tolist()
    lv = levels.tolist()
    starts = [lv[0]] + [lv[i + 1] for i in cuts]
    ends = [lv[i] for i in cuts] + [lv[-1]]
    return list(zip(starts, ends, strict=True))


def _region(g: NDArray[np.uint8], level: int, seed: tuple[int, int], connectivity: int
            ) -> tuple[NDArray[np.bool_], tuple[int, int, int, int]]:
    """The connected component of ``{g >= level}`` holding pixel `seed` (row, column).

    Returns the component as a bool array over its bounding box, and the box (x0, y0, x1,
    y1), x1/y1 exclusive.
    """
    h, w = g.shape
    ff = np.zeros((h + 2, w + 2), np.uint8)
    sy, sx = seed
    flags = connectivity | cv2.FLOODFILL_FIXED_RANGE | cv2.FLOODFILL_MASK_ONLY | (1 << 8)
    _, _, _, (rx, ry, rw, rh) = cv2.floodFill(g, ff, (sx, sy), 0,
                                              loDiff=int(g[sy, sx]) - level, upDiff=255,
                                              flags=flags)
    return ff[ry + 1:ry + rh + 1, rx + 1:rx + rw + 1] > 0, (rx, ry, rx + rw, ry + rh)


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
        return _not_found(mask.shape, REASON_NO_PERSON)
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
    # outside the mask's box nothing is read: zeros and NaN are written at memory speed
    color_masked = np.zeros(color.shape, color.dtype)
    depth_masked = np.full(mask.shape, np.nan, np.float32)
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size:
        cols = np.flatnonzero(mask.any(axis=0))
        box = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
        inner = color_masked[box]
        _blank_outside(color[box].reshape(*inner.shape[:2], -1),
                       inner.reshape(*inner.shape[:2], -1), depth[box], depth_masked[box],
                       mask[box], 0.001 if depth.dtype == np.uint16 else 1.0, MAX_DEPTH_M)
    return color_masked, depth_masked


@njit(cache=True)
def _blank_outside(color: NDArray[np.uint8], out: NDArray[np.uint8], depth: NDArray,
                   out_depth: NDArray[np.float32], mask: NDArray[np.bool_], scale: float,
                   max_m: float) -> None:
    """`apply_mask` inside the mask's box, in one pass: `out` = `color` inside the mask (it is
    0 elsewhere already); `out_depth` = the depth in metres (`depth` times `scale`) inside the
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
