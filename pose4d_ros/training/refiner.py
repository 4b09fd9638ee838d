"""The part refiner's training (`core.refine`): the detections it learns from, run as the nodes
run them, its samples, and the cascade of stages fitted one after the other, each on the parts
as the stages before it move them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.refine import OUTPUTS, PartRefiner, fit_refiner, known_parts, targets
from pose4d_ros.core.refine import features as refine_features
from pose4d_ros.core.stages import DetectorStage, ForegroundStage
from pose4d_ros.datasets.frame import Frame
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
    (`core.refine.targets`)."""
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
