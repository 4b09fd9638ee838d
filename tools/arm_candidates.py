"""Where the right elbow or wrist is when the detector misplaces it: among the arm's candidates?

    .venv/bin/python tools/arm_candidates.py data/synth/test [--model rgbd_14]

Runs the foreground and the detector over a labelled CAD-60 set or bag, each frame on its own
and at the depth-predicted person scale (no tracking prior). For the best pose, it lists each
arm's `limb_candidates` (`core.dpm.dp`: the DP's own arm, then the best elbow cells given the
shoulder, each with its best wrists) and, for each elbow and wrist the pose misplaces (PCK@0.1,
the table's rule), the rank of the first candidate cell of that part within the threshold of
the truth: 0 = the next-best placement the model allows, -1 = none of them. What a prior over
these candidates (`SearchConfig.arm_prior`) can at best repair.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

import numpy as np

from pose4d_ros.core.dpm.dp import (
    LIMB_CANDIDATES,
    backtrack,
    best_roots,
    limb_candidates,
    model_arrays,
    score_level,
)
from pose4d_ros.core.dpm.infer import Detector
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.stages import ForegroundStage
from pose4d_ros.core.threads import set_blas_threads
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.models import model_path


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('source', help='labelled CAD-60 directory or bag')
    ap.add_argument('--model', default='rgbd_14')
    args = ap.parse_args(argv)
    set_blas_threads(1)
    model = load_model(model_path(args.model))
    detector = Detector(model)
    _, parents, springs, anchors, bias = model_arrays(model)
    names = model.part_names
    foreground = ForegroundStage()
    ranks: dict[str, Counter] = {'elbow': Counter(), 'wrist': Counter()}
    counted = Counter()
    for f in load_frames([args.source]):
        fg, color, depth = foreground.step(f.color, f.depth_m, f.intrinsics)
        plan = detector.plan(color.shape[:2], depth, mask=fg.mask, intrinsics=f.intrinsics)
        if plan is None:
            continue
        levels = detector.pyramid(color, depth, plan, mask=fg.mask, blanked=True)
        results = [r for r in (score_level(level, model) for level in levels) if r is not None]
        res = max(results, key=lambda r: float(r.root.max()))
        parts, _ = backtrack(best_roots(res, 1), parents, res.resp, res.ix, res.iy, res.ik,
                             springs, anchors, bias)
        truth, _, labelled = f.truth.labelled(names)
        threshold = 0.1 * float(np.max(np.ptp(truth[labelled], axis=0)))
        for side in ('left_', 'right_'):
            if side + 'elbow' not in names:
                continue
            mid, end = names.index(side + 'elbow'), names.index(side + 'wrist')
            cand, _ = limb_candidates(res.resp, res.score, res.ix, res.iy, res.ik, parents,
                                      springs, anchors, bias, parts[0], mid, end,
                                      LIMB_CANDIDATES)
            for slot, part, group in ((0, mid, 'elbow'), (1, end, 'wrist')):
                if not labelled[part]:
                    continue
                counted[group] += 1
                # the part's distinct cells in the candidates' order (the DP's own first)
                cells = np.array(list(dict.fromkeys(map(tuple, cand[:, slot, 1:]))))
                u, v = res.level.cell_to_pixel(cells[:, 0], cells[:, 1], model.filter_shape)
                near = np.hypot(u - truth[part, 0], v - truth[part, 1]) <= threshold
                if near[0]:
                    continue
                hits = np.flatnonzero(near[1:])
                ranks[group][int(hits[0]) if len(hits) else -1] += 1
    for group, counter in ranks.items():
        missed = sum(counter.values())
        found = missed - counter[-1]
        print(f'{group}: {counted[group]} labelled, {missed} misplaced by the DP; the truth is '
              f'among the candidates for {found}: ' +
              ', '.join(f'rank {k}: {n}' for k, n in sorted(counter.items()) if k >= 0) +
              f'; none: {counter[-1]}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
