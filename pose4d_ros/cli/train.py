"""`pose4d train`: train a part model (RGB-D 4D-DPM, or RGB-only = Yang & Ramanan's baseline).

    pose4d train SOURCE... --out MODEL.npz [--parts 10|14] [--channels rgbd|rgb] [--types K]
                 [--seed N] [--range A-B]

SOURCE is a CAD-60 directory (real or synthetic: a root of dataN/ directories, or one dataN/)
or an LSPET root (with --range, e.g. 1-2500). Negatives (for hard-negative mining) are the
background of the training frames: the strips of each frame away from the person, and for sets
with person masks (synthetic) the room itself, assembled from the frames where the person is
elsewhere. See `core.dpm.train` for the method.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.cli._dpm import git_commit, load_frames, log, machine
from pose4d_ros.cli._progress import progress
from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.dpm.model import PartModel, load_model, save_model
from pose4d_ros.core.dpm.samples import (
    Negative,
    TrainConfig,
    background_crops,
    bone_ratios,
    part_joints,
    person_scale,
)
from pose4d_ros.core.dpm.threads import set_blas_threads
from pose4d_ros.core.dpm.train import (
    calibrate,
    positive_scale,
    scale_span,
    train,
)
from pose4d_ros.core.pipeline import DetectorStage, ForegroundStage
from pose4d_ros.core.refine import OUTPUTS, PartRefiner, fit_refiner, known_parts, targets
from pose4d_ros.core.refine import features as refine_features
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.models import model_path


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


def room_backgrounds(samples: list[Frame], *, dilate_px: int = 5) -> list[Negative]:
    """The room behind the person, per video of a masked (synthetic) set: every pixel from the
    latest frame in which the (dilated) person mask leaves it free; pixels the person never
    leaves are cut off by keeping the widest free band of columns on either side."""
    import cv2

    by_video: dict[str, list[Frame]] = defaultdict(list)
    for s in samples:
        if s.mask is not None and s.depth_m is not None:
            by_video[s.video or s.key].append(s)
    kernel = np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8)
    out = []
    for vid, ss in by_video.items():
        h, w = ss[0].color.shape[:2]
        col = np.zeros((h, w, 3), np.uint8)
        dep = np.full((h, w), np.nan, np.float32)
        free = np.zeros((h, w), bool)
        for s in ss:
            busy = cv2.dilate(s.mask.astype(np.uint8), kernel) > 0
            ok = ~busy
            col[ok] = s.color[ok]
            dep[ok] = s.depth_m[ok]
            free |= ok
        if free.all():
            out.append(Negative(col, dep, f'{vid} (room)'))
            continue
        cols_free = free.all(axis=0)
        # widest run of fully free columns
        best, start, run0 = (0, 0), None, 0
        for x in range(w + 1):
            if x < w and cols_free[x]:
                if start is None:
                    start = x
            elif start is not None:
                if x - start > best[1] - best[0]:
                    best = (start, x)
                start = None
        run0 = best[1] - best[0]
        if run0 >= w // 4:
            x0, x1 = best
            out.append(Negative(np.ascontiguousarray(col[:, x0:x1]),
                                np.ascontiguousarray(dep[:, x0:x1]), f'{vid} (room)'))
    return out


def with_foreground_masks(samples: list[Frame]) -> list[Frame]:
    """The samples with `mask` replaced by the foreground stage's mask (`core.foreground`),
    so that a masked model trains on what it will see; a frame where the foreground finds no
    person keeps its own mask (the renderer's), or none."""
    from pose4d_ros.core.camera import cad60_intrinsics
    from pose4d_ros.core.foreground import segment

    out = []
    missed = 0
    for s in progress(samples, 'foreground'):
        if s.depth_m is None:
            out.append(s)
            continue
        h, w = s.depth_m.shape
        res = segment(s.depth_m, s.intrinsics or cad60_intrinsics(w, h))
        if res.found:
            out.append(replace(s, mask=res.mask))
        else:
            missed += 1
            out.append(s)
    if missed:
        log(f'foreground found no person in {missed} of {len(samples)} frames '
            '(their own masks are used)')
    return out


def build_negatives(samples: list[Frame], cfg: TrainConfig, max_images: int, seed: int,
                    extra: list[Frame] | None = None) -> list[Negative]:
    """Background images for mining: room plates (masked sets, and the `extra` frames, which
    serve as backgrounds only) + strips beside the person."""
    negs = room_backgrounds(samples)
    if extra:
        rooms = room_backgrounds(extra)
        if not rooms:
            raise ValueError(f'--background: no room could be assembled from {len(extra)} '
                             'frames (a synthetic set with person masks and depth is needed)')
        negs += rooms
    strips: list[Negative] = []
    for s in samples:
        uv, _ = part_joints(s, cfg.tree.names)
        sc = person_scale(s, cfg.tree.names, cfg, uv)
        if np.isfinite(sc):
            strips.extend(background_crops(s, sc))
    rng = np.random.default_rng(seed)
    room = max(max_images - len(negs), 0)
    if len(strips) > room:
        strips = [strips[i] for i in np.sort(rng.choice(len(strips), room, replace=False))]
    if cfg.channels == 'rgb':
        negs = [Negative(n.color, None, n.key) for n in negs]
        strips = [Negative(n.color, None, n.key) for n in strips]
    return negs + strips


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
        return recalibrate(args, samples, t0)
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
        'command': 'pose4d train ' + ' '.join(shlex.quote(a) for a in sys.argv[2:])
                   if len(sys.argv) > 1 and sys.argv[1] == 'train' else '',
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


def depth_lifting(model: PartModel) -> str:
    """How the model lifts each part to 3-D, in a line."""
    if model.depth_offset_m is None:
        return 'no depth look-up'
    lookup = model.depth_lookup
    return 'depth look-up per part (window radius, quantile, mm behind the surface): ' + ', '.join(
        f'{n} ' + ('3 px, 0.5' if lookup is None else f'{100 * lookup[i, 0]:.1f} cm, '
                   f'{lookup[i, 1]:.1f}') + f', {1e3 * model.depth_offset_m[i]:+.0f}'
        for i, n in enumerate(model.part_names))


def recalibrate(args: argparse.Namespace, samples: list[Frame], t0: float) -> int:
    """`--calibrate MODEL`: the last steps of `train` alone, on `samples`: the person scales
    searched without depth (from all of them) and the calibration (on the same deterministic
    subset of `TrainConfig.calibration_samples` frames, masked as the model was trained),
    recorded in the model's metadata."""
    model = load_model(model_path(str(args.calibrate)))
    trained = TrainConfig.of_model(model.metadata)
    if trained.masked_input:
        samples = with_foreground_masks(samples)
    # the search without depth covers the middle of the people's scales, as `train` sets it
    scales = np.array([positive_scale(s, model.part_names, trained) for s in samples])
    scales = scales[scales > 2]
    if len(scales):
        model = replace(model, search_range_px=scale_span(scales, args.search_percent))
    usable = [s for s in samples if part_joints(s, model.part_names)[1].sum() >= 2]
    n = trained.calibration_samples
    if len(usable) > n:
        rng = np.random.default_rng(args.seed)
        usable = [usable[i] for i in np.sort(rng.choice(len(usable), n, replace=False))]
    model = calibrate(model, usable, use_depth=model.channels == 'rgbd', progress=progress)
    meta = dict(model.metadata)
    meta['calibrated'] = json.dumps({
        'command': 'pose4d train ' + ' '.join(shlex.quote(a) for a in sys.argv[2:])
                   if sys.argv[1:2] == ['train'] else '',
        'data': ' '.join(str(Path(s).resolve()) for s in args.sources), 'frames': len(usable),
        'git_commit': git_commit(), 'at': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
        'wall_seconds': round(time.time() - t0, 1)})
    model = replace(model, metadata=meta)
    save_model(model, args.out)
    span = model.search_range_px or model.scale_range_px
    print(f'wrote {args.out}: {args.calibrate} calibrated on {len(usable)} frames; person '
          f'scales searched without depth {span[0]:.1f}-{span[1]:.1f} px'
          + (f', ranked with a scale prior of {model.scale_prior:g} per octave'
             if model.channels == 'rgb' else '') + f'; {depth_lifting(model)}')
    return 0


@dataclass
class RefinerFrame:
    """What a refiner stage learns from, per labelled frame: the detector's parts (`uv`, lifted
    depths `z`, `confidence`), the frame's depth on the person (NaN elsewhere) and its camera,
    and the joints' true pixels and depths where `labelled`."""

    uv: NDArray[np.float64]
    z: NDArray[np.float64]
    confidence: NDArray[np.float64]
    depth: NDArray[np.float32]
    intrinsics: Intrinsics
    true_uv: NDArray[np.float64]
    true_z: NDArray[np.float64]
    labelled: NDArray[np.bool_]


def refiner_frames(model: PartModel, samples: list[Frame]) -> list[RefinerFrame]:
    """The foreground and `model`'s detector (its refiner left out) run over `samples` as the
    nodes run them (each video in order, the previous frame guiding the arms), once for all
    the stages: each frame's depth is kept in memory (0.3 MB at 320x240; 11,092 frames, 3.4
    GB)."""
    foreground = ForegroundStage()
    detector = DetectorStage(replace(model, refiner=None))
    out = []
    video = None
    for f in progress(samples, 'detections', len(samples)):
        if f.depth_m is None or f.intrinsics is None:
            raise ValueError(f'{f.key}: --refine needs RGB-D frames with camera intrinsics')
        if f.video != video:
            foreground.reset()
            detector.reset()
            video = f.video
        fg, color, depth = foreground.step(f.color, f.depth_m, f.intrinsics)
        found = detector.step(color, depth, f.intrinsics, mask=fg.mask,
                              stamp_s=f.stamp_ns * 1e-9, blanked=True)
        true_uv, truth, labelled = f.truth.labelled(found.names)
        out.append(RefinerFrame(found.uv, found.xyz[:, 2], found.confidence.astype(np.float64),
                                np.where(fg.mask, depth, np.nan).astype(np.float32),
                                f.intrinsics, true_uv, truth[:, 2], labelled))
    return out


def moved(frame: RefinerFrame, model: PartModel, stage: PartRefiner) -> RefinerFrame:
    """`frame` with its parts where `stage` (one or more of `model`'s refiner stages) puts
    them."""
    uv, z = stage.apply(model.part_names, model.parents, frame.uv, frame.z, frame.confidence,
                        frame.depth, frame.intrinsics)
    return replace(frame, uv=uv, z=z)


def refiner_samples(model: PartModel, frames: list[RefinerFrame]
                    ) -> tuple[NDArray[np.float32], NDArray[np.int64], NDArray[np.float64]]:
    """The training samples of a refiner stage: for every labelled part of `frames` with a
    detection and a lifted depth, where the stages before it put it, its features
    (`core.refine.features`), its index and what the stage is to learn
    (`core.refine.targets`)."""
    names = model.part_names
    xs, parts, ys = [], [], []
    for f in frames:
        x = refine_features(names, model.parents, f.uv, f.z, f.confidence, f.depth,
                            f.intrinsics)
        y = targets(names, f.uv, f.z, f.true_uv, f.true_z, f.intrinsics.fx)
        use = f.labelled & np.isfinite(y).all(axis=1) & known_parts(x)
        xs.append(x[use])
        parts.append(np.flatnonzero(use))
        ys.append(y[use])
    return np.concatenate(xs), np.concatenate(parts), np.concatenate(ys)


def refine(args: argparse.Namespace, samples: list[Frame], t0: float) -> int:
    """`--refine MODEL`: fit MODEL's part refiner on `samples`, `--stages` stages one after
    the other, recorded in the model's metadata."""
    model = load_model(model_path(str(args.refine)))
    if model.channels != 'rgbd':
        raise ValueError(f'{args.refine}: the refiner reads depth; an RGB model has none')
    if args.stages < 1 or args.depth_stages < 0:
        raise ValueError(f'--stages must be >= 1 and --depth-stages >= 0, got {args.stages} '
                         f'and {args.depth_stages}')
    frames = refiner_frames(model, samples)
    t1 = time.time()
    refiner: PartRefiner | None = None
    n_stages = args.stages + args.depth_stages
    for stage in range(n_stages):
        x, part, target = refiner_samples(model, frames)
        fitted = fit_refiner(model.part_names, x, part, target, trees=args.trees,
                             depth=args.tree_depth,
                             outputs=OUTPUTS if stage < args.stages else ('dz',))
        refiner = fitted if refiner is None else refiner.then(fitted)
        if stage + 1 < n_stages:  # the next stage learns where this one puts the parts
            frames = [moved(f, model, fitted) for f in frames]
        print(f'refiner stage {stage + 1}: {len(target)} parts, median residual '
              f'{1000 * np.median(np.abs(target[:, 2])):.1f} mm in depth, '
              f'{np.median(np.hypot(*target[:, :2].T)):.3f} person scales across')
    meta = dict(model.metadata)
    meta['refiner'] = json.dumps({
        'command': 'pose4d train ' + ' '.join(shlex.quote(a) for a in sys.argv[2:])
                   if sys.argv[1:2] == ['train'] else '',
        'data': ' '.join(str(Path(s).resolve()) for s in args.sources), 'frames': len(samples),
        'samples': len(target), 'stages': args.stages, 'depth_stages': args.depth_stages,
        'trees': args.trees,
        'depth': args.tree_depth, 'fit_seconds': round(time.time() - t1, 1),
        'git_commit': git_commit(), 'at': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
        'wall_seconds': round(time.time() - t0, 1)})
    model = replace(model, refiner=refiner, metadata=meta)
    save_model(model, args.out)
    print(f'wrote {args.out}: {args.refine} with a {refiner.stages}-stage part refiner '
          f'({args.depth_stages} of depth only) fitted on '
          f'{len(target)} parts of {len(samples)} frames ({", ".join(refiner.groups)}; '
          f'{args.trees} trees of depth '
          f'{args.tree_depth} per group and output), {(time.time() - t0) / 60:.1f} min')
    return 0
