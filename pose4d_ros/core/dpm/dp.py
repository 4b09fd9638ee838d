"""One pyramid level of the 4D-DPM: the filter GEMM, the tree DP and backtracking.

Yang & Ramanan (PAMI 2013), section 4: all part-type filters score every cell in one float32
GEMM (`im2col` x the stacked filters); messages pass from the leaves to the root (eq. 4) through
a generalized distance transform per child type (`core.dpm.dt`) and the co-occurrence biases;
the best root cells are backtracked through the stored argmaxes to every part's cell and type.
`limb_candidates` serves the tracking prior of `core.dpm.infer.Detector` (the few best arms the
tree allows). The kernels are single-threaded numba: BLAS owns the threads (see `core.dpm.infer`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.dpm.dt import dt2d
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.hog import Level

# --------------------------------------------------------------------------- numba kernels


@nb.njit(cache=True)
def im2col(feat: NDArray[np.float32], fh: int, fw: int) -> NDArray[np.float32]:
    """(ny*nx, fh*fw*C) float32: row (y*nx + x) = the (fh, fw, C) window at cell (y, x),
    flattened row-major (the filters' layout)."""
    h, w, c = feat.shape
    ny = h - fh + 1
    nx = w - fw + 1
    row = fw * c
    cols = np.empty((ny * nx, fh * row), np.float32)
    for y in range(ny):
        for x in range(nx):
            r = y * nx + x
            for i in range(fh):
                base = i * row
                for j in range(fw):
                    for ch in range(c):
                        cols[r, base + j * c + ch] = feat[y + i, x + j, ch]
    return cols


@nb.njit(cache=True)
def tree_dp(resp: NDArray[np.float32], parents: NDArray[np.int64],
            springs: NDArray[np.float32], anchors: NDArray[np.int32],
            bias: NDArray[np.float32]):
    """Message passing from the leaves to the root (Yang & Ramanan eq. 4).

    Parameters
    ----------
    resp : (P, K, ny, nx) float32 filter responses.
    parents, springs, anchors, bias : the model's (see `PartModel`).

    Returns
    -------
    root : (K, ny, nx) float32 best pose score with the root of type k at each cell.
    ix, iy : (P, K, ny, nx) int32 spring argmaxes of each child type (see `dt.dt2d`).
    ik : (P, K, ny, nx) int32 best child type for each parent type and parent cell.
    score : (P, K, ny, nx) float32 each part's filter response plus its children's messages
        (the best score of the subtree below the part, for sub-cell refinement).
    """
    p_n, k_n, ny, nx = resp.shape
    n = ny * nx
    score = resp.copy()
    ix = np.empty((p_n, k_n, ny, nx), np.int32)
    iy = np.empty((p_n, k_n, ny, nx), np.int32)
    ik = np.zeros((p_n, k_n, ny, nx), np.int32)
    msg = np.empty((k_n, ny, nx), np.float32)
    tmp = np.empty((ny, nx), np.float32)
    best = np.empty(n, np.float32)
    flat_msg = msg.reshape(k_n, n)
    flat_score = score.reshape(p_n, k_n, n)
    flat_ik = ik.reshape(p_n, k_n, n)
    for c in range(p_n - 1, 0, -1):
        par = parents[c]
        for k in range(k_n):
            dt2d(score[c, k], springs[c, k, 0], springs[c, k, 1], springs[c, k, 2],
                 springs[c, k, 3], anchors[c, k, 0], anchors[c, k, 1], msg[k], ix[c, k],
                 iy[c, k], tmp)
        # max over child types with the co-occurrence bias, type by type over whole maps
        # (contiguous inner loops that the compiler vectorises)
        for l in range(k_n):
            b0 = bias[c, l, 0]
            out_k = flat_ik[c, l]
            for j in range(n):
                best[j] = flat_msg[0, j] + b0
            for k in range(1, k_n):
                b = bias[c, l, k]
                for j in range(n):
                    s = flat_msg[k, j] + b
                    if s > best[j]:
                        best[j] = s
                        out_k[j] = k
            dst = flat_score[par, l]
            for j in range(n):
                dst[j] += best[j]
    root = np.empty((k_n, ny, nx), np.float32)
    for k in range(k_n):
        root[k] = score[0, k] + bias[0, 0, k]
    return root, ix, iy, ik, score


@nb.njit(cache=True)
def _spring_local(resp: NDArray[np.float32], springs: NDArray[np.float32],
                  anchors: NDArray[np.int32], bias: NDArray[np.float32], c: int, t: int, r: int,
                  q: int, pt: int, pr: int, pc: int) -> float:
    """Part c's share of the pose score at type t, cell (r, q) with its parent at (pt, pr, pc):
    its map value in `resp` (filter responses; subtree scores give the subtree's) less the
    spring, plus the type pair's bias."""
    dx = q - pc - anchors[c, t, 0]
    dy = r - pr - anchors[c, t, 1]
    sp = springs[c, t]
    return (resp[c, t, r, q] - (sp[0] * dx + sp[1] * dx * dx + sp[2] * dy + sp[3] * dy * dy)
            + bias[c, pt, t])


@nb.njit(cache=True)
def backtrack(roots: NDArray[np.int64], parents: NDArray[np.int64], resp: NDArray[np.float32],
              ix: NDArray[np.int32], iy: NDArray[np.int32], ik: NDArray[np.int32],
              springs: NDArray[np.float32], anchors: NDArray[np.int32],
              bias: NDArray[np.float32]):
    """Follow the argmaxes from root cells to every part.

    Parameters
    ----------
    roots : (N, 3) int (type, row, col) of the root.

    Returns
    -------
    parts : (N, P, 3) int64 (type, row, col) per part.
    local : (N, P) float32 each part's filter score + spring + bias (sums to the pose score).
    """
    n = roots.shape[0]
    p_n = parents.shape[0]
    out = np.empty((n, p_n, 3), np.int64)
    local = np.empty((n, p_n), np.float32)
    for j in range(n):
        t, y, x = roots[j, 0], roots[j, 1], roots[j, 2]
        out[j, 0, 0] = t
        out[j, 0, 1] = y
        out[j, 0, 2] = x
        local[j, 0] = resp[0, t, y, x] + bias[0, 0, t]
        for c in range(1, p_n):
            par = parents[c]
            lt, py, px = out[j, par, 0], out[j, par, 1], out[j, par, 2]
            k = ik[c, lt, py, px]
            cy = iy[c, k, py, px]
            cx = ix[c, k, cy, px]
            out[j, c, 0] = k
            out[j, c, 1] = cy
            out[j, c, 2] = cx
            local[j, c] = _spring_local(resp, springs, anchors, bias, c, k, cy, cx, lt, py, px)
    return out, local


@nb.njit(cache=True)
def subcell_offsets(score: NDArray[np.float32], parts: NDArray[np.int64],
                    parents: NDArray[np.int64], springs: NDArray[np.float32],
                    anchors: NDArray[np.int32]):
    """Sub-cell offsets (rows, cols) of a backtracked pose, each in [-0.5, 0.5]: per part and
    axis, the vertex of the parabola through its subtree score less its spring (the parent
    kept where it is) at the chosen cell and its two neighbours; 0 where that is not a peak."""
    p_n = parts.shape[0]
    ny, nx = score.shape[2], score.shape[3]
    dr = np.zeros(p_n)
    dc = np.zeros(p_n)
    for c in range(p_n):
        t, r, q = parts[c, 0], parts[c, 1], parts[c, 2]
        vals = np.empty(5)  # centre, up, down, left, right
        offs = ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1))
        ok = True
        for n in range(5):
            rr, qq = r + offs[n][0], q + offs[n][1]
            if rr < 0 or rr >= ny or qq < 0 or qq >= nx:
                vals[n] = np.nan
                continue
            v = np.float64(score[c, t, rr, qq])
            if c > 0:
                par = parents[c]
                dx = qq - parts[par, 2] - anchors[c, t, 0]
                dy = rr - parts[par, 1] - anchors[c, t, 1]
                sp = springs[c, t]
                v -= sp[0] * dx + sp[1] * dx * dx + sp[2] * dy + sp[3] * dy * dy
            vals[n] = v
        ok = not np.isnan(vals[0])
        if ok and not (np.isnan(vals[1]) or np.isnan(vals[2])):
            den = vals[1] - 2.0 * vals[0] + vals[2]
            if den < 0:
                dr[c] = min(max(0.5 * (vals[1] - vals[2]) / den, -0.5), 0.5)
        if ok and not (np.isnan(vals[3]) or np.isnan(vals[4])):
            den = vals[3] - 2.0 * vals[0] + vals[4]
            if den < 0:
                dc[c] = min(max(0.5 * (vals[3] - vals[4]) / den, -0.5), 0.5)
    return dr, dc


# Cells the tracking prior chooses among: this many best elbow cells (at least 2 cells apart),
# each with its best wrist and this many more.
LIMB_CANDIDATES = 4


@nb.njit(cache=True)
def _child_value(src: NDArray[np.float32], springs: NDArray[np.float32],
                 anchors: NDArray[np.int32], bias: NDArray[np.float32], c: int, pt: int,
                 pr: int, pc: int, out: NDArray[np.float64], arg: NDArray[np.int64]) -> None:
    """Part c's best value over its types at every cell with its parent at type `pt`, cell
    (pr, pc): ``src[c, t] - spring + bias[c, pt, t]`` (`src` = filter responses, or subtree
    scores to include the part's children), and the type that gives it."""
    k_n, ny, nx = src.shape[1], src.shape[2], src.shape[3]
    out[:] = -np.inf
    arg[:] = 0
    # type by type over whole maps (the same comparisons in the same order per cell as a loop
    # over the types per cell, in contiguous inner loops)
    for t in range(k_n):
        for r in range(ny):
            for q in range(nx):
                v = _spring_local(src, springs, anchors, bias, c, t, r, q, pt, pr, pc)
                if v > out[r, q]:
                    out[r, q] = v
                    arg[r, q] = t


@nb.njit(cache=True)
def _peaks(value: NDArray[np.float64], n: int) -> NDArray[np.int64]:
    """Up to n (row, col) of the highest cells of `value`, at least 2 cells apart (Chebyshev),
    best first (`value` is overwritten)."""
    ny, nx = value.shape
    out = np.empty((n, 2), np.int64)
    k = 0
    while k < n:
        i = np.argmax(value)
        r, q = i // nx, i % nx
        if not np.isfinite(value[r, q]):
            break
        out[k, 0] = r
        out[k, 1] = q
        k += 1
        value[max(r - 2, 0):r + 3, max(q - 2, 0):q + 3] = -np.inf
    return out[:k]


@nb.njit(cache=True)
def limb_candidates(resp: NDArray[np.float32], score: NDArray[np.float32],
                    ix: NDArray[np.int32], iy: NDArray[np.int32], ik: NDArray[np.int32],
                    parents: NDArray[np.int64], springs: NDArray[np.float32],
                    anchors: NDArray[np.int32], bias: NDArray[np.float32],
                    parts: NDArray[np.int64], mid: int, end: int, n: int):
    """The best few placements of a limb (part `mid` and its child `end`, -1 for none) with
    the rest of the backtracked pose `parts` (P, 3) fixed.

    The candidates are the DP's own placement first, then `n` best cells of `mid` given its
    parent (its subtree's best, at least 2 cells apart), each with its best `end` (as the DP
    backtracks it) and `n` more `end` cells given it.

    Returns
    -------
    cand : (M, 2, 3) int64 (type, row, col) of mid and end (end's all -1 without one).
    local : (M, 2) float64 each one's share of the pose score (0 for a missing end).
    """
    ny, nx = score.shape[2], score.shape[3]
    pt, pr, pc = parts[parents[mid], 0], parts[parents[mid], 1], parts[parents[mid], 2]
    value = np.empty((ny, nx))
    vtype = np.empty((ny, nx), np.int64)
    _child_value(score, springs, anchors, bias, mid, pt, pr, pc, value, vtype)
    mids = np.empty((n + 1, 3), np.int64)
    mids[0] = parts[mid]
    peaks = _peaks(value, n)
    m_n = 1
    for i in range(len(peaks)):
        r, q = peaks[i, 0], peaks[i, 1]
        t = vtype[r, q]
        if t == mids[0, 0] and r == mids[0, 1] and q == mids[0, 2]:
            continue
        mids[m_n, 0], mids[m_n, 1], mids[m_n, 2] = t, r, q
        m_n += 1
    per = 1 if end < 0 else n + 1
    cand = np.full((m_n * per, 2, 3), -1, np.int64)
    local = np.zeros((m_n * per, 2))
    ev = np.empty((ny, nx))
    et = np.empty((ny, nx), np.int64)
    k = 0
    for i in range(m_n):
        t, r, q = mids[i, 0], mids[i, 1], mids[i, 2]
        lm = _spring_local(resp, springs, anchors, bias, mid, t, r, q, pt, pr, pc)
        if end < 0:
            cand[k, 0] = mids[i]
            local[k, 0] = lm
            k += 1
            continue
        # the end as the DP backtracks it (for the DP's own mid: the pose's own end)
        if i == 0:
            bt, by, bx = parts[end, 0], parts[end, 1], parts[end, 2]
        else:
            bt = ik[end, t, r, q]
            by = iy[end, bt, r, q]
            bx = ix[end, bt, by, q]
        cand[k, 0] = mids[i]
        cand[k, 1, 0], cand[k, 1, 1], cand[k, 1, 2] = bt, by, bx
        local[k, 0] = lm
        local[k, 1] = _spring_local(resp, springs, anchors, bias, end, bt, by, bx, t, r, q)
        k += 1
        _child_value(resp, springs, anchors, bias, end, t, r, q, ev, et)
        ends = _peaks(ev, n)
        for j in range(len(ends)):
            er, eq = ends[j, 0], ends[j, 1]
            cand[k, 0] = mids[i]
            cand[k, 1, 0], cand[k, 1, 1], cand[k, 1, 2] = et[er, eq], er, eq
            local[k, 0] = lm
            local[k, 1] = _spring_local(resp, springs, anchors, bias, end, et[er, eq], er, eq,
                                        t, r, q)
            k += 1
    return cand[:k], local[:k]


# --------------------------------------------------------------------------- one level


@dataclass(frozen=True)
class LevelResult:
    """The DP of one level, kept for backtracking (and for training's feature extraction)."""

    level: Level
    resp: NDArray[np.float32]   # (P, K, ny, nx)
    root: NDArray[np.float32]   # (K, ny, nx)
    ix: NDArray[np.int32]
    iy: NDArray[np.int32]
    ik: NDArray[np.int32]
    score: NDArray[np.float32] | None = None   # (P, K, ny, nx) subtree scores
    unary: NDArray[np.float32] | None = None   # (P, ny, nx) the network's term in `resp`


def model_arrays(model: PartModel) -> tuple:
    """The model's arrays in the dtypes the numba kernels take (computed once per model)."""
    return (np.ascontiguousarray(model.filter_matrix()),
            np.asarray(model.parents, np.int64),
            np.ascontiguousarray(model.springs, np.float32),
            np.ascontiguousarray(model.anchors, np.int32),
            np.ascontiguousarray(model.bias, np.float32))


def score_level(level: Level, model: PartModel, arrays: tuple | None = None,
                unary: Callable[[Level, int, int], NDArray[np.float32]] | None = None,
                floor: Callable[[Level, NDArray[np.float32]], None] | None = None
                ) -> LevelResult | None:
    """Filter responses (one GEMM) and the tree DP on one pyramid level; None if the level's
    image (without its padding) is smaller than a filter. `unary(level, ny, nx)`: a (P, ny,
    nx) term added to every type's response of each part (`core.dpm.net_unary`);
    `floor(level, resp)`: raises the responses in place before the DP
    (`core.dpm.infer.OcclusionFloor`)."""
    wmat, parents, springs, anchors, bias = arrays if arrays is not None else model_arrays(model)
    fh, fw = model.filter_shape
    h, w, _ = level.feat.shape
    ih, iw = level.image_cells
    if ih < fh or iw < fw:
        return None
    ny, nx = h - fh + 1, w - fw + 1
    cols = im2col(level.feat, fh, fw)
    # positions x filters, then transposed: the same products as wmat @ cols.T (the same
    # responses), 12 % less time with the features' rows cold in the cache
    resp = np.ascontiguousarray((cols @ wmat.T).T).reshape(model.n_parts, model.n_types,
                                                           ny, nx)
    extra = None
    if unary is not None:
        extra = unary(level, ny, nx)
        resp += extra[:, None]
    if floor is not None:
        floor(level, resp)
    root, ix, iy, ik, score = tree_dp(resp, parents, springs, anchors, bias)
    return LevelResult(level, resp, root, ix, iy, ik, score, extra)


def best_roots(result: LevelResult, count: int, threshold: float = -np.inf,
               min_dist: int = 1) -> NDArray[np.int64]:
    """Up to `count` root cells (type, row, col) with the highest scores >= threshold, at least
    `min_dist` cells apart (Chebyshev), best first."""
    best = result.root.max(axis=0)
    btype = result.root.argmax(axis=0)
    if count == 1:
        r, c = np.unravel_index(int(np.argmax(best)), best.shape)
        if best[r, c] < threshold:
            return np.zeros((0, 3), np.int64)
        return np.array([[btype[r, c], r, c]], np.int64)
    order = np.argsort(-best, axis=None, kind='stable')
    flat = best.ravel()
    picked: list[tuple[int, int, int]] = []
    for idx in order:
        if flat[idx] < threshold or len(picked) >= count:
            break
        r, c = divmod(int(idx), best.shape[1])
        if all(max(abs(r - pr), abs(c - pc)) >= min_dist for _, pr, pc in picked):
            picked.append((int(btype[r, c]), r, c))
    return np.array(picked, np.int64).reshape(-1, 3)
