"""`pose4d synth`: render synthetic RGB-D people in CAD-60's on-disk format.

People are posed by real Kinect motion (UTKinect takes and/or MSR Action3D sequences), each
video a window of a take on a new random body in a new random room (see
`pose4d_ros.synth.video`). Output: one `dataN/` per subject N (UTKinect's and MSR Action3D's
subjects share the numbers: data7 holds both sources' subject 7), each with `activityLabel.txt`
and its videos (`<id>.txt`, `<id>/RGB_<k>.png`, `<id>/Depth_<k>.png`, plus `<id>/Mask_<k>.png`,
the person mask), and a `synth.json` at the top recording the command's parameters and every
video's source. The set is built in a temporary directory next to `--out` and renamed when
complete, so a failed or interrupted run leaves nothing behind.

With `--people N` (2-3) every video shows N people (`pose4d_ros.synth.people`): person 1 is the
video's own window of motion, written as in a one-person set (`<id>.txt`); persons k = 2..N,
each another UTKinect take (or another window of one) on another body, standing 1-4 m apart
laterally at different distances, are written to `<id>_p<k>.txt` in the same line format, with
all confidences 0 in the frames where that person is not seen (fewer than 40 pixels of it at
320x240: out of the picture or hidden; person 1's too); `Mask_<k>.png` holds every person's
pixels and `People_<k>.png` (8-bit) numbers them (k = person k, 0 = nobody). `--crossing` sets
the share of videos in which one person walks past in front of another (hidden for up to about a
second). The reader (`pose4d_ros.datasets.cad60`) gives every person's ground truth in
`Frame.people`.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from pose4d_ros import __version__
from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.files import replace_dir
from pose4d_ros.synth.takes import plan_actions


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'synth', help='render synthetic RGB-D people in CAD-60 format',
        description=' '.join(__doc__.split('\n\n')[i].replace('\n', ' ') for i in (1, 2)),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('--utkinect', type=Path, default=None,
                   help='UTKinect directory (joints_sNN_eMM.txt, actionLabel.txt)')
    p.add_argument('--msraction3d', type=Path, default=None,
                   help='MSR Action3D directory (aAA_sSS_eEE_skeleton3D.txt): instead of or '
                        'besides --utkinect (at least one); its empty and broken sequences are '
                        'skipped (listed in synth.json)')
    p.add_argument('--out', required=True, type=Path, help='output directory (must not exist)')
    p.add_argument('--seed', type=int, default=0, help='random seed (bodies, rooms, noise)')
    p.add_argument('--takes', default='all',
                   help="takes: 'all' or a comma list of s01_e01 (MSR Action3D: take 1 of "
                        "every action), s02 (all takes), s01-s06, a05_s07_e02 (MSR Action3D)")
    p.add_argument('--frames', type=int, default=60, help='frames per video (at most)')
    p.add_argument('--stride', type=int, default=1,
                   help='keep every N-th frame of the 30 fps motion (frame numbers keep 30 fps)')
    p.add_argument('--start', type=float, default=0.0,
                   help='seconds into each take where the first window starts')
    p.add_argument('--videos-per-take', type=int, default=1,
                   help='windows per take, spread evenly from --start to the end')
    p.add_argument('--actions', default=None,
                   help='comma list of UTKinect actions (waveHands, sitDown, ...): the windows '
                        'of each take are spread over each of these actions instead; and of MSR '
                        'Action3D actions (a01-a20 or names: highArmWave, ..., pickUpThrow): '
                        'only those sequences are used')
    p.add_argument('--body-per', choices=('video', 'subject'), default='video',
                   help='a new random body for every video, or one per UTKinect subject')
    # defaults: `synth.video.Staging` (imported in `run`, to keep `pose4d --help` fast)
    p.add_argument('--stature', type=float, nargs=2, metavar=('LO', 'HI'), default=None,
                   help="bodies' standing heights, metres, drawn uniformly (default: 1.52 1.95)")
    p.add_argument('--distance', type=float, nargs=2, metavar=('LO', 'HI'), default=None,
                   help="the person's distance from the camera, metres, drawn uniformly "
                        '(default: 2.4 3.4)')
    p.add_argument('--turn', type=float, nargs=2, metavar=('LO', 'HI'), default=None,
                   help='turn of the motion about the vertical, degrees, drawn uniformly: 0 '
                        'faces the camera, 90 shows the right side (default: -25 25)')
    p.add_argument('--camera-height', type=float, nargs=2, metavar=('LO', 'HI'), default=None,
                   help='the camera mounted above the heads: its height above the floor, '
                        'metres, drawn uniformly (with --camera-pitch; default: 0.85-1.35 m, '
                        'aimed at the person\'s middle)')
    p.add_argument('--camera-pitch', type=float, nargs=2, metavar=('LO', 'HI'), default=None,
                   help='the mounted camera\'s pitch down, degrees, drawn uniformly (with '
                        '--camera-height)')
    p.add_argument('--arm-jitter', type=float, default=0.0, metavar='DEG',
                   help='pose the arms away from the recorded motion by up to DEG degrees (at '
                        'the shoulder and the elbow, varying smoothly through each video): arm '
                        'poses the subjects never made, for training data')
    p.add_argument('--people', type=int, default=1, metavar='N',
                   help='people in every video, 1-3: person 1 in <id>.txt as in a one-person '
                        'set, persons k = 2..N in <id>_p<k>.txt (same line format; confidences '
                        '0 in frames where the person is out of view or hidden), each from '
                        'another take (or window) on another body, 1-4 m apart laterally, at '
                        'different distances (default --distance 2.5 4.0 for N > 1); with '
                        '--body-per subject only person 1 keeps the subject\'s body')
    p.add_argument('--alone', type=int, default=None, metavar='K',
                   help='with --people N: the same videos (the same room, placement and motion) '
                   'with person K (1..N) alone in them, as a one-person set: the baseline a '
                   'several-person set is compared with')
    p.add_argument('--crossing', type=float, default=None, metavar='FRACTION',
                   help='share of the videos (N > 1) in which one person walks past in front '
                        'of another, hiding it for up to about a second (default: 0.34 for '
                        'N > 1)')
    p.add_argument('--occluders', type=float, default=0.3,
                   help='probability of furniture between camera and person')
    p.add_argument('--width', type=int, default=320, help='image width (CAD-60: 320)')
    p.add_argument('--height', type=int, default=240, help='image height (CAD-60: 240)')
    p.add_argument('--no-noise', action='store_true',
                   help='exact depth and clean colour (no Kinect model)')
    p.add_argument('--force', action='store_true', help='replace --out if it exists')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    p.set_defaults(func=run)


def _check(args: argparse.Namespace) -> None:
    if args.utkinect is None and args.msraction3d is None:
        raise ValueError('give --utkinect DIR, --msraction3d DIR or both')
    for name in ('utkinect', 'msraction3d'):
        path = getattr(args, name)
        if path is not None and not path.is_dir():
            raise ValueError(f'--{name} {path}: not a directory')
    for name in ('frames', 'stride', 'videos_per_take', 'width', 'height'):
        if getattr(args, name) < 1:
            raise ValueError(f'--{name.replace("_", "-")} must be >= 1, got '
                             f'{getattr(args, name)}')
    if args.videos_per_take > 100:
        raise ValueError(f'--videos-per-take must be <= 100, got {args.videos_per_take}')
    if not 0.0 <= args.occluders <= 1.0:
        raise ValueError(f'--occluders must be in [0, 1], got {args.occluders}')
    if args.start < 0:
        raise ValueError(f'--start must be >= 0 seconds, got {args.start}')
    if not 1 <= args.people <= 3:
        raise ValueError(f'--people must be 1, 2 or 3, got {args.people}')
    if args.alone is not None and not 1 <= args.alone <= args.people or \
            args.alone is not None and args.people == 1:
        raise ValueError(f'--alone {args.alone}: needs --people N (2-3) and 1 <= K <= N')
    if args.crossing is not None:
        if args.people == 1:
            raise ValueError('--crossing needs --people 2 or 3 (one person crosses no one)')
        if not 0.0 <= args.crossing <= 1.0:
            raise ValueError(f'--crossing must be a fraction in [0, 1], got {args.crossing}')
    if args.seed < 0:
        raise ValueError(f'--seed must be >= 0, got {args.seed}')
    if args.out.exists() and not args.force:
        raise ValueError(f'--out {args.out}: already exists (use --force to replace it)')
    if not args.out.parent.is_dir():
        raise ValueError(f'--out {args.out}: parent directory does not exist')


def run(args: argparse.Namespace) -> int:
    from pose4d_ros.datasets import cad60
    from pose4d_ros.synth import people, video
    from pose4d_ros.util.progress import progress

    _check(args)
    several = args.people > 1
    staging = _staging(args)
    intrinsics = cad60_intrinsics(args.width, args.height)
    motions, names, skipped = video.load_motions(args.utkinect, args.msraction3d,
                                                 args.takes, args.actions)
    plans = [plan for m in motions for plan in video.plan_videos(
        m, seed=args.seed, videos=args.videos_per_take, frames=args.frames, stride=args.stride,
        start_s=args.start, actions=plan_actions(args.actions))]
    if not plans:
        raise ValueError(f'--actions {args.actions}: none of the takes has any of them')
    total = sum(p.n_frames for p in plans)
    crossing = 0.34 if args.crossing is None else args.crossing
    crossings = people.crossing_videos(plans, crossing) if several else [False] * len(plans)
    out = args.out.resolve()
    tmp = Path(tempfile.mkdtemp(prefix=f'.{out.name}.', suffix='.partial', dir=out.parent))
    t0 = time.perf_counter()
    n_bytes = 0
    try:
        labels: dict[int, dict[str, str]] = {}
        bodies: dict = {}
        records = []
        with progress(desc='pose4d synth', total=total, disable=args.quiet) as bar:
            for plan, crosses in zip(plans, crossings, strict=True):
                job = _job(args, plan, crosses, motions, intrinsics, staging, bodies)
                person_dir = tmp / f'data{plan.subject}'
                person_dir.mkdir(exist_ok=True)
                n_bytes += video.write_video(job, person_dir, progress=bar.update)
                labels.setdefault(plan.subject, {})[plan.video_id] = plan.activity
                records.append(video.video_record(job, person_dir))
        for subject, videos in labels.items():
            cad60.write_activity_labels(tmp / f'data{subject}' / 'activityLabel.txt', videos)
        info = _info(args, names, staging, records, skipped, crossing)
        (tmp / 'synth.json').write_text(json.dumps(info, indent=1) + '\n')
        replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    elapsed = time.perf_counter() - t0
    print(f'pose4d synth: {len(plans)} videos, {total} frames, {n_bytes / 1e6:.1f} MB '
          f'({n_bytes / max(total, 1) / 1e3:.1f} kB/frame) in {elapsed:.1f} s '
          f'({total / elapsed:.1f} frames/s incl. PNG writing) -> {out}')
    return 0


def _staging(args: argparse.Namespace):
    from pose4d_ros.synth import people, video

    default = video.Staging()
    return video.Staging(
        stature_m=tuple(args.stature or default.stature_m),
        distance_m=tuple(args.distance or (people.PEOPLE_DISTANCE_M if args.people > 1
                                           else default.distance_m)),
        turn_deg=tuple(args.turn or default.turn_deg), arm_jitter_deg=args.arm_jitter,
        camera_height_m=None if args.camera_height is None else tuple(args.camera_height),
        camera_pitch_deg=None if args.camera_pitch is None else tuple(args.camera_pitch))


def _job(args: argparse.Namespace, plan, crosses: bool, motions: list, intrinsics, staging,
         bodies: dict):
    """A planned video, prepared to render (its body the subject's with --body-per subject)."""
    from pose4d_ros.synth import people, video

    body = None
    if args.body_per == 'subject':
        if plan.subject not in bodies:
            bodies[plan.subject] = video.subject_body(args.seed, plan.subject,
                                                      stature_m=staging.stature_m)
        body = bodies[plan.subject]
    if args.people == 1:
        motion = next(m for m in motions if m.name == plan.take)
        return video.prepare_video(plan, motion, intrinsics, body=body,
                                   occluder_prob=args.occluders,
                                   kinect_noise=not args.no_noise, staging=staging)
    job = people.prepare_people_video(
        plan, motions, intrinsics, people=args.people, crossing=crosses, body=body,
        occluder_prob=args.occluders, kinect_noise=not args.no_noise, staging=staging)
    return job if args.alone is None else video.alone(job, args.alone)


def _info(args: argparse.Namespace, names: list[str], staging, records: list[dict],
          skipped: list[str], crossing: float) -> dict:
    """synth.json: the command's parameters and every video's record."""
    info = {
        'generator': f'pose4d synth {__version__}',
        'command': ' '.join(sys.argv),
        'seed': args.seed, 'takes': names, 'frames': args.frames, 'stride': args.stride,
        'start_s': args.start, 'videos_per_take': args.videos_per_take,
        'actions': args.actions,
        'body_per': args.body_per, 'occluders': args.occluders,
        'stature_m': list(staging.stature_m), 'distance_m': list(staging.distance_m),
        'turn_deg': list(staging.turn_deg), 'arm_jitter_deg': staging.arm_jitter_deg,
        'size': [args.width, args.height], 'kinect_noise': not args.no_noise,
    }
    if args.msraction3d is not None:
        info.update({'utkinect': None if args.utkinect is None else str(args.utkinect),
                     'msraction3d': str(args.msraction3d), 'msraction3d_skipped': skipped})
    if staging.mount is not None:  # a set with the default camera's synth.json stays the same
        info.update({'camera_height_m': list(staging.camera_height_m),
                     'camera_pitch_deg': list(staging.camera_pitch_deg)})
    if args.people > 1:  # a one-person set's synth.json stays as it always was
        info.update({'people': args.people, 'crossing': crossing})
    return {**info, 'videos': records}
