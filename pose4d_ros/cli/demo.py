"""`pose4d demo`: the main job (`make demo`).

Replays the bundled sample bags (synthetic RGB-D people, held-out real motion: one person, then
two) at 1x through the node graph, each stage its own process started exactly as `ros2 run`
starts it (no launch files): replay -> foreground -> detector -> tracker -> ik, and a recorder.
Each is scored against its ground truth (the recorded /pose4d/skeleton, or with several people
/pose4d/skeletons: per person, id switches) beside the same core run offline over the same bag
(what `pose4d eval` does), the joints on /tf checked against the skeletons, and drawn:
out/overlay.mp4 and out/overlay.png (one person: the skeleton by joint source, the ground truth,
each frame's latency), out/overlay_people2.mp4/.png (each track id in its own colour), and
out/results.json (the one-person bag's results at the top, the two-person bag's under its name).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pose4d_ros.cli._args import load_list
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.files import write_json
from pose4d_ros.datasets import bag, cad60_bag
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.evaluation import demo
from pose4d_ros.graph import run as graph_run
from pose4d_ros.models import model_path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser('demo', help='replay the sample bags through the node graph and '
                              'score the skeletons', description=__doc__.split('\n\n')[1])
    p.add_argument('--bag', type=Path, default=None, help='one bag to replay (default: the '
                   'bundled samples, with ground truth on cad60/skeleton(s))')
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
    results, status = {}, 0
    bags = [args.bag] if args.bag else [graph_run.default_bag(b) for b in graph_run.SAMPLE_BAGS]
    for bag_path in bags:
        topics = bag.topics(bag_path)
        if cad60_bag.SKELETON_TOPIC not in topics:
            raise ValueError(f'{bag_path}: no ground truth on {cad60_bag.SKELETON_TOPIC}')
        several = cad60_bag.SKELETONS_TOPIC in topics
        # a several-person bag: its node logs and recording in out/<bag>/
        out = args.out / bag_path.name if several else args.out
        print(f'\npose4d demo: replaying {bag_path} at {args.rate}x through '
              f'{" -> ".join(graph_run.STAGES)} (one process each)')
        graph = graph_run.run_graph(bag_path, out, rate=args.rate, model=args.model,
                                    timeout=args.timeout, load=args.load)
        frames = load_frames([str(bag_path)])
        rec = demo.read_recording(graph.recorded)
        latency = {s: (graph.left[s] - graph.entered[s]) * 1e3 for s in graph.left
                   if s in graph.entered}
        res = demo.run_results(
            graph.frames, rec, latency, demo.score_run(frames, rec, load_model(
                model_path(args.model))), bag=str(bag_path), rate=args.rate,
            load=list(args.load), input_rate_hz=graph.input_rate_hz(),
            tf=graph_run.tf_per_skeleton(graph.recorded, rec.skeleton))
        print(demo.format_run(res))
        stem = f'overlay_{bag_path.name.removeprefix("sample_")}' if several else 'overlay'
        shown = demo.write_overlays(args.out, stem, frames, rec, latency,
                                    fps=graph.input_rate_hz())
        print(f'wrote {args.out / stem}.mp4 ({shown} frames) and {args.out / stem}.png')
        results.update({bag_path.name: res} if several else res)
        status = status or int(not res['skeletons_out'])
    write_json(args.out / 'results.json', results, indent=1)
    print(f'wrote {args.out / "results.json"}')
    return status
