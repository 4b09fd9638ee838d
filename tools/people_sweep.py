"""Sweep the several-person tracker's settings on a set, the detections computed once.

    .venv/bin/python tools/people_sweep.py data/synth/val2 --birth-score 0,2,4,5,6,8 \
        --confirm-frames 2,3,5 --trust-score 5,7,inf --second-look false,true

The foreground and the detector do not depend on the tracker's settings (`core.people`: the
detector's slots follow the foreground's candidates), so each frame's detections and masked
depth are computed once per foreground setting (`ForegroundConfig.second_look`); the tracker
and the IK are then run for every combination and scored as
`pose4d eval` scores several people (`evaluation.pipeline.people_scores`). Choose on a
validation set (training subjects), never on a test set (pose4d_ros/models/README.md).
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from pose4d_ros.core.dpm.model import PartModel, load_model
from pose4d_ros.core.files import write_json
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.people import PeopleIk, PeopleTracker, TrackingConfig
from pose4d_ros.core.pipeline import FramePipeline
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.core.stages import DetectorStage, ForegroundStage, IkStage, TrackerStage
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.evaluation.pipeline import Row, people_scores
from pose4d_ros.models import model_path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('source')
    p.add_argument('--model', default='rgbd_14')
    p.add_argument('--birth-score', default='5')
    p.add_argument('--confirm-frames', default='3')
    p.add_argument('--trust-score', default='inf')
    p.add_argument('--second-look', default='true')
    p.add_argument('--json', type=Path, default=None)
    args = p.parse_args(argv)
    frames = load_frames([args.source])
    base = TrackingConfig()
    model = load_model(model_path(args.model))
    results = []
    for look in [x.strip().lower() in ('true', '1') for x in args.second_look.split(',')]:
        detections, depths = _detections(frames, model, base, look)
        for birth, confirm, trust in itertools.product(
                [float(x) for x in args.birth_score.split(',')],
                [int(x) for x in args.confirm_frames.split(',')],
                [float(x) for x in args.trust_score.split(',')]):
            config = replace(base, birth_score=birth, confirm_frames=confirm, trust_score=trust)
            out = _scores(frames, detections, depths, config)
            t = out['tracking']
            results.append({'second_look': look, 'birth_score': birth,
                            'confirm_frames': confirm,
                            'trust_score': trust if math.isfinite(trust) else None,
                            'average7': out['table']['pck']['average7'],
                            **{k: t[k] for k in ('idf1', 'mota', 'id_switches_per_1000',
                                                 'missed_per_1000', 'false_per_1000')}})
            r = results[-1]
            print(f'second_look {look!s:5} birth_score {birth:5.1f} confirm {confirm} trust '
                  f'{trust:5.1f}: average7 {r["average7"]:.2f} idf1 {r["idf1"]:.3f} mota '
                  f'{r["mota"]:.3f} idsw/1k {r["id_switches_per_1000"]:.2f} miss/1k '
                  f'{r["missed_per_1000"]:.1f} false/1k {r["false_per_1000"]:.1f}', flush=True)
    if args.json is not None:
        write_json(args.json, results, indent=1)
    return 0


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
    tracker, ik = PeopleTracker(TrackerStage, config), PeopleIk(IkStage)
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


if __name__ == '__main__':
    np.seterr(all='ignore')
    sys.exit(main())
