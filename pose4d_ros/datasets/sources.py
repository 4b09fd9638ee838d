"""One opener for every source of frames: `open_source` (CAD-60 directory, rosbag2, LSPET, a
folder of RGB-D frames with its `camera_info.yaml`),
and `load_frames`, all the frames of several sources in memory.

Every source yields `frame.Frame`s; adding a source means writing one generator of them (like
`cad60.read_frames`, `cad60_bag.read_frames`, `lspet.read_frames`) and naming it here.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pose4d_ros.datasets import bag, cad60, cad60_bag, camera_bag, frames_dir, lspet
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.util.progress import progress


def parse_range(text: str | None) -> tuple[int, int] | None:
    """'A-B' -> (A, B) inclusive; None stays None."""
    if text is None:
        return None
    try:
        a, b = (int(v) for v in text.split('-'))
    except ValueError as exc:
        raise ValueError(f"range must be 'A-B' (e.g. 1-2500), got {text!r}") from exc
    if not 1 <= a <= b:
        raise ValueError(f'range must satisfy 1 <= A <= B, got {text!r}')
    return a, b


def parse_ranges(text: str) -> list[tuple[int, int]]:
    """'A-B,C-D,...' -> [(A, B), (C, D), ...] inclusive (each as `parse_range`), in order and
    not overlapping."""
    ranges = [parse_range(part.strip()) for part in text.split(',')]
    for (_, b), (c, _) in zip(ranges[:-1], ranges[1:], strict=True):
        if c <= b:
            raise ValueError(f'ranges must be in increasing order without overlap, got {text!r}')
    return ranges  # type: ignore[return-value]


def source_kind(path: str | Path) -> str:
    """'lspet' for an LSPET root (joints.mat + images/), 'cad60' for a CAD-60 root (dataN/
    directories, or one dataN directory), 'bag' for a rosbag2 (e.g. made by
    `pose4d cad60-to-bag`, or any camera's recording, ROS 1 .bag files too), 'frames' for a
    folder of RGB-D frames with `camera_info.yaml`
    (`datasets.frames_dir`: a real camera's recording)."""
    p = Path(path)
    if not p.exists():
        raise OSError(f'{p}: no such file or directory')
    if (p / 'metadata.yaml').is_file() or (p.is_file() and p.suffix == '.bag'):
        return 'bag'
    if (p / 'joints.mat').is_file() and (p / 'images').is_dir():
        return 'lspet'
    if p.is_dir() and (any(p.glob('data*/activityLabel.txt'))
                       or (p / 'activityLabel.txt').is_file()):
        return 'cad60'
    if frames_dir.is_frames_dir(p):
        return 'frames'
    raise ValueError(f'{p}: neither an LSPET root (joints.mat, images/), a CAD-60 directory '
                     '(dataN/ with activityLabel.txt), a rosbag2 (metadata.yaml) nor a folder '
                     'of RGB-D frames (camera_info.yaml with color/ and depth/)')


def open_source(path: str | Path, *, frame_range: tuple[int, int] | None = None,
                stride: int = 1, fps: float | None = None,
                topics: dict[str, str | None] | None = None, hold: int = 1
                ) -> Iterator[Frame]:
    """The frames of a source (see `source_kind`), in order.

    Parameters
    ----------
    path : an LSPET root, a CAD-60 directory, a rosbag2 or a folder of frames.
    frame_range : LSPET: image numbers (A, B), inclusive (required for LSPET).
    stride : keep every `stride`-th frame (of each video, for CAD-60).
    fps : a folder of frames: its frame rate (default: its `frames.yaml`, else 30).
    topics : a camera's recording: `camera_bag.read_frames`' color_topic, depth_topic,
        info_topic (None: picked by type and encoding).
    hold : a folder of separate frames: each held this many frames (`frames_dir`).
    """
    if stride < 1:
        raise ValueError(f'stride must be >= 1, got {stride}')
    kind = source_kind(path)
    if kind == 'cad60':
        return cad60.read_frames(path, stride=stride)
    if kind == 'lspet':
        if frame_range is None:
            raise ValueError(f'{path}: an LSPET source needs --range A-B (e.g. 1-2500)')
        frames = lspet.read_frames(path, *frame_range)
    elif kind == 'frames':
        frames = frames_dir.read_frames(path, fps=fps, hold=hold)
    elif Path(path).is_dir() and not any(topics.values() if topics else ()) and set(
            cad60_bag.CAMERA_TOPICS) <= set(bag.topics(path)):
        frames = cad60_bag.read_frames(path)  # our own topics, with ground truth if any
    else:
        frames = camera_bag.read_frames(path, **(topics or {}))
    return itertools.islice(frames, 0, None, stride)


def load_frames(sources: list[str], *, frame_range: str | None = None, stride: int = 1,
                max_frames: int | None = None, labelled: bool = True,
                fps: float | None = None, topics: dict[str, str | None] | None = None,
                hold: int = 1) -> list[Frame]:
    """All frames of the sources (an LSPET source uses `frame_range`); `max_frames` keeps an
    evenly spread subset (deterministic). With `labelled`, a frame without ground truth is an
    error."""
    rng_ = parse_range(frame_range)
    frames: list[Frame] = []
    for src in sources:
        it = open_source(src, frame_range=rng_, stride=stride, fps=fps, topics=topics,
                         hold=hold)
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
