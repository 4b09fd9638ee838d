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

from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.model import PartModel, load_model
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import score_joint_sets
from pose4d_ros.core.pipeline import DetectorStage, FramePipeline
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.datasets.cad60_bag import BagFrame, cad60_frames, read_frames
from pose4d_ros.models import model_path

ROWS = ('rgbd', 'rgbd_kf', 'rgbd_kf_ik')


def pipeline_for(model: str | Path | PartModel, *, search: SearchConfig | None = None
                 ) -> FramePipeline:
    """A FramePipeline with the default stages and the given part model."""
    if not isinstance(model, PartModel):
        model = load_model(model_path(model))
    return FramePipeline(DetectorStage(model, search=search))


def run_pipeline(frames: Iterable[BagFrame], pipeline: FramePipeline,
                 progress: Callable[[int], Any] | None = None
                 ) -> tuple[dict[str, list[JointSet]], list[JointSet], tuple[int, int]]:
    """Predictions of every row, the ground truths (frame by frame) and the image size."""
    preds: dict[str, list[JointSet]] = {row: [] for row in ROWS}
    truths: list[JointSet] = []
    size = (0, 0)
    for k, frame in enumerate(frames):
        size = (frame.color.shape[1], frame.color.shape[0])
        if frame.truth is None:
            raise ValueError(f'frame at {frame.stamp_ns} ns has no ground truth')
        out = pipeline.step(frame.color, frame.depth_m, frame.intrinsics, frame.stamp_ns * 1e-9)
        preds['rgbd'].append(out.parts)
        preds['rgbd_kf'].append(out.tracked)
        preds['rgbd_kf_ik'].append(out.skeleton)
        truths.append(frame.truth)
        if progress is not None:
            progress(k + 1)
    return preds, truths, size


def score_rows(preds: dict[str, list[JointSet]], truths: list[JointSet],
               image_size: tuple[int, int]) -> dict[str, dict[str, dict[str, float]]]:
    """The table of each row. Rows of 10 parts score their joints; the IK row scores all 14
    (elbows and knees included). Ground truth outside the image is not scored."""
    rows = {}
    for row, p in preds.items():
        names = SKELETON_14 if row.endswith('_ik') else tuple(
            n for n in SKELETON_14 if p and n in p[0].names)
        rows[row] = score_joint_sets(p, truths, names, image_size=image_size)
    return rows


def frames_of(source: str | Path, *, stride: int = 1) -> Iterable[BagFrame]:
    """The frames of a bag (a directory with metadata.yaml) or of a CAD-60 directory."""
    source = Path(source)
    if (source / 'metadata.yaml').is_file():
        if stride != 1:
            raise ValueError(f'{source}: --stride applies to CAD-60 directories, not bags')
        return read_frames(source)
    return cad60_frames(source, stride=stride)


def evaluate_source(source: str | Path, *, model: str | Path | PartModel = 'rgbd_10',
                    stride: int = 1, search: SearchConfig | None = None,
                    progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """{'frames': N, 'rows': {row: table}} of the whole pipeline over a bag with ground truth
    on /cad60/skeleton, or over a CAD-60 directory (each video a new track)."""
    pipeline = pipeline_for(model, search=search)
    preds, truths, size = run_pipeline(frames_of(source, stride=stride), pipeline, progress)
    if not truths:
        raise ValueError(f'{source}: no frames with colour, depth and camera_info')
    return {'frames': len(truths), 'rows': score_rows(preds, truths, size)}


def evaluate_bag(path: str | Path, *, model: str | Path = 'rgbd_10',
                 progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """`evaluate_source` of a bag."""
    if not (Path(path) / 'metadata.yaml').is_file():
        raise ValueError(f'{path}: not a rosbag2 directory (no metadata.yaml)')
    return evaluate_source(path, model=model, progress=progress)
