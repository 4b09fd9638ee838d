"""The whole core pipeline over recorded frames, scored like the paper's tables.

One pass of `core.pipeline.FramePipeline` (the stages the ROS graph runs) over the frames gives
three rows at once: `rgbd` (the detector's parts), `rgbd_kf` (after the SLQE tracker) and
`rgbd_kf_ik` (the 14-joint skeleton, elbows and knees by IK). `pose4d eval` and `pose4d demo`
use it, so the offline numbers and the live graph's come from the same code.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import score_joint_sets
from pose4d_ros.core.pipeline import DetectorStage, FramePipeline
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.datasets.cad60_bag import BagFrame, read_frames
from pose4d_ros.models import model_path

ROWS = ('rgbd', 'rgbd_kf', 'rgbd_kf_ik')


def pipeline_for(model: str | Path) -> FramePipeline:
    """A FramePipeline with the default stages and the given part model."""
    return FramePipeline(DetectorStage(load_model(model_path(model))))


def run_pipeline(frames: Iterable[BagFrame], pipeline: FramePipeline,
                 progress: Callable[[int], Any] | None = None
                 ) -> tuple[dict[str, list[JointSet]], list[JointSet]]:
    """Predictions of every row and the ground truths, frame by frame."""
    preds: dict[str, list[JointSet]] = {row: [] for row in ROWS}
    truths: list[JointSet] = []
    for k, frame in enumerate(frames):
        if frame.truth is None:
            raise ValueError(f'frame at {frame.stamp_ns} ns has no ground truth')
        out = pipeline.step(frame.color, frame.depth_m, frame.intrinsics, frame.stamp_ns * 1e-9)
        preds['rgbd'].append(out.parts)
        preds['rgbd_kf'].append(out.tracked)
        preds['rgbd_kf_ik'].append(out.skeleton)
        truths.append(frame.truth)
        if progress is not None:
            progress(k + 1)
    return preds, truths


def score_rows(preds: dict[str, list[JointSet]], truths: list[JointSet]
               ) -> dict[str, dict[str, dict[str, float]]]:
    """The table of each row. Rows of 10 parts score their joints; the IK row scores all 14
    (elbows and knees included)."""
    rows = {}
    for row, p in preds.items():
        names = SKELETON_14 if row.endswith('_ik') else tuple(
            n for n in SKELETON_14 if p and n in p[0].names)
        rows[row] = score_joint_sets(p, truths, names)
    return rows


def evaluate_bag(path: str | Path, *, model: str | Path = 'rgbd_10',
                 progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """{'frames': N, 'rows': {row: table}} for a bag with ground truth on /cad60/skeleton."""
    pipeline = pipeline_for(model)
    preds, truths = run_pipeline(read_frames(path), pipeline, progress)
    if not truths:
        raise ValueError(f'{path}: no frames with colour, depth and camera_info')
    return {'frames': len(truths), 'rows': score_rows(preds, truths)}
