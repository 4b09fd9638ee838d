"""The 8-bit depth image and its extremal regions (steps 2 and 3 of `segment`): depth in
[`depth_near_m`, `depth_far_m`] maps to 255..1, and the component tree of the upper level sets
``{g >= t}`` is built by union-find (Najman & Couprie 2006); a region's MSER stability is its
relative growth over `mser_delta` levels further away."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.foreground.config import RegionConfig

DEFAULT = RegionConfig()  # the defaults, one instance (frozen)


def depth_to_levels(depth_m: NDArray[np.floating], *,
                    config: RegionConfig = DEFAULT,
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
    depth_m = np.asarray(depth_m)
    if depth_m.dtype not in (np.float32, np.float64):
        depth_m = depth_m.astype(np.float64)
    if depth_m.ndim != 2 or (drop is not None and drop.shape != depth_m.shape):
        raise ValueError(f'depth {depth_m.shape} and drop {None if drop is None else drop.shape}'
                         ' must be one 2-D shape')
    out = np.empty(depth_m.shape, np.uint8)
    _levels(depth_m, np.float32(config.depth_near_m),
            np.float32(254.0 / (config.depth_far_m - config.depth_near_m)),
            _NO_DROP if drop is None else drop, drop is not None, out)
    return out


# `_levels` without pixels to drop: its drop argument, never read
_NO_DROP = np.zeros((1, 1), np.bool_)


@njit(cache=True)
def _levels(depth_m: NDArray[np.floating], near: np.float32, scale: np.float32,
            drop: NDArray[np.bool_], use_drop: bool, out: NDArray[np.uint8]) -> None:
    """`depth_to_levels` in one pass (numpy's took seven), in the depth's precision: g =
    255.5 - (z - near) scale, truncated; NaN compares False."""
    h, w = depth_m.shape
    for r in range(h):
        for c in range(w):
            g = np.float32(255.5) - (depth_m[r, c] - near) * scale
            ok = g >= 1.0 and g < 256.0 and not (use_drop and drop[r, c])
            out[r, c] = np.uint8(g) if ok else 0


@njit(cache=True, inline='always')
def _find(parent: NDArray[np.int32], p: int) -> int:
    """The root of p's set. Inlined into its callers by numba (a compiled call per pixel and
    neighbour was 40 % of the component tree: 1.78 -> 1.04 ms a frame on the demo bag)."""
    while parent[p] != p:
        parent[p] = parent[parent[p]]  # path halving
        p = parent[p]
    return p


@njit(cache=True)
def _component_tree(g: NDArray[np.uint8], conn8: bool, pix: NDArray[np.int32],
                    nodes: NDArray[np.int32], pend: NDArray[np.int32]) -> tuple:
    """Every extremal region of `g` (components of ``{g >= t}``, t = 255..1) as tree nodes.
    (One numba kernel of more than 100 lines: split into calls, its inner loop would pay
    for them on every pixel.)

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


def component_tree(g: NDArray[np.uint8], conn8: bool) -> tuple:
    """`_component_tree` with this thread's workspace for the image size."""
    h, w = g.shape
    ws = getattr(_LOCAL, 'workspace', None)
    if ws is None or ws[0] != (h, w):
        ws = ((h, w), np.empty((10, (h + 2) * (w + 2)), np.int32),
              np.empty((10, h * w), np.int32), np.empty(h * w, np.int32))
        _LOCAL.workspace = ws
    return _component_tree(g, conn8, ws[1], ws[2], ws[3])


@njit(cache=True)
def variation(level: NDArray[np.int32], size: NDArray[np.int32], parent: NDArray[np.int32],
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


@dataclass(frozen=True)
class StableRegions:
    """The component tree of the 8-bit image on every `step`-th pixel (`shape`), node by node:
    level, size (pixels at that step), box (x0, y0, x1, y1, x1/y1 exclusive), sum of levels,
    seed pixel (flat index), MSER variation, area at full resolution; and the indices of the
    stable nodes (`stable`). The arrays are views into this thread's workspace: valid until the
    next `stable_regions` call of the thread."""

    shape: tuple[int, int]
    step: int
    level: NDArray[np.int32]
    size: NDArray[np.int32]
    x0: NDArray[np.int32]
    y0: NDArray[np.int32]
    x1: NDArray[np.int32]
    y1: NDArray[np.int32]
    gsum: NDArray[np.int32]
    seed: NDArray[np.int32]
    variation: NDArray[np.float64]
    area_px: NDArray[np.float64]
    stable: NDArray[np.int64]


def stable_regions(g: NDArray[np.uint8], config: RegionConfig) -> StableRegions:
    """The extremal regions of `g` and the stable ones: MSER's score at most
    `mser_max_variation` and no larger than `max_region_area_px`, the trained background area.

    The tree is built on every `tree_step`-th pixel (a person is ~100 px tall even at the
    subsampled resolution); the chosen regions are then traced at full resolution.
    """
    st = config.tree_step
    gs = g if st == 1 else np.ascontiguousarray(g[::st, ::st])
    level, size, x0, y0, x1, y1, gsum, seed, parent = component_tree(gs, config.connectivity == 8)
    var = variation(level, size, parent, config.mser_delta,
                    max(config.mser_min_area_px // (st * st), 1))
    area_px = size.astype(np.float64) * (st * st)
    stable = (var <= config.mser_max_variation) & (area_px <= config.max_region_area_px)
    return StableRegions((gs.shape[0], gs.shape[1]), st, level, size, x0, y0, x1, y1, gsum, seed,
                         var, area_px, np.flatnonzero(stable))
