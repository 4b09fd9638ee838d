"""Sweep the several-person tracker's settings on a set, the detections computed once
(`tools/people_sweep.py`).

The foreground and the detector do not depend on the tracker's settings (`core.people`: the
detector's slots follow the foreground's candidates), so each frame's detections and masked
depth are computed once per foreground setting (`ForegroundConfig.second_look`); the tracker
and the IK are then run for every combination and scored as
`pose4d eval` scores several people (`evaluation.pipeline.people_scores`). Choose on a
validation set (training subjects), never on a test set (pose4d_ros/models/README.md).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import replace

from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.people import PeopleIk, PeopleTracker, TrackingConfig
from pose4d_ros.core.pipeline import FramePipeline
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.core.stages import DetectorStage, ForegroundStage, IkStage, TrackerStage
from pose4d_ros.evaluation.pipeline import Row, people_scores


def sweep(frames: list, model: PartModel, *, second_looks: Sequence[bool],
          birth_scores: Sequence[float], confirm_frames: Sequence[int],
          trust_scores: Sequence[float]) -> Iterator[dict]:
    """One result per combination of the settings (second look outermost, then birth score,
    confirm frames and trust score): the settings (`trust_score` None for inf), PCK@0.1
    `average7` and the tracking scores (`idf1`, `mota`, `id_switches_per_1000`,
    `missed_per_1000`, `false_per_1000`)."""
    base = TrackingConfig()
    for look in second_looks:
        detections, depths = _detections(frames, model, base, look)
        for birth, confirm, trust in itertools.product(birth_scores, confirm_frames,
                                                       trust_scores):
            config = replace(base, birth_score=birth, confirm_frames=confirm, trust_score=trust)
            out = _scores(frames, detections, depths, config)
            t = out['tracking']
            yield {'second_look': look, 'birth_score': birth, 'confirm_frames': confirm,
                   'trust_score': trust if math.isfinite(trust) else None,
                   'average7': out['table']['pck']['average7'],
                   **{k: t[k] for k in ('idf1', 'mota', 'id_switches_per_1000',
                                        'missed_per_1000', 'false_per_1000')}}


def describe(r: dict) -> str:
    """One result of `sweep` as a line."""
    trust = math.inf if r['trust_score'] is None else r['trust_score']
    return (f'second_look {r["second_look"]!s:5} birth_score {r["birth_score"]:5.1f} confirm '
            f'{r["confirm_frames"]} trust {trust:5.1f}: average7 {r["average7"]:.2f} idf1 '
            f'{r["idf1"]:.3f} mota {r["mota"]:.3f} idsw/1k {r["id_switches_per_1000"]:.2f} '
            f'miss/1k {r["missed_per_1000"]:.1f} false/1k {r["false_per_1000"]:.1f}')


def _detections(frames: list, model: PartModel, base: TrackingConfig, second_look: bool
                ) -> tuple[list, list]:
    """Each frame's detections and masked depth, as the several-person pipeline makes them."""
    pipeline = FramePipeline(DetectorStage(model), people=base,
                             foreground=ForegroundStage(ForegroundConfig(second_look=second_look)))
    detections, depths = [], []
    for f in frames:
        found, _, _, depth_mm = pipeline.foreground.step_people(f.color, f.depth_m,
                                                                f.intrinsics, base.max_people)
        detections.append(pipeline.multi.detector.step(f.color, f.depth_m, f.intrinsics, found,
                                                       stamp_s=f.stamp_ns * 1e-9))
        depths.append(depth_mm)
    return detections, depths


def _scores(frames: list, detections: list, depths: list, config: TrackingConfig) -> dict:
    """`people_scores` of the tracker and IK with `config` on the detections."""
    tracker, ik = PeopleTracker(TrackerStage(), config), PeopleIk(IkStage())
    row = Row()
    last = None
    for f, dets, depth in zip(frames, detections, depths, strict=True):
        stamp_s = f.stamp_ns * 1e-9
        if last is not None and not 0.0 <= stamp_s - last <= 1.0:  # a new video
            tracker.reset()
            ik.reset()
        last = stamp_s
        people = ik.step(tracker.step(dets, stamp_s, f.intrinsics), depth, f.intrinsics)
        row.add(people[0] if people else None, 0.0, tuple(people))
    return people_scores(row, frames, SKELETON_14)
