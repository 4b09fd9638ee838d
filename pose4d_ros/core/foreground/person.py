"""The person rules (step 4 of `segment`), in two stages: the stable regions of a person's
size by the tree's statistics (`person_sized`), then each traced at full resolution, split at
empty depth gaps and measured (`depth_parts`); a part passes `person_rules` (height, width,
surface, fill, depth extent and, with a floor, the heights of its top and bottom rows) and the
best `part_score` wins."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.foreground.config import ForegroundConfig, PersonConfig
from pose4d_ros.core.foreground.regions import StableRegions

# Intersection over union with a box of the previous frame's people above which a part may be
# one of them (`part_score`'s bonus, `bent_rules`)
FOLLOW_OVERLAP = 0.3
# How far (a share of that box's height) the top row of a person bending may be from the top
# of their box in the previous frame (`bent_rules`): one bends over several frames, while a
# piece of someone's legs seen below a nearer person does not start where their head was
FOLLOW_TOP = 0.1


@dataclass(frozen=True)
class Part:
    """A depth part of a stable region: a candidate person (internal; for tuning).

    crop : (h, w) bool pixels over the part's region box, whose top-left pixel is `origin`.
    box : (x0, y0, x1, y1) of the part, x1/y1 exclusive. lo, hi : its 8-bit level range.
    n : pixels; z : median depth, m; height_m, width_m : box size at depth z; area_m2 :
    surface seen from the camera; fill : n over box area; variation : the region's MSER
    variation; side : touches the left or right image border; cut : touches the bottom one
    (a person too near to be seen whole; the borders are where the readings end,
    `seen_edges`); top_m, bottom_m : height
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


# A depth image's edge is where its readings end: a depth image registered to the colour
# camera has a band without readings along its borders (lab_walk's Xtion: 12-15 px at the
# top, left and bottom, 26 at the right, of 640x480), then a few rows or columns where the
# readings thin out; a row or column with at least this share of the median row's or column's
# readings is inside the edge
SEEN_SHARE = 0.9


def seen_edges(valid: NDArray[np.bool_]) -> tuple[int, int, int]:
    """Where a depth image's readings end (`valid`: pixels with a reading): the first seen
    column, one past the last seen column, one past the last seen row (`SEEN_SHARE`). A part
    reaching them is cut by the image's side or bottom edge; an image with readings up to its
    borders has (0, width, height)."""
    h, w = valid.shape
    rows, cols = valid.sum(axis=1, dtype=np.int32), valid.sum(axis=0, dtype=np.int32)
    seen_rows = np.flatnonzero(rows >= SEEN_SHARE * np.partition(rows, h // 2)[h // 2])
    seen_cols = np.flatnonzero(cols >= SEEN_SHARE * np.partition(cols, w // 2)[w // 2])
    if seen_rows.size == 0 or seen_cols.size == 0:
        return 0, w, h
    return int(seen_cols[0]), int(seen_cols[-1]) + 1, int(seen_rows[-1]) + 1


def person_sized(regions: StableRegions, intrinsics: Intrinsics, config: ForegroundConfig,
                 boxes: Sequence[tuple[int, int, int, int]],
                 edges: tuple[int, int, int]) -> NDArray[np.int64]:
    """Stage 1 of the person rules, on the tree's statistics (box, mean depth): the stable
    regions worth tracing, best first (none: no region of person size).

    A region may still hold an occluder or a piece of furniture besides the person, so only
    the person's lower size bounds apply, and the upper ones with `merge_slack`. At most
    `max_candidates` regions that may hold a whole person (or a person of the previous frame,
    `boxes`, bending: a cut person's lower bounds, `bent_rules`), then as many cut by the
    bottom edge (`edges`: where the depth image's readings end, `seen_edges`).
    """
    r, st = regions, regions.step
    left, right, bottom = edges
    cand = r.stable
    z = config.depth_near_m + (255.0 - r.gsum[cand] / r.size[cand]) * config.metres_per_level
    height_m = (r.y1[cand] - r.y0[cand]) * st * z / intrinsics.fy
    width_m = (r.x1[cand] - r.x0[cand]) * st * z / intrinsics.fx
    area_m2 = r.area_px[cand] * z * z / (intrinsics.fx * intrinsics.fy)
    slack = config.merge_slack
    # a region cut by the bottom edge may be a person too near to be seen whole, whose
    # lower bounds are smaller; such regions come after every other (see `segment`)
    whole_size = ((height_m >= config.person_min_height_m)
                  & (area_m2 >= config.person_min_area_m2))
    cut_size = (height_m >= config.person_min_cut_height_m) & (area_m2 >= config.min_cut_area_m2)
    near = (r.y1[cand] * st >= bottom) & cut_size
    if boxes and math.isfinite(config.person_min_bent_top_m):
        whole_size |= cut_size & _follows(boxes, r.x0[cand] * st, r.y0[cand] * st,
                                          r.x1[cand] * st, r.y1[cand] * st)
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
        return cand
    side = (r.x0[cand] * st <= left) | (r.x1[cand] * st >= right)
    score = (np.log(r.area_px[cand]) - config.stability_weight * r.variation[cand]
             - config.border_penalty * side + 1000.0 * strict)
    rank = np.argsort(-score, kind='stable')
    # the best few regions that may hold a whole person, and the best few near ones
    return np.concatenate([_distinct(cand[rank[only_near[rank] == near]], r.x0, r.y0, r.x1,
                                     r.y1, r.size, config.max_candidates)
                           for near in (False, True)])


def _follows(boxes: Sequence[tuple[int, int, int, int]], x0: NDArray, y0: NDArray,
             x1: NDArray, y1: NDArray) -> NDArray[np.bool_]:
    """Which of the boxes (x0, y0, x1, y1; arrays) may be a person of `boxes` bending: one
    overlapping it by more than `FOLLOW_OVERLAP` (intersection over union), its top row within
    `FOLLOW_TOP` of that box's height of its top."""
    out = np.zeros(len(x0), bool)
    area = (x1 - x0) * (y1 - y0)
    for a0, b0, a1, b1 in boxes:
        inter = (np.maximum(np.minimum(x1, a1) - np.maximum(x0, a0), 0)
                 * np.maximum(np.minimum(y1, b1) - np.maximum(y0, b0), 0))
        out |= ((inter > FOLLOW_OVERLAP * (area + (a1 - a0) * (b1 - b0) - inter))
                & (np.abs(y0 - b0) <= FOLLOW_TOP * (b1 - b0)))
    return out


def _follows_one(box: tuple[int, int, int, int],
                 boxes: Sequence[tuple[int, int, int, int]]) -> bool:
    """`_follows` for one box (plain arithmetic: a few calls per region and frame)."""
    for b in boxes:
        d = box[1] - b[1]
        if (_overlap(b, box) > FOLLOW_OVERLAP
                and -FOLLOW_TOP * (b[3] - b[1]) <= d <= FOLLOW_TOP * (b[3] - b[1])):
            return True
    return False


def depth_parts(g: NDArray[np.uint8], regions: StableRegions, order: NDArray[np.int64],
                above: NDArray[np.float32] | None, intrinsics: Intrinsics,
                config: ForegroundConfig, *, occluded: bool = False,
                boxes: Sequence[tuple[int, int, int, int]],
                edges: tuple[int, int, int]) -> list[Part]:
    """Stage 2, on the full-resolution pixels of the regions `order` picked: each split at
    empty depth gaps (an occluder in front, furniture behind), and a part deeper than
    `person_max_extent_m` at Otsu's threshold too; every part is a candidate. `occluded`: the
    parts may be people partly hidden by a nearer one (`occluded_rules`), whose top and bottom
    heights are measured from the smaller sizes of a cut person on, as are all when `boxes`
    (the previous frame's people, who may bend: `bent_rules`) are given.

    Each region is traced and its parts measured by one kernel call (`_region_parts`): per
    region, a handful of Python-level calls instead of some seventy small numpy ones."""
    parts = []
    mpl = config.metres_per_level
    gap_levels = config.occluder_gap_m / mpl
    extent_levels = config.person_max_extent_m / mpl
    st, ws = regions.step, regions.shape[1]
    heights = _NO_HEIGHTS if above is None else above
    # with people in the previous frame, any part may be one of them bending (`bent_rules`
    # judges that), and its heights are measured from a cut person's sizes on
    small = occluded or bool(boxes)
    for i in order.tolist():
        sy, sx = divmod(int(regions.seed[i]), ws)
        crop, bx, rows = _region_parts(g, heights, above is not None, int(regions.level[i]),
                                       sy * st, sx * st, config.connectivity == 8, gap_levels,
                                       extent_levels, config.edge_rows)
        box = tuple(bx.tolist())
        for a, b, n, med, r0, r1, c0, c1, extent, top, bottom, whole in rows.tolist():
            pt = _describe(crop, g, box, int(a), int(b), int(n), int(med),
                           (int(r0), int(r1), int(c0), int(c1)), extent, top, bottom,
                           bool(whole), float(regions.variation[i]), intrinsics, edges,
                           config, mpl, small)
            if pt is not None:
                parts.append(pt)
    return parts


def _distinct(order: NDArray[np.int64], x0: NDArray, y0: NDArray, x1: NDArray, y1: NDArray,
              size: NDArray, n: int) -> NDArray[np.int64]:
    """The first `n` regions of `order` (best first) that are not nested copies of one picked
    before: the regions of one chain are often the same pixels at several levels."""
    return _distinct_kernel(order.astype(np.int64), x0, y0, x1, y1, size, n)


@njit(cache=True)
def _distinct_kernel(order: NDArray[np.int64], x0: NDArray, y0: NDArray, x1: NDArray,
                     y1: NDArray, size: NDArray, n: int) -> NDArray[np.int64]:
    """`_distinct`, one pass in numba (the same box overlaps and size ratios)."""
    picked = np.empty(max(min(n, len(order)), 0), np.int64)
    k = 0
    for t in range(min(8 * n, len(order))):
        i = order[t]
        nested = False
        for q in range(k):
            j = picked[q]
            iw = min(x1[i], x1[j]) - max(x0[i], x0[j])
            ih = min(y1[i], y1[j]) - max(y0[i], y0[j])
            if iw <= 0 or ih <= 0:
                continue
            inter = np.int64(iw) * np.int64(ih)
            union = (np.int64(x1[i] - x0[i]) * np.int64(y1[i] - y0[i])
                     + np.int64(x1[j] - x0[j]) * np.int64(y1[j] - y0[j]) - inter)
            if inter / float(union) > 0.9 and \
                    min(size[i], size[j]) > 0.9 * max(size[i], size[j]):
                nested = True
                break
        if nested:
            continue
        picked[k] = i
        k += 1
        if k == n:
            break
    return picked[:k]


def _describe(crop: NDArray[np.bool_], g: NDArray[np.uint8], origin: tuple[int, ...],
              lo: int, hi: int, n: int, med: int, extent_box: tuple[int, int, int, int],
              extent_levels: float, top: float, bottom: float, whole: bool, var: float,
              intrinsics: Intrinsics, edges: tuple[int, int, int], config: ForegroundConfig,
              metres_per_level: float, occluded: bool = False) -> Part | None:
    """One depth part as `_region_parts` measured it (levels `lo`-`hi` of the region `crop`
    over box `origin`; `n` pixels, median level `med`, rows `r0:r1` and columns `c0:c1` of
    the crop, depth extent in levels, heights of its top and bottom rows; `edges`: where the
    readings end, left, right and bottom, `seen_edges`); None when it is
    too small to be anything (`occluded`: its tops and bottoms judged by a cut person's
    sizes; `metres_per_level` is the config's, computed once by the caller)."""
    if n < config.mser_min_area_px:
        return None
    r0, r1, c0, c1 = extent_box
    # level l is at depth near + (255 - l) * metres_per_level
    z = config.depth_near_m + (255.0 - med) * metres_per_level
    bh, bw = r1 - r0, c1 - c0
    box = (origin[0] + c0, origin[1] + r0, origin[0] + c1, origin[1] + r1)
    cut = box[3] >= edges[2]
    height_m, width_m = bh * z / intrinsics.fy, bw * z / intrinsics.fx
    area, fill = n * z * z / (intrinsics.fx * intrinsics.fy), n / (bh * bw)
    extent = extent_levels * metres_per_level
    # the heights above the floor decide only among parts of a person's size
    if not size_rules(height_m, width_m, area, fill, extent, cut or occluded, config):
        top = bottom = math.nan
    if not whole:
        gl = g[origin[1]:origin[3], origin[0]:origin[2]]
        crop = crop & (gl >= lo) & (gl <= hi)
    return Part(crop=crop, origin=(origin[0], origin[1]), box=box, lo=lo, hi=hi, n=n, z=z,
                height_m=height_m, width_m=width_m, area_m2=area, fill=fill, variation=var,
                side=box[0] <= edges[0] or box[2] >= edges[1], cut=cut, top_m=top, bottom_m=bottom,
                extent_m=extent)


def size_rules(height_m: float, width_m: float, area_m2: float, fill: float, extent_m: float,
               cut: bool, config: PersonConfig) -> bool:
    """Whether a part has a person's height, width, surface, fill and depth extent (`cut`:
    the smaller height and surface of a person cut by the image's bottom edge)."""
    c = config
    min_height = c.person_min_cut_height_m if cut else c.person_min_height_m
    min_area = c.min_cut_area_m2 if cut else c.person_min_area_m2
    return (min_height <= height_m <= c.person_max_height_m
            and c.person_min_width_m <= width_m <= c.person_max_width_m
            and min_area <= area_m2 <= c.person_max_area_m2
            and fill <= c.person_max_fill and extent_m <= c.person_max_extent_m)


def person_rules(part: Part, config: PersonConfig, near: bool = False) -> bool:
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


def occluded_rules(part: Part, config: PersonConfig) -> bool:
    """Whether a part may be a person partly hidden by a nearer one: the smaller height and
    surface of a person cut by the image's bottom edge (`person_min_cut_height_m`), the other
    sizes and, with a floor, the height of its top rows (the head or the shoulders are seen)
    as a whole person's; no rule on its bottom rows (the legs may be the hidden part)."""
    c = config
    if not size_rules(part.height_m, part.width_m, part.area_m2, part.fill, part.extent_m,
                      True, c):
        return False
    return not (math.isfinite(part.top_m)
                and not c.person_min_top_m <= part.top_m <= c.person_max_top_m)


def bent_rules(part: Part, config: PersonConfig,
               boxes: Sequence[tuple[int, int, int, int]]) -> bool:
    """Whether a part may be a person of the previous frame bending or crouching (`_follows`
    one of `boxes`): a cut person's height and surface (`person_min_cut_height_m`), the other
    sizes as a whole person's, a floor, its top rows at least `person_min_bent_top_m` above it
    and its bottom rows on it."""
    c = config
    return (math.isfinite(part.top_m) and c.person_min_bent_top_m <= part.top_m
            <= c.person_max_top_m and not part.bottom_m > c.person_max_bottom_m
            and size_rules(part.height_m, part.width_m, part.area_m2, part.fill,
                           part.extent_m, True, c)
            and _follows_one(part.box, boxes))


def part_score(part: Part, config: PersonConfig,
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
    if prev_box is not None and _overlap(prev_box, part.box) > FOLLOW_OVERLAP:
        score += config.previous_bonus
    return score


# `_region_parts` without a floor: its heights argument, never read
_NO_HEIGHTS = np.zeros((1, 1), np.float32)


@njit(cache=True)
def _region_parts(g: NDArray[np.uint8], above: NDArray[np.float32], has_above: bool,
                  level: int, sy: int, sx: int, conn8: bool, gap_levels: float,
                  extent_levels: float, edge_rows: int
                  ) -> tuple[NDArray[np.bool_], NDArray[np.int64], NDArray[np.float64]]:
    """One stable region traced and cut into depth parts, in one pass of compiled code.
    (One numba kernel of more than 100 lines: its steps, trace, histogram, cut and describe,
    hand each other the visited map, the box, the crop and the histogram of levels, which
    helpers used nowhere else would pass back and forth; what stands alone, a range's
    extent, Otsu cut and median, is its helpers already.)

    The region is the connected component of ``{g >= level}`` (8- or 4-connected) holding
    pixel (`sy`, `sx`); its histogram of levels is split where more than `gap_levels` levels
    are empty, and a range whose 5th-95th percentile extent exceeds `extent_levels` is also
    cut at Otsu's threshold (both halves kept besides the whole).

    Returns the region as a bool array over its box, the box (x0, y0, x1, y1; x1/y1
    exclusive) and one row per part: first and last level, pixels, median level, the rows
    r0:r1 and columns c0:c1 of the crop it spans, its depth extent in levels, the median
    height above the floor of its top and bottom `edge_rows` rows (NaN without `has_above`
    or without a finite height there) and whether it is the whole region (1.0) or not."""
    h, w = g.shape
    seen = np.zeros((h, w), np.uint8)
    stack = np.empty(h * w, np.int64)
    seen[sy, sx] = 1
    stack[0] = sy * w + sx
    top_ = 1
    y0, y1, x0, x1 = sy, sy, sx, sx
    while top_ > 0:
        top_ -= 1
        y, x = divmod(stack[top_], w)
        y0, y1, x0, x1 = min(y0, y), max(y1, y), min(x0, x), max(x1, x)
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if (dy == 0 and dx == 0) or (not conn8 and dy != 0 and dx != 0):
                    continue
                v, u = y + dy, x + dx
                if 0 <= v < h and 0 <= u < w and seen[v, u] == 0 and g[v, u] >= level:
                    seen[v, u] = 1
                    stack[top_] = v * w + u
                    top_ += 1
    ch, cw = y1 - y0 + 1, x1 - x0 + 1
    crop = np.empty((ch, cw), np.bool_)
    hist = np.zeros(256, np.int64)
    for y in range(ch):
        for x in range(cw):
            inside = seen[y0 + y, x0 + x] != 0
            crop[y, x] = inside
            if inside:
                hist[g[y0 + y, x0 + x]] += 1
    box = np.array([x0, y0, x1 + 1, y1 + 1], np.int64)
    first, last = 0, 255
    while hist[first] == 0:
        first += 1
    while hist[last] == 0:
        last -= 1
    # level ranges between gaps of more than gap_levels empty levels
    ranges = []
    lo = first
    prev = first
    for lv in range(first + 1, last + 1):
        if hist[lv] == 0:
            continue
        if gap_levels > 0 and lv - prev > gap_levels:
            ranges.append((lo, prev))
            lo = lv
        prev = lv
    ranges.append((lo, last))
    bounds = []
    for lo, hi in ranges:
        bounds.append((lo, hi))
        if _extent_kernel(hist, lo, hi) > extent_levels:
            cut = lo + _otsu_kernel(hist, lo, hi)
            bounds.append((lo, cut))
            bounds.append((cut + 1, hi))
    # no slices or NaN fills here: each costs a Python-level call per kernel call
    rows = np.empty((len(bounds), 12))
    for k in range(len(bounds)):
        a, b = bounds[k]
        n = 0
        for lv in range(a, b + 1):
            n += hist[lv]
        half = (n + 1) // 2
        med, cum = a, hist[a]
        while cum < half:
            med += 1
            cum += hist[med]
        r0, r1, c0, c1 = ch, -1, cw, -1
        for y in range(ch):
            for x in range(cw):
                if crop[y, x] and a <= g[y0 + y, x0 + x] <= b:
                    r0, r1, c0, c1 = min(r0, y), max(r1, y), min(c0, x), max(c1, x)
        values = (a, b, n, med, r0, r1 + 1, c0, c1 + 1, _extent_kernel(hist, a, b))
        for j in range(9):
            rows[k, j] = values[j]
        rows[k, 9] = rows[k, 10] = np.nan
        if has_above and n > 0:
            for j, (ra, rb) in enumerate(((r0, min(r0 + edge_rows, r1 + 1)),
                                          (max(r1 + 1 - edge_rows, 0), r1 + 1))):
                vals = np.empty((rb - ra) * cw, np.float32)
                m = 0
                for y in range(ra, rb):
                    for x in range(cw):
                        if crop[y, x] and a <= g[y0 + y, x0 + x] <= b:
                            v = above[y0 + y, x0 + x]
                            if np.isfinite(v):
                                vals[m] = v
                                m += 1
                rows[k, 9 + j] = _median_kernel(vals, m)
        rows[k, 11] = 1.0 if a <= first and b >= last else 0.0
    return crop, box, rows


@njit(cache=True)
def _extent_kernel(hist: NDArray[np.int64], lo: int, hi: int) -> int:
    """Levels between the 5th and 95th percentiles of `hist[lo:hi + 1]` (the first level
    whose cumulative count reaches each, as `searchsorted`)."""
    n = 0
    for lv in range(lo, hi + 1):
        n += hist[lv]
    a, b = 0.05 * n, 0.95 * n
    ia = ib = -1
    cum = 0
    for lv in range(lo, hi + 1):
        cum += hist[lv]
        if ia < 0 and cum >= a:
            ia = lv
        if ib < 0 and cum >= b:
            ib = lv
    return ib - ia


@njit(cache=True)
def _otsu_kernel(hist: NDArray[np.int64], lo: int, hi: int) -> int:
    """Otsu's threshold of `hist[lo:hi + 1]`: the last bin of the lower class, counted from
    `lo` (the middle bin when no split has both classes non-empty)."""
    total = 0.0
    moment = 0.0
    for k in range(hi - lo + 1):
        total += hist[lo + k]
        moment += hist[lo + k] * k
    w0 = m0 = 0.0
    best, arg = -1.0, -1
    for k in range(hi - lo):
        w0 += hist[lo + k]
        m0 += hist[lo + k] * k
        w1 = total - w0
        if w0 == 0 or w1 == 0:
            continue
        between = w0 * w1 * (m0 / w0 - (moment - m0) / w1) ** 2
        if between > best:
            best, arg = between, k
    return arg if arg >= 0 else (hi - lo + 1) // 2


@njit(cache=True)
def _median_kernel(values: NDArray[np.float32], n: int) -> float:
    """`stats.median` of the first `n` float32 `values` in compiled code (NaN when none)."""
    if n == 0:
        return np.nan
    s = np.empty(n, np.float32)
    for i in range(n):
        s[i] = values[i]
    s.sort()
    k = n // 2
    if n % 2:
        return float(s[k])
    return float(np.float32(s[k - 1] + s[k])) / 2.0


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Intersection over union of two boxes (`min`/`max` written out: a call each, per part
    per frame)."""
    iw = (a[2] if a[2] < b[2] else b[2]) - (a[0] if a[0] > b[0] else b[0])
    ih = (a[3] if a[3] < b[3] else b[3]) - (a[1] if a[1] > b[1] else b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return inter / float((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)
