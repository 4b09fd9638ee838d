"""Sweep the several-person tracker's settings on a set, the detections computed once.

    .venv/bin/python tools/people_sweep.py data/synth/val2 --birth-score 0,2,4,5,6,8 \
        --confirm-frames 2,3,5 --trust-score 5,7,inf --second-look false,true

Prints a line per combination and with `--json` writes them all (`evaluation.people_sweep`:
the detections once per foreground setting, the tracker and the IK per combination, scored as
`pose4d eval` scores several people). Choose on a validation set (training subjects), never on
a test set (pose4d_ros/models/README.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.files import write_json
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.evaluation.people_sweep import describe, sweep
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
    model = load_model(model_path(args.model))
    results = []
    for r in sweep(frames, model,
                   second_looks=[x.strip().lower() in ('true', '1')
                                 for x in args.second_look.split(',')],
                   birth_scores=[float(x) for x in args.birth_score.split(',')],
                   confirm_frames=[int(x) for x in args.confirm_frames.split(',')],
                   trust_scores=[float(x) for x in args.trust_score.split(',')]):
        results.append(r)
        print(describe(r), flush=True)
    if args.json is not None:
        write_json(args.json, results, indent=1)
    return 0


if __name__ == '__main__':
    np.seterr(all='ignore')
    sys.exit(main())
