"""Hard-negative mining (`train`, step 4): the current model's poses that violate a
constraint, in background images and, by loss-augmented inference, in the labelled frames.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.dpm.dp import (
    LevelResult,
    backtrack,
    best_roots,
    model_arrays,
    score_level,
    tree_dp,
)
from pose4d_ros.core.dpm.dt import NEG
from pose4d_ros.core.dpm.infer import Detector, SearchPlan
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.hog import Level
from pose4d_ros.training.dpm.samples import (
    Negative,
    Positive,
    Progress,
    TrainConfig,
    frame_of,
    level_of,
)
from pose4d_ros.training.dpm.solver import Examples, Layout, Whitening, dot, pose_blocks, whitened


def _add_new(ex: Examples, candidates: Iterable[tuple], room: int) -> int:
    """Add the candidate constraints (key, blocks, label, margin, ref) whose key the cache does
    not hold yet, until `room` are added or the cache is full; returns how many were added.
    `blocks` is called for a new key only (the constraint's feature blocks)."""
    seen = set(ex.keys)
    added = 0
    for key, blocks, label, margin, ref in candidates:
        if key in seen:
            continue
        if not ex.add(blocks(), label, margin, ref, key):
            break
        seen.add(key)
        added += 1
        if added >= room:
            break
    return added


def mine_background(model: PartModel, negatives: list[Negative], ex: Examples, lay: Layout,
                    cfg: TrainConfig, white: Whitening, room: int,
                    progress: Progress | None, round_: int) -> int:
    """Add poses scoring above -1 in background images (at most `room`); returns how many."""
    return _add_new(ex, _background_poses(model, negatives, lay, cfg, white, progress, round_),
                    room)


def _background_poses(model: PartModel, negatives: list[Negative], lay: Layout,
                      cfg: TrainConfig, white: Whitening, progress: Progress | None,
                      round_: int) -> Iterator[tuple]:
    det = Detector(model)
    arrays = det._arrays
    _, parents, springs, anchors, bias = arrays
    lo, hi = model.scale_range_px
    n_lev = max(int(np.ceil(np.log2(hi / lo) * cfg.levels_per_octave)) + 1, 1)
    scales = tuple(cfg.canonical_scale_px / (lo * (hi / lo) ** (i / max(n_lev - 1, 1)))
                   for i in range(n_lev))
    it: Iterable = enumerate(negatives)
    if progress is not None:
        it = progress(it, f'round {round_}: background', len(negatives))
    for j, neg in it:
        h, w = neg.color.shape[:2]
        plan = SearchPlan(0, 0, w, h, scales, False)
        found = []
        for li, level in enumerate(det.pyramid(neg.color, neg.depth_m, plan)):
            res = score_level(level, model, arrays)
            if res is None:
                continue
            roots = best_roots(res, cfg.negatives_per_image, -1.0, min_dist=2)
            if len(roots) == 0:
                continue
            parts, local = backtrack(roots, parents, res.resp, res.ix, res.iy, res.ik,
                                     springs, anchors, bias)
            for k in range(len(roots)):
                found.append((float(local[k].sum()), li, level, parts[k]))
        found.sort(key=lambda f: -f[0])
        for _score, li, level, parts in found[:cfg.negatives_per_image]:
            yield (('neg', j, li, *parts.ravel().tolist()),
                   lambda level=level, parts=parts: whitened(pose_blocks(
                       level.feat, parts, parents, anchors, lay, cfg.filter_cells,
                       cfg.bias_feature), white), -1.0, 1.0, -1)


def mine_structural(model: PartModel, pos: list[Positive], samples: Sequence,
                    w: NDArray[np.float64], ex: Examples, lay: Layout, cfg: TrainConfig,
                    white: Whitening, room: int, progress: Progress | None, round_: int) -> int:
    """Add violated margin-rescaling constraints from the labelled frames: the poses that
    maximise score + loss (exact, the loss decomposes over parts) and whose score is not at
    least their loss below the labelled pose's. Returns how many were added."""
    return _add_new(ex, _violating_poses(model, pos, samples, w, ex, lay, cfg, white, progress,
                                         round_), room)


def _positive_levels(model: PartModel, pos: list[Positive], samples: Sequence,
                     cfg: TrainConfig, progress: Progress | None, label: str
                     ) -> Iterator[tuple[int, Positive, Level, LevelResult]]:
    """(index, positive, its level, the model's DP on it) for every labelled pose whose
    level is at least a filter large."""
    arrays = model_arrays(model)
    it: Iterable = enumerate(pos)
    if progress is not None:
        it = progress(it, label, len(pos))
    for i, p in it:
        color, depth, mask, _ = frame_of(samples[p.sample], cfg.tree.names, cfg, p.flipped)
        level = level_of(color, depth, mask, p.box, p.level_scale, cfg)
        res = score_level(level, model, arrays)
        if res is not None:
            yield i, p, level, res


def _violating_poses(model: PartModel, pos: list[Positive], samples: Sequence,
                     w: NDArray[np.float64], ex: Examples, lay: Layout, cfg: TrainConfig,
                     white: Whitening, progress: Progress | None, round_: int
                     ) -> Iterator[tuple]:
    _, parents, springs, anchors, bias = model_arrays(model)
    p_n = lay.n_parts
    unit = 2.0 / p_n
    arr = ex.arrays()
    for i, p, level, res in _positive_levels(model, pos, samples, cfg, progress,
                                             f'round {round_}: poses'):
        ny, nx = res.resp.shape[2:]
        yy, xx = np.mgrid[0:ny, 0:nx]
        far = np.hypot(yy[None] - p.cells[:, 0, None, None],
                       xx[None] - p.cells[:, 1, None, None]) > p.tau     # (P, ny, nx)
        far &= p.known()[:, None, None]   # an unlabelled part is never wrong
        aug = res.resp + (unit * far).astype(np.float32)[:, None]
        root, ix, iy, ik, _ = tree_dp(aug, parents, springs, anchors, bias)
        aug_res = LevelResult(level, aug, root, ix, iy, ik)
        roots = best_roots(aug_res, cfg.structural_per_positive, min_dist=2)
        if len(roots) == 0:
            continue
        poses, local = backtrack(roots, parents, aug, ix, iy, ik, springs, anchors, bias)
        gt_score = float(dot(w, *arr[:6], arr[8], i))
        for k in range(len(roots)):
            wrong = far[np.arange(p_n), poses[k, :, 1], poses[k, :, 2]]
            loss = unit * float(wrong.sum())
            if loss <= 0:
                continue
            score = float(local[k].sum()) - loss
            if gt_score - score >= loss - 1e-6:
                continue
            yield (('pose', i, *poses[k].ravel().tolist()),
                   lambda level=level, pose=poses[k]: whitened(pose_blocks(
                       level.feat, pose, parents, anchors, lay, cfg.filter_cells,
                       cfg.bias_feature), white, -1.0), 1.0, loss, i)


def relabel_positives(model: PartModel, pos: list[Positive], types: NDArray[np.int64],
                      samples: Sequence, ex: Examples, lay: Layout, cfg: TrainConfig,
                      white: Whitening, progress: Progress | None, round_: int) -> int:
    """Latent positives (Yang & Ramanan's `poslatent`): each labelled pose i (example i of
    `ex`) becomes the best pose of the current model whose part c keeps its type
    `types[i, c]` and lies within `cfg.latent_radius` cells (Chebyshev) of its labelled cell;
    an unlabelled part may take any cell and type, a labelled one of type -1 any type.
    Rewrites the examples' blocks in place; returns how many poses moved."""
    _, parents, springs, anchors, bias = model_arrays(model)
    r = cfg.latent_radius
    moved = 0
    for i, p, level, res in _positive_levels(model, pos, samples, cfg, progress,
                                             f'round {round_}: latent positives'):
        ny, nx = res.resp.shape[2:]
        resp = np.full_like(res.resp, NEG)
        known = p.known()
        for c in range(lay.n_parts):
            t = int(types[i, c])
            if not known[c]:   # an unlabelled part: anywhere, any type
                resp[c] = res.resp[c]
                continue
            if t < 0:          # labelled, but its offset type is unknown: any type
                t = slice(None)
            r0, c0 = int(p.cells[c, 0]), int(p.cells[c, 1])
            ys = slice(max(r0 - r, 0), min(r0 + r + 1, ny))
            xs = slice(max(c0 - r, 0), min(c0 + r + 1, nx))
            resp[c, t, ys, xs] = res.resp[c, t, ys, xs]
        root, ix, iy, ik, _ = tree_dp(resp, parents, springs, anchors, bias)
        roots = best_roots(LevelResult(level, resp, root, ix, iy, ik), 1)
        if len(roots) == 0 or root[roots[0, 0], roots[0, 1], roots[0, 2]] < NEG / 2:
            continue
        parts, _ = backtrack(roots, parents, resp, ix, iy, ik, springs, anchors, bias)
        ex.xf[i], ex.of[i], ex.xd[i], ex.od[i], ex.xb[i], ex.ob[i] = whitened(pose_blocks(
            level.feat, parts[0], parents, anchors, lay, cfg.filter_cells, cfg.bias_feature),
            white)
        moved += int((parts[0, :, 1:] != p.cells).any())
    return moved
