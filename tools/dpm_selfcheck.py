"""Self-check of the part model's training on LSPET: train on a few photographs, then on those
very photographs check that inference and training agree.

    .venv/bin/python tools/dpm_selfcheck.py ../shared/data/lspet --range 1-150 --rounds 2 \
        [--latent-radius 1] [--model M.npz]

(With --model the given model is checked and nothing is trained.) For every photograph with
all 14 joints labelled (not mirrored), on the training crop's level (`samples.level_of`, the
level the positives and the wrong poses are cut from):

1. the score `backtrack` reports for the best pose equals w . Phi(pose) with Phi from
   `solver.pose_blocks` on the same level (a sign, anchor or offset mismatch between training
   and inference shows here);
2. the labelled pose's own score (filters at the labelled cells, best types) against the best
   pose's, the share of cells whose best root outscores it, and the best pose's share of parts
   within the loss radius of their labels and its PCK@0.1 (cell centres, no sub-cell step);
3. the same labelled pose scored on the level of the whole photograph at the same scale (what
   `Detector` searches): the HOG cell grid then has another phase.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pose4d_ros.core.dpm.dp import (
    backtrack,
    best_roots,
    model_arrays,
    score_level,
)
from pose4d_ros.core.dpm.infer import Detector, SearchPlan
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.training.dpm.diagnose import labelled_score
from pose4d_ros.training.dpm.negatives import build_negatives
from pose4d_ros.training.dpm.samples import (
    TrainConfig,
    frame_of,
    level_of,
    part_joints,
    person_scale,
    prepare_positive,
)
from pose4d_ros.training.dpm.solver import Layout, pose_blocks
from pose4d_ros.training.dpm.train import train


def raw_w(model) -> tuple[np.ndarray, Layout]:
    """The model's parameters as one vector in the QP's layout, on raw (unwhitened) windows."""
    p, k = model.n_parts, model.n_types
    lay = Layout(p, k, int(np.prod(model.filters.shape[2:])))
    w = np.concatenate([model.filters.reshape(-1), model.springs.reshape(-1),
                        model.bias.reshape(-1)]).astype(np.float64)
    return w, lay


def check(model, samples, cfg: TrainConfig) -> dict:
    det = Detector(model)
    arrays = model_arrays(model)
    _, parents, springs, anchors, bias = arrays
    tree, fs = cfg.tree, cfg.filter_cells
    w, lay = raw_w(model)
    worst, rows = 0.0, []
    for idx, s in enumerate(samples):
        uv, vis = part_joints(s, tree.names)
        if not vis.all():
            continue
        sc = person_scale(s, tree.names, cfg, uv)
        p = prepare_positive(s, idx, False, sc, tree, cfg)
        if p is None:
            continue
        color, depth, mask, _ = frame_of(s, tree.names, cfg, False)
        level = level_of(color, depth, mask, p.box, p.level_scale, cfg)
        res = score_level(level, model, arrays)
        roots = best_roots(res, 1)
        parts, local = backtrack(roots, parents, res.resp, res.ix, res.iy, res.ik, springs,
                                 anchors, bias)
        xf, of, xd, od, xb, ob = pose_blocks(level.feat, parts[0], parents, anchors, lay, fs, 1.0)
        phi = sum(float(xf[c] @ w[of[c]:of[c] + lay.dim]) + float(xb[c] * w[ob[c]])
                  + (float(xd[c] @ w[od[c]:od[c] + 4]) if od[c] >= 0 else 0.0)
                  for c in range(lay.n_parts))
        worst = max(worst, abs(phi - float(local[0].sum())))
        gt = labelled_score(res.resp.astype(np.float64), p.cells, model)
        best = res.root.max(axis=0)
        near = np.hypot(*(parts[0, :, 1:] - p.cells).T) <= p.tau
        bu, bv = level.cell_to_pixel(parts[0, :, 1], parts[0, :, 2], (fs, fs))
        pck = np.hypot(bu - uv[:, 0], bv - uv[:, 1]) <= 0.1 * float(np.max(np.ptp(uv, axis=0)))
        h, w_ = s.color.shape[:2]
        full = det.pyramid(s.color, None, SearchPlan(0, 0, w_, h, (p.level_scale,), False))[0]
        rf = score_level(full, model, arrays)
        r, c = full.pixel_to_cell(uv[:, 0], uv[:, 1], (fs, fs))
        ny, nx = rf.resp.shape[2:]
        gt_full = (labelled_score(rf.resp.astype(np.float64), np.stack([r, c], 1), model)
                   if r.min() >= 0 and c.min() >= 0 and r.max() < ny and c.max() < nx
                   else np.nan)
        rows.append((gt, float(best.max()), float((best > gt + 1e-6).mean()),
                     float(near.mean()), gt_full, float(pck.mean())))
    a = np.asarray(rows)
    return {'photos': len(a), 'max_abs_backtrack_minus_w_phi': worst,
            'labelled_score_median': float(np.median(a[:, 0])),
            'best_score_median': float(np.median(a[:, 1])),
            'cells_above_labelled_median': float(np.median(a[:, 2])),
            'best_parts_within_loss_radius_pct': 100 * float(a[:, 3].mean()),
            'best_pck01_on_crop_pct': 100 * float(a[:, 5].mean()),
            'labelled_score_on_whole_photo_median': float(np.nanmedian(a[:, 4]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('root', help='LSPET root')
    ap.add_argument('--range', dest='frame_range', default='1-150', metavar='A-B')
    ap.add_argument('--rounds', type=int, default=2)
    ap.add_argument('--svm-c', type=float, default=1e-4)
    ap.add_argument('--latent-radius', type=int, default=0)
    ap.add_argument('--negative-images', type=int, default=100)
    ap.add_argument('--model', type=Path, help='check this model instead of training one')
    args = ap.parse_args(argv)
    samples = load_frames([args.root], frame_range=args.frame_range)
    cfg = TrainConfig(parts='14', channels='rgb', svm_c=args.svm_c, mining_rounds=args.rounds,
                      structural_per_positive=2, latent_radius=args.latent_radius)
    if args.model is None:
        t0 = time.perf_counter()
        negs = build_negatives(samples, cfg, args.negative_images, cfg.seed)
        model, report = train(samples, negs, cfg, log=print)
        print(f'trained in {time.perf_counter() - t0:.0f} s')
    else:
        model = load_model(args.model)
    for key, val in check(model, samples, cfg).items():
        print(f'{key}: {val:.6g}' if isinstance(val, float) else f'{key}: {val}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
