"""The core pipeline over labelled frames, scored like the paper's tables (`pose4d eval`, `demo`).

A part model's rows come from `core.pipeline.FramePipeline` (the stages the ROS graph runs) over
the frames. An RGB-D model gives the paper's ablation: `rgbd`, the 4D-DPM on each frame alone (the
pipeline reset before every frame: no arm prior, no per-track person scale, the foreground
without its previous frame), then, from one pass over each video as the nodes run it, `rgbd_t`
(the detector with its temporal aids: the previous frame's arms, the track's person scale),
`rgbd_kf` (after the SLQE tracker) and `rgbd_kf_ik` (the 14-joint skeleton, elbows and knees by
IK). Each addition is thus measured on its own: `rgbd` -> `rgbd_t` the detector's use of
earlier frames, `rgbd_t` -> `rgbd_kf` the filter, `rgbd_kf` -> `rgbd_kf_ik` the IK. An RGB model
gets no depth (no foreground: the whole colour image, Yang & Ramanan) and gives `rgb`, as does
the photograph network (`core.convnet`, `convnet_rows`). Frames
that are no sequence (LSPET photos, an evenly spread subset) are each on their own: the pipeline
forgets the previous frame, and only the detector's row is given. `peer_rows` runs the peer
(MediaPipe, `pose4d_ros.peer`) over the same frames; `score_rows` scores every row the same way.

Each row records its CPU time per frame (`cpu_ms`: p50, p95 of this process's CPU time,
`time.process_time`): the detector's rows the foreground and the detector, `_kf` also the
tracker, `_kf_ik` all four stages; the peer's is the CPU time of its worker process plus the
3-D look-up here. The part model's rows also record the search's work per frame
(`search_cells`: mean, p95 and max of the filter positions scored, `core.dpm.infer.SearchWork`),
which no machine's speed or load changes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from pose4d_ros.core import joints as cj
from pose4d_ros.core.convnet import PHOTO_SCALES, ConvNet
from pose4d_ros.core.dpm.infer import SearchConfig, SearchWork
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.dpm.net_unary import NetUnary
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.core.metrics import curves, joint_arrays, score_groups
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.core.pipeline import STAGES, FramePipeline
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.core.slqe import SlqeConfig
from pose4d_ros.core.stages import DetectorStage, ForegroundStage, TrackerStage
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.evaluation.tracking_metrics import score_people, seen_share, seen_table
from pose4d_ros.peer import Peer
from pose4d_ros.util.stats import ms_stats

# A model's rows (suffixes of its channels) and the stages each one's CPU time counts
ROW_STAGES = {'': STAGES[:2], '_t': STAGES[:2], '_kf': STAGES[:3], '_kf_ik': STAGES}


@dataclass
class Row:
    """One row's output over the frames: a JointSet per frame and its CPU ms."""

    preds: list[JointSet] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)
    people: list[tuple[JointSet, ...]] = field(default_factory=list)
    cells: list[int] = field(default_factory=list)
    # a several-person `_kf_ik` row: each frame's detections (those the part model scored)
    # and confirmed tracks, the stages before the skeletons (`evaluation.real`)
    stages: dict[str, list[tuple[JointSet, ...]]] = field(default_factory=dict)

    def add(self, pred: JointSet, cpu_s: float,
            people: tuple[JointSet, ...] | None = None, cells: int | None = None) -> None:
        """One frame: the prediction (the primary person's) and, from a several-person
        pipeline, every person's skeleton; `cells`: the part model's search work."""
        self.preds.append(pred)
        self.cpu_ms.append(cpu_s * 1e3)
        if people is not None:
            self.people.append(people)
        if cells is not None:
            self.cells.append(cells)

    @property
    def no_pose(self) -> int:
        """Frames in which the row has no joint at all."""
        return sum(bool((p.source == MISSING).all()) for p in self.preds)


def pipeline_rows(frames: Iterable[Frame], model: PartModel, *, name: str | None = None,
                  search: SearchConfig | None = None, scale: ScaleConfig | None = None,
                  sequence: bool = True, people: TrackingConfig | None = None,
                  single_frame: bool = True,
                  show: Callable[[Sequence[Frame], str], Iterable[Frame]] | None = None,
                  foreground: ForegroundConfig | None = None, slqe: SlqeConfig | None = None,
                  unary: NetUnary | None = None) -> dict[str, Row]:
    """The rows of a part model over the frames ({`name` (default: its channels) + suffix:
    row}); `sequence` False puts each frame on its own (the detector's row alone). In a
    sequence, an RGB-D model gives `_t`, `_kf` and `_kf_ik` from one pass as the nodes run it
    and, unless `single_frame` is False, the paper's single-frame detector row (no suffix) from
    a second pass that resets the pipeline before every frame. `people`: the several-person
    pipeline (`FramePipeline(people=...)`, as the nodes run it), whose `_kf_ik` row also holds
    every person's skeleton (`Row.people`); `show(frames, label)` wraps each pass's frames
    (a progress bar); `foreground`, `slqe`: those stages' configurations (default: the
    core's); `unary`: the photograph network in the part model's score (`DetectorStage`)."""
    stages = {'foreground': foreground, 'slqe': slqe, 'unary': unary}
    frames = list(frames)
    name = name or model.channels
    show = show or (lambda fs, _label: fs)
    depth = model.channels == 'rgbd'
    if not (depth and sequence):
        return {name: _pass(show(frames, name), model, ('',), search, scale, people,
                            reset=True, **stages)['']}
    rows = {}
    if single_frame:
        rows.update(_pass(show(frames, f'{name} (single frame)'), model, ('',), search, scale,
                          people, reset=True, **stages))
    rows.update(_pass(show(frames, name), model, ('_t', '_kf', '_kf_ik'), search, scale,
                      people, reset=False, **stages))
    return {name + s: row for s, row in rows.items()}


def _pass(frames: Iterable[Frame], model: PartModel, suffixes: tuple[str, ...],
          search: SearchConfig | None, scale: ScaleConfig | None,
          people: TrackingConfig | None, *, reset: bool,
          foreground: ForegroundConfig | None = None, slqe: SlqeConfig | None = None,
          unary: NetUnary | None = None) -> dict[str, Row]:
    """One pass of the pipeline over the frames, the rows `suffixes` (the detector's, the
    filter's, the skeleton's, in that order); `reset`: before every frame."""
    pipeline = FramePipeline(DetectorStage(model, search=search, scale=scale, unary=unary),
                             people=people,
                             foreground=ForegroundStage(foreground),
                             tracker=TrackerStage(slqe=slqe))
    depth = model.channels == 'rgbd'
    rows = {s: Row() for s in suffixes}
    for f in frames:
        if depth and f.depth_m is None:
            raise ValueError(f'{f.key}: no depth image for the rgbd model')
        if reset:
            pipeline.reset()
        cells = SearchWork.cells
        out = pipeline.step(f.color, f.depth_m if depth else None, f.intrinsics,
                            f.stamp_ns * 1e-9)
        cells = SearchWork.cells - cells
        for s, pred in zip(suffixes, (out.parts, out.tracked, out.skeleton), strict=False):
            rows[s].add(pred, sum(out.cpu_s[stage] for stage in ROW_STAGES[s]),
                        out.people if people is not None and s == '_kf_ik' else None, cells)
        if people is not None and '_kf_ik' in rows:
            stages = rows['_kf_ik'].stages
            stages.setdefault('detected', []).append(
                tuple(d for d in out.detections if np.isfinite(d.score)))
            stages.setdefault('tracked', []).append(out.tracks)
    return rows


def convnet_rows(frames: Iterable[Frame], net: ConvNet, *, name: str | None = None,
                 scales: Sequence[float] = PHOTO_SCALES) -> dict[str, Row]:
    """The row of a photograph network (`core.convnet`) over the frames, each on its own, read
    at `scales` ({`name` (default: its channels): row}); its CPU time is the network's."""
    row = Row()
    for f in frames:
        t0 = time.process_time()
        uv, prob = net.detect(f.color, scales)
        cpu_s = time.process_time() - t0
        row.add(JointSet(net.joint_names, uv, confidence=prob.astype(np.float32),
                         source=np.full(len(uv), cj.DETECTED, np.uint8),
                         score=float(prob.mean())), cpu_s)
    return {name or net.channels: row}


def peer_rows(frames: Iterable[Frame], peer: Peer, *, sequence: bool = True
              ) -> dict[str, Row]:
    """The peer's row over the frames: a new video wherever our tracker starts a new track (a
    stamp gap over `SlqeConfig.max_dt_s`, or a stamp going back), every frame unless
    `sequence`."""
    row = Row()
    last = None
    for f in frames:
        stamp_s = f.stamp_ns * 1e-9
        new_video = not sequence or last is None or not 0.0 <= stamp_s - last <= \
            SlqeConfig.max_dt_s
        last = stamp_s
        row.add(peer.step(f.color, f.depth_m, f.intrinsics, new_video=new_video),
                peer.last_cpu_s)
    return {peer.name: row}


def score_rows(rows: dict[str, Row], frames: Sequence[Frame]
               ) -> dict[str, dict[str, dict[str, float]]]:
    """The table of each row, with its CPU ms per frame (`cpu_ms`) when it has them (a row
    read from a recording has none). A row scores the joints of the 14-joint skeleton it
    predicts (an `_ik` row all 14, elbows and knees included); ground truth outside the image
    is not scored.

    Frames with several people (`Frame.people`): each frame's people are matched to the row's
    skeletons one to one by torso distance (`evaluation.tracking_metrics.score_people`), the
    table is pooled over people (a person without a skeleton: every joint wrong) and the row
    gets `tracking` (IDF1, MOTA, id switches, ...). A single-person row (the detector's, the
    filter's, the peer's) is one skeleton a frame, scored the same way."""
    tables = {}
    several = any(getattr(f, 'people', ()) for f in frames)
    for name, row in rows.items():
        names = row_names(name, row)
        if several:
            out = people_scores(row, frames, names)
            tables[name] = {**out['table'], 'tracking': out['tracking']}
        else:
            tables[name] = score_groups(names=names, **row_arrays(name, row, frames)[1])
        if row.cpu_ms:
            tables[name]['cpu_ms'] = ms_stats(row.cpu_ms)
        if row.cells:
            cells = np.asarray(row.cells, np.float64)
            tables[name]['search_cells'] = {'mean': round(float(cells.mean()), 1),
                                            'p95': float(np.percentile(cells, 95)),
                                            'max': int(cells.max())}
    return tables


def frame_people(frame: Frame) -> tuple[JointSet, ...]:
    """Every person's ground truth of a frame (`Frame.people`, or its one `truth`)."""
    people = getattr(frame, 'people', ())
    return tuple(people) if people else ((frame.truth,) if frame.truth is not None else ())


def people_scores(row: Row, frames: Sequence[Frame], names: tuple[str, ...]) -> dict:
    """`tracking_metrics.score_people` of a row (its several-person skeletons, or its one
    prediction a frame) over the frames, each video a sequence of its own."""
    preds = row.people if row.people else [(p,) for p in row.preds]
    sizes = [(f.color.shape[1], f.color.shape[0]) for f in frames]
    out = score_people([frame_people(f) for f in frames], preds, names, image_sizes=sizes,
                       videos=sequence_labels(frames))
    # the same person-frames by how much of each person is seen (`seen_table`)
    (matched, truths), index = out['matched'], out['frames']
    out['table']['seen'] = seen_table(
        matched, truths, [seen_share(t, frames[k].depth_m) for t, k in zip(truths, index,
                                                                            strict=True)],
        names, image_sizes=[sizes[k] for k in index])
    return out


def sequence_labels(frames: Sequence[Frame]) -> list[int]:
    """A label per frame, new wherever the tracker starts a new track: a new video, a stamp
    gap over `SlqeConfig.max_dt_s`, or a stamp going back."""
    labels, label, last = [], 0, None
    for f in frames:
        stamp_s = f.stamp_ns * 1e-9
        if last is not None and (f.video != last[1] or
                                 not 0.0 <= stamp_s - last[0] <= SlqeConfig.max_dt_s):
            label += 1
        labels.append(label)
        last = (stamp_s, f.video)
    return labels


def curve_rows(rows: dict[str, Row], frames: Sequence[Frame], alphas: Sequence[float]
               ) -> dict[str, dict]:
    """`core.metrics.curves` of each row at `alphas`, on the joints `score_rows` scores."""
    out = {}
    for name, row in rows.items():
        names, arrays = row_arrays(name, row, frames)
        out[name] = curves(names=names, alphas=np.asarray(alphas), **arrays)
    return out


def row_names(name: str, row: Row) -> tuple[str, ...]:
    """The joints a row is scored on: all 14 for an `_ik` row, else those it predicts."""
    return SKELETON_14 if name.endswith('_ik') else tuple(
        n for n in SKELETON_14 if row.preds and n in row.preds[0].names)


def row_arrays(name: str, row: Row, frames: Sequence[Frame]) -> tuple[tuple[str, ...], dict]:
    names = row_names(name, row)
    sizes = [(f.color.shape[1], f.color.shape[0]) for f in frames]
    return names, joint_arrays(row.preds, [f.truth for f in frames], names, image_sizes=sizes)
