"""`pose4d eval`: run the perception core over a labelled set and print the paper's table.

    pose4d eval SOURCE --json FILE [--model M ...] [--range A-B] [--peer mediapipe
                [--peer-depth OFFSETS.json | --fit-peer-depth OFFSETS.json]]
                [--margin M] [--birth-score S] [--plot FILE.png] [--draw DIR]

SOURCE is a CAD-60 directory (real or synthetic), a rosbag2 with ground truth (`pose4d
cad60-to-bag`) or an LSPET root (with --range). Every row runs the live pipeline's own stages
(`core.pipeline.FramePipeline`, what the nodes run) over every frame
(`evaluation.pipeline`):

- `rgbd`, `rgbd_t`, `rgbd_kf`, `rgbd_kf_ik`, the paper's ablation: the foreground stage
  (`core.foreground`) masks the person on the depth image and the RGB-D part model searches the
  levels that the person's depth gives inside the mask's box, each frame on its own (`rgbd`:
  the 4D-DPM alone, no state from earlier frames); then frame after frame, each video a new
  track, as the nodes run it: the detector with its temporal aids (`rgbd_t`: the previous
  frame's arms, the track's person scale), the SLQE Kalman filter (`rgbd_kf`), inverse
  kinematics for elbows and knees (`rgbd_kf_ik`, which scores them too). `--no-single-frame`
  skips the `rgbd` pass. With --max-frames (a subset, no longer a sequence) each frame is on
  its own and only `rgbd` is given.
- `rgb`: the Yang & Ramanan baseline: the RGB-only part model over the whole colour image and
  the whole trained scale range, no depth at all.

- `mediapipe` (`--peer mediapipe`): MediaPipe Pose 0.10.21 (`pose4d_ros.peer`, installed by
  `make peer`) on the same frames, its joints lifted to 3-D by the detector's depth look-up; in
  video mode, a new video where the tracker starts a new track (each photo or subset frame on
  its own). `--peer-depth OFFSETS.json` adds `mediapipe_fit`: the same joints moved along
  their rays by a per-joint depth offset fitted on training renders, as our detector's parts
  are (`evaluation.peer_depth`); `--fit-peer-depth OFFSETS.json` fits those offsets on SOURCE
  (labelled training renders) and runs the peer alone.

- `rgb` on LSPET: the photograph network (`core.convnet`, `lspet_convnet`): each joint's heat
  map over the photograph, read at `--photo-scales`, no part model (`--model lspet_rgb_14` gives
  the HOG mixture of parts). An RGB-D model (`--model rgbd_14`, what the nodes run) on
  photographs gives one row named after it: its colour channel alone
  (`core.dpm.model.colour_channel`: the depth half of every filter dropped, the search without
  depth over its training people's scales), the real-appearance test of the nodes' detector.
- `--colour-net NETWORK` (default `lspet_convnet`, as the detector node runs; `none`: off):
  every part model's colour unary also takes the photograph network's heat maps
  (`core.dpm.net_unary`, the detector node's `detector.colour_net`), weighted by `--config
  unary.weight=W` and `unary.hog_weight=H`; an RGB-D model's row on photographs is then
  `<model>+<network>`. `--net-precision` (default int8, as the node) runs the networks'
  8-bit twins (`pose4d quantize-convnet`) or their float graphs.

Default models: the shipped `rgbd_14` (what the nodes run) and `rgb_10` for a CAD-60 set,
`lspet_convnet` for LSPET; `--model` (repeatable) replaces them (`--model rgbd_10` gives the
paper's 10-part rows), each model giving the rows of its channels. Every row
records its CPU time per frame (`cpu_ms`: p50, p95; see `evaluation.pipeline`). `--draw DIR`
writes every frame with each row's skeleton and the ground truth, and each row's worst and best
frames as one grid (`evaluation.draw`).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, replace
from pathlib import Path

import cv2

from pose4d_ros.cli._args import factor_list
from pose4d_ros.core.convnet import PHOTO_SCALES, PRECISIONS, ConvNet, valid_scales
from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.model import PartModel, colour_channel
from pose4d_ros.core.dpm.net_unary import NetUnary, UnaryConfig
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.files import write_atomic, write_json
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.core.registration import edge_shift, shift_image
from pose4d_ros.core.slqe import SlqeConfig
from pose4d_ros.core.threads import set_blas_threads
from pose4d_ros.datasets.sources import load_frames, source_kind
from pose4d_ros.evaluation import draw, overrides, plot, real, tables
from pose4d_ros.evaluation.peer_depth import (
    fit_depth_offsets,
    offset_row,
    read_offsets,
    write_offsets,
)
from pose4d_ros.evaluation.pipeline import (
    Row,
    convnet_rows,
    curve_rows,
    ms_stats,
    peer_rows,
    pipeline_rows,
    score_rows,
)
from pose4d_ros.evaluation.tables import clean_row, default_models, format_table, load_any
from pose4d_ros.models import DEFAULT_COLOUR_NET, DEFAULT_NET_PRECISION
from pose4d_ros.peer import PEERS, Peer, make_peer
from pose4d_ros.util.progress import log, progress


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'eval', help="run the core over a labelled set and print the paper's table",
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('source', metavar='SOURCE', help='CAD-60 directory or LSPET root')
    p.add_argument('--json', required=True, type=Path, help='write the table here (JSON)')
    p.add_argument('--model', action='append', default=None,
                   help='model (.npz or shipped name); repeat for several rows; default: '
                        'rgbd_14 + rgb_10 (CAD-60), lspet_convnet (LSPET)')
    p.add_argument('--range', dest='frame_range', metavar='A-B',
                   help='LSPET image numbers (inclusive), e.g. 2501-3000')
    p.add_argument('--stride', type=int, default=1, help='every n-th frame of a CAD-60 video')
    p.add_argument('--max-frames', type=int, default=None)
    p.add_argument('--levels', type=int, default=SearchConfig.n_levels,
                   help='pyramid levels searched around the depth-predicted scale (1-3)')
    p.add_argument('--person-scales', type=factor_list, default=ScaleConfig.factors,
                   metavar='F,F,...', help="factors on the depth-predicted person scale, one "
                   'chosen per track (core.dpm.scale); 1 = the predicted scale only')
    p.add_argument('--photo-scales', type=factor_list, default=PHOTO_SCALES, metavar='F,F,...',
                   help="the photograph network's reading scales (core.convnet: maps read at "
                        'each, averaged)')
    p.add_argument('--max-people', type=int, default=None, metavar='N',
                   help='run the several-person pipeline the nodes run, searching at most N '
                   'people a frame (default: on a set with several people, 4; else the '
                   "single-person pipeline of the paper)")
    p.add_argument('--margin', type=float, default=SearchConfig.margin,
                   help="the search box's margin around the foreground box, person scales")
    p.add_argument('--birth-score', type=float, default=TrackingConfig.birth_score,
                   help="several-person pipeline: a tentative track's least part model score "
                        'while another track is confirmed (core.people.TrackingConfig)')
    p.add_argument('--config', action='append', default=[], metavar='SECTION.KEY=VALUE',
                   help='set a field of the core configuration of a stage, repeatable: '
                        'foreground.person_min_cut_height_m=0.5, slqe.limb_parts=left_wrist,'
                        'right_wrist, scale.warm_up_frames=2 (sections: foreground, search, '
                        'scale, slqe, tracking, unary; evaluation.overrides)')
    p.add_argument('--colour-net', metavar='NETWORK', default=DEFAULT_COLOUR_NET,
                   help="the photograph network (shipped name or .npz) as a colour unary of "
                        "every part model's tree, as the detector node runs it (core.dpm."
                        "net_unary; its weights: --config unary.weight=W, unary.hog_weight=H); "
                        "'none': the part models' HOG filters alone")
    p.add_argument('--net-precision', choices=PRECISIONS, default=DEFAULT_NET_PRECISION,
                   help="the photograph networks' arithmetic (rows and --colour-net): int8 runs "
                        'their 8-bit twin (pose4d quantize-convnet)')
    p.add_argument('--no-single-frame', action='store_true',
                   help='skip the single-frame `rgbd` pass (the temporal rows only)')
    p.add_argument('--blas-threads', type=int, default=1)
    p.add_argument('--peer', choices=PEERS,
                   help='one more row: the peer on the same frames (needs `make peer`)')
    p.add_argument('--peer-depth', type=Path, metavar='OFFSETS.json',
                   help="with --peer: also the row `<peer>_fit`, the peer's 3-D joints moved "
                        'by these fitted depth offsets')
    p.add_argument('--fit-peer-depth', type=Path, metavar='OFFSETS.json',
                   help="with --peer: fit the peer's per-joint depth offsets on SOURCE "
                        '(training renders) and write them here; no model is run')
    p.add_argument('--labels', type=Path, metavar='LABELS.json',
                   help='a real recording (a folder of frames, or a bag without ground truth): '
                        "hand labels of every person's box (evaluation.real): people found "
                        'and ghosts')
    for name, what in (('color', 'colour image'), ('depth', 'depth image (registered to the '
                                                    'colour image)'), ('info', 'camera_info')):
        p.add_argument(f'--{name}-topic', metavar='TOPIC',
                       help=f"a camera's recording (rosbag2 or ROS 1 .bag): its {what} topic "
                            '(default: picked by message type and encoding)')
    p.add_argument('--hold', type=int, default=1, metavar='N',
                   help='a folder of separate frames: each held N frames at --fps (default 30), '
                        "a still camera's stream: what the tracker confirms over frames")
    p.add_argument('--fps', type=float, default=None,
                   help="a folder of frames: its frame rate (default: its frames.yaml's, else "
                        '30)')
    p.add_argument('--depth-shift', type=depth_shift, default=None, metavar='DX,DY',
                   help="move every frame's depth image by DX, DY pixels (x right, y down) onto "
                        'its colour image, for a camera whose depth is registered off (a real '
                        "recording's table gives the shift its edges suggest: registration)")
    p.add_argument('--plot', type=Path, metavar='FILE.png',
                   help='also draw PCK against the threshold (0 to 0.5) per joint group, one '
                        'curve per row, and the 3-D error distribution')
    p.add_argument('--draw', type=Path, metavar='DIR',
                   help="also write every frame with each row's skeleton and the ground truth "
                        "(DIR/<row>/), and each row's worst and best frames as a grid "
                        '(DIR/<row>_worst_best.jpg)')
    p.set_defaults(func=run)


def depth_shift(text: str) -> tuple[int, int]:
    """`--depth-shift DX,DY`: two whole numbers of pixels."""
    try:
        dx, dy = (int(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f'{text!r}: give two whole numbers of pixels, DX,DY (e.g. 10,2)') from None
    return dx, dy


def shifted(frames: list, shift: tuple[int, int] | None) -> list:
    """`frames` with their depth moved by `shift` (`--depth-shift`; None: as they are)."""
    if shift is None:
        return frames
    return [f if f.depth_m is None else replace(f, depth_m=shift_image(f.depth_m, *shift))
            for f in frames]


def run(args: argparse.Namespace) -> int:
    import pose4d_ros.core.foreground  # noqa: F401  (loads scipy and its BLAS before the set)

    set_blas_threads(args.blas_threads)
    kind = source_kind(args.source)
    if (args.peer_depth or args.fit_peer_depth) and not args.peer:
        raise ValueError('--peer-depth and --fit-peer-depth need --peer')
    offsets = read_offsets(args.peer_depth) if args.peer_depth else None
    real_recording = kind == 'frames' or args.labels is not None or _unlabelled_bag(args, kind)
    models = ({} if args.fit_peer_depth else
              {m: load_any(m, args.net_precision)
               for m in (args.model or default_models('frames' if real_recording else kind))})
    if not valid_scales(args.photo_scales):
        raise ValueError(f'--photo-scales {args.photo_scales}: must include 1 and lie within '
                         f'0.25..4')
    # the peer first: without its venv, stop before any work
    peer = make_peer(args.peer) if args.peer else None
    if args.plot is not None and args.plot.suffix.lower() != '.png':
        raise ValueError(f'--plot {args.plot}: the figure is a PNG file (.png)')
    try:
        if real_recording:
            result = real_rows(args, models, peer)
            print(format_real(result))
            if peer is not None:
                result['peer'] = peer.description
            write_json(args.json, result)
            return 0
        rows, frames, curves = table_rows(args, kind, models, peer, offsets)
    finally:
        if peer is not None:
            peer.close()
    print(format_table(rows, frames))
    out = {'frames': frames, 'rows': {k: clean_row(v) for k, v in rows.items()}}
    if peer is not None:
        out['peer'] = peer.description
    write_json(args.json, out)
    if args.plot is not None:
        figure = plot.draw(curves, f'{Path(args.source).name}: {frames} frames')
        ok, png = cv2.imencode('.png', figure, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if not ok:
            raise ValueError(f'could not encode the figure {figure.shape}')
        write_atomic(args.plot, png.tobytes())
        log(f'wrote {args.plot}')
    return 0


def table_rows(args: argparse.Namespace, kind: str, models: dict[str, PartModel | ConvNet],
               peer: Peer | None, offsets: dict[str, float] | None = None
               ) -> tuple[dict[str, dict], int, dict[str, dict]]:
    """Every model's rows and the peer's ({row name: table}), the number of frames, and the
    rows' accuracy curves (`evaluation.pipeline.curve_rows` at `evaluation.plot.ALPHAS`).
    `offsets`: the peer's fitted depth offsets (the `<peer>_fit` row); with
    `args.fit_peer_depth` the offsets are fitted on these frames and written there."""
    frames = shifted(load_frames([args.source], frame_range=args.frame_range,
                                 stride=args.stride, max_frames=args.max_frames),
                     args.depth_shift)
    sequence = kind in ('cad60', 'bag') and args.max_frames is None
    max_people = args.max_people
    if max_people is None and any(getattr(f, 'people', ()) for f in frames):
        max_people = TrackingConfig.max_people
    settings = overrides.parse(args.config)
    people = None if max_people is None else overrides.apply(TrackingConfig(
        max_people=max_people, birth_score=args.birth_score), settings, 'tracking')
    unary = colour_unary(args, settings)
    rows: dict[str, Row] = {}
    used: set[str] = set()
    for given, m in models.items():
        name = m.channels
        if m.channels == 'rgbd' and all(f.depth_m is None for f in frames):
            # photographs: the model's colour channel alone, its row named after the model
            # (and the network in its colour unary: rgbd_14+lspet_convnet)
            m, name = colour_channel(m), Path(given).stem
            if unary is not None:
                name += '+' + Path(args.colour_net).stem
        elif m.channels == 'rgbd' and any(f.depth_m is None for f in frames):
            raise ValueError(f'{args.source}: some frames have no depth image for the rgbd '
                             'model')
        while name in used:  # a second model of the same channels: rgbd', rgbd'_kf, ...
            name += "'"
        used.add(name)
        if isinstance(m, ConvNet):
            rows.update(convnet_rows(progress(frames, name), m, name=name,
                                     scales=args.photo_scales))
            continue
        rows.update(pipeline_rows(frames, m, name=name, sequence=sequence, show=progress,
                                  single_frame=not args.no_single_frame, people=people,
                                  **stage_configs(args, settings, unary)))
    if peer is not None:
        rows.update(peer_rows(progress(frames, peer.name), peer, sequence=sequence))
        if args.fit_peer_depth is not None:
            fitted = fit_depth_offsets(rows[peer.name], frames)
            write_offsets(args.fit_peer_depth, fitted, source=str(args.source),
                          peer=peer.description)
            log(f'wrote {args.fit_peer_depth}: ' + ', '.join(
                f'{k} {v["offset_m"] * 1e3:.0f} mm' for k, v in fitted.items()))
        if offsets is not None:
            rows[f'{peer.name}_fit'] = offset_row(rows[peer.name], offsets)
    for name, row in rows.items():
        if row.no_pose:
            log(f'{name}: no pose in {row.no_pose} of {len(frames)} frames')
    if args.draw is not None:
        for path in draw.draw_rows(rows, frames, args.draw):
            log(f'wrote {path}')
    return score_rows(rows, frames), len(frames), curve_rows(rows, frames, plot.ALPHAS)


def colour_unary(args: argparse.Namespace, settings: dict) -> NetUnary | None:
    """The photograph network as the part models' colour unary (`--colour-net`), or None."""
    if args.colour_net == 'none' and 'unary' in settings:
        raise ValueError('--config unary.*: needs a --colour-net')
    try:
        return tables.colour_unary(args.colour_net, args.net_precision,
                                   overrides.apply(UnaryConfig(), settings, 'unary'))
    except ValueError as exc:
        raise ValueError(f'--colour-net {exc}') from None


def stage_configs(args: argparse.Namespace, settings: dict, unary: NetUnary | None) -> dict:
    """The stages' configurations from the flags and `--config` (`pipeline_rows`' keywords)."""
    return {'search': overrides.apply(SearchConfig(n_levels=args.levels, margin=args.margin),
                                      settings, 'search'),
            'scale': overrides.apply(ScaleConfig(factors=args.person_scales), settings,
                                     'scale'),
            'foreground': overrides.apply(ForegroundConfig(), settings, 'foreground'),
            'slqe': overrides.apply(SlqeConfig(), settings, 'slqe'), 'unary': unary}


def real_rows(args: argparse.Namespace, models: dict[str, PartModel | ConvNet],
              peer: Peer | None) -> dict:
    """A recording without joint labels (a real camera's): every RGB-D model run as the nodes
    run it (the several-person pipeline), each scored against the peer as the reference and
    against the hand labels (`--labels`), `evaluation.real`; `--draw` draws every frame."""
    frames = load_frames([args.source], stride=args.stride, max_frames=args.max_frames,
                         labelled=False, fps=args.fps, topics={
                             'color_topic': args.color_topic, 'depth_topic': args.depth_topic,
                             'info_topic': args.info_topic}, hold=args.hold)
    if any(f.depth_m is None for f in frames):
        raise ValueError(f'{args.source}: a real recording needs depth in every frame')
    frames = shifted(frames, args.depth_shift)
    try:  # how far the depth edges lie from the colour edges (every 4th frame)
        registration = asdict(edge_shift((f.color, f.depth_m) for f in frames[::4]))
    except ValueError as exc:
        registration = {'error': str(exc)}
    labels = real.read_labels(args.labels) if args.labels is not None else None
    settings = overrides.parse(args.config)
    people = overrides.apply(TrackingConfig(
        max_people=args.max_people or TrackingConfig.max_people, birth_score=args.birth_score),
        settings, 'tracking')
    unary = colour_unary(args, settings)
    reference = (peer_rows(progress(frames, peer.name), peer)[peer.name].preds
                 if peer is not None else [JointSet.missing(('head',))] * len(frames))
    out: dict[str, dict] = {}
    for given, m in models.items():
        if isinstance(m, ConvNet) or m.channels != 'rgbd':
            raise ValueError(f'--model {given}: a real RGB-D recording takes RGB-D part models')
        name = Path(given).stem + (f'+{Path(args.colour_net).stem}' if unary else '')
        row = pipeline_rows(frames, m, name='rgbd', show=progress, single_frame=False,
                            people=people, **stage_configs(args, settings, unary))['rgbd_kf_ik']
        ours = row.people
        out[name] = {**real.agreement(frames, ours, reference, labels),
                     'cpu_ms': ms_stats(row.cpu_ms),
                     'bones_3d': real.bone_steadiness(frames, ours),
                     # the same scores at the stages before: where the pipeline loses joints
                     'stages': {stage: _stage_summary(real.agreement(frames, people, reference,
                                                                     labels))
                                for stage, people in row.stages.items()}}
        if args.draw is not None:
            real.draw_frames(frames, ours, reference, args.draw / name, labels)
            log(f'wrote {len(frames)} drawings to {args.draw / name}')
    if peer is not None:
        out[peer.name] = {'bones_3d': real.bone_steadiness(
            frames, [(r,) if real.present(r).any() else () for r in reference])}
        if labels is not None:
            out[peer.name]['labels'] = real.agreement(frames, [() for _ in frames], reference,
                                                      labels)['labels']
    return {'frames': len(frames), 'source': str(args.source), 'real': out,
            'depth_shift': args.depth_shift, 'registration': registration}


def format_real(result: dict) -> str:
    """The agreement table of `real_rows`, one line per model."""
    lines = [f"{result['source']}: {result['frames']} frames (real, no joint labels)",
             f"{'row':28s} {'agree@0.1':>9s} {'@0.2':>6s} {'joints':>6s} {'people/fr':>9s} "
             f"{'found':>9s} {'ghosts':>6s} {'cpu p50':>8s} {'bones 3-D: dev':>14s} "
             f"{'within':>6s}"]
    for name, t in result['real'].items():
        lab = t.get('labels')
        who = 'ours' if 'joints' in t else 'reference'
        found = f"{lab[who]}/{lab['labelled']}" if lab else '-'
        ghosts = lab['ghosts'][who] if lab else '-'
        bones = t.get('bones_3d', {})
        steady = f"{bones.get('mad_rel')!s:>14s} {bones.get('within')!s:>6s}"
        if 'joints' not in t:  # the peer's people only
            lines.append(f"{name:28s} {'':>9s} {'':>6s} {'':>6s} {'':>9s} {found:>9s} "
                         f"{ghosts!s:>6s} {'':>8s} {steady}")
            continue
        ppf = t['people_per_frame'].get('ours', 0)
        cpu = t['cpu_ms']['p50']
        lines.append(f"{name:28s} {t['agree@0.1']!s:>9s} {t['agree@0.2']!s:>6s} "
                     f"{t['joints']:>6d} {ppf:>9.2f} {found:>9s} {ghosts!s:>6s} {cpu!s:>8s} "
                     f'{steady}')
        for stage, s in t.get('stages', {}).items():  # the stages before the skeletons
            found = f"{s['found']}/{lab['labelled']}" if lab else '-'
            lines.append(f"{'  ' + stage:28s} {s['agree@0.1']!s:>9s} {s['agree@0.2']!s:>6s} "
                         f"{'':>6s} {s['people_per_frame'].get('ours', 0):>9.2f} {found:>9s} "
                         f"{s.get('ghosts', '-')!s:>6s}")
    reg = result.get('registration') or {}
    if 'dx' in reg:
        lines.append(f"registration: the depth edges lie nearest the colour edges moved by "
                     f"{reg['dx']}, {reg['dy']} px ({reg['chamfer_px']} px away there on average, "
                     f"{reg['unshifted_px']} px as given; {reg['frames']} frames)"
                     + (f"; depth moved by {result['depth_shift']}" if result.get('depth_shift')
                        else ''))
    return '\n'.join(lines)


def _unlabelled_bag(args: argparse.Namespace, kind: str) -> bool:
    """A bag that is a camera's recording (no ground truth topic, or its topics named)."""
    from pose4d_ros.datasets import bag, cad60_bag

    if kind != 'bag':
        return False
    if args.color_topic or args.depth_topic or args.info_topic or Path(args.source).is_file():
        return True
    topics = bag.topics(args.source)
    return cad60_bag.SKELETON_TOPIC not in topics and cad60_bag.SKELETONS_TOPIC not in topics


def _stage_summary(table: dict) -> dict:
    """An agreement table's headline figures (`evaluation.real.agreement`), for a stage."""
    keep = ('agree@0.1', 'agree@0.2', 'agree@0.1_by_group', 'offset_by_group', 'people_per_frame')
    out = {k: table[k] for k in keep}
    if 'labels' in table:
        out['found'], out['ghosts'] = table['labels']['ours'], table['labels']['ghosts']['ours']
    return out
