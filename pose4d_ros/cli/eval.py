"""`pose4d eval`: run the perception core over a labelled set and print the paper's table.

    pose4d eval SOURCE --json FILE [--model M ...] [--range A-B] [--peer mediapipe]

SOURCE is a CAD-60 directory (real or synthetic), a rosbag2 with ground truth (`pose4d
cad60-to-bag`) or an LSPET root (with --range). Each row is a variant of the core run over every
frame:

- `rgbd`, `rgbd_kf`, `rgbd_kf_ik`: the live pipeline's own stages (`core.pipeline.FramePipeline`,
  what the nodes run), frame after frame, each video a new track: the foreground stage
  (`core.foreground`) masks the person on the depth image, the RGB-D part model searches the
  levels that the person's depth gives inside the mask's box (`rgbd`); the SLQE Kalman filter
  tracks the parts (`rgbd_kf`); inverse kinematics adds elbows and knees (`rgbd_kf_ik`, which
  scores them too). With --max-frames (a subset, no longer a sequence) only `rgbd` is given.
- `rgb`: the Yang & Ramanan baseline: the RGB-only part model over the whole colour image and
  the whole trained scale range, no depth at all.

- `mediapipe` (`--peer mediapipe`): MediaPipe Pose 0.10.21 (`pose4d_ros.peer`, installed by
  `make peer`) on the same frames, its joints lifted to 3-D by the detector's depth look-up; in
  video mode, a new video where the tracker starts a new track (each photo or subset frame on
  its own).

Default models: the shipped `rgbd_10` and `rgb_10` for a CAD-60 set, `lspet_rgb_14` for LSPET;
`--model` (repeatable) replaces them, each model giving the row of its channels. More rows
(tracker, IK) plug in as more `Variant`s: `run_variant` yields predictions, `score` scores them.
Every row records its CPU time per frame (`cpu_ms`: p50, p95; see `_pipeline_eval`).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.cli._dpm import load_samples, log, ms_stats, progress
from pose4d_ros.cli._pipeline_eval import evaluate_peer, evaluate_source
from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.dpm.infer import Detector, SearchConfig
from pose4d_ros.core.dpm.model import PartModel, load_model
from pose4d_ros.core.dpm.samples import part_joints
from pose4d_ros.core.dpm.threads import set_blas_threads
from pose4d_ros.core.files import write_json
from pose4d_ros.core.joints import MISSING
from pose4d_ros.core.metrics import score_groups
from pose4d_ros.core.skeleton import JOINT_GROUPS
from pose4d_ros.datasets.sources import Sample, source_kind
from pose4d_ros.models import model_path
from pose4d_ros.peer import NAMES as PEER_NAMES
from pose4d_ros.peer import PEERS, MediaPipePeer

TABLE_METRICS = (('pck', 'PCK@0.1 (%)'), ('pck@0.2', 'PCK@0.2 (%)'), ('apk', 'APK (%)'),
                 ('error_px', 'error (px)'), ('error_mm', '3-D median error (mm)'),
                 ('within_10cm', '3-D within 10 cm (%)'))


@dataclass
class Predictions:
    """A variant's output over a set of frames.

    Attributes
    ----------
    names : J predicted joint names.
    uv : (F, J, 2) float64 pixels, NaN = not predicted.
    scores : (F, J) float64 confidences (for APK).
    found : (F,) bool, a pose was returned for the frame.
    cpu_ms : (F,) float64 CPU time per frame, ms.
    """

    names: tuple[str, ...]
    uv: NDArray[np.float64]
    scores: NDArray[np.float64]
    found: NDArray[np.bool_]
    cpu_ms: NDArray[np.float64]


# A variant turns one frame into (uv (J, 2), scores (J,)) or None when it returns nothing.
FrameFn = Callable[[Sample], tuple[NDArray, NDArray] | None]


@dataclass
class Variant:
    """One row of the table: a name, the joint names it predicts, and its per-frame call;
    `cpu_s` gives the last frame's CPU seconds where they are not this process's (a peer)."""

    name: str
    names: tuple[str, ...]
    run: FrameFn
    cpu_s: Callable[[], float] | None = None


def detector_variant(name: str, model: PartModel, *, use_depth: bool,
                     search: SearchConfig | None = None) -> Variant:
    """The part detector as a variant: with depth, the foreground stage's mask bounds the
    search and gives the scale (the live pipeline); without, the whole image (Yang &
    Ramanan)."""
    det = Detector(model, search)
    if use_depth:
        from pose4d_ros.core.foreground import segment

    def run(s: Sample) -> tuple[NDArray, NDArray] | None:
        if use_depth and s.depth_m is not None:
            h, w = s.depth_m.shape
            intr = s.intrinsics or cad60_intrinsics(w, h)
            fg = segment(s.depth_m, intr)
            if fg.found:
                poses = det.detect(s.color, s.depth_m, mask=fg.mask, intrinsics=intr)
            else:  # no person found: search the whole frame rather than give up
                poses = det.detect(s.color, s.depth_m, intrinsics=intr)
        else:
            poses = det.detect(s.color, None)
        if not poses:
            return None
        return poses[0].uv, poses[0].confidence

    return Variant(name, model.part_names, run)


def peer_variant(peer: MediaPipePeer) -> Variant:
    """The peer as a variant, each frame on its own (photos, or a subset of a video)."""

    def run(s: Sample) -> tuple[NDArray, NDArray] | None:
        joints = peer.step(s.color, s.depth_m, s.intrinsics, new_video=True)
        if (joints.source == MISSING).all():
            return None
        return joints.uv, joints.confidence

    return Variant(peer.name, PEER_NAMES, run, cpu_s=lambda: peer.last_cpu_s)


def run_variant(variant: Variant, samples: Sequence[Sample]) -> Predictions:
    """Run a variant over the frames."""
    j = len(variant.names)
    uv = np.full((len(samples), j, 2), np.nan)
    sc = np.full((len(samples), j), np.nan)
    found = np.zeros(len(samples), bool)
    cpu_ms = np.zeros(len(samples))
    for i, s in enumerate(progress(samples, variant.name)):
        start = time.process_time()
        out = variant.run(s)
        cpu_ms[i] = 1e3 * (variant.cpu_s() if variant.cpu_s else time.process_time() - start)
        if out is not None:
            uv[i], sc[i] = out
            found[i] = True
    return Predictions(variant.names, uv, sc, found, cpu_ms)


def ground_truth(samples: Sequence[Sample], names: Sequence[str]
                 ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(F, J, 2) ground-truth pixels and (F, J) visibility of the named joints (aliases
    'wrist' -> CAD-60 'hand', 'ankle' -> 'foot'); joints outside the image are not visible."""
    gt = np.full((len(samples), len(names), 2), np.nan)
    vis = np.zeros((len(samples), len(names)), bool)
    for i, s in enumerate(samples):
        uv, v = part_joints(s, names)
        h, w = s.color.shape[:2]
        with np.errstate(invalid='ignore'):
            inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (
                uv[:, 1] <= h - 1)
        gt[i] = uv
        vis[i] = v & inside
    return gt, vis


def score(pred: Predictions, samples: Sequence[Sample]) -> dict[str, dict[str, float]]:
    """The paper's table row (`core.metrics.score_groups`) of a variant's predictions."""
    gt, vis = ground_truth(samples, pred.names)
    scores = np.where(np.isfinite(pred.scores), pred.scores, -np.inf)
    return {**score_groups(pred.uv, scores, gt, vis, pred.names),
            'cpu_ms': ms_stats(pred.cpu_ms)}


def format_table(rows: dict[str, dict[str, dict[str, float]]], frames: int) -> str:
    """The rows as text: one block per metric (those some row has), groups as columns; '-'
    where a row has no value, 'inf' for a median that more than half the joints miss."""
    groups = [g for g in JOINT_GROUPS if any(g in r['pck'] for r in rows.values())]
    cols = groups + ['average', 'average7']
    width = max(14, *(len(name) + 2 for name in rows))
    lines = [f'{frames} frames']
    for key, title in TABLE_METRICS:
        if not any(key in row for row in rows.values()):
            continue
        shown = [c for c in cols if any(c in row.get(key, {}) for row in rows.values())]
        lines += ['', title, ' ' * width + ''.join(f'{c:>10}' for c in shown)]
        for name, row in rows.items():
            vals = row.get(key, {})
            lines.append(f'{name:<{width}}' + ''.join(
                f'{vals[c]:>10.1f}' if c in vals and not np.isnan(vals[c]) else f'{"-":>10}'
                for c in shown))
    if any('cpu_ms' in row for row in rows.values()):
        lines += ['', 'CPU per frame (ms)', ' ' * width + f'{"p50":>10}{"p95":>10}']
        lines += [f'{name:<{width}}' + ''.join(
            f'{row["cpu_ms"][k]:>10.1f}' if row['cpu_ms'][k] is not None else f'{"-":>10}'
            for k in ('p50', 'p95')) for name, row in rows.items() if 'cpu_ms' in row]
    return '\n'.join(lines)


def _clean(table: dict[str, dict[str, float]]) -> dict[str, dict[str, float | None]]:
    """The row in the JSON's order (`TABLE_METRICS`, then cpu_ms), NaN and infinity as null."""
    order = [k for k, _ in TABLE_METRICS] + [k for k in table if k not in dict(TABLE_METRICS)]
    return {k: {g: (round(float(v), 3) if v is not None and np.isfinite(v) else None)
                for g, v in table[k].items()} for k in order if k in table}


def default_models(kind: str) -> list[str]:
    return ['lspet_rgb_14'] if kind == 'lspet' else ['rgbd_10', 'rgb_10']


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'eval', help="run the core over a labelled set and print the paper's table",
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('source', metavar='SOURCE', help='CAD-60 directory or LSPET root')
    p.add_argument('--json', required=True, type=Path, help='write the table here (JSON)')
    p.add_argument('--model', action='append', default=None,
                   help='model (.npz or shipped name); repeat for several rows; default: '
                        'rgbd_10 + rgb_10 (CAD-60), lspet_rgb_14 (LSPET)')
    p.add_argument('--range', dest='frame_range', metavar='A-B',
                   help='LSPET image numbers (inclusive), e.g. 2501-3000')
    p.add_argument('--stride', type=int, default=1, help='every n-th frame of a CAD-60 video')
    p.add_argument('--max-frames', type=int, default=None)
    p.add_argument('--levels', type=int, default=SearchConfig.n_levels,
                   help='pyramid levels searched around the depth-predicted scale (1-3)')
    p.add_argument('--blas-threads', type=int, default=1)
    p.add_argument('--peer', choices=PEERS,
                   help='one more row: the peer on the same frames (needs `make peer`)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pose4d_ros.core.foreground  # noqa: F401  (loads scipy and its BLAS before the set)

    set_blas_threads(args.blas_threads)
    kind = source_kind(args.source)
    models = [load_model(model_path(m)) for m in (args.model or default_models(kind))]
    # the peer first: without its venv, stop before any work
    peer = MediaPipePeer() if args.peer else None
    try:
        rows, frames = table_rows(args, kind, models, peer)
    finally:
        if peer is not None:
            peer.close()
    print(format_table(rows, frames))
    out = {'frames': frames, 'rows': {k: _clean(v) for k, v in rows.items()}}
    if peer is not None:
        out['peer'] = peer.description
    write_json(args.json, out)
    return 0


def table_rows(args: argparse.Namespace, kind: str, models: list[PartModel],
               peer: MediaPipePeer | None) -> tuple[dict[str, dict], int]:
    """Every model's rows and the peer's ({row name: table}), and the number of frames."""
    samples = load_samples([args.source], frame_range=args.frame_range, stride=args.stride,
                           max_frames=args.max_frames, seed=0)
    has_depth = any(s.depth_m is not None for s in samples)
    rows: dict[str, dict[str, dict[str, float]]] = {}
    for m in models:
        use_depth = m.channels == 'rgbd'
        if use_depth and not has_depth:
            raise ValueError(f'{args.source}: no depth images for the rgbd model')
        name = m.channels
        while name in rows:
            name += "'"
        search = SearchConfig(n_levels=args.levels)
        if use_depth and kind in ('cad60', 'bag') and args.max_frames is None:
            # the graph's own stages, frame after frame: rgbd, + Kalman filter, + IK
            res = with_bar(name, partial(evaluate_source, args.source, model=m,
                                         stride=args.stride, search=search))
            for row, table in res['rows'].items():
                rows[name + row[len('rgbd'):]] = table
            continue
        rows[name] = score_variant(
            detector_variant(name, m, use_depth=use_depth, search=search), samples)
    if peer is not None:
        if kind in ('cad60', 'bag') and args.max_frames is None:
            # the frames and video boundaries the pipeline rows saw
            rows.update(with_bar(peer.name, partial(evaluate_peer, args.source, peer,
                                                    stride=args.stride))['rows'])
        else:
            rows[peer.name] = score_variant(peer_variant(peer), samples)
    return rows, len(samples)


def with_bar(name: str, evaluate: Callable[..., dict]) -> dict:
    """`evaluate(progress=...)` with a progress bar counting its frames."""
    bar = progress(None, name)
    try:
        return evaluate(progress=lambda n: bar.update(n - bar.n))
    finally:
        bar.close()


def score_variant(variant: Variant, samples: Sequence[Sample]) -> dict[str, dict[str, float]]:
    """Run a variant over the frames and score it, saying in how many it found no pose."""
    pred = run_variant(variant, samples)
    if not pred.found.all():
        log(f'{variant.name}: no pose in {int((~pred.found).sum())} of {len(samples)} frames')
    return score(pred, samples)
