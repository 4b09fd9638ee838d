"""`segment`: the steps of the foreground (the package docstring) composed, on one depth frame
at the working resolution."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, depth_to_metres
from pose4d_ros.core.foreground.config import (
    REASON_NO_DEPTH,
    REASON_NO_PERSON,
    REASON_NO_REGION,
    REASON_OK,
    REASON_TOO_SMALL,
    ForegroundConfig,
    ForegroundResult,
    not_found,
)
from pose4d_ros.core.foreground.floor import fit_floor, floor_height
from pose4d_ros.core.foreground.mask import complete, grow_down, upsample_mask
from pose4d_ros.core.foreground.person import (
    FOLLOW_OVERLAP,
    Part,
    _overlap,
    bent_rules,
    depth_parts,
    occluded_rules,
    part_score,
    person_rules,
    person_sized,
    seen_edges,
)
from pose4d_ros.core.foreground.regions import depth_to_levels, stable_regions
from pose4d_ros.core.stats import median

DEFAULT = ForegroundConfig()  # the defaults, one instance (frozen)
# `ndarray.any` without its Python wrapper
_any = np.logical_or.reduce
# Largest share of a part's pixels that another, better person may hold (`segment_people`)
OVERLAP = 0.2
# Pixels around the people found that a second look for people hidden behind them leaves out
# (the ragged band of mixed depths along a person's outline, `segment_people`)
BEHIND_MARGIN_PX = 2


def segment(depth_m: NDArray[np.floating], intrinsics: Intrinsics, *,
            config: ForegroundConfig = DEFAULT,
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
        return not_found((h, w), REASON_TOO_SMALL)
    if (intrinsics.width, intrinsics.height) != (w, h):
        raise ValueError(f'depth image is {w}x{h} but the intrinsics are '
                         f'{intrinsics.width}x{intrinsics.height}')
    f = max(h // config.working_height_px, 1)
    if f > 1:
        return _subsampled_segment(depth, intrinsics, f, config, previous)
    depth = depth_to_metres(depth)  # new float32 array: inputs are never touched
    valid = np.isfinite(depth)
    if not valid.any():
        return not_found((h, w), REASON_NO_DEPTH)

    prev_box = previous.box if previous is not None and previous.found else None
    boxes = [] if prev_box is None else [prev_box]
    floor, above, parts, reason = _examine(depth, intrinsics, config, previous, boxes)
    if not parts:
        return not_found((h, w), reason, floor)
    scores = [part_score(pt, config, prev_box) for pt in parts]
    ok = [k for k, pt in enumerate(parts) if person_rules(pt, config)]
    if _unfollowed(boxes, [parts[k] for k in ok]):  # the person of the previous frame bending?
        ok += [k for k, pt in enumerate(parts) if bent_rules(pt, config, boxes)]
    if not ok:  # a person too near to be seen whole, only when no whole one is in view
        ok = [k for k, pt in enumerate(parts) if person_rules(pt, config, near=True)]
    if not ok:
        return not_found((h, w), REASON_NO_PERSON, floor)
    best = parts[max(ok, key=lambda k: scores[k])]
    return _result(best, depth, valid, floor, above, config)


def _result(part: Part, depth: NDArray[np.float32], valid: NDArray[np.bool_],
            floor: NDArray[np.float64] | None, above: NDArray[np.float32] | None,
            config: ForegroundConfig, behind: bool = False) -> ForegroundResult:
    """The foreground of one chosen part: its pixels completed (step 5) and grown down to the
    floor (`grow_down`), its median depth."""
    mask = _part_mask(part, depth.shape)
    complete(mask, ~valid, part.box, config)
    box = grow_down(mask, depth, above, part.box, config)
    zr = depth[mask]
    zr = zr[np.isfinite(zr)]
    return ForegroundResult(mask=mask, box=box, depth_m=median(zr), found=True,
                            reason=REASON_OK, stability=part.variation, level=part.lo,
                            floor=floor, behind=behind)


def _part_mask(part: Part, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    mask = np.zeros(shape, dtype=bool)
    x0, y0 = part.origin
    mask[y0:y0 + part.crop.shape[0], x0:x0 + part.crop.shape[1]] = part.crop
    return mask


def segment_people(depth_m: NDArray[np.floating], intrinsics: Intrinsics, *,
                   config: ForegroundConfig = DEFAULT,
                   previous: list[ForegroundResult] | tuple[ForegroundResult, ...] = (),
                   max_people: int = 4) -> tuple[list[ForegroundResult], int]:
    """Every person in a depth image: the parts of `segment` that pass the person rules, best
    first, each sharing at most `OVERLAP` of its pixels with a better one (a region of the same
    person at another level is not another person).

    Parameters are `segment`'s; `previous` are the people of the previous frame (a part
    overlapping one of their boxes gets the `previous_bonus`); `max_people` bounds what is
    returned (the work of tracing is the same).

    Returns
    -------
    people : at most `max_people` results (found, each its own mask), best first.
    found : how many distinct people the rules passed (may exceed `max_people`).
    """
    if max_people < 1:
        raise ValueError(f'max_people must be >= 1, got {max_people}')
    depth = np.asarray(depth_m)
    if depth.ndim != 2:
        raise ValueError(f'depth image must be 2-D, got shape {depth.shape}')
    h, w = depth.shape
    if h < 8 or w < 8:
        return [], 0
    if (intrinsics.width, intrinsics.height) != (w, h):
        raise ValueError(f'depth image is {w}x{h} but the intrinsics are '
                         f'{intrinsics.width}x{intrinsics.height}')
    f = max(h // config.working_height_px, 1)
    if f > 1:
        small, small_k, _ = _subsampled(depth, intrinsics, f, None)
        prev = [_subsampled(depth, intrinsics, f, p)[2] for p in previous]
        people, found = segment_people(small, small_k, config=config, previous=prev,
                                       max_people=max_people)
        return [_upsampled(p, small, depth, intrinsics, f, config) for p in people], found
    depth = depth_to_metres(depth)
    valid = np.isfinite(depth)
    if not valid.any():
        return [], 0
    floor, above, drop = _floor(depth, intrinsics, config,
                                previous[0] if len(previous) else None)
    boxes = [p.box for p in previous if p.found and p.box is not None]
    parts, _ = _parts(depth, intrinsics, config, above, drop, boxes=boxes)
    picked = _distinct_people([pt for pt in parts if person_rules(pt, config)], depth.shape,
                              config, boxes, [])
    left = _unfollowed(boxes, [pt for pt, _ in picked])
    if left:  # people of the previous frame not found by the usual rules, bending?
        picked += _distinct_people([pt for pt in parts if bent_rules(pt, config, left)],
                                   depth.shape, config, boxes, picked)
    # people too near to be seen whole (cut by the image's bottom edge), beside the others
    picked += _distinct_people([pt for pt in parts if person_rules(pt, config, near=True)],
                               depth.shape, config, boxes, picked)
    first = len(picked)
    if config.second_look and picked and first < max_people and (
            not previous or any(p.behind for p in previous)
            or _gone_beside(previous, [pt.box for pt, _ in picked])):
        # where someone may be hidden: at a stream's start, when someone of the previous frame
        # is missing beside a person found (gone behind them) or while the second look finds
        # someone
        picked += _behind(depth, intrinsics, config, above, drop, boxes, picked)
    people = [_result(pt, depth, valid, floor, above, config, behind=k >= first)
              for k, (pt, _) in enumerate(picked[:max_people])]
    # completion may add a pixel to two people: it stays with the better one (the masks are
    # these results' own, just made: changed in place)
    taken = np.zeros(depth.shape, bool)
    for person in people:
        person.mask[taken] = False
        taken |= person.mask
    return people, len(picked)


def _distinct_people(parts: list[Part], shape: tuple[int, ...], config: ForegroundConfig,
                     boxes: list[tuple[int, int, int, int]],
                     picked: list[tuple[Part, NDArray[np.bool_]]]
                     ) -> list[tuple[Part, NDArray[np.bool_]]]:
    """The parts (best first by `part_score`, a part overlapping a previous box in `boxes`
    with its bonus) that share at most `OVERLAP` of their pixels with a better one, or with
    one of `picked`; each with its mask."""
    parts = sorted(parts, key=lambda pt: -max([part_score(pt, config, b) for b in boxes]
                                              or [part_score(pt, config)]))
    out: list[tuple[Part, NDArray[np.bool_]]] = []
    for pt in parts:
        mask = _part_mask(pt, shape)
        if any((mask & m).sum() > OVERLAP * min(pt.n, q.n) for q, m in picked + out):
            continue
        out.append((pt, mask))
    return out


def _unfollowed(boxes: list[tuple[int, int, int, int]], parts: list[Part]
                ) -> list[tuple[int, int, int, int]]:
    """The boxes (the previous frame's people) that none of `parts` overlaps by more than
    `FOLLOW_OVERLAP`: people who may be bending, and may pass `bent_rules`."""
    left = []
    for b in boxes:
        for pt in parts:
            if _overlap(b, pt.box) > FOLLOW_OVERLAP:
                break
        else:
            left.append(b)
    return left


def _gone_beside(previous: list[ForegroundResult] | tuple[ForegroundResult, ...],
                 boxes: list[tuple[int, int, int, int]]) -> bool:
    """Whether a person of the previous frame is not found again (each box found taken by
    the previous box it overlaps most, one to one) where their box, grown by a tenth of its
    height, meets the box of a person found: they may have gone behind them. A region that
    is gone elsewhere (out of view, or a wall's edge at the image's border that passes the
    rules one frame in two) is no reason for a second look."""
    left = [p.box for p in previous if p.box is not None]
    if len(left) <= len(boxes):
        return False
    for b in boxes:
        best = max(left, key=lambda a: _overlap(a, b))
        if _overlap(best, b) > 0:
            left.remove(best)
    for x0, y0, x1, y1 in left:
        g = (y1 - y0) // 10
        grown = (x0 - g, y0 - g, x1 + g, y1 + g)
        if any(_overlap(grown, b) > 0 for b in boxes):
            return True
    return False


def _behind(depth: NDArray[np.float32], intrinsics: Intrinsics, config: ForegroundConfig,
            above: NDArray[np.float32] | None, drop: NDArray[np.bool_] | None,
            boxes: list[tuple[int, int, int, int]],
            picked: list[tuple[Part, NDArray[np.bool_]]]
            ) -> list[tuple[Part, NDArray[np.bool_]]]:
    """People partly hidden by the people found (`picked`): found again with those people's
    pixels (and `BEHIND_MARGIN_PX` around them) left out.

    A person whose outline touches a nearer person's in the image is no stable region of
    their own: at the depths just beyond theirs their region joins the nearer person's,
    whose pixels are all nearer, and grows at once (MSER's variation is large). Without the
    nearer person, the one behind is a region of its own, as when alone. Only a part that
    reaches a person found in the image and lies behind them (farther by over
    `occluder_gap_m`) is taken, and it needs only `occluded_rules` (its head or shoulders at a
    person's height above the floor, a cut person's size; without a floor nothing is taken:
    a piece of the wall framed by the people found would pass): anything else was judged by
    the first look.
    """
    k = 2 * BEHIND_MARGIN_PX + 1
    grown = [cv2.dilate(m.view(np.uint8), np.ones((k, k), np.uint8)).view(bool)
             for _, m in picked]
    taken = np.logical_or.reduce(grown)
    parts, _ = _parts(depth, intrinsics, config, above, taken if drop is None else drop | taken,
                      occluded=True)
    # the pixels just outside each person found: a part behind them reaches them there
    rings = [cv2.dilate(m.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool) & ~taken
             for m in grown]
    ok = []
    for pt in parts:
        # without a floor, a piece of the wall framed by people would pass for one's top
        if not (math.isfinite(pt.top_m) and occluded_rules(pt, config)):
            continue
        mask = _part_mask(pt, depth.shape)
        if any(pt.z > q.z + config.occluder_gap_m and _any(mask & ring, axis=None)
               for (q, _), ring in zip(picked, rings, strict=True)):
            ok.append(pt)
    return _distinct_people(ok, depth.shape, config, boxes, picked)


def _subsampled_segment(depth: NDArray, intrinsics: Intrinsics, f: int,
                        config: ForegroundConfig, previous: ForegroundResult | None
                        ) -> ForegroundResult:
    """`segment` on every f-th pixel of every f-th row, its mask brought back to full size
    (each pixel takes the value of the one it was represented by)."""
    small, small_k, previous = _subsampled(depth, intrinsics, f, previous)
    return _upsampled(segment(small, small_k, config=config, previous=previous), small,
                      depth, intrinsics, f, config)


def _subsampled(depth: NDArray, intrinsics: Intrinsics, f: int,
                previous: ForegroundResult | None
                ) -> tuple[NDArray, Intrinsics, ForegroundResult | None]:
    """Every f-th pixel of every f-th row, its intrinsics, and `previous` on that grid."""
    small = np.ascontiguousarray(depth[::f, ::f])
    k = intrinsics
    small_k = Intrinsics(k.fx / f, k.fy / f, k.cx / f, k.cy / f, small.shape[1], small.shape[0])
    if previous is not None and previous.box is not None:
        x0, y0, x1, y1 = previous.box
        previous = replace(previous, box=(x0 // f, y0 // f, -(-x1 // f), -(-y1 // f)))
    return small, small_k, previous


def _upsampled(out: ForegroundResult, small: NDArray, depth: NDArray, k: Intrinsics, f: int,
               config: ForegroundConfig) -> ForegroundResult:
    """A result found on the subsampled grid, its mask at full size."""
    h, w = depth.shape
    if not out.found:
        return replace(out, mask=np.zeros((h, w), bool))
    floor = np.full(4, np.nan) if out.floor is None else out.floor
    depth = np.asarray(depth)
    mask = upsample_mask(out.mask, depth_to_metres(small), depth,
                          0.001 if depth.dtype == np.uint16 else 1.0, f,
                          np.array([k.fx, k.fy, k.cx, k.cy]), floor,
                          config.floor_tolerance_m, config.mser_delta * config.metres_per_level)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    box = (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)
    return replace(out, mask=mask, box=box)


def _floor(depth: NDArray[np.float32], intrinsics: Intrinsics, config: ForegroundConfig,
           previous: ForegroundResult | None
           ) -> tuple[NDArray[np.float64] | None, NDArray[np.float32] | None,
                      NDArray[np.bool_] | None]:
    """Step 1: the floor plane (or None), every pixel's height above it and the pixels that
    are floor (None without a floor)."""
    if not config.floor_remove:
        return None, None, None
    floor = fit_floor(depth, intrinsics, config=config,
                      previous=None if previous is None else previous.floor)
    if floor is None:
        return None, None, None
    above = floor_height(depth, intrinsics, floor)
    drop = above < config.floor_tolerance_m  # NaN (no reading) compares False, unwarned
    return floor, above, drop


def _examine(depth: NDArray[np.float32], intrinsics: Intrinsics, config: ForegroundConfig,
             previous: ForegroundResult | None, boxes: Sequence[tuple[int, int, int, int]]
             ) -> tuple[NDArray[np.float64] | None, NDArray[np.float32] | None, list[Part],
                        str]:
    """Floor, stable regions and their depth parts (the candidates `segment` chooses from;
    `boxes`: the previous person's, `_parts`).

    Returns the floor plane (or None), every pixel's height above it (or None), the parts,
    and the reason when there are none.
    """
    floor, above, drop = _floor(depth, intrinsics, config, previous)
    return (floor, above, *_parts(depth, intrinsics, config, above, drop, boxes=boxes))


def _parts(depth: NDArray[np.float32], intrinsics: Intrinsics, config: ForegroundConfig,
           above: NDArray[np.float32] | None, drop: NDArray[np.bool_] | None, *,
           occluded: bool = False, boxes: Sequence[tuple[int, int, int, int]] = ()
           ) -> tuple[list[Part], str]:
    """The stable regions of `depth` without the pixels `drop` and their depth parts
    (`depth_parts`, `occluded` passed on; `boxes`: the previous frame's people, who may
    bend, `bent_rules`), and the reason when there are none."""
    g = depth_to_levels(depth, config=config, drop=drop)
    regions = stable_regions(g, config)
    if regions.stable.size == 0:
        return [], REASON_NO_REGION
    edges = seen_edges(np.isfinite(depth))
    order = person_sized(regions, intrinsics, config, boxes, edges)
    if order.size == 0:
        return [], REASON_NO_PERSON
    return depth_parts(g, regions, order, above, intrinsics, config, occluded=occluded,
                       boxes=boxes, edges=edges), REASON_NO_PERSON
