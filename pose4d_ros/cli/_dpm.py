"""Shared pieces of the part-model verbs (`train`, `eval`, `bench`): loading sources, machine
and thread facts, training metadata."""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pose4d_ros.cli._progress import progress
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.datasets.sources import open_source, parse_range


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def factor_list(text: str) -> tuple[float, ...]:
    """argparse type: '0.87,1,1.15' -> (0.87, 1.0, 1.15)."""
    try:
        return tuple(float(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a comma list of numbers') from None


def load_frames(sources: list[str], *, frame_range: str | None = None, stride: int = 1,
                max_frames: int | None = None, labelled: bool = True) -> list[Frame]:
    """All frames of the sources (an LSPET source uses `frame_range`); `max_frames` keeps an
    evenly spread subset (deterministic). With `labelled`, a frame without ground truth is an
    error."""
    rng_ = parse_range(frame_range)
    frames: list[Frame] = []
    for src in sources:
        it = open_source(src, frame_range=rng_, stride=stride)
        with progress(it, f'reading {Path(src).name}') as bar:  # closed on a damaged file too
            frames.extend(bar)
    if max_frames is not None and len(frames) > max_frames:
        idx = np.unique(np.linspace(0, len(frames) - 1, max_frames).round().astype(int))
        frames = [frames[i] for i in idx]
    if not frames:
        raise ValueError(f'no frames in {", ".join(sources)}')
    if labelled:
        for f in frames:
            if f.truth is None:
                raise ValueError(f'{f.key}: no ground truth (a bag needs /cad60/skeleton)')
    return frames


def ms_stats(ms: Iterable[float]) -> dict[str, float | None]:
    """p50 and p95 of per-frame times in ms (None for none)."""
    a = np.asarray(list(ms), np.float64)
    if not a.size:
        return {'p50': None, 'p95': None}
    return {'p50': round(float(np.percentile(a, 50)), 3),
            'p95': round(float(np.percentile(a, 95)), 3)}


def git_commit() -> str:
    try:
        root = Path(__file__).resolve().parents[2]
        out = subprocess.run(['git', '-C', str(root), 'rev-parse', '--short', 'HEAD'],
                             capture_output=True, text=True, timeout=5)
        return out.stdout.strip() if out.returncode == 0 else ''
    except (OSError, subprocess.SubprocessError):
        return ''


def machine() -> dict[str, str | int]:
    """Cores, CPU model and the thread settings that matter for timing."""
    import numba

    from pose4d_ros.core.dpm.threads import blas_threads

    cpu = platform.processor() or ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return {'cores': os.cpu_count() or 0, 'cpu': cpu, 'python': platform.python_version(),
            'numba_threads': int(numba.get_num_threads()),
            'blas_threads': ', '.join(f'{k}={v}' for k, v in blas_threads().items()) or 'n/a',
            'load_average': ' '.join(f'{x:.2f}' for x in os.getloadavg())}
