"""Pose estimation metrics of the paper's tables (after Yang & Ramanan, PAMI 2013).

- PCK: a predicted joint is correct when it lies within `alpha * max(h, w)` of the ground
  truth, h and w being the size of the tight box around the frame's visible ground-truth
  joints. A missing prediction (NaN) counts as wrong.
- APK: each predicted joint is a detection with a score; detections are sorted by score and a
  detection is a true positive when within the same distance of its ground truth, otherwise a
  false positive. Average precision over the precision-recall curve (all points, VOC style),
  recall relative to the number of visible ground-truth joints.
- Error: mean pixel distance to the ground truth, over the joints that were predicted.
- 3-D (where predictions and ground truth have 3-D positions): over the same joints as PCK
  (visible ground truth with a 3-D position), the median distance to the ground truth in mm
  (`error_mm`) and the percentage within 10 cm (`within_10cm`). A joint without a predicted 3-D
  position counts as infinitely far: it is never within 10 cm, and when more than half of a
  group's joints have none, its median is infinite (null in JSON).

Left and right joints are pooled into groups (`skeleton.JOINT_GROUPS`). The PCK, APK and pixel
error `average` is over the groups of the paper's tables present (head, shoulder, wrist, hip,
ankle); PCK's `average7` is over all seven groups (NaN unless all seven are scored); the 3-D
metrics' `average` is over every group present.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.core.skeleton import JOINT_GROUPS, TABLE_GROUPS

WITHIN_M = 0.10  # the 3-D hit distance of `within_10cm`, metres


def reference_size(gt: NDArray[np.floating], visible: NDArray[np.bool_]) -> NDArray[np.float64]:
    """max(h, w) of the tight box around each frame's visible ground-truth joints.

    Parameters
    ----------
    gt : (F, J, 2) float pixels.
    visible : (F, J) bool.

    Returns
    -------
    (F,) float64 pixels; NaN for frames without two visible joints.
    """
    gt = np.asarray(gt, dtype=np.float64)
    vis = np.asarray(visible, dtype=bool) & np.isfinite(gt).all(axis=2)
    pts = np.where(vis[..., None], gt, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)  # all-NaN frames
        span = np.nanmax(pts, axis=1) - np.nanmin(pts, axis=1)
    size = np.max(span, axis=1)
    size[vis.sum(axis=1) < 2] = np.nan
    return size


def _distances(pred: NDArray, gt: NDArray) -> NDArray[np.float64]:
    d = np.asarray(pred, np.float64) - np.asarray(gt, np.float64)
    return np.hypot(d[..., 0], d[..., 1])


def _check(pred: NDArray, gt: NDArray, visible: NDArray) -> None:
    if np.shape(pred) != np.shape(gt) or np.shape(gt)[-1:] != (2,) or np.ndim(gt) != 3:
        raise ValueError(f'pred {np.shape(pred)} and gt {np.shape(gt)} must both be (F, J, 2)')
    if np.shape(visible) != np.shape(gt)[:2]:
        raise ValueError(f'visible {np.shape(visible)} must be (F, J) = {np.shape(gt)[:2]}')


def correct(pred: NDArray, gt: NDArray, visible: NDArray, *, alpha: float = 0.1
            ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per-joint correctness under the PCK rule.

    Returns
    -------
    hit : (F, J) bool, prediction within `alpha * size` of the ground truth.
    counted : (F, J) bool, the ground truth is visible in a frame with a reference size.
    """
    _check(pred, gt, visible)
    size = reference_size(gt, visible)
    counted = np.asarray(visible, bool) & np.isfinite(gt).all(axis=2) & np.isfinite(size)[:, None]
    with np.errstate(invalid='ignore'):
        hit = _distances(pred, gt) <= alpha * size[:, None]
    return hit & counted, counted


def pck_per_frame(pred: NDArray, gt: NDArray, visible: NDArray, *, alpha: float = 0.1
                  ) -> NDArray[np.float64]:
    """(F,) PCK@alpha of each frame in percent over its counted joints (`correct`); NaN where
    none is."""
    hit, counted = correct(pred, gt, visible, alpha=alpha)
    n = counted.sum(axis=1)
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(n > 0, 100.0 * (hit & counted).sum(axis=1) / n, np.nan)


def average_precision(scores: NDArray, true_positive: NDArray[np.bool_], n_positives: int
                      ) -> float:
    """All-point interpolated average precision of scored detections, in [0, 1]."""
    if n_positives <= 0:
        return float('nan')
    order = np.argsort(-np.asarray(scores, np.float64), kind='stable')
    tp = np.asarray(true_positive, bool)[order]
    ctp = np.cumsum(tp)
    recall = ctp / n_positives
    precision = ctp / np.arange(1, len(tp) + 1)
    # precision envelope, then area under the step curve
    mrec = np.concatenate([[0.0], recall, [recall[-1] if len(recall) else 0.0]])
    mpre = np.concatenate([[0.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    steps = np.nonzero(mrec[1:] != mrec[:-1])[0]
    return float(np.sum((mrec[steps + 1] - mrec[steps]) * mpre[steps + 1]))


def score_groups(pred: NDArray, scores: NDArray, gt: NDArray, visible: NDArray,
                 names: list[str] | tuple[str, ...], *, alphas: tuple[float, ...] = (0.1, 0.2),
                 pred_xyz: NDArray | None = None, gt_xyz: NDArray | None = None
                 ) -> dict[str, dict[str, float]]:
    """The paper's table for one method: PCK, APK and pixel error per joint group, and the
    3-D errors when `pred_xyz` and `gt_xyz` are given.

    Parameters
    ----------
    pred : (F, J, 2) float predicted pixels, NaN = not predicted.
    scores : (F, J) float detection scores (higher = more confident), for APK.
    gt : (F, J, 2) float ground-truth pixels, same joint order as `names`.
    visible : (F, J) bool, ground truth visible / labelled.
    names : J joint names (skeleton names; see `skeleton.JOINT_GROUPS`).
    alphas : PCK thresholds; the first is the main one (`pck`, `apk`), each also gives
        `pck@<alpha>`.
    pred_xyz, gt_xyz : (F, J, 3) float metres in one frame (the camera's), NaN = unknown.

    Returns
    -------
    {'pck': {group: percent, ..., 'average': percent, 'average7': percent}, 'pck@0.2':
    {...}, 'apk': {...}, 'error_px': {...}} over the groups present in `names`, and with 3-D
    'error_mm' {group: mm, ..., 'average': mm} and 'within_10cm' {group: percent, ...,
    'average': percent}.
    """
    _check(pred, gt, visible)
    if (pred_xyz is None) != (gt_xyz is None):
        raise ValueError('give both pred_xyz and gt_xyz, or neither')
    if gt_xyz is not None and not (np.shape(pred_xyz) == np.shape(gt_xyz)
                                   == np.shape(gt)[:2] + (3,)):
        raise ValueError(f'pred_xyz {np.shape(pred_xyz)} and gt_xyz {np.shape(gt_xyz)} must '
                         f'both be (F, J, 3) = {np.shape(gt)[:2] + (3,)}')
    scores = np.asarray(scores, np.float64)
    if scores.shape != np.shape(gt)[:2]:
        raise ValueError(f'scores {scores.shape} must be (F, J) = {np.shape(gt)[:2]}')
    if len(names) != np.shape(gt)[1]:
        raise ValueError(f'{len(names)} names for {np.shape(gt)[1]} joints')
    predicted = np.isfinite(np.asarray(pred, np.float64)).all(axis=2)
    dist = _distances(pred, gt)
    groups = _groups(names)

    table: dict[str, dict[str, float]] = {}
    for k, alpha in enumerate(alphas):
        hit, counted = correct(pred, gt, visible, alpha=alpha)
        table['pck' if k == 0 else f'pck@{alpha:g}'] = _pck(hit, counted, groups)
        if k == 0:
            counted_main = counted
            apk = {}
            for g, idx in groups.items():
                det = predicted[:, idx] & np.isfinite(scores[:, idx])
                apk[g] = 100.0 * average_precision(
                    scores[:, idx][det], hit[:, idx][det], int(counted[:, idx].sum()))
            table['apk'] = _with_average(apk)
    err = {}
    for g, idx in groups.items():
        ok = predicted[:, idx] & np.asarray(visible, bool)[:, idx] & np.isfinite(dist[:, idx])
        err[g] = float(dist[:, idx][ok].mean()) if ok.any() else float('nan')
    table['error_px'] = _with_average(err)
    if gt_xyz is not None:
        table.update(_errors_3d(np.asarray(pred_xyz, np.float64), np.asarray(gt_xyz, np.float64),
                                counted_main, groups))
    # main alpha first for readers: pck, pck@0.2, apk, error_px, error_mm, within_10cm
    if len(alphas) > 1:
        table = {'pck': table['pck'], **{k: v for k, v in table.items() if k != 'pck'}}
    return table


def _groups(names: list[str] | tuple[str, ...]) -> dict[str, list[int]]:
    """The joint groups present in `names`: {group: indices into names}."""
    groups = {g: [names.index(n) for n in members if n in names]
              for g, members in JOINT_GROUPS.items()}
    return {g: idx for g, idx in groups.items() if idx}


def _pck(hit: NDArray[np.bool_], counted: NDArray[np.bool_], groups: dict[str, list[int]]
         ) -> dict[str, float]:
    """PCK per group in percent, with its `average` and `average7`."""
    pck = {g: 100.0 * float(hit[:, idx].sum()) / max(int(counted[:, idx].sum()), 1)
           for g, idx in groups.items()}
    return {**_with_average(pck), 'average7': _mean([pck.get(g, np.nan) for g in JOINT_GROUPS])}


def _distances_3d(pred_xyz: NDArray[np.float64], gt_xyz: NDArray[np.float64],
                  counted: NDArray[np.bool_], groups: dict[str, list[int]]
                  ) -> dict[str, NDArray[np.float64]]:
    """3-D distances in metres per group, over the counted joints with a 3-D ground truth;
    a joint without a predicted 3-D position is infinitely far (never close enough)."""
    scored = counted & np.isfinite(gt_xyz).all(axis=2)
    dist = np.linalg.norm(pred_xyz - gt_xyz, axis=2)
    dist[~np.isfinite(dist)] = np.inf
    return {g: dist[:, idx][scored[:, idx]] for g, idx in groups.items()}


def _errors_3d(pred_xyz: NDArray[np.float64], gt_xyz: NDArray[np.float64],
               counted: NDArray[np.bool_], groups: dict[str, list[int]]
               ) -> dict[str, dict[str, float]]:
    """`error_mm` and `within_10cm` per group (see the module docstring)."""
    dist = _distances_3d(pred_xyz, gt_xyz, counted, groups)
    error_mm, within = {}, {}
    for g, d in dist.items():
        error_mm[g] = 1e3 * float(np.median(d)) if d.size else float('nan')
        within[g] = 100.0 * float(np.mean(d <= WITHIN_M)) if d.size else float('nan')
    scored_groups = [g for g in groups if not np.isnan(error_mm[g])]
    return {'error_mm': {**error_mm, 'average': _mean([error_mm[g] for g in scored_groups])},
            'within_10cm': {**within, 'average': _mean([within[g] for g in scored_groups])}}


def _mean(values: list[float]) -> float:
    """The mean, NaN if any value is NaN (a group not scored) or there is none; an infinite
    value makes it infinite."""
    return float(np.mean(values)) if values and not np.isnan(values).any() else float('nan')


def _with_average(values: dict[str, float]) -> dict[str, float]:
    core = [values[g] for g in TABLE_GROUPS if g in values and np.isfinite(values[g])]
    out = {g: values[g] for g in JOINT_GROUPS if g in values}
    out['average'] = float(np.mean(core)) if core else float('nan')
    return out


def joint_arrays(predictions: list[JointSet | None], truths: list[JointSet],
                 names: tuple[str, ...], *,
                 image_sizes: Sequence[tuple[int, int]] | None = None
                 ) -> dict[str, NDArray]:
    """Frame-aligned predictions and ground truths as the arrays of `score_groups`.

    Parameters
    ----------
    predictions : one JointSet per frame (None = no output for that frame: every joint wrong).
        MISSING joints count as not predicted; a joint's confidence is its APK score.
    truths : the ground truth of each frame, e.g. CAD-60's 15 joints; a joint is visible when
        labelled (`JointSet.labelled`: its confidence positive and its pixel finite, a
        predicted `left_wrist` scored against CAD-60's `left_hand`).
    names : the joints to score (predicted names).
    image_sizes : (width, height) of each frame; ground-truth joints outside the image are not
        visible.

    Returns
    -------
    {'pred', 'scores', 'gt', 'visible', 'pred_xyz', 'gt_xyz'}: the keyword arguments of
    `score_groups` (with `names`); the 3-D pair is None unless the ground truth has 3-D
    positions and the predictions have any (a row without 3-D output, such as the RGB-only
    baseline, has none).
    """
    if len(predictions) != len(truths):
        raise ValueError(f'{len(predictions)} predictions for {len(truths)} frames')
    f, j = len(truths), len(names)
    pred = np.full((f, j, 2), np.nan)
    pred_xyz = np.full((f, j, 3), np.nan)
    scores = np.full((f, j), np.nan)
    gt = np.full((f, j, 2), np.nan)
    gt_xyz = np.full((f, j, 3), np.nan)
    visible = np.zeros((f, j), bool)
    for k, (p, t) in enumerate(zip(predictions, truths, strict=True)):
        gt[k], gt_xyz[k], visible[k] = t.labelled(names)
        if image_sizes is not None:
            w, h = image_sizes[k]
            with np.errstate(invalid='ignore'):
                visible[k] &= ((gt[k] >= 0) & (gt[k] <= (w - 1, h - 1))).all(axis=1)
        for i, name in enumerate(names):
            pi = p.get(name) if p is not None else None
            if pi is not None and p.source[pi] != MISSING:
                pred[k, i] = p.uv[pi]
                pred_xyz[k, i] = p.xyz[pi]
                scores[k, i] = p.confidence[pi]
    with_3d = np.isfinite(gt_xyz).any() and np.isfinite(pred_xyz).any()
    return {'pred': pred, 'scores': scores, 'gt': gt, 'visible': visible,
            'pred_xyz': pred_xyz if with_3d else None, 'gt_xyz': gt_xyz if with_3d else None}


def score_joint_sets(predictions: list[JointSet | None], truths: list[JointSet],
                     names: tuple[str, ...], *, alphas: tuple[float, ...] = (0.1, 0.2),
                     image_sizes: Sequence[tuple[int, int]] | None = None
                     ) -> dict[str, dict[str, float]]:
    """The table of `score_groups` for frame-aligned predictions and ground truths (see
    `joint_arrays`)."""
    arrays = joint_arrays(predictions, truths, names, image_sizes=image_sizes)
    return score_groups(names=names, alphas=alphas, **arrays)


def curves(pred: NDArray, gt: NDArray, visible: NDArray, names: list[str] | tuple[str, ...],
           alphas: NDArray[np.floating], *, pred_xyz: NDArray | None = None,
           gt_xyz: NDArray | None = None, **_: object) -> dict[str, dict[str, list[float]]]:
    """PCK against the threshold per group, and the 3-D distances behind `within_10cm`.

    Takes the arrays of `joint_arrays` (its `scores` ignored). At each alpha of `alphas` the
    PCK of each group is the `pck` of `score_groups` at that alpha (the same rule, `correct`),
    and 'average' and 'average7' as there.

    Returns
    -------
    {'pck': {group: [percent per alpha], 'average': [...], 'average7': [...]}, and with 3-D
    'distance_mm': {group: sorted distances in mm (inf = no 3-D prediction)}} over the joints
    PCK counts at the first alpha (the counted joints do not depend on alpha).
    """
    groups = _groups(names)
    per_alpha = [_pck(*correct(pred, gt, visible, alpha=float(alpha)), groups)
                 for alpha in np.asarray(alphas, np.float64)]
    out: dict[str, dict[str, list[float]]] = {
        'pck': {k: [row[k] for row in per_alpha] for k in per_alpha[0]} if per_alpha else {}}
    if pred_xyz is not None and gt_xyz is not None:
        _, counted = correct(pred, gt, visible)
        dist = _distances_3d(np.asarray(pred_xyz, np.float64), np.asarray(gt_xyz, np.float64),
                             counted, groups)
        out['distance_mm'] = {g: sorted(1e3 * d) for g, d in dist.items()}
    return out
