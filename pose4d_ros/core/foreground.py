"""Person foreground from the depth image: floor removal and MSER (first stage of the paper).

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", section 3 (foreground extraction): maximally
stable extremal regions (MSER, Matas et al. 2002) are found on the depth image, regions larger
than a trained area threshold are background (walls, floor), and the person's region masks the
colour and depth images before the part detector runs.

Steps of `segment` (one depth frame, float32 metres, NaN = no reading):

1. Floor plane. RANSAC on the 3-D points of the lower part of the image: planes through three
   points whose normal is within `floor_max_tilt_deg` of the optical "up" (-y) and that pass
   `floor_min_height_m`-`floor_max_height_m` below the camera; the plane with most inliers is
   refined by least squares. Pixels less than `floor_tolerance_m` above it are dropped. Without
   this, the floor in front of the person is nearer than the person and joins the feet in
   every depth threshold, so the person's region leaks into the floor.
2. 8-bit depth. Depth in [`depth_near_m`, `depth_far_m`] maps linearly to 255..1 (near is
   bright); no reading, floor and out-of-range pixels are 0. A connected component of
   ``{g >= t}`` is then the set of connected pixels nearer than the depth of level t.
3. MSER (OpenCV, bright regions only). A region R(t) is kept when its area variation
   ``(|R(t - delta)| - |R(t + delta)|) / |R(t)|`` is below `mser_max_variation` (the paper's
   stability score) and its area is within [`mser_min_area_px`, `max_region_area_px`]; regions
   larger than `max_region_area_px` (trained) are background.
4. Person rules. A region's metric size comes from its box and median depth with the
   intrinsics: height ``h_px z / fy`` and width ``w_px z / fx`` must be in the configured
   ranges. Of the regions that pass, the largest wins (regions are nested, so this is the
   whole person rather than a part of it); with `previous`, regions overlapping the previous
   box are preferred.
5. Clean-up. Pixels much nearer than the person (an occluder in front: a gap of more than
   `occluder_gap_m` in the region's depth histogram) are cut off; holes inside the mask that
   have no reading (Kinect dropouts) are filled.

Defaults were tuned on the synthetic training set (UTKinect subjects s01-s06 rendered in random
rooms, `pose4d synth`, 1536 frames) by a coordinate search maximising the mean mask IoU against
the rendered person masks; the test set (s07-s08, unseen bodies and rooms) was not used for
tuning. The tuning script is kept with the project notes (``foreground_tune.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, depth_to_metres

# Reasons given when no person is found.
REASON_OK = ''
REASON_TOO_SMALL = 'image too small'
REASON_NO_DEPTH = 'no valid depth'
REASON_NO_REGION = 'no stable region'
REASON_NO_PERSON = 'no region of person size'


@dataclass(frozen=True)
class ForegroundConfig:
    """Parameters of `segment`; defaults tuned on the synthetic training set (module docstring).

    Attributes
    ----------
    depth_near_m, depth_far_m : depth range mapped to the 8-bit image, metres (near -> 255,
        far -> 1, everything else 0).
    mser_delta : MSER stability step, 8-bit levels (one level = (far - near) / 254 metres).
    mser_min_area_px : smallest region, pixels (at the input resolution).
    max_region_area_px : the trained background area threshold: larger regions are background.
        It is also the largest region MSER reports.
    mser_max_variation : the paper's stability score: largest relative area change over
        +-delta levels for a region to be stable.
    mser_min_diversity : OpenCV's pruning of nested regions of almost the same size (0 = keep
        all).
    person_min_height_m, person_max_height_m : height of a person region, metres (box height
        times median depth over fy).
    person_min_width_m, person_max_width_m : width, metres (box width times depth over fx).
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
    fill_holes : fill holes of the mask that have no depth reading.
    previous_bonus : with `previous`, score multiplier for a region whose box overlaps the
        previous box (1 = no temporal preference).
    seed : RANSAC random seed (the result is a function of the input).
    """

    depth_near_m: float = 0.4
    depth_far_m: float = 5.0
    mser_delta: int = 4
    mser_min_area_px: int = 60
    max_region_area_px: int = 30000
    mser_max_variation: float = 0.5
    mser_min_diversity: float = 0.1
    person_min_height_m: float = 0.6
    person_max_height_m: float = 2.3
    person_min_width_m: float = 0.15
    person_max_width_m: float = 2.0
    floor_remove: bool = True
    floor_rows_fraction: float = 0.5
    floor_sample_step: int = 4
    floor_iterations: int = 64
    floor_inlier_m: float = 0.004
    floor_tolerance_m: float = 0.05
    floor_max_tilt_deg: float = 30.0
    floor_min_height_m: float = 0.3
    floor_max_height_m: float = 3.0
    floor_min_inliers: int = 40
    occluder_gap_m: float = 0.3
    fill_holes: bool = True
    previous_bonus: float = 1.5
    seed: int = 0

    def __post_init__(self) -> None:
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
        if not 0.0 <= self.mser_min_diversity < 1.0:
            raise ValueError(f'mser_min_diversity must be in [0, 1), got '
                             f'{self.mser_min_diversity}')
        for lo, hi in (('person_min_height_m', 'person_max_height_m'),
                       ('person_min_width_m', 'person_max_width_m'),
                       ('floor_min_height_m', 'floor_max_height_m')):
            a, b = getattr(self, lo), getattr(self, hi)
            if not 0.0 <= a < b:
                raise ValueError(f'need 0 <= {lo} < {hi}, got {lo}={a}, {hi}={b}')
        if not 0.0 < self.floor_rows_fraction <= 1.0:
            raise ValueError(f'floor_rows_fraction must be in (0, 1], got '
                             f'{self.floor_rows_fraction}')
        for name in ('floor_sample_step', 'floor_iterations', 'floor_min_inliers'):
            if getattr(self, name) < 1:
                raise ValueError(f'{name} must be >= 1, got {getattr(self, name)}')
        for name in ('floor_inlier_m', 'floor_tolerance_m'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')
        if not 0.0 < self.floor_max_tilt_deg < 90.0:
            raise ValueError(f'floor_max_tilt_deg must be in (0, 90), got '
                             f'{self.floor_max_tilt_deg}')
        if not self.occluder_gap_m >= 0:
            raise ValueError(f'occluder_gap_m must be >= 0, got {self.occluder_gap_m}')
        if not self.previous_bonus >= 1.0:
            raise ValueError(f'previous_bonus must be >= 1, got {self.previous_bonus}')

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
    stability : the chosen region's MSER area variation over +-delta levels (smaller = more
        stable); NaN when nothing was found.
    level : the 8-bit threshold of the chosen region (its pixels have g >= level); -1 if none.
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

    rng = np.random.default_rng(config.seed)
    idx = rng.integers(0, n_pts, size=(config.floor_iterations, 3))
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
        q = pts[inl]
        c = q.mean(axis=0)
        _, _, vt = np.linalg.svd(q - c, full_matrices=False)
        n = vt[2] * (-1.0 if vt[2][1] > 0 else 1.0)
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


def _mser(config: ForegroundConfig, max_area: int) -> cv2.MSER:
    mser = cv2.MSER_create(delta=config.mser_delta, min_area=config.mser_min_area_px,
                           max_area=max_area, max_variation=config.mser_max_variation,
                           min_diversity=config.mser_min_diversity)
    mser.setPass2Only(True)  # bright regions only: near objects in our encoding
    return mser


def _split_occluder(z: NDArray[np.float32], gap_m: float) -> float:
    """Depth above which the region's far cluster starts, or -inf when no gap.

    z : (N,) depths of the region's pixels (finite). A gap is a run of empty histogram bins
    at least `gap_m` wide; the far side of the farthest gap is kept.
    """
    if gap_m <= 0 or z.size < 2:
        return -math.inf
    zs = np.sort(z)
    gaps = np.diff(zs)
    big = np.flatnonzero(gaps > gap_m)
    if big.size == 0:
        return -math.inf
    k = int(big[-1])
    return float(zs[k] + zs[k + 1]) * 0.5


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


def _box_of(mask: NDArray[np.bool_]) -> tuple[int, int, int, int] | None:
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Intersection over union of two boxes."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return inter / float((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


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
    depth = depth_to_metres(depth)  # new float32 array: inputs are never touched
    valid = np.isfinite(depth)
    if not valid.any():
        return _not_found((h, w), REASON_NO_DEPTH)

    floor = None
    drop = None
    if config.floor_remove:
        floor = fit_floor(depth, intrinsics, config=config,
                          previous=None if previous is None else previous.floor)
        if floor is not None:
            with np.errstate(invalid='ignore'):
                drop = floor_height(depth, intrinsics, floor) < config.floor_tolerance_m
    g = depth_to_levels(depth, config=config, drop=drop)

    max_area = min(config.max_region_area_px, h * w - 1)
    if config.mser_min_area_px >= max_area:
        return _not_found((h, w), REASON_TOO_SMALL, floor)
    regions, boxes = _mser(config, max_area).detectRegions(g)
    if len(regions) == 0:
        return _not_found((h, w), REASON_NO_REGION, floor)

    near, mpl = config.depth_near_m, config.metres_per_level
    prev_box = previous.box if previous is not None and previous.found else None
    best, best_score = -1, 0.0
    for i, (pts, (bx, by, bw, bh)) in enumerate(zip(regions, boxes, strict=True)):
        area = len(pts)
        levels = g[pts[:, 1], pts[:, 0]]
        z = near + (255.0 - float(np.median(levels))) * mpl
        height_m = bh * z / intrinsics.fy
        width_m = bw * z / intrinsics.fx
        if not (config.person_min_height_m <= height_m <= config.person_max_height_m
                and config.person_min_width_m <= width_m <= config.person_max_width_m):
            continue
        score = float(area)
        if prev_box is not None and _overlap(prev_box, (bx, by, bx + bw, by + bh)) > 0.3:
            score *= config.previous_bonus
        if score > best_score:
            best, best_score = i, score
    if best < 0:
        return _not_found((h, w), REASON_NO_PERSON, floor)

    pts = regions[best]
    level = int(g[pts[:, 1], pts[:, 0]].min())
    mask = np.zeros((h, w), dtype=bool)
    mask[pts[:, 1], pts[:, 0]] = True
    zr = depth[pts[:, 1], pts[:, 0]]
    cut = _split_occluder(zr, config.occluder_gap_m)
    if cut > -math.inf:
        near_px = zr < cut
        mask[pts[near_px, 1], pts[near_px, 0]] = False
        zr = zr[~near_px]
    box = _box_of(mask)
    if box is None:  # cannot happen: the far cluster is never empty
        return _not_found((h, w), REASON_NO_PERSON, floor)
    if config.fill_holes:
        _fill_holes(mask, ~valid, box)
    stability = _variation(g, mask, level, config.mser_delta)
    return ForegroundResult(mask=mask, box=box, depth_m=float(np.median(zr)), found=True,
                            reason=REASON_OK, stability=stability, level=level, floor=floor)


def _variation(g: NDArray[np.uint8], mask: NDArray[np.bool_], level: int, delta: int) -> float:
    """MSER area variation (|R(t - delta)| - |R(t + delta)|) / |R(t)| of the region in `mask`.

    R(l) is the connected component of ``{g >= l}`` that contains the region's nearest pixel;
    only pixels inside the region's box grown by half its size are counted (enough for a
    ranking; the exact value needs the whole image).
    """
    area = np.count_nonzero(mask)
    if area == 0:
        return math.nan
    seed = np.unravel_index(int(np.argmax(np.where(mask, g, 0))), g.shape)
    sizes = []
    for lv in (level - delta, level + delta):
        if lv <= 0:
            sizes.append(np.count_nonzero(g > 0))
            continue
        n, lab = cv2.connectedComponents((g >= min(lv, 255)).astype(np.uint8), connectivity=8)
        k = lab[seed]
        sizes.append(int(np.count_nonzero(lab == k)) if k > 0 else 0)
    return (sizes[0] - sizes[1]) / float(area)


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
    depth = depth_to_metres(np.asarray(depth_m))
    if depth.shape != mask.shape:
        raise ValueError(f'depth shape {depth.shape} does not match the mask {mask.shape}')
    keep = mask if color.ndim == 2 else mask[..., None]
    color_masked = np.where(keep, color, np.zeros((), color.dtype))
    depth[~mask] = np.nan  # depth_to_metres returned a new array
    return color_masked, depth
