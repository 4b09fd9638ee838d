"""The deployed cost: the node graph's CPU per frame beside the in-process core's and the
peer's, over the same frames (`pose4d bench --graph`).

What is compared, each over every colour frame of the bag in its order:
- `core_ms_per_frame`: the four stages in this process as the nodes configure them (the
  several-person path, every person region searched), a fresh pipeline like a node's after
  its start-up (compiled, nothing tracked yet): each stage's mean CPU ms a frame, and `total`;
- `peer_ms_per_frame` (with a peer): the peer's mean CPU a frame (every process and thread of
  it) plus `peer_decode_ms`, the CPU of reading the bag's colour message into an array as a
  node that takes `sensor_msgs/Image` messages does (`deserialize_message`, then
  `wire.color_from_msg`): what a node of the peer would pay for its input too (ours read the
  bytes in place, `nodes.common.image_of_bytes`, for less);
- each graph run (`nodes`: one process per stage; `pipeline`: the one-process node): each
  process's CPU while the bag plays and drains, per frame (and `threads_ms_per_frame`, the
  same by thread: the executor's, Fast DDS's and the frame worker's, `Graph.thread_seconds`);
  `stages_ms_per_frame`, the sum over the stage processes (the replay, recorder and load are
  not the graph's); `to_core` and `to_peer`, that sum over the core's and over the peer's.

Means, not medians: a process's CPU over a run is a mean a frame, so the core's is too (its
first frames of a track search every person scale, and the nodes pay those as well).
With `repeat` > 1 each graph runs that many times: its figures are the run with the median
stage CPU, and `spread` gives each figure's minimum, median and maximum over the runs.
With `profile`, each node runs under cProfile (`nodes.common`'s POSE4D_PROFILE) and
`calls_per_frame` gives each process's Python-level calls a frame (all its threads).
"""

from __future__ import annotations

import os
import pstats
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pose4d_ros.core.pipeline import STAGES, FramePipeline
from pose4d_ros.datasets import bag, cad60_bag
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.graph.run import GRAPHS, run_graph
from pose4d_ros.peer import Peer
from pose4d_ros.util.progress import progress
from pose4d_ros.util.stats import ms_stats


def core_cost(pipeline: FramePipeline, frames: Sequence[Frame]) -> dict[str, float]:
    """Mean CPU ms a frame of each stage and of all four (`total`) over `frames` in order."""
    cpu = {k: 0.0 for k in (*STAGES, 'total')}
    for f in progress(frames, 'core'):
        out = pipeline.step(f.color, f.depth_m, f.intrinsics, f.stamp_ns * 1e-9)
        for name, s in out.cpu_s.items():
            cpu[name] += s
            cpu['total'] += s
    return {k: round(v * 1e3 / len(frames), 3) for k, v in cpu.items()}


def colour_decode_ms(bag_path: Path) -> float:
    """Mean CPU ms of reading one of the bag's colour messages (its CDR bytes as published)
    into an array through the message object, as a node taking `sensor_msgs/Image` does."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from pose4d_ros.wire import color_from_msg

    total, n = 0.0, 0
    for m in bag.read_messages(bag_path, [cad60_bag.COLOR_TOPIC]):
        t0 = time.process_time()
        color_from_msg(deserialize_message(m.data, Image))
        total += time.process_time() - t0
        n += 1
    return round(total * 1e3 / max(n, 1), 3)


def peer_cost(peer: Peer, frames: Sequence[Frame]) -> float:
    """The peer's mean CPU ms a frame over `frames` as one video."""
    total = 0.0
    for i, f in enumerate(progress(frames, peer.name)):
        peer.step(f.color, f.depth_m, f.intrinsics, new_video=i == 0)
        total += peer.last_cpu_s
    return round(total * 1e3 / len(frames), 3)


def _calls_per_frame(folder: Path, frames: int, graph: str) -> dict[str, float]:
    """Python-level calls a frame of each process, from its threads' cProfile files (named
    by node: in the `composed` graph the stage nodes', and its main thread's, are its)."""
    calls: dict[str, int] = {}
    for path in sorted(folder.glob('*.prof')):
        process = path.name.split('.', 1)[0]
        if graph == 'composed' and (process in STAGES or '+' in process):
            process = 'composed'
        calls[process] = calls.get(process, 0) + pstats.Stats(str(path)).total_calls
    return {k: round(v / max(frames, 1), 1) for k, v in calls.items()}


def graph_run(bag_path: Path, graph: str, out: Path, *, profile: Path | None = None,
              **options: Any) -> dict:
    """One replay of the bag through `graph` (of `GRAPHS`): frames, latency, CPU."""
    if profile is not None:
        folder = profile / graph
        for old in folder.glob('*.prof'):
            old.unlink()
        os.environ['POSE4D_PROFILE'] = str(folder)
    try:
        r = run_graph(bag_path, out, graph=graph, **options)
    finally:
        os.environ.pop('POSE4D_PROFILE', None)
    lat = r.latency_ms()
    t_out = np.sort(np.fromiter(r.left.values(), float))
    out_rate = (len(t_out) - 1) / (t_out[-1] - t_out[0]) if len(t_out) > 1 else None
    cpu = {exe: round(t * 1e3 / max(r.frames, 1), 2) for exe, t in r.cpu_s.items()}
    run = {'frames_in': r.frames, 'frames_replayed': len(r.entered),
           'frames_out': len(r.left), 'frames_dropped': r.frames - len(r.left),
           'input_rate_hz': round(r.input_rate_hz(), 2),
           'output_rate_hz': round(out_rate, 2) if out_rate else None,
           'latency_ms': ms_stats(lat.tolist()),
           # a backlog shows as latency growing over the run
           'latency_p50_ms_by_third': [ms_stats(part.tolist())['p50']
                                       for part in np.array_split(lat, 3)],
           'cpu_ms_per_frame': cpu,
           # each process's CPU by thread: the node's executor, Fast DDS's, the frame worker's
           'threads_ms_per_frame': {
               exe: {kind: round(t * 1e3 / max(r.frames, 1), 2) for kind, t in kinds.items()}
               for exe, kinds in r.thread_s.items()},
           'stages_ms_per_frame': round(sum(cpu.get(s, 0.0) for s in GRAPHS[graph]), 2),
           # where frames were lost: each stage's count on /diagnostics
           'dropped_by_stage': r.dropped}
    if profile is not None:
        run['calls_per_frame'] = _calls_per_frame(profile / graph, r.frames, graph)
    return run


def _spread(runs: list[dict]) -> dict[str, list[float]]:
    """Minimum, median and maximum over the runs of each headline figure."""
    figures = {'stages_ms_per_frame': [r['stages_ms_per_frame'] for r in runs],
               'frames_out': [r['frames_out'] for r in runs],
               'latency_p95_ms': [r['latency_ms']['p95'] for r in runs
                                  if r['latency_ms']['p95'] is not None]}
    return {k: [round(float(np.min(v)), 2), round(float(np.median(v)), 2),
                round(float(np.max(v)), 2)] for k, v in figures.items() if v}


def graph_bench(bag_path: Path, pipeline: FramePipeline, frames: Sequence[Frame], out: Path, *,
                peer: Peer | None = None, repeat: int = 1, profile: Path | None = None,
                **options: Any) -> dict:
    """Both graphs against the core (and the peer) on every frame of the bag; see the module
    docstring. `options` go to `run_graph` (rate, model, best_effort, load)."""
    result: dict = {'frames': len(frames), 'core_ms_per_frame': core_cost(pipeline, frames)}
    core = result['core_ms_per_frame']['total']
    if peer is not None:
        decode = colour_decode_ms(bag_path)
        result.update(peer=peer.description, peer_decode_ms=decode,
                      peer_ms_per_frame=round(peer_cost(peer, frames) + decode, 3))
    for graph in GRAPHS:
        runs = [graph_run(bag_path, graph, out, profile=profile, **options)
                for _ in range(repeat)]
        chosen = sorted(runs, key=lambda r: r['stages_ms_per_frame'])[(len(runs) - 1) // 2]
        summary = {**chosen, 'to_core': round(chosen['stages_ms_per_frame'] / core, 3)}
        if peer is not None:
            summary['to_peer'] = round(chosen['stages_ms_per_frame']
                                       / result['peer_ms_per_frame'], 3)
        if repeat > 1:
            summary['spread'] = _spread(runs)
        result[graph] = summary
    return result


def describe(result: dict) -> list[str]:
    """The printout of `graph_bench`'s result."""
    core = result['core_ms_per_frame']
    lines = [f"core (in process, nodes' configuration, every frame): {core['total']} ms CPU a "
             'frame (' + ', '.join(f'{k} {core[k]}' for k in STAGES) + ')']
    if 'peer_ms_per_frame' in result:
        lines.append(f"peer: {result['peer_ms_per_frame']} ms CPU a frame with its colour "
                     f"decode ({result['peer_decode_ms']} ms; {result['peer']})")
    for graph in (g for g in GRAPHS if g in result):  # (a bench from before `composed`)
        st = result[graph]
        line = (f"graph {graph:<9} {st['frames_replayed']}/{st['frames_in']} frames replayed, "
                f"{st['frames_out']} out, in {st['input_rate_hz']} Hz, out "
                f"{st['output_rate_hz']} Hz, latency p50 {st['latency_ms']['p50']} ms p95 "
                f"{st['latency_ms']['p95']} ms (p50 by third of the run "
                f"{st['latency_p50_ms_by_third']}); CPU ms per frame: "
                + ', '.join(f'{k} {v}' for k, v in st['cpu_ms_per_frame'].items())
                + f"; stages {st['stages_ms_per_frame']} = {st['to_core']}x the core"
                + (f", {st['to_peer']}x the peer" if 'to_peer' in st else '')
                + '; dropped by stage: '
                + ', '.join(f'{k} {v}' for k, v in st['dropped_by_stage'].items()))
        if 'spread' in st:
            line += '; over the runs (min, median, max): ' + ', '.join(
                f'{k} {v}' for k, v in st['spread'].items())
        if 'calls_per_frame' in st:
            line += '; Python calls a frame: ' + ', '.join(
                f'{k} {v}' for k, v in st['calls_per_frame'].items())
        lines.append(line)
    return lines
