"""`pose4d demo`: the main job (`make demo`).

Replays the bundled sample bag (synthetic RGB-D person, held-out real motion) at 1x through the
node graph, each stage its own process started exactly as `ros2 run` starts it (no launch
files): replay -> foreground -> detector -> tracker -> ik, and a recorder. Then it scores the
recorded /pose4d/skeleton against the bag's ground truth, runs the same core offline over the
same bag (what `pose4d eval` does) for comparison, checks the joints the graph put on /tf
against the skeletons, and writes out/overlay.mp4 (a video frame per skeleton out: the skeleton
drawn by joint source, the ground truth, the frame's latency), out/overlay.png (four of those
frames) and out/results.json.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from pose4d_ros.cli._args import load_list
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.files import write_atomic, write_json
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.datasets import bag, cad60_bag
from pose4d_ros.datasets.messages import joints_from_msg, stamp_to_ns
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.evaluation.draw import overlay_frame, overlay_picture, write_video
from pose4d_ros.evaluation.pipeline import Row, pipeline_rows, score_rows
from pose4d_ros.evaluation.tables import format_table
from pose4d_ros.graph.run import STAGES, GraphRun, default_bag, run_graph, tf_per_skeleton
from pose4d_ros.models import model_path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser('demo', help='replay the sample bag through the node graph and '
                              'score the skeleton', description=__doc__.split('\n\n')[1])
    p.add_argument('--bag', type=Path, default=None, help='bag to replay (default: the '
                   'bundled sample, with ground truth on cad60/skeleton)')
    p.add_argument('--out', type=Path, default=Path('out'), help='output directory')
    p.add_argument('--rate', type=float, default=1.0, help='replay speed (1 = real time)')
    p.add_argument('--model', default='rgbd_14', help='detector model (shipped name or .npz)')
    p.add_argument('--timeout', type=float, default=60.0,
                   help='seconds to wait for the graph to connect and to drain')
    p.add_argument('--load', type=load_list, default=(), metavar='busy,query',
                   help='beside the graph while the bag plays: a process keeping a core busy, '
                   'and/or the ros2 command line querying the nodes (pose4d_ros.graph.load)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    bag_path = args.bag or default_bag()
    if cad60_bag.SKELETON_TOPIC not in bag.topics(bag_path):
        raise ValueError(f'{bag_path}: no ground truth on {cad60_bag.SKELETON_TOPIC}')
    print(f'pose4d demo: replaying {bag_path} at {args.rate}x through '
          f'{" -> ".join(STAGES)} (one process each)')
    result = run_graph(bag_path, args.out, rate=args.rate, model=args.model,
                       timeout=args.timeout, load=args.load)
    return report(bag_path, result, args)


def report(bag_path: Path, result: GraphRun, args: argparse.Namespace) -> int:
    frames = load_frames([str(bag_path)])
    skeletons = {}
    for m in bag.read_messages(result.recorded, ['/pose4d/skeleton']):
        msg = bag.deserialize(m)
        skeletons.setdefault(stamp_to_ns(msg.header.stamp), joints_from_msg(msg))
    graph = Row([skeletons.get(f.stamp_ns, JointSet.missing(SKELETON_14)) for f in frames])
    offline = pipeline_rows(frames, load_model(model_path(args.model)))
    tables = score_rows({'graph': graph, **offline}, frames)
    n_in, latency = result.frames, result.latency_ms()
    results = {
        'bag': str(bag_path), 'rate': args.rate, 'load': list(args.load),
        'input_rate_hz': result.input_rate_hz(),
        'frames_in': n_in, 'skeletons_out': len(skeletons),
        'frames_lost': n_in - len(skeletons),
        'latency_ms': ({'p50': float(np.percentile(latency, 50)),
                        'p95': float(np.percentile(latency, 95)), 'n': int(latency.size)}
                       if latency.size else None),
        'tf': tf_per_skeleton(result.recorded, skeletons),
        'graph': tables.pop('graph'), 'offline': tables,
    }
    print(format_table({'graph (live, rgbd+kf+ik)': results['graph'],
                        **{f'offline {k}': v for k, v in tables.items()}}, n_in))
    print(f'\nframes in {n_in} (replayed at {result.input_rate_hz():.1f} Hz), skeletons out '
          f'{len(skeletons)}, lost {n_in - len(skeletons)}')
    if latency.size:
        print(f'latency colour frame -> /pose4d/skeleton: p50 {results["latency_ms"]["p50"]:.1f}'
              f' ms, p95 {results["latency_ms"]["p95"]:.1f} ms (n = {latency.size})')
    tf = results['tf']
    print(f'/tf: {tf["transforms"]} transforms, one per located joint, stamped like the '
          f'skeleton, for {tf["matching"]} of {tf["skeletons"]} skeletons')
    overlay = overlay_picture(frames, graph.preds)
    ok, png = cv2.imencode('.png', overlay[:, :, ::-1])
    if not ok:
        raise ValueError(f'could not encode the overlay picture ({overlay.shape})')
    write_atomic(args.out / 'overlay.png', png.tobytes())
    latencies = {s: (result.left[s] - result.entered[s]) * 1e3 for s in result.left
                 if s in result.entered}
    shown = [(f, skeletons[f.stamp_ns], latencies.get(f.stamp_ns)) for f in frames
             if f.stamp_ns in skeletons]
    write_video(args.out / 'overlay.mp4', (overlay_frame(*x) for x in shown),
                fps=result.input_rate_hz())
    write_json(args.out / 'results.json', results, indent=1)
    print(f'wrote {args.out / "overlay.mp4"} ({len(shown)} frames), '
          f'{args.out / "overlay.png"} and {args.out / "results.json"}')
    return 0 if len(skeletons) else 1


