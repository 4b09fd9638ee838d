"""The part model's training around `training.dpm.train`: the frames masked as the live pipeline
masks them, and the calibration again on other frames (`pose4d train --calibrate`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.training.dpm.samples import TrainConfig, part_joints
from pose4d_ros.training.dpm.train import calibrate, positive_scale, scale_span
from pose4d_ros.util.progress import log, progress


def with_foreground_masks(samples: list[Frame]) -> list[Frame]:
    """The samples with `mask` replaced by the foreground stage's mask (`core.foreground`),
    so that a masked model trains on what it will see; a frame where the foreground finds no
    person keeps its own mask (the renderer's), or none."""
    from pose4d_ros.core.camera import cad60_intrinsics
    from pose4d_ros.core.foreground import segment

    out = []
    missed = 0
    for s in progress(samples, 'foreground'):
        if s.depth_m is None:
            out.append(s)
            continue
        h, w = s.depth_m.shape
        res = segment(s.depth_m, s.intrinsics or cad60_intrinsics(w, h))
        if res.found:
            out.append(replace(s, mask=res.mask))
        else:
            missed += 1
            out.append(s)
    if missed:
        log(f'foreground found no person in {missed} of {len(samples)} frames '
            '(their own masks are used)')
    return out


def recalibrate(model: PartModel, samples: list[Frame], *, search_percent: float,
                seed: int) -> tuple[PartModel, int]:
    """The last steps of `training.dpm.train.train` alone, on `samples`: the person scales searched
    without depth (from all of them, covering `search_percent` to 100 minus it) and the
    calibration (on the same deterministic subset of `TrainConfig.calibration_samples` frames,
    masked as the model was trained); the model and the number of frames calibrated on."""
    trained = TrainConfig.of_model(model.metadata)
    if trained.masked_input:
        samples = with_foreground_masks(samples)
    # the search without depth covers the middle of the people's scales, as `train` sets it
    scales = np.array([positive_scale(s, model.part_names, trained) for s in samples])
    scales = scales[scales > 2]
    if len(scales):
        model = replace(model, search_range_px=scale_span(scales, search_percent))
    usable = [s for s in samples if part_joints(s, model.part_names)[1].sum() >= 2]
    n = trained.calibration_samples
    if len(usable) > n:
        rng = np.random.default_rng(seed)
        usable = [usable[i] for i in np.sort(rng.choice(len(usable), n, replace=False))]
    model = calibrate(model, usable, use_depth=model.channels == 'rgbd', progress=progress)
    return model, len(usable)


def depth_lifting(model: PartModel) -> str:
    """How the model lifts each part to 3-D, in a line."""
    if model.depth_offset_m is None:
        return 'no depth look-up'
    lookup = model.depth_lookup
    return 'depth look-up per part (window radius, quantile, mm behind the surface): ' + ', '.join(
        f'{n} ' + ('3 px, 0.5' if lookup is None else f'{100 * lookup[i, 0]:.1f} cm, '
                   f'{lookup[i, 1]:.1f}') + f', {1e3 * model.depth_offset_m[i]:+.0f}'
        for i, n in enumerate(model.part_names))
