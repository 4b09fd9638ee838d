"""`pose4d train`: train a part model (RGB-D 4D-DPM, or RGB-only = Yang & Ramanan's baseline).

    pose4d train SOURCE... --out MODEL.npz [--parts 10|14] [--channels rgbd|rgb] [--types K]
                 [--seed N] [--range A-B]

SOURCE is a CAD-60 directory (real or synthetic: a root of dataN/ directories, or one dataN/)
or an LSPET root (with --range, e.g. 1-2500). Negatives (for hard-negative mining) are the
background of the training frames: the strips of each frame away from the person, and for sets
with person masks (synthetic) the room itself, assembled from the frames where the person is
elsewhere. See `training.dpm.train` for the method.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from pose4d_ros.core.dpm.model import load_model, save_model
from pose4d_ros.core.threads import set_blas_threads
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.models import model_path
from pose4d_ros.training.dpm.negatives import build_negatives
from pose4d_ros.training.dpm.samples import TrainConfig, bone_ratios, part_joints
from pose4d_ros.training.dpm.train import train
from pose4d_ros.training.part_model import depth_lifting, recalibrate, with_foreground_masks
from pose4d_ros.training.refiner import fit_stages, refiner_frames
from pose4d_ros.util.machine import command_line, git_commit, machine
from pose4d_ros.util.progress import log, progress


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'train', help='train a part model (RGB-D or RGB-only)',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('sources', nargs='+', metavar='SOURCE',
                   help='CAD-60 directory or LSPET root')
    p.add_argument('--out', required=True, type=Path, help='model file to write (.npz)')
    p.add_argument('--parts', choices=('10', '14', '22'), default='10',
                   help='part tree (22: the 14 joints and the middle of each limb bone)')
    p.add_argument('--channels', choices=('rgbd', 'rgb'), default='rgbd',
                   help='rgbd: colour + depth filter per type; rgb: colour only')
    p.add_argument('--types', type=int, default=6, help='mixture types per part (K)')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--range', dest='frame_range', metavar='A-B',
                   help='LSPET image numbers (inclusive), e.g. 1-2500')
    p.add_argument('--stride', type=int, default=1, help='every n-th frame of a CAD-60 video')
    p.add_argument('--max-frames', type=int, default=None,
                   help='train on at most this many frames (evenly spread)')
    p.add_argument('--sbin', type=int, default=4, help='HOG cell size, pixels')
    p.add_argument('--filter-cells', type=int, default=5, help='filter size, cells')
    p.add_argument('--scale-px', type=float, default=32.0,
                   help='person scale (about a torso) at the model level, pixels')
    p.add_argument('--depth-encoding', choices=('float', 'u8'), default='float',
                   help='depth HOG on float metres or on 8-bit scaled depth')
    p.add_argument('--masked', action='store_true',
                   help='train on frames blanked outside the foreground mask (core.foreground '
                        'run on each frame, as the live pipeline does)')
    p.add_argument('--rounds', type=int, default=8, help='mining rounds')
    p.add_argument('--svm-c', type=float, default=3e-4, help='SVM C of eq. (5)')
    p.add_argument('--positive-weight', type=float, default=1.0,
                   help="weight of the labelled poses' constraints (C x this)")
    p.add_argument('--no-background', action='store_true',
                   help='no background negatives (only wrong poses of the labelled frames)')
    p.add_argument('--negatives-per-image', type=int, default=6)
    p.add_argument('--poses-per-frame', type=int, default=4,
                   help='wrong poses mined per labelled frame and round')
    p.add_argument('--latent-radius', type=int, default=0,
                   help='cells a labelled part may move to the best-scoring cell before each '
                        'mining round (latent positives; 0: fixed at the labels)')
    p.add_argument('--partial-labels', action='store_true',
                   help='also train on frames with some parts unlabelled (those parts latent; '
                        'needs --latent-radius)')
    p.add_argument('--min-labelled', type=int, default=10,
                   help='fewest labelled parts of a frame used with --partial-labels')
    p.add_argument('--jitter', type=int, default=0,
                   help='extra copies of every positive cut with the crop origin shifted by '
                        'less than one HOG cell (another phase of the cell grid)')
    p.add_argument('--background', action='append', default=[], metavar='SOURCE',
                   help='person-free background images: the rooms of a synthetic CAD-60 set '
                        '(pose4d synth), assembled from the frames where the person is '
                        'elsewhere; counted first against --max-negative-images (repeatable)')
    p.add_argument('--cache-limit', type=int, default=20000, help='constraint cache size')
    p.add_argument('--max-negative-images', type=int, default=1500)
    p.add_argument('--no-flip', action='store_true', help='no mirrored positives')
    p.add_argument('--search-percent', type=float, default=TrainConfig.search_percent,
                   help='the search without depth covers the training people\'s person scales '
                        'from this percentile to 100 minus it (also with --calibrate)')
    p.add_argument('--scale-from', choices=('torso', 'bones'), default='torso',
                   help='person scale of a frame without depth: the longer shoulder-to-hip '
                        'side, or every labelled bone against its typical fraction of it '
                        '(learned from SOURCE and kept in the model)')
    p.add_argument('--calibrate', type=Path, metavar='MODEL.npz',
                   help="no training: fit MODEL's part confidences and depth offsets again on "
                        'SOURCE (as the last step of training does) and write it to --out')
    p.add_argument('--refine', type=Path, metavar='MODEL.npz',
                   help="no training: run the foreground and MODEL's detector over SOURCE's "
                        "labelled RGB-D frames as the nodes do, fit MODEL's part refiner "
                        '(core.refine) on its detections and write it to --out')
    p.add_argument('--trees', type=int, default=200,
                   help='--refine: trees per part group and output')
    p.add_argument('--tree-depth', type=int, default=5, help='--refine: depth of a tree')
    p.add_argument('--stages', type=int, default=1,
                   help='--refine: stages of the cascade, each fitted on the parts as the '
                        'stages before it move them')
    p.add_argument('--depth-stages', type=int, default=0,
                   help='--refine: further stages after those that correct only the depth')
    p.add_argument('--blas-threads', type=int, default=1,
                   help='OpenBLAS threads (1: the measured best on 2 shared cores)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pose4d_ros.core.foreground  # noqa: F401  (loads scipy and its BLAS before the set)

    t0 = time.time()
    set_blas_threads(args.blas_threads)
    cfg = TrainConfig(parts=args.parts, channels=args.channels, n_types=args.types,
                      sbin=args.sbin, filter_cells=args.filter_cells,
                      canonical_scale_px=args.scale_px, depth_encoding=args.depth_encoding,
                      masked_input=args.masked, flip=not args.no_flip, svm_c=args.svm_c,
                      positive_weight=args.positive_weight,
                      mining_rounds=args.rounds, background_negatives=not args.no_background,
                      negatives_per_image=args.negatives_per_image,
                      structural_per_positive=args.poses_per_frame,
                      latent_radius=args.latent_radius, partial_labels=args.partial_labels,
                      min_labelled=args.min_labelled, jitter=args.jitter,
                      search_percent=args.search_percent,
                      cache_limit=args.cache_limit, seed=args.seed)
    if args.out.suffix != '.npz':
        raise ValueError(f'{args.out}: the model file must end in .npz')
    samples = load_frames(args.sources, frame_range=args.frame_range, stride=args.stride,
                          max_frames=args.max_frames)
    if args.calibrate is not None:
        return calibrate_again(args, samples, t0)
    if args.refine is not None:
        return refine(args, samples, t0)
    if cfg.channels == 'rgbd' and not any(s.depth_m is not None for s in samples):
        raise ValueError(f'{", ".join(args.sources)}: no depth images; use --channels rgb')
    if cfg.masked_input:
        samples = with_foreground_masks(samples)
    if args.scale_from == 'bones':
        cfg = replace(cfg, bone_ratios=bone_ratios(
            (part_joints(s, cfg.tree.names) for s in samples), cfg.tree))
        log('bone ratios to the torso side: ' + ', '.join(
            f'{cfg.tree.names[c]} {r:.2f}' for (_, c), r in zip(cfg.tree.edges(),
                                                               cfg.bone_ratios, strict=True)))
    extra = (load_frames(args.background, stride=args.stride, labelled=False)
             if args.background else None)
    negatives = (build_negatives(samples, cfg, args.max_negative_images, args.seed, extra)
                 if cfg.background_negatives else [])
    log(f'{len(samples)} frames, {len(negatives)} background images')
    m = machine()
    meta = {
        'data': ' '.join(str(Path(s).resolve()) for s in args.sources)
                + (f' range {args.frame_range}' if args.frame_range else ''),
        'command': command_line('train'),
        'seed': str(args.seed), 'git_commit': git_commit(),
        'trained_at': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
        'machine': f"{m['cores']} cores, {m['cpu']}",
    }
    model, report = train(samples, negatives, cfg, progress=progress, log=log, metadata=meta)
    elapsed = time.time() - t0
    meta = dict(model.metadata)
    meta['wall_seconds'] = f'{elapsed:.1f}'
    model = replace(model, metadata=meta)
    save_model(model, args.out)
    size = args.out.stat().st_size
    print(f'wrote {args.out} ({size / 1e6:.2f} MB): {model.n_parts} parts x {model.n_types} '
          f'types, {model.channels}, {report.n_positives} positives, '
          f'{len(negatives)} background images, {elapsed / 60:.1f} min')
    return 0


def _provenance(args: argparse.Namespace, t0: float, **facts: object) -> str:
    """What `--calibrate` and `--refine` record in the model's metadata (JSON)."""
    return json.dumps({
        'command': command_line('train'),
        'data': ' '.join(str(Path(s).resolve()) for s in args.sources), **facts,
        'git_commit': git_commit(), 'at': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
        'wall_seconds': round(time.time() - t0, 1)})


def calibrate_again(args: argparse.Namespace, samples: list[Frame], t0: float) -> int:
    """`--calibrate MODEL`: `training.part_model.recalibrate` on `samples`, recorded in the
    model's metadata."""
    model, n = recalibrate(load_model(model_path(str(args.calibrate))), samples,
                           search_percent=args.search_percent, seed=args.seed)
    model = replace(model, metadata={**model.metadata,
                                     'calibrated': _provenance(args, t0, frames=n)})
    save_model(model, args.out)
    span = model.search_range_px or model.scale_range_px
    print(f'wrote {args.out}: {args.calibrate} calibrated on {n} frames; person '
          f'scales searched without depth {span[0]:.1f}-{span[1]:.1f} px'
          + (f', ranked with a scale prior of {model.scale_prior:g} per octave'
             if model.channels == 'rgb' else '') + f'; {depth_lifting(model)}')
    return 0


def refine(args: argparse.Namespace, samples: list[Frame], t0: float) -> int:
    """`--refine MODEL`: fit MODEL's part refiner on `samples`, `--stages` stages one after
    the other (`training.refiner`), recorded in the model's metadata."""
    model = load_model(model_path(str(args.refine)))
    if model.channels != 'rgbd':
        raise ValueError(f'{args.refine}: the refiner reads depth; an RGB model has none')
    if args.stages < 1 or args.depth_stages < 0:
        raise ValueError(f'--stages must be >= 1 and --depth-stages >= 0, got {args.stages} '
                         f'and {args.depth_stages}')
    frames = refiner_frames(model, samples)
    t1 = time.time()
    refiner, n = fit_stages(model, frames, stages=args.stages, depth_stages=args.depth_stages,
                            trees=args.trees, tree_depth=args.tree_depth)
    meta = _provenance(args, t0, frames=len(samples), samples=n, stages=args.stages,
                       depth_stages=args.depth_stages, trees=args.trees,
                       depth=args.tree_depth, fit_seconds=round(time.time() - t1, 1))
    model = replace(model, refiner=refiner, metadata={**model.metadata, 'refiner': meta})
    save_model(model, args.out)
    print(f'wrote {args.out}: {args.refine} with a {refiner.stages}-stage part refiner '
          f'({args.depth_stages} of depth only) fitted on '
          f'{n} parts of {len(samples)} frames ({", ".join(refiner.groups)}; '
          f'{args.trees} trees of depth '
          f'{args.tree_depth} per group and output), {(time.time() - t0) / 60:.1f} min')
    return 0
