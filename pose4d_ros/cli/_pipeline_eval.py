"""The whole core pipeline over recorded frames, scored like the paper's tables.

One pass of `core.pipeline.FramePipeline` (the stages the ROS graph runs) over the frames gives
three rows at once: `rgbd` (the detector's parts), `rgbd_kf` (after the SLQE tracker) and
`rgbd_kf_ik` (the 14-joint skeleton, elbows and knees by IK). `pose4d eval` and `pose4d demo`
use it, so the offline numbers and the live graph's come from the same code. `evaluate_peer`
runs the peer (MediaPipe, `pose4d_ros.peer`) over the same frames, scored by the same code.

Each row records its CPU time per frame (`cpu_ms`: p50, p95 of this process's CPU time,
`time.process_time`): `rgbd` the foreground and the detector, `rgbd_kf` also the tracker,
`rgbd_kf_ik` all four stages; the peer's is the CPU time of its worker process plus the
3-D look-up here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pose4d_ros.cli._dpm import ms_stats
from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.model import PartModel, load_model
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import score_joint_sets
from pose4d_ros.core.pipeline import STAGES, DetectorStage, FramePipeline
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.core.slqe import SlqeConfig
from pose4d_ros.datasets.cad60_bag import BagFrame, cad60_frames, read_frames
from pose4d_ros.models import model_path
from pose4d_ros.peer import MediaPipePeer

ROWS = ('rgbd', 'rgbd_kf', 'rgbd_kf_ik')
# The stages (`core.pipeline.STAGES`) whose CPU time each row costs
ROW_STAGES = {'rgbd': STAGES[:2], 'rgbd_kf': STAGES[:3], 'rgbd_kf_ik': STAGES}


def pipeline_for(model: str | Path | PartModel, *, search: SearchConfig | None = None
                 ) -> FramePipeline:
    """A FramePipeline with the default stages and the given part model."""
    if not isinstance(model, PartModel):
        model = load_model(model_path(model))
    return FramePipeline(DetectorStage(model, search=search))


@dataclass
class RowRun:
    """What rows made over a run of frames: each row's predictions and CPU ms per frame, the
    ground truths and the image size."""

    preds: dict[str, list[JointSet]] = field(default_factory=dict)
    cpu_ms: dict[str, list[float]] = field(default_factory=dict)
    truths: list[JointSet] = field(default_factory=list)
    size: tuple[int, int] = (0, 0)

    def add(self, row: str, pred: JointSet, cpu_s: float) -> None:
        self.preds.setdefault(row, []).append(pred)
        self.cpu_ms.setdefault(row, []).append(cpu_s * 1e3)

    def add_truth(self, frame: BagFrame) -> None:
        if frame.truth is None:
            raise ValueError(f'frame at {frame.stamp_ns} ns has no ground truth')
        self.truths.append(frame.truth)
        self.size = (frame.color.shape[1], frame.color.shape[0])


def run_pipeline(frames: Iterable[BagFrame], pipeline: FramePipeline,
                 progress: Callable[[int], Any] | None = None) -> RowRun:
    """Predictions of every row, the ground truths (frame by frame) and the image size."""
    run = RowRun()
    for k, frame in enumerate(frames):
        run.add_truth(frame)
        out = pipeline.step(frame.color, frame.depth_m, frame.intrinsics, frame.stamp_ns * 1e-9)
        for row, pred in zip(ROWS, (out.parts, out.tracked, out.skeleton), strict=True):
            run.add(row, pred, sum(out.cpu_s[stage] for stage in ROW_STAGES[row]))
        if progress is not None:
            progress(k + 1)
    return run


def run_peer(frames: Iterable[BagFrame], peer: MediaPipePeer,
             progress: Callable[[int], Any] | None = None) -> RowRun:
    """The peer's row over the frames, a new video wherever our tracker starts a new track (a
    stamp gap over `SlqeConfig.max_dt_s`, or a stamp going back)."""
    run = RowRun()
    last = None
    for k, frame in enumerate(frames):
        run.add_truth(frame)
        stamp_s = frame.stamp_ns * 1e-9
        new_video = last is None or not 0.0 <= stamp_s - last <= SlqeConfig.max_dt_s
        last = stamp_s
        pred = peer.step(frame.color, frame.depth_m, frame.intrinsics, new_video=new_video)
        run.add(peer.name, pred, peer.last_cpu_s)
        if progress is not None:
            progress(k + 1)
    return run


def score_rows(run: RowRun) -> dict[str, dict[str, dict[str, float]]]:
    """The table of each row, with its CPU ms per frame (`cpu_ms`). Rows of 10 parts score
    their joints; the IK row scores all 14 (elbows and knees included); the peer its joints.
    Ground truth outside the image is not scored."""
    rows = {}
    for row, p in run.preds.items():
        names = SKELETON_14 if row.endswith('_ik') else tuple(
            n for n in SKELETON_14 if p and n in p[0].names)
        rows[row] = {**score_joint_sets(p, run.truths, names, image_size=run.size),
                     'cpu_ms': ms_stats(run.cpu_ms[row])}
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
    run = run_pipeline(frames_of(source, stride=stride), pipeline, progress)
    if not run.truths:
        raise ValueError(f'{source}: no frames with colour, depth and camera_info')
    return {'frames': len(run.truths), 'rows': score_rows(run)}


def evaluate_peer(source: str | Path, peer: MediaPipePeer, *, stride: int = 1,
                  progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """`evaluate_source`'s output for the peer: its row over the same frames."""
    run = run_peer(frames_of(source, stride=stride), peer, progress)
    if not run.truths:
        raise ValueError(f'{source}: no frames with colour, depth and camera_info')
    return {'frames': len(run.truths), 'rows': score_rows(run)}


def evaluate_bag(path: str | Path, *, model: str | Path = 'rgbd_10',
                 progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """`evaluate_source` of a bag."""
    if not (Path(path) / 'metadata.yaml').is_file():
        raise ValueError(f'{path}: not a rosbag2 directory (no metadata.yaml)')
    return evaluate_source(path, model=model, progress=progress)
