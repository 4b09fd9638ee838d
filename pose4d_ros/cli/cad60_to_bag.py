"""`pose4d cad60-to-bag DIR OUT`: a CAD-60 directory (real or synthetic) -> rosbag2."""

from __future__ import annotations

import argparse
from pathlib import Path

from pose4d_ros.datasets import cad60_bag
from pose4d_ros.util.progress import progress


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'cad60-to-bag', help='convert a CAD-60 directory to a rosbag2',
        description='Convert a CAD-60 directory (dataN/ person dirs, real or synthetic) to a '
        'rosbag2 with camera/color/image_raw (rgb8), camera/depth/image_raw (16UC1), '
        'camera/color/camera_info and the ground truth on cad60/skeleton (JointArray), plus '
        'cad60/mask for synthetic sets and cad60/skeletons (SkeletonArray, every person, '
        'track_id = person) for several-person sets (pose4d synth --people N).')
    p.add_argument('dir', type=Path, help='CAD-60 directory (a dataN/ or a folder of them)')
    p.add_argument('out', type=Path, help='new bag directory (must not exist)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    p.add_argument('--no-compress', action='store_true', help='no zstd chunk compression')
    p.add_argument('--projection', choices=('perspective', 'affine'), default='perspective',
                   help='projection of the ground-truth joints to pixels')
    p.add_argument('--videos', help='comma-separated video ids (default: all)')
    p.add_argument('--max-frames', type=int, help='at most this many frames per video')
    p.add_argument('--t0', type=float, default=1_700_000_000.0,
                   help='stamp of the first frame, seconds since the epoch')
    p.add_argument('--frame-id', default=cad60_bag.FRAME_ID)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f'--max-frames must be >= 1, got {args.max_frames}')
    with progress(desc='cad60-to-bag') as bar:
        result = cad60_bag.convert(
            args.dir, args.out, storage=args.storage, compress=not args.no_compress,
            projection=args.projection, t0_s=args.t0,
            videos=args.videos.split(',') if args.videos else None,
            max_frames=args.max_frames, frame_id=args.frame_id,
            progress=lambda n: bar.update(n - bar.n))
    size = sum(f.stat().st_size for f in result.path.iterdir())
    print(f'wrote {result.path}: {result.frames} frames of {result.videos} video(s), '
          f'{result.duration_s:.2f} s, {size / 1e6:.1f} MB '
          f'({size / 1e6 / max(result.duration_s, 1e-9):.2f} MB per second of video); '
          + ', '.join(f'{t} {n}' for t, n in result.counts.items()))
    return 0
