"""`pose4d bench`: time per stage on real frames, and the node graph's throughput and latency.

    pose4d bench SOURCE --json FILE [--model rgbd_14] [--frames N] [--warmup W] [--graph]
                 [--peer mediapipe]

Each frame goes through the stages as the live pipeline runs them, in order
(`core.pipeline.FramePipeline`): the foreground stage's mask on the depth image
(`ForegroundStage`, with the previous frame's floor and box), the part detector on the masked
frame (`DetectorStage`: `core.dpm.infer.Detector.detect` and the 3-D lift), the SLQE tracker
and the IK (`TrackerStage`, `IkStage`); an RGB model gets no depth and no foreground. The p50
and p95 of each stage's CPU time (this process's, `time.process_time`: `stages_ms`) and wall
time (`wall_ms`), and of their sum over the four stages (`total`: one frame through all of
them), are taken over the frames after `--warmup` (numba compilation and caches).

Python-level calls per frame (`stages.<stage>.calls_per_frame`): the same frames run again
through a fresh pipeline with a `cProfile` profiler per stage (`FramePipeline.profilers`), so
the timed pass is not disturbed; its total call count over the frames after `--warmup`, per
frame. Interpreter-bound work (many small numpy calls, Python loops) slows down most on a
slower core, so the count tells how a stage will fare there (the timings do not: they are this
machine's). It is deterministic: the same frames give the same count on any machine. So is the
detector's compiled work counted in that pass (`stages.detector.search_cells_per_frame`: the
filter positions scored a frame, `core.dpm.infer.SearchWork`; the filter GEMM and the tree DP
grow with it).

Several people (`--people several`, the default for a source with several people's ground
truth): the stages of `core.people` (`FramePipeline(people=...)`), and `people_ms`: each
stage's CPU ms (p50, p95) over the frames with 1, 2, 3, ... confirmed people tracked
(`len(FrameResult.people)`), with their count (`frames`).

With `--peer mediapipe` (`make peer`), MediaPipe Pose runs on the same frames in the same run,
each frame right after our stages took it (a slow moment of the host weighs on both sides
alike; its warm-up on the same frames as ours), as a user tracking a video would run it (video
mode, one video):
`peer_ms` is its worker process's CPU time per frame (every thread of it) plus the 3-D look-up
(`pose4d_ros.peer`), `peer_wall_ms` the wall time of a frame's round trip to the worker, and
`ratio_to_peer` = `stages_ms.total.p50 / peer_ms.p50`. CPU time makes the ratio a ratio of
cost that holds on any machine; pin the whole command to one core (`taskset -c 0 pose4d bench
...`) to compare on one core, as a robot's busy computer would give each.

With `--graph` (SOURCE a bag), the bag is then replayed at `--rate` through the node graph, one
process per stage as `ros2 run` starts them (`nodes`), and through the one-process `pipeline`
node: colour frames in and skeletons out are counted, and the latency from a frame's arrival to
its skeleton's is measured in this process on one clock; each process's CPU a frame is set
beside the core's and the peer's on every frame of the bag (`graph.bench`: the deployed
cost). The machine (cores,
CPU) and the thread settings are printed, because on a 2-core machine they decide the numbers:
BLAS is set to `--blas-threads` (1 by default, the measured best; see `core.threads`).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from pose4d_ros.cli._args import factor_list, load_list
from pose4d_ros.core.convnet import PRECISIONS
from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.files import write_json
from pose4d_ros.core.threads import set_blas_threads
from pose4d_ros.datasets.sources import load_frames, source_kind
from pose4d_ros.evaluation.tables import colour_unary, default_models
from pose4d_ros.models import DEFAULT_COLOUR_NET, DEFAULT_NET_PRECISION, model_path
from pose4d_ros.peer import PEERS, make_peer
from pose4d_ros.util.machine import machine
from pose4d_ros.util.stats import ms_stats


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'bench', help='time per perception stage (p50, p95)',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('source', metavar='SOURCE', help='CAD-60 directory (or LSPET root)')
    p.add_argument('--json', required=True, type=Path, help='write the timings here (JSON)')
    p.add_argument('--model', default=None,
                   help='model (.npz or shipped name); default rgbd_14 (lspet_rgb_14 on LSPET)')
    p.add_argument('--range', dest='frame_range', metavar='A-B', help='LSPET image numbers')
    p.add_argument('--frames', type=int, default=200, help='frames timed (spread over the set)')
    p.add_argument('--warmup', type=int, default=10, help='frames run before timing')
    p.add_argument('--levels', type=int, default=SearchConfig.n_levels,
                   help='pyramid levels searched around the depth-predicted scale (1-3)')
    p.add_argument('--person-scales', type=factor_list, default=ScaleConfig.factors,
                   metavar='F,F,...', help="factors on the depth-predicted person scale, one "
                   'chosen per track (core.dpm.scale); 1 = the predicted scale only')
    p.add_argument('--colour-net', metavar='NETWORK', default=DEFAULT_COLOUR_NET,
                   help="the photograph network in the part model's colour unary (the detector "
                        "node's detector.colour_net, its default weights), timed in the "
                        "detector; 'none': the part model's HOG filters alone")
    p.add_argument('--net-precision', choices=PRECISIONS, default=DEFAULT_NET_PRECISION,
                   help="the network's arithmetic (detector.colour_net_precision)")
    p.add_argument('--blas-threads', type=int, default=1, help='OpenBLAS threads')
    p.add_argument('--people', choices=('auto', 'one', 'several'), default='auto',
                   help='track one person (the paper) or several (core.people); auto: several '
                   "when SOURCE has several people's ground truth")
    p.add_argument('--no-calls', dest='calls', action='store_false',
                   help='skip the profiled pass that counts the Python calls per stage')
    p.add_argument('--peer', choices=PEERS,
                   help='also time the peer on the same frames (needs `make peer`)')
    p.add_argument('--graph', action='store_true',
                   help='also replay SOURCE (a bag) through the node graph and the pipeline node')
    p.add_argument('--rate', type=float, default=1.0, help='replay rate of --graph')
    p.add_argument('--best-effort', action='store_true',
                   help='--graph: replay the camera topics best effort, as camera drivers do')
    p.add_argument('--load', type=load_list, default=(), metavar='busy,query',
                   help='--graph: beside the graph, a process keeping a core busy and/or the ros2 '
                   'command line querying the nodes (pose4d_ros.graph.load)')
    p.add_argument('--repeat', type=int, default=1,
                   help='--graph: runs of each graph (their median and spread are reported)')
    p.add_argument('--profile', type=Path, metavar='DIR',
                   help="--graph: run the nodes under cProfile (their files in DIR) and report "
                        "each process's Python calls a frame")
    p.add_argument('--out', type=Path, default=Path('out/bench'),
                   help='where --graph writes its recordings and node logs')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.frames < 1 or args.warmup < 0:
        raise ValueError(f'--frames must be >= 1 and --warmup >= 0, got {args.frames}, '
                         f'{args.warmup}')
    from pose4d_ros.core.people import TrackingConfig
    from pose4d_ros.core.pipeline import STAGES, FramePipeline
    from pose4d_ros.core.stages import DetectorStage
    from pose4d_ros.evaluation.bench import count_calls, time_stages

    threads = set_blas_threads(args.blas_threads)
    kind = source_kind(args.source)
    if args.graph and kind != 'bag':
        raise ValueError(f'{args.source}: --graph needs a bag (got a {kind} source)')
    # the stages time a part model; the photograph network's CPU per photo is `eval`'s cpu_ms
    model = load_model(model_path(args.model or ('lspet_rgb_14' if kind == 'lspet'
                                                 else default_models(kind)[0])))
    unary = colour_unary(args.colour_net, args.net_precision)
    peer = make_peer(args.peer) if args.peer else None  # without its venv, stop before any work
    try:
        frames = load_frames([args.source], frame_range=args.frame_range,
                             max_frames=args.frames + args.warmup, labelled=False)
        use_depth = model.channels == 'rgbd'
        if use_depth and any(f.depth_m is None for f in frames):
            raise ValueError(f'{args.source}: no depth images for the rgbd model')
        several = use_depth and (args.people == 'several' or (
            args.people == 'auto' and any(len(f.people) > 1 for f in frames)))

        def new_pipeline() -> FramePipeline:
            return FramePipeline(
                DetectorStage(model, search=SearchConfig(n_levels=args.levels),
                              scale=ScaleConfig(factors=args.person_scales), unary=unary),
                people=TrackingConfig() if several else None)

        timed = time_stages(new_pipeline(), frames, args.warmup, use_depth=use_depth,
                            several=several, after_warmup=lambda: threads.update(
                                set_blas_threads(args.blas_threads)), peer=peer)
        peer_cpu, peer_wall = timed.pop('peer_cpu', None), timed.pop('peer_wall', None)
        calls, cells = count_calls(new_pipeline(), frames, args.warmup, use_depth) \
            if args.calls else (None, None)
        graph = graph_bench(args, model, unary, peer) if args.graph else None
    finally:
        if peer is not None:
            peer.close()
    m = machine()
    h, w = frames[0].color.shape[:2]
    print(f"machine: {m['cores']} cores, {m['cpu']}, load average {m['load_average']}, "
          f"this process may use CPUs {sorted(os.sched_getaffinity(0))}")
    print(f"threads: numba {m['numba_threads']} (no parallel kernels), BLAS {m['blas_threads']}"
          f" (set to {args.blas_threads}: {', '.join(f'{v}' for v in threads.values())})")
    print(f'model: {model.channels}, {model.n_parts} parts x {model.n_types} types; '
          f'{max(len(frames) - args.warmup, 0)} frames of {w}x{h} after {args.warmup} warm-up')
    out: dict = {**timed, 'people': 'several' if several else 'one'}
    if calls is not None:
        out['stages'] = {k: {'calls_per_frame': v} for k, v in calls.items()}
        out['stages']['detector']['search_cells_per_frame'] = cells
    lines = {k: (out['stages_ms'][k], out['wall_ms'][k]) for k in out['stages_ms']}
    if peer is not None:
        out['peer'] = peer.description
        out['peer_ms'], out['peer_wall_ms'] = ms_stats(peer_cpu), ms_stats(peer_wall)
        out['ratio_to_peer'] = round(out['stages_ms']['total']['p50']
                                     / out['peer_ms']['p50'], 3)
        lines[peer.name] = (out['peer_ms'], out['peer_wall_ms'])
    print(f'{"ms per frame":<12} {"CPU p50":>9} {"CPU p95":>9} {"wall p50":>9} {"wall p95":>9}'
          + (f' {"calls":>9}' if calls is not None else ''))
    for name, stats in lines.items():
        print(f'{name:<12} ' + ' '.join(f'{v:9.2f}' if v is not None else f'{"-":>9}'
                                        for st in stats for v in (st['p50'], st['p95']))
              + (f' {calls[name]:9.1f}' if calls is not None and name in calls else ''))
    if several:
        print(f'{"people":<6} {"frames":>6} ' + ' '.join(f'{k:>10}' for k in (*STAGES, 'total'))
              + '   (CPU ms p50 per frame by people tracked)')
        for n, g in out['people_ms'].items():
            print(f'{n:<6} {g["frames"]:>6} ' + ' '.join(
                f'{g[k]["p50"]:10.2f}' if g[k]['p50'] is not None else f'{"-":>10}'
                for k in (*STAGES, 'total')))
    if cells is not None:
        print(f'detector search: {cells:.1f} filter positions scored a frame (counted)')
    if peer is not None:
        print(f"ours / {peer.name} (CPU p50): {out['ratio_to_peer']:.3f} ({out['peer']})")
    if graph is not None:
        from pose4d_ros.graph.bench import describe

        out['graph'] = graph
        print('\n'.join(describe(graph)))
    write_json(args.json, out)
    return 0


def graph_bench(args: argparse.Namespace, model: object, unary: object, peer: object) -> dict:
    """The bag through the stage processes and the pipeline node, beside the core and the
    peer on every frame of it (`graph.bench`)."""
    from pose4d_ros.core.people import TrackingConfig
    from pose4d_ros.core.pipeline import FramePipeline
    from pose4d_ros.core.stages import DetectorStage
    from pose4d_ros.graph.bench import graph_bench as bench_graph

    bag_path = Path(args.source)
    frames = load_frames([args.source], labelled=False)
    # as the nodes run it: the several-person path, every person region searched
    pipeline = FramePipeline(DetectorStage(model, unary=unary), people=TrackingConfig())
    return bench_graph(bag_path, pipeline, frames, args.out, peer=peer, repeat=args.repeat,
                       profile=args.profile, rate=args.rate, model=args.model or 'rgbd_14',
                       best_effort=args.best_effort, load=args.load)
