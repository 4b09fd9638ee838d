"""Why the photo model fails: the labelled pose's own score against the pose the search finds.

    .venv/bin/python tools/lspet_diagnose.py ../shared/data/lspet --range 2501-2600 \
        [--model lspet_rgb_14] [--json out/lspet_diagnose.json]

For every photograph whose 14 joints are all labelled:
- the labelled person's scale (`training.dpm.samples.person_scale` with the model's training
  settings, as training measured it) and the model's level at that scale;
- the score of the labelled pose on that level: each part's filter at the labelled cell, its
  spring from its parent's labelled cell and the best types (an exact max over the types on the
  tree);
- the best pose on that same level (what the search would return if it knew the scale), and the
  best pose over the whole search (`Detector.detect`, what `pose4d eval` scores);
- each pose's PCK@0.1 against the labels (the table's rule);
- the search's `TOP_K` best poses (`Detector.detect(..., top_k=TOP_K)`, suppressed by
  overlap): the best PCK@0.2 among them (what a better ranking of the same candidates could
  gain), where the best pose lies (its centre's distance from the labelled person's, over the
  labelled box's size) and its PCK@0.2 with left and right swapped (a person seen from behind);
- the labelled torso's tilt (neck to the hips' midpoint against the image's down direction: 0
  upright, 180 upside down), and the found pose's PCK@0.2 by tilt.

If the found pose outscores the labelled one, the model ranks a wrong pose above the truth (a
training problem); if the labelled pose scores higher but is not found, the search misses it.
Prints the shares and medians; `--json` writes every photo's numbers.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pose4d_ros.core.dpm.dp import model_arrays, score_level
from pose4d_ros.core.dpm.infer import Detector, SearchPlan
from pose4d_ros.core.dpm.model import PartModel, load_model
from pose4d_ros.core.files import write_json
from pose4d_ros.core.metrics import pck_per_frame, reference_size
from pose4d_ros.core.skeleton import mirror_index
from pose4d_ros.datasets.lspet import read_frames
from pose4d_ros.models import model_path
from pose4d_ros.training.dpm.diagnose import labelled_score
from pose4d_ros.training.dpm.samples import TrainConfig, person_scale


def pck(uv: np.ndarray, truth: np.ndarray, alpha: float = 0.1) -> float:
    """PCK@alpha of the pose `uv` against the all-labelled joints `truth` (the table's rule,
    `core.metrics`)."""
    return float(pck_per_frame(uv[None], truth[None], _all(truth), alpha=alpha)[0])


def _all(truth: np.ndarray) -> np.ndarray:
    """(1, J) every joint of `truth` labelled."""
    return np.ones((1, len(truth)), bool)


TOP_K = 10


def diagnose(root: str, first: int, last: int, model: PartModel) -> list[dict]:
    det = Detector(model)
    arrays = model_arrays(model)
    fh, fw = model.filter_shape
    trained = TrainConfig.of_model(model.metadata)
    swap = mirror_index(model.part_names)
    neck = model.part_names.index('neck')
    hips = [model.part_names.index('left_hip'), model.part_names.index('right_hip')]
    out = []
    for frame in read_frames(root, first, last):
        truth, _, vis = frame.truth.labelled(model.part_names)
        if not vis.all():
            continue
        s = person_scale(frame, model.part_names, trained, truth)
        if not (np.isfinite(s) and s > 2):
            continue
        h, w = frame.color.shape[:2]
        f = model.canonical_scale_px / s
        level = det.pyramid(frame.color, None, SearchPlan(0, 0, w, h, (f,), False))[0]
        res = score_level(level, model, arrays)
        if res is None:
            continue
        rows, cols = level.pixel_to_cell(truth[:, 0], truth[:, 1], (fh, fw))
        ny, nx = res.resp.shape[2:]
        if rows.min() < 0 or cols.min() < 0 or rows.max() >= ny or cols.max() >= nx:
            continue
        gt = labelled_score(res.resp.astype(np.float64), np.stack([rows, cols], 1), model)
        same = det.poses_from_levels([level])[0]
        cands = det.detect(frame.color, None, top_k=TOP_K)
        found = cands[0]
        off = (float(np.hypot(*(found.uv.mean(0) - truth.mean(0))))
               / float(reference_size(truth[None], _all(truth))[0]))
        down = truth[hips].mean(0) - truth[neck]
        out.append({'key': Path(frame.key).name, 'person_scale_px': round(s, 1),
                    'labelled_score': round(gt, 3),
                    'same_scale_score': round(same.score, 3),
                    'same_scale_pck': round(pck(same.uv, truth), 1),
                    'found_score': round(found.score, 3),
                    'found_pck': round(pck(found.uv, truth), 1),
                    'found_scale_ratio': round(found.scale / f, 3),
                    'found_pck20': round(pck(found.uv, truth, 0.2), 1),
                    'found_swapped_pck20': round(pck(found.uv[swap], truth, 0.2), 1),
                    'found_centre_off': round(off, 3),
                    'torso_tilt_deg': round(abs(float(np.degrees(np.arctan2(*down)))), 1),
                    f'best_of_{TOP_K}_pck20': round(max(pck(c.uv, truth, 0.2)
                                                        for c in cands), 1)})
    return out


def summary(rows: list[dict]) -> str:
    def col(k: str) -> np.ndarray:
        return np.array([r[k] for r in rows], float)
    gt, same, found = col('labelled_score'), col('same_scale_score'), col('found_score')
    ratio = col('found_scale_ratio')
    near = np.abs(np.log(ratio)) <= np.log(1.15)
    lines = [f'{len(rows)} photographs with all 14 joints labelled',
             f'median score: labelled pose {np.median(gt):.2f}, best at its scale '
             f'{np.median(same):.2f}, found {np.median(found):.2f}',
             f'found pose outscores the labelled one: {100 * np.mean(found > gt):.1f} %',
             f'best pose at the labelled scale outscores the labelled one: '
             f'{100 * np.mean(same > gt + 1e-6):.1f} %',
             f'labelled pose scores above 0 (the SVM boundary): {100 * np.mean(gt > 0):.1f} %',
             f'found at the labelled scale (+-15 %): {100 * np.mean(near):.1f} %'
             f', smaller (level scale > 1.15x): {100 * np.mean(ratio > 1.15):.1f} %'
             f', larger: {100 * np.mean(ratio < 1 / 1.15):.1f} %',
             f'PCK@0.1: found {np.mean(col("found_pck")):.1f}, best at the labelled scale '
             f'{np.mean(col("same_scale_pck")):.1f}']
    p20, off = col('found_pck20'), col('found_centre_off')
    either = np.maximum(p20, col('found_swapped_pck20'))
    on = off <= 0.25
    lines += [f'PCK@0.2: found {np.mean(p20):.1f}, the best of the {TOP_K} best poses '
              f'{np.mean(col(f"best_of_{TOP_K}_pck20")):.1f}, found with left and right '
              f'swapped where that fits better {np.mean(either):.1f}',
              f'found pose centred on the labelled person (within 0.25 of its size): '
              f'{100 * np.mean(on):.1f} % (PCK@0.2 {np.mean(p20[on]) if on.any() else np.nan:.1f}'
              f'; elsewhere {np.mean(p20[~on]) if (~on).any() else np.nan:.1f})']
    tilt = col('torso_tilt_deg')
    by_tilt = []
    for lo, hi in ((0, 30), (30, 90), (90, 181)):
        sel = (tilt >= lo) & (tilt < hi)
        if sel.any():
            by_tilt.append(f'{lo}-{min(hi, 180)} degrees {np.mean(p20[sel]):.1f} ({sel.sum()})')
    lines.append('PCK@0.2 of the found pose by torso tilt (photographs): ' + ', '.join(by_tilt))
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('root', help='LSPET root')
    p.add_argument('--range', dest='frame_range', default='2501-2600', metavar='A-B')
    p.add_argument('--model', default='lspet_rgb_14')
    p.add_argument('--json', type=Path)
    args = p.parse_args(argv)
    a, b = (int(v) for v in args.frame_range.split('-'))
    rows = diagnose(args.root, a, b, load_model(model_path(args.model)))
    if not rows:
        print('no photograph with all 14 joints labelled in range', file=sys.stderr)
        return 1
    print(summary(rows))
    if args.json is not None:
        write_json(args.json, {'model': args.model, 'range': args.frame_range, 'photos': rows})
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
