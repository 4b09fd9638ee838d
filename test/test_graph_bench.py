"""The deployed cost's measurement (`pose4d bench --graph`, `graph.bench`) and the heap setting
every node runs with (`core.malloc`)."""

from __future__ import annotations

import json
import os
import resource
import subprocess

import pytest
from harness import executable

from pose4d_ros.core.malloc import keep_freed_memory
from pose4d_ros.graph.bench import GRAPHS, STAGES, _spread, describe


def _minor_faults_of_frames(n: int = 40, size: int = 921_600) -> int:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(n):
        block = bytearray(size)  # a VGA colour frame's buffer, written, then freed
        block[::4096] = b'\x01' * len(block[::4096])
        del block
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def test_kept_memory_serves_each_frame_without_fresh_pages():
    assert keep_freed_memory(), 'mallopt refused (is this glibc?)'
    _minor_faults_of_frames(2)  # the heap grows to hold one frame once
    # glibc's defaults gave 138 faults over these 40 frames (its trim hands the top of the
    # heap back and the next frame faults it in again); kept, the frames reuse one block
    assert _minor_faults_of_frames() < 10


def test_a_graph_discovers_this_host_only_unless_told_otherwise(monkeypatch):
    from pose4d_ros.graph.run import graph_environment

    monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE', raising=False)
    monkeypatch.delenv('FASTRTPS_DEFAULT_PROFILES_FILE', raising=False)
    graph_environment()
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'].endswith('fastdds.xml')
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')  # the user's choice stays
    graph_environment()
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'


def test_the_spread_and_the_printout_name_every_figure():
    runs = [{'stages_ms_per_frame': v, 'frames_out': 300, 'latency_ms': {'p95': p}}
            for v, p in ((20.0, 30.0), (22.0, 25.0), (21.0, 40.0))]
    assert _spread(runs) == {'stages_ms_per_frame': [20.0, 21.0, 22.0],
                             'frames_out': [300.0, 300.0, 300.0],
                             'latency_p95_ms': [25.0, 30.0, 40.0]}
    run = {'frames_replayed': 300, 'frames_in': 300, 'frames_out': 300,
           'input_rate_hz': 30.0, 'output_rate_hz': 30.0,
           'latency_ms': {'p50': 10.0, 'p95': 20.0}, 'latency_p50_ms_by_third': [10, 10, 10],
           'cpu_ms_per_frame': {'ik': 1.0}, 'stages_ms_per_frame': 20.0, 'to_core': 2.0,
           'dropped_by_stage': {}}
    text = '\n'.join(describe({'core_ms_per_frame': dict.fromkeys((*STAGES, 'total'), 1.0),
                               'nodes': run, 'composed': run, 'pipeline': run}))
    assert text.count('stages 20.0 = 2.0x the core') == 3
    assert 'graph composed' in text


@pytest.mark.slow
def test_bench_graph_sets_each_graph_beside_the_core_with_calls_per_process(tmp_path):
    out = tmp_path / 'bench.json'
    run = subprocess.run(
        [str(executable('pose4d')), 'bench', 'bags/sample', '--json', str(out), '--frames',
         '4', '--warmup', '2', '--no-calls', '--graph', '--rate', '0.25', '--out',
         str(tmp_path / 'graph'), '--profile', str(tmp_path / 'profile')],
        capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    graph = json.loads(out.read_text())['graph']
    core = graph['core_ms_per_frame']
    assert graph['frames'] == 45 and core['total'] == pytest.approx(
        sum(core[s] for s in STAGES), abs=0.01)
    for name, processes in GRAPHS.items():
        st = graph[name]
        assert st['frames_out'] == 45, st
        assert st['stages_ms_per_frame'] == pytest.approx(
            sum(st['cpu_ms_per_frame'][p] for p in processes), abs=0.02)
        assert st['to_core'] == pytest.approx(st['stages_ms_per_frame'] / core['total'],
                                              abs=1e-3)
        # each process's CPU by kind adds up to it (`frames` is the rest of the process's,
        # threads that ended included; the two read a few ms apart, each in /proc's ticks);
        # the executor and the frame worker both work
        tick_ms = 1e3 / os.sysconf('SC_CLK_TCK') / st['frames_in']
        for p in processes:
            threads = st['threads_ms_per_frame'][p]
            nodes = len(STAGES) if p == 'composed' else 1
            assert set(threads) == {'executor', 'dds', 'frames'}, threads
            assert sum(threads.values()) == pytest.approx(
                st['cpu_ms_per_frame'][p], abs=4 * nodes * tick_ms + 0.02), threads
            assert threads['executor'] > 0 and threads['frames'] > 0, threads
        # every node ran under the profiler and wrote its calls at exit
        assert set(processes) <= set(st['calls_per_frame']), st['calls_per_frame']
        assert all(st['calls_per_frame'][p] > 50 for p in processes)


def test_the_results_page_gives_each_stage_node_by_thread():
    from pose4d_ros.evaluation.results_doc import graph_table

    core = {'foreground': 2.0, 'detector': 6.0, 'tracker': 0.5, 'ik': 0.2, 'total': 8.7}
    run = {'stages_ms_per_frame': 13.0, 'to_core': 1.49, 'frames_out': 300, 'frames_in': 300,
           'latency_ms': {'p95': 20.0},
           'cpu_ms_per_frame': {'foreground': 3.0, 'detector': 7.5, 'tracker': 1.3, 'ik': 1.2},
           'threads_ms_per_frame': {s: {'executor': 0.5, 'dds': 0.2, 'frames': 0.6}
                                    for s in STAGES}}
    lines = graph_table({'core_ms_per_frame': core, 'nodes': run, 'pipeline': dict(
        run, threads_ms_per_frame={})})
    assert '| ik | 0.5 | 0.2 | 0.6 | 1.2 | 0.2 |' in lines
    assert sum(line.startswith('| detector |') for line in lines) == 1
    # a bench from before the split: no thread table
    del run['threads_ms_per_frame']
    assert not any('executor' in line for line in graph_table(
        {'core_ms_per_frame': core, 'nodes': run, 'pipeline': run}))
