"""A digest of everything the four stages put out on some frames: run it before and after a
change that should only rewrite how a stage computes (fewer Python calls, a kernel), and the
two digests must be equal.

    .venv/bin/python tools/stage_digest.py data/bench300_bag:300 data/synth/test30:240 \
        data/synth/test60_people2:200:people

Each argument is SOURCE[:FRAMES[:people]] (a CAD-60 set or bag; `people`: the several-person
pipeline, `FramePipeline(people=...)`). Per frame it hashes the bytes of the foreground (mask,
box, depth, floor plane, its blanked colour and depth), the detected parts, the tracked parts,
the skeleton and every person's skeleton, and prints one SHA-256 per source and one over all.
Run from the checkout (`PYTHONPATH=.`) to digest the code in the working tree, after
`find pose4d_ros -name '*.nb[ic]' -delete`: numba's cache of a kernel is renewed when its
own file changes, not when a kernel it calls from another file does.
"""

from __future__ import annotations

import argparse
import hashlib
import sys

import numpy as np

from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.core.pipeline import FramePipeline
from pose4d_ros.core.stages import DetectorStage
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.evaluation.tables import colour_unary, default_models
from pose4d_ros.models import DEFAULT_COLOUR_NET, model_path


def _feed(h: hashlib._Hash, value: object) -> None:
    """Every array's bytes (with its dtype and shape), every other value's repr."""
    if isinstance(value, np.ndarray):
        h.update(f'{value.dtype}{value.shape}'.encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (list, tuple)):
        for v in value:
            _feed(h, v)
    elif hasattr(value, '__dict__'):
        for k, v in sorted(vars(value).items()):
            h.update(k.encode())
            _feed(h, v)
    else:
        h.update(repr(value).encode())


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('sources', nargs='+', metavar='SOURCE[:FRAMES[:people]]')
    p.add_argument('--model', default=None, help='part model (the CAD-60 default)')
    p.add_argument('--colour-net', default=DEFAULT_COLOUR_NET,
                   help="the photograph network in the colour unary, as the detector node runs "
                        "it by default ('none': off)")
    args = p.parse_args()
    model = load_model(model_path(args.model or default_models('cad60')[0]))
    unary = colour_unary(args.colour_net)
    total = hashlib.sha256()
    for spec in args.sources:
        source, frames, people = (spec.split(':') + ['', ''])[:3]
        frames = load_frames([source], max_frames=int(frames) if frames else None,
                             labelled=False)
        pipeline = FramePipeline(DetectorStage(model, unary=unary),
                                 people=TrackingConfig() if people == 'people' else None)
        h = hashlib.sha256()
        for f in frames:
            r = pipeline.step(f.color, f.depth_m, f.intrinsics, f.stamp_ns * 1e-9)
            _feed(h, (r.foreground, r.color_masked, r.depth_masked, r.parts, r.tracked,
                      r.skeleton, r.people, r.foregrounds, r.candidates, r.born, r.ended))
        print(f'{h.hexdigest()}  {spec} ({len(frames)} frames)')
        total.update(h.digest())
    print(f'{total.hexdigest()}  all')
    return 0


if __name__ == '__main__':
    sys.exit(main())
