"""The part refiner's training (`core.refine`): the detections it learns from, run as the nodes
run them, its samples and what each part is to learn (`targets`), a stage's ensembles
(`fit_refiner`, boosted trees of `training.boost`), and the cascade of stages fitted one after
the other, each on the parts as the stages before it move them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.boost import BoostedTrees
from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.refine import (
    LIMITS,
    OUTPUTS,
    PartRefiner,
    group_of,
    known_parts,
    mirrored_parts,
    person_scale,
)
from pose4d_ros.core.refine import features as refine_features
from pose4d_ros.core.stages import DetectorStage, ForegroundStage
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.training.boost import fit
from pose4d_ros.util.progress import progress


@dataclass
class RefinerFrame:
    """What a refiner stage learns from, per labelled frame: the detector's parts (`uv`, lifted
    depths `z`, `confidence`), the frame's depth on the person (NaN elsewhere) and its camera,
    and the joints' true pixels and depths where `labelled`."""

    uv: NDArray[np.float64]
    z: NDArray[np.float64]
    confidence: NDArray[np.float64]
    depth: NDArray[np.float32]
    intrinsics: Intrinsics
    true_uv: NDArray[np.float64]
    true_z: NDArray[np.float64]
    labelled: NDArray[np.bool_]


def refiner_frames(model: PartModel, samples: list[Frame]) -> list[RefinerFrame]:
    """The foreground and `model`'s detector (its refiner left out) run over `samples` as the
    nodes run them (each video in order, the previous frame guiding the arms), once for all
    the stages: each frame's depth is kept in memory (0.3 MB at 320x240; 11,092 frames, 3.4
    GB)."""
    foreground = ForegroundStage()
    detector = DetectorStage(replace(model, refiner=None))
    out = []
    video = None
    for f in progress(samples, 'detections', len(samples)):
        if f.depth_m is None or f.intrinsics is None:
            raise ValueError(f'{f.key}: --refine needs RGB-D frames with camera intrinsics')
        if f.video != video:
            foreground.reset()
            detector.reset()
            video = f.video
        fg, color, depth = foreground.step(f.color, f.depth_m, f.intrinsics)
        found = detector.step(color, depth, f.intrinsics, mask=fg.mask,
                              stamp_s=f.stamp_ns * 1e-9, blanked=True)
        true_uv, truth, labelled = f.truth.labelled(found.names)
        out.append(RefinerFrame(found.uv, found.xyz[:, 2], found.confidence.astype(np.float64),
                                np.where(fg.mask, depth, np.nan).astype(np.float32),
                                f.intrinsics, true_uv, truth[:, 2], labelled))
    return out


def moved(frame: RefinerFrame, model: PartModel, stage: PartRefiner) -> RefinerFrame:
    """`frame` with its parts where `stage` (one or more of `model`'s refiner stages) puts
    them."""
    uv, z = stage.apply(model.part_names, model.parents, frame.uv, frame.z, frame.confidence,
                        frame.depth, frame.intrinsics)
    return replace(frame, uv=uv, z=z)


def refiner_samples(model: PartModel, frames: list[RefinerFrame]
                    ) -> tuple[NDArray[np.float32], NDArray[np.int64], NDArray[np.float64]]:
    """The training samples of a refiner stage: for every labelled part of `frames` with a
    detection and a lifted depth, where the stages before it put it, its features
    (`core.refine.features`), its index and what the stage is to learn
    (`targets`)."""
    names = model.part_names
    xs, parts, ys = [], [], []
    for f in frames:
        x = refine_features(names, model.parents, f.uv, f.z, f.confidence, f.depth,
                            f.intrinsics)
        y = targets(names, f.uv, f.z, f.true_uv, f.true_z, f.intrinsics.fx)
        use = f.labelled & np.isfinite(y).all(axis=1) & known_parts(x)
        xs.append(x[use])
        parts.append(np.flatnonzero(use))
        ys.append(y[use])
    return np.concatenate(xs), np.concatenate(parts), np.concatenate(ys)


def fit_stages(model: PartModel, frames: list[RefinerFrame], *, stages: int,
               depth_stages: int, trees: int, tree_depth: int,
               say: Callable[[str], None] = print) -> tuple[PartRefiner, int]:
    """`model`'s part refiner fitted on `frames`: `stages` stages of every output, then
    `depth_stages` of the depth only, each on the parts where the stages before it put them;
    the refiner and the number of samples of its last stage. `say` reports each stage."""
    refiner: PartRefiner | None = None
    n_stages = stages + depth_stages
    for stage in range(n_stages):
        x, part, target = refiner_samples(model, frames)
        fitted = fit_refiner(model.part_names, x, part, target, trees=trees, depth=tree_depth,
                             outputs=OUTPUTS if stage < stages else ('dz',))
        refiner = fitted if refiner is None else refiner.then(fitted)
        if stage + 1 < n_stages:  # the next stage learns where this one puts the parts
            frames = [moved(f, model, fitted) for f in frames]
        say(f'refiner stage {stage + 1}: {len(target)} parts, median residual '
            f'{1000 * np.median(np.abs(target[:, 2])):.1f} mm in depth, '
            f'{np.median(np.hypot(*target[:, :2].T)):.3f} person scales across')
    return refiner, len(target)


def targets(names: Sequence[str], uv: NDArray[np.floating], z: NDArray[np.floating],
            true_uv: NDArray[np.floating], true_z: NDArray[np.floating], fx: float
            ) -> NDArray[np.float64]:
    """(P, 3) what the refiner learns for detected parts (`uv`, lifted depths `z`) whose joints
    are at `true_uv`, `true_z`: `OUTPUTS`, NaN where either is unknown."""
    scale = person_scale(z, fx)
    d = (np.asarray(true_uv, np.float64) - uv) / scale
    d[:, 0] = np.where(mirrored_parts(tuple(names)), -d[:, 0], d[:, 0])
    return np.column_stack([d, np.asarray(true_z, np.float64) - z])


def fit_refiner(names: Sequence[str], x: NDArray[np.floating], part: NDArray[np.integer],
                target: NDArray[np.floating], *, trees: int = 200, depth: int = 5,
                min_samples: int = 200, outputs: Sequence[str] = OUTPUTS) -> PartRefiner:
    """Fit the ensembles of each group of `names` on samples `x` (N, F) of parts `part` (N,)
    (indices into `names`) with `target` (N, 3) (`targets`; clipped to the largest
    corrections); only those of `outputs` (the others correct nothing). Groups with fewer than
    `min_samples` samples get none."""
    if not outputs or not set(outputs) <= set(OUTPUTS):
        raise ValueError(f'outputs must be some of {OUTPUTS}, got {tuple(outputs)}')
    x = np.asarray(x, np.float64)
    part = np.asarray(part)
    target = np.clip(np.asarray(target, np.float64), -LIMITS, LIMITS)
    ok = known_parts(x) & np.isfinite(target).all(axis=1)
    groups, ensembles = [], []
    for g in dict.fromkeys(group_of(n) for n in names):
        sel = ok & np.isin(part, [i for i, n in enumerate(names) if group_of(n) == g])
        if sel.sum() >= min_samples:
            groups.append(g)
            ensembles += [fit(x[sel], target[sel, k], trees=trees, depth=depth)
                          if out in outputs else _nothing(trees, depth)
                          for k, out in enumerate(OUTPUTS)]
    if not groups:
        raise ValueError(f'too few samples to fit a part refiner ({int(ok.sum())})')
    return PartRefiner.stack(groups, ensembles)


def _nothing(trees: int, depth: int) -> BoostedTrees:
    """An ensemble of the shape `fit` gives that predicts 0 (skipped by the predictor)."""
    n = 2 ** depth - 1
    return BoostedTrees(0.0, np.zeros((trees, n), np.int16),
                        np.full((trees, n), np.inf, np.float32),
                        np.zeros((trees, n + 1), np.float32))
