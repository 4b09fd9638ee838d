"""The person rules (step 4 of `segment`), in two stages: the stable regions of a person's
size by the tree's statistics (`person_sized`), then each traced at full resolution, split at
empty depth gaps and measured (`depth_parts`); a part passes `person_rules` (height, width,
surface, fill, depth extent and, with a floor, the heights of its top and bottom rows) and the
best `part_score` wins."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.foreground.config import ForegroundConfig, PersonConfig
from pose4d_ros.core.foreground.regions import StableRegions, trace_region
from pose4d_ros.core.stats import median

# `ndarray.any` without its Python wrapper (the per-frame path)
_any = np.logical_or.reduce


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


def person_sized(regions: StableRegions, intrinsics: Intrinsics, config: ForegroundConfig
                 ) -> NDArray[np.int64]:
    """Stage 1 of the person rules, on the tree's statistics (box, mean depth): the stable
    regions worth tracing, best first (none: no region of person size).

    A region may still hold an occluder or a piece of furniture besides the person, so only
    the person's lower size bounds apply, and the upper ones with `merge_slack`. At most
    `max_candidates` regions that may hold a whole person, then as many cut by the bottom edge.
    """
    r, st = regions, regions.step
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
    near = ((r.y1[cand] == r.shape[0]) & (height_m >= config.person_min_cut_height_m)
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
        return cand
    side = (r.x0[cand] == 0) | (r.x1[cand] == r.shape[1])
    score = (np.log(r.area_px[cand]) - config.stability_weight * r.variation[cand]
             - config.border_penalty * side + 1000.0 * strict)
    rank = np.argsort(-score, kind='stable')
    # the best few regions that may hold a whole person, and the best few near ones
    return np.concatenate([_distinct(cand[rank[only_near[rank] == near]], r.x0, r.y0, r.x1,
                                     r.y1, r.size, config.max_candidates)
                           for near in (False, True)])


def depth_parts(g: NDArray[np.uint8], regions: StableRegions, order: NDArray[np.int64],
                above: NDArray[np.float32] | None, intrinsics: Intrinsics,
                config: ForegroundConfig, *, occluded: bool = False) -> list[Part]:
    """Stage 2, on the full-resolution pixels of the regions `order` picked: each split at
    empty depth gaps (an occluder in front, furniture behind), and a part deeper than
    `person_max_extent_m` at Otsu's threshold too; every part is a candidate. `occluded`: the
    parts may be people partly hidden by a nearer one (`occluded_rules`), whose top and bottom
    heights are measured from the smaller sizes of a cut person on."""
    h, w = g.shape
    parts = []
    gap_levels = config.occluder_gap_m / config.metres_per_level
    extent_levels = config.person_max_extent_m / config.metres_per_level
    st, ws = regions.step, regions.shape[1]
    for i in order.tolist():
        sy, sx = divmod(int(regions.seed[i]), ws)
        crop, bx = trace_region(g, int(regions.level[i]), (sy * st, sx * st),
                                config.connectivity)
        gl = g[bx[1]:bx[3], bx[0]:bx[2]]
        hl = None if above is None else above[bx[1]:bx[3], bx[0]:bx[2]]
        hist = np.bincount(gl[crop], minlength=256)
        present = hist.nonzero()[0]
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
                pt = _describe(part, hist[a:b + 1], a, b, bx, float(regions.variation[i]), hl,
                               intrinsics, (w, h), config, occluded)
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


def _describe(part: NDArray[np.bool_], hist: NDArray[np.int64], lo: int, hi: int,
              origin: tuple[int, int, int, int], var: float, above: NDArray[np.float32] | None,
              intrinsics: Intrinsics, size: tuple[int, int], config: ForegroundConfig,
              occluded: bool = False) -> Part | None:
    """Measure one depth part; None when it is too small to be anything (`occluded`: its
    tops and bottoms measured from a cut person's sizes on)."""
    cum = hist.cumsum()
    n = int(cum[-1])
    if n < config.mser_min_area_px:
        return None
    # median level -> depth; level l is at depth near + (255 - l) * metres_per_level
    med = lo + int(cum.searchsorted((n + 1) // 2))
    z = config.depth_near_m + (255.0 - med) * config.metres_per_level
    rows = _any(part, axis=1).nonzero()[0]
    cols = _any(part, axis=0).nonzero()[0]
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    bh, bw = r1 - r0, c1 - c0
    box = (origin[0] + c0, origin[1] + r0, origin[0] + c1, origin[1] + r1)
    cut = box[3] == size[1]
    height_m, width_m = bh * z / intrinsics.fy, bw * z / intrinsics.fx
    area, fill = n * z * z / (intrinsics.fx * intrinsics.fy), n / (bh * bw)
    extent = _extent_levels(hist, cum) * config.metres_per_level
    top = bottom = math.nan
    # the heights above the floor decide only among parts of a person's size
    if above is not None and size_rules(height_m, width_m, area, fill, extent, cut or occluded,
                                        config):
        k = config.edge_rows
        t = above[r0:r0 + k][part[r0:r0 + k]]
        b = above[max(r1 - k, 0):r1][part[max(r1 - k, 0):r1]]
        top, bottom = median(t[np.isfinite(t)]), median(b[np.isfinite(b)])
    return Part(crop=part, origin=(origin[0], origin[1]), box=box, lo=lo, hi=hi, n=n, z=z,
                height_m=height_m, width_m=width_m, area_m2=area, fill=fill, variation=var,
                side=box[0] == 0 or box[2] == size[0], cut=cut, top_m=top, bottom_m=bottom,
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
    if prev_box is not None and _overlap(prev_box, part.box) > 0.3:
        score += config.previous_bonus
    return score


def _extent_levels(hist: NDArray[np.int64], cum: NDArray[np.int64] | None = None) -> int:
    """Levels between the 5th and 95th percentiles of a histogram (`cum` its cumulative sum,
    if known)."""
    cum = hist.cumsum() if cum is None else cum
    n = cum[-1]
    return int(cum.searchsorted(0.95 * n) - cum.searchsorted(0.05 * n))


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
    levels = hist.nonzero()[0]
    if levels.size == 0:
        return []
    if gap_levels <= 0:
        return [(int(levels[0]), int(levels[-1]))]
    cuts = ((levels[1:] - levels[:-1]) > gap_levels).nonzero()[0].tolist()
    lv = levels.tolist()
    starts = [lv[0]] + [lv[i + 1] for i in cuts]
    ends = [lv[i] for i in cuts] + [lv[-1]]
    return list(zip(starts, ends, strict=True))


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Intersection over union of two boxes."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return inter / float((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)
