"""`pose4d bench`: time per perception stage (foreground, detector) on real frames.

    pose4d bench SOURCE --json FILE [--model rgbd_10] [--frames N] [--warmup W]

Each frame goes through the stages as the live pipeline runs them: the foreground stage's
MSER mask on the depth image (`core.foreground.segment`), then the part detector on the frame,
its mask and depth (`core.dpm.infer.Detector.detect`). The p50 and p95 of each stage's wall time
are taken over the frames after `--warmup` (numba compilation and caches). The machine (cores,
CPU) and the thread settings are printed, because on a 2-core machine they decide the numbers:
BLAS is set to `--blas-threads` (1 by default, the measured best; see `core.dpm.threads`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pose4d_ros.cli._dpm import load_samples, machine, progress
from pose4d_ros.cli.eval import default_models, resolve_model, write_json
from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.dpm.infer import Detector, SearchConfig
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.dpm.threads import set_blas_threads
from pose4d_ros.datasets.sources import source_kind


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'bench', help='time per perception stage (p50, p95)',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('source', metavar='SOURCE', help='CAD-60 directory (or LSPET root)')
    p.add_argument('--json', required=True, type=Path, help='write the timings here (JSON)')
    p.add_argument('--model', default=None,
                   help='model (.npz or shipped name); default rgbd_10 (lspet_rgb_14 on LSPET)')
    p.add_argument('--range', dest='frame_range', metavar='A-B', help='LSPET image numbers')
    p.add_argument('--frames', type=int, default=200, help='frames timed (spread over the set)')
    p.add_argument('--warmup', type=int, default=10, help='frames run before timing')
    p.add_argument('--levels', type=int, default=SearchConfig.n_levels,
                   help='pyramid levels searched around the depth-predicted scale (1-3)')
    p.add_argument('--blas-threads', type=int, default=1, help='OpenBLAS threads')
    p.set_defaults(func=run)


def _stats(ms: list[float]) -> dict[str, float | None]:
    if not ms:
        return {'p50': None, 'p95': None}
    a = np.asarray(ms)
    return {'p50': round(float(np.percentile(a, 50)), 3),
            'p95': round(float(np.percentile(a, 95)), 3)}


def run(args: argparse.Namespace) -> int:
    if args.frames < 1 or args.warmup < 0:
        raise ValueError(f'--frames must be >= 1 and --warmup >= 0, got {args.frames}, '
                         f'{args.warmup}')
    from pose4d_ros.core.foreground import segment  # loads scipy (and its BLAS) first

    threads = set_blas_threads(args.blas_threads)
    kind = source_kind(args.source)
    model = load_model(resolve_model(args.model or default_models(kind)[0]))
    samples = load_samples([args.source], frame_range=args.frame_range, stride=1,
                           max_frames=args.frames + args.warmup, seed=0)
    use_depth = model.channels == 'rgbd'
    if use_depth and all(s.depth_m is None for s in samples):
        raise ValueError(f'{args.source}: no depth images for the rgbd model')
    det = Detector(model, SearchConfig(n_levels=args.levels))
    fg_ms: list[float] = []
    det_ms: list[float] = []
    for i, s in enumerate(progress(samples, 'bench')):
        mask = None
        intr = None
        t0 = time.perf_counter()
        if s.depth_m is not None and use_depth:
            h, w = s.depth_m.shape
            intr = s.intrinsics or cad60_intrinsics(w, h)
            fg = segment(s.depth_m, intr)
            mask = fg.mask if fg.found else None
        t1 = time.perf_counter()
        det.detect(s.color, s.depth_m if use_depth else None, mask=mask, intrinsics=intr)
        t2 = time.perf_counter()
        if i >= args.warmup:
            if use_depth:
                fg_ms.append((t1 - t0) * 1e3)
            det_ms.append((t2 - t1) * 1e3)
    m = machine()
    h, w = samples[0].color.shape[:2]
    print(f"machine: {m['cores']} cores, {m['cpu']}, load average {m['load_average']}")
    print(f"threads: numba {m['numba_threads']} (no parallel kernels), BLAS {m['blas_threads']}"
          f" (set to {args.blas_threads}: {', '.join(f'{v}' for v in threads.values())})")
    print(f'model: {model.channels}, {model.n_parts} parts x {model.n_types} types; '
          f'{len(det_ms)} frames of {w}x{h} after {args.warmup} warm-up')
    out = {'stages_ms': {'foreground': _stats(fg_ms), 'detector': _stats(det_ms)}}
    for stage, st in out['stages_ms'].items():
        if st['p50'] is None:
            print(f'{stage:<12} -')
        else:
            print(f"{stage:<12} p50 {st['p50']:8.2f} ms   p95 {st['p95']:8.2f} ms")
    write_json(args.json, out)
    return 0
