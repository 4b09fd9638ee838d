"""`pose4d track-eval`: the tracker (SLQE) and the IK on real Kinect motion (UTKinect).

Tracking: the 10 parts of each take are projected to 320x240 (CAD-60 intrinsics) and corrupted
like a detector (seeded: 3 px noise, 10 % outliers 20-60 px away, 5 % dropouts); the corrupted
input, a plain constant-velocity Kalman filter, the same filter with the innovation gate and
SLQE are scored by mean pixel error against the clean projection, on the training subjects and
on the test subjects separately. IK: elbows and knees are hidden and inferred from the 3-D
shoulders, hips, wrists and ankles, with the joint-limit prior alone and with depth support
(capsules ray-cast on the real skeleton; the synthetic body renderer), scored in mm.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import TextIO

from pose4d_ros import __version__
from pose4d_ros.core.files import write_json
from pose4d_ros.evaluation import ik, tracking


def _subjects(spec: str) -> tuple[int, ...]:
    """'1-6' or '7,8' -> subject numbers."""
    out: list[int] = []
    for item in spec.split(','):
        item = item.strip().lower().replace('s', '')
        if '-' in item:
            lo, _, hi = item.partition('-')
            out.extend(range(int(lo), int(hi) + 1))
        elif item:
            out.append(int(item))
    if not out:
        raise ValueError(f'no subjects in {spec!r}')
    return tuple(out)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'track-eval', help='evaluate the SLQE tracker and the IK on real UTKinect motion',
        description=__doc__.split('\n\n')[1].replace('\n', ' '),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('utkinect', type=Path, help='UTKinect directory (joints_sNN_eMM.txt)')
    p.add_argument('--json', type=Path, required=True, help='where to write the results')
    p.add_argument('--seed', type=int, default=0, help='corruption and depth-noise seed')
    p.add_argument('--train', default='1-6', help='training subjects (tuning, reported apart)')
    p.add_argument('--test', default='7-8', help='test subjects (never tuned on)')
    p.add_argument('--tune', action='store_true',
                   help='tune Q, R, gate, coupling (and the IK prior and depth cost) on the '
                        'training subjects first, instead of using the shipped defaults')
    p.add_argument('--ik-stride', type=int, default=3,
                   help='every N-th frame for the IK with the prior alone')
    p.add_argument('--depth-stride', type=int, default=15,
                   help='every N-th frame for the IK with depth (rendering is slow)')
    p.add_argument('--no-ik', action='store_true', help='tracking only')
    p.add_argument('--ik-method', choices=('geometric', 'dh', 'both'), default='both',
                   help="IK solver(s): the law-of-cosines circle, the paper's DH chains "
                        "(rows 'dh: ...'), or both on the same frames")
    p.add_argument('--msraction3d', type=Path, default=None,
                   help='MSR Action3D directory: the IK also on its sequences, same training '
                        "and test subjects (tables 'msr_train', 'msr_test')")
    p.add_argument('--no-tracking', action='store_true', help='IK only')
    p.add_argument('--no-ablations', action='store_true',
                   help='skip SLQE without coupling and SLQE with a constant-velocity state')
    p.add_argument('--no-render', action='store_true',
                   help='skip the synthetic-body renderer variant of the IK')
    p.add_argument('--quiet', action='store_true', help='no progress messages')
    p.set_defaults(func=run)


def _jsonable(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if hasattr(value, 'tolist'):
        return value.tolist()  # type: ignore[union-attr]
    return str(value)


def _print_tracking(title: str, res: dict, out: TextIO | None = None) -> None:
    # out None: print's own default, the sys.stdout of the moment (a default of sys.stdout
    # would be the one of the import: closed by now when that was a test's capture)
    groups = [g for g in next(iter(res.values())) if g not in ('average', 'coverage')]
    print(f'\n{title}', file=out)
    print(f"  {'method':<17}" + ''.join(f'{g:>9}' for g in groups) +
          f"{'average':>9}{'coverage':>9}{'vs input':>9}", file=out)
    base = res['input']['average']
    for method, table in res.items():
        red = 1.0 - table['average'] / base
        print(f'  {method:<17}' + ''.join(f'{table[g]:9.2f}' for g in groups) +
              f"{table['average']:9.2f}{table['coverage']:9.3f}{100 * red:8.1f}%", file=out)


def _print_ik(title: str, rows: dict, out: TextIO | None = None) -> None:
    print(f'\n{title}', file=out)
    print(f"  {'variant':<34}{'elbow':>8}{'knee':>8}{'average':>9}{'joints':>8}  flags",
          file=out)
    for name, t in rows.items():
        flags = ', '.join(f'{k} {v}' for k, v in t['flags'].items() if v)
        print(f"  {name:<34}{t['elbow']:8.1f}{t['knee']:8.1f}{t['average']:9.1f}"
              f"{t['n']:8d}  {flags}", file=out)


def run(args: argparse.Namespace) -> int:
    if args.ik_stride < 1 or args.depth_stride < 1:
        raise ValueError(f'--ik-stride ({args.ik_stride}) and --depth-stride '
                         f'({args.depth_stride}) must be >= 1')
    say = (lambda msg: None) if args.quiet else \
        (lambda msg: print(f'[track-eval] {msg}', file=sys.stderr, flush=True))
    train_s, test_s = _subjects(args.train), _subjects(args.test)
    if set(train_s) & set(test_s):
        raise ValueError(f'training {train_s} and test {test_s} subjects overlap')
    t0 = time.perf_counter()
    train = tracking.load_segments(args.utkinect, train_s)
    test = tracking.load_segments(args.utkinect, test_s)
    if not train or not test:
        raise ValueError(f'{args.utkinect}: no takes for training subjects {train_s} '
                         f'({len(train)} segments) or test subjects {test_s} '
                         f'({len(test)} segments)')
    say(f'{len(train)} training segments ({sum(len(s.times) for s in train)} frames), '
        f'{len(test)} test segments ({sum(len(s.times) for s in test)} frames)')

    report: dict = {'version': __version__, 'seed': args.seed, 'utkinect': str(args.utkinect),
                    'train_subjects': train_s, 'test_subjects': test_s,
                    'corruption': tracking.config_dict(tracking.Corruption())}
    report.update(tracking={}, tracking_targets={})
    if not args.no_tracking:
        native = tracking.load_segments(args.utkinect, test_s, native=True)
        report.update(tracking.tracking_report(
            train, test, native, seed=args.seed, tune=args.tune,
            ablations=not args.no_ablations, progress=say))
        for name, res in report['tracking'].items():
            _print_tracking(f'Tracking, {name}: mean pixel error on the detected part-frames',
                            res['detected_frames'])
            _print_tracking(f'Tracking, {name}: mean pixel error on all part-frames',
                            res['all_frames'])
    if not args.no_ik:
        sets = {'train': train, 'test': test}
        if args.msraction3d is not None:
            sets['msr_train'] = tracking.load_msr_segments(args.msraction3d, train_s)
            sets['msr_test'] = tracking.load_msr_segments(args.msraction3d, test_s)
            say(f"MSR Action3D: {len(sets['msr_train'])} training and "
                f"{len(sets['msr_test'])} test segments")
        methods = ik.IK_METHODS if args.ik_method == 'both' else (args.ik_method,)
        report['ik'] = ik.ik_tables(sets, methods=methods, tune=args.tune, seed=args.seed,
                                    stride=args.ik_stride, depth_stride=args.depth_stride,
                                    render=not args.no_render, progress=say)
        for name in sets:
            _print_ik(f'IK, {name} subjects: mean 3-D error of the inferred joints, mm',
                      report['ik'][name])
    report['seconds'] = time.perf_counter() - t0
    write_json(args.json, report, indent=1, default=_jsonable)
    say(f'wrote {args.json} ({report["seconds"]:.0f} s)')
    return 0
