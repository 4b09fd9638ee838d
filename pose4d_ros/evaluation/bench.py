"""The measurements behind `pose4d bench` (the verb parses, calls these and prints): CPU and wall
time per stage over frames (`time_stages`, with the peer's cost on the same frames taken frame
by frame between them), Python-level calls per stage (`count_calls`). The verb's docstring says
what each figure means."""

from __future__ import annotations

import cProfile
import pstats
import time
from collections.abc import Callable, Sequence

from pose4d_ros.core.dpm.infer import SearchWork
from pose4d_ros.core.pipeline import STAGES, FramePipeline
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.peer import Peer
from pose4d_ros.util.progress import progress
from pose4d_ros.util.stats import ms_stats


def _step(pipeline: FramePipeline, f: Frame, use_depth: bool):
    return pipeline.step(f.color, f.depth_m if use_depth else None, f.intrinsics,
                         f.stamp_ns * 1e-9)


def time_stages(pipeline: FramePipeline, frames: Sequence[Frame], warmup: int, *,
                use_depth: bool, several: bool,
                after_warmup: Callable[[], None] = lambda: None,
                peer: Peer | None = None) -> dict:
    """Each stage's CPU and wall ms per frame (and their `total`: one frame through all four)
    over the frames after `warmup` (`after_warmup` is called when the warm-up is over): the
    verb's `stages_ms` and `wall_ms`, and with `several` `people_ms` (CPU ms by the number of
    people tracked in the frame, with the count of such frames). With `peer`, the peer takes
    each frame right after the stages (the frames one video): `peer_cpu` and `peer_wall`, its
    CPU and wall ms per frame over the same frames. Interleaved frame by frame, a slow moment
    of the host weighs on both sides of the ratio alike."""
    ms = {clock: {k: [] for k in (*STAGES, 'total')} for clock in ('cpu', 'wall')}
    by_people: dict[int, dict[str, list[float]]] = {}  # people tracked -> stage -> CPU ms
    peer_cpu: list[float] = []
    peer_wall: list[float] = []
    for i, f in enumerate(progress(frames, 'bench')):
        if i == min(warmup, len(frames) - 1):
            after_warmup()
        out = _step(pipeline, f, use_depth)
        if peer is not None:
            start = time.perf_counter()
            peer.step(f.color, f.depth_m, f.intrinsics, new_video=i == 0)
            if i >= warmup:
                peer_wall.append((time.perf_counter() - start) * 1e3)
                peer_cpu.append(peer.last_cpu_s * 1e3)
        if i < warmup:
            continue
        for clock, times in (('cpu', out.cpu_s), ('wall', out.wall_s)):
            for name in STAGES:
                if name != 'foreground' or use_depth:
                    ms[clock][name].append(times[name] * 1e3)
            ms[clock]['total'].append(sum(times.values()) * 1e3)
        if several:
            group = by_people.setdefault(len(out.people), {k: [] for k in (*STAGES, 'total')})
            for name in STAGES:
                group[name].append(out.cpu_s[name] * 1e3)
            group['total'].append(sum(out.cpu_s.values()) * 1e3)
    result: dict = {'stages_ms': {k: ms_stats(v) for k, v in ms['cpu'].items()},
                    'wall_ms': {k: ms_stats(v) for k, v in ms['wall'].items()}}
    if several:
        result['people_ms'] = {str(n): {'frames': len(g['total']),
                                        **{k: ms_stats(v) for k, v in g.items()}}
                               for n, g in sorted(by_people.items())}
    if peer is not None:
        result['peer_cpu'], result['peer_wall'] = peer_cpu, peer_wall
    return result


def count_calls(pipeline: FramePipeline, frames: Sequence[Frame], warmup: int,
                use_depth: bool) -> tuple[dict[str, float], float]:
    """Python-level calls per frame of each stage and of all of them (`total`): cProfile's
    total call count over the frames after `warmup`, one profiler per stage; and the part
    model's search work per frame over the same frames (filter positions scored,
    `core.dpm.infer.SearchWork`). Both are counts: the same on any machine."""
    profilers = {name: cProfile.Profile() for name in STAGES}
    start = min(warmup, len(frames) - 1)
    cells = 0
    for i, f in enumerate(progress(frames, 'calls')):
        pipeline.profilers = profilers if i >= start else None
        before = SearchWork.cells
        _step(pipeline, f, use_depth)
        if i >= start:
            cells += SearchWork.cells - before
    n = len(frames) - start
    calls = {name: round(pstats.Stats(p).total_calls / n, 1) if p.getstats() else 0.0
             for name, p in profilers.items()}
    calls['total'] = round(sum(calls.values()), 1)
    return calls, round(cells / n, 1)

