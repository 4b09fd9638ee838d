"""Labelled frames for training and evaluating the part model, from any source.

A source is a small function that yields `Sample`s: a colour image, the depth image if the
source has one (float32 metres, NaN = no reading), and the 2-D ground truth of the joints it
knows in skeleton names (`core.skeleton`), with a visibility flag per joint. Adding a source (a
bag, another dataset) means writing one such generator and naming it in `open_source`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics


@dataclass(frozen=True)
class Sample:
    """One labelled frame.

    Attributes
    ----------
    color : (H, W, 3) uint8 colour image.
    depth_m : (H, W) float32 metres registered to `color`, NaN = no reading; None if the
        source has no depth.
    joints_uv : (J, 2) float64 pixel (u, v) of each joint in `names`; NaN when not labelled.
    visible : (J,) bool, the joint is labelled (and, where the source says so, visible).
    names : J skeleton joint names (`core.skeleton`), e.g. 'head', 'left_wrist'.
    mask : (H, W) bool person mask if the source has one (synthetic renders), else None.
    intrinsics : the colour camera, if known.
    key : where the frame comes from (file or dataset/frame), for messages.
    """

    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32] | None
    joints_uv: NDArray[np.float64]
    visible: NDArray[np.bool_]
    names: tuple[str, ...]
    mask: NDArray[np.bool_] | None = None
    intrinsics: Intrinsics | None = None
    key: str = ''
    extra: dict = field(default_factory=dict)


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


def source_kind(path: str | Path) -> str:
    """'lspet' for an LSPET root (joints.mat + images/), 'cad60' for a CAD-60 root (dataN/
    directories, or one dataN directory), 'bag' for a rosbag2 with ground truth (made by
    `pose4d cad60-to-bag`)."""
    p = Path(path)
    if not p.exists():
        raise OSError(f'{p}: no such file or directory')
    if (p / 'metadata.yaml').is_file():
        return 'bag'
    if (p / 'joints.mat').is_file() and (p / 'images').is_dir():
        return 'lspet'
    if p.is_dir() and (any(p.glob('data*/activityLabel.txt'))
                       or (p / 'activityLabel.txt').is_file()):
        return 'cad60'
    raise ValueError(f'{p}: neither an LSPET root (joints.mat, images/), a CAD-60 directory '
                     '(dataN/ with activityLabel.txt) nor a rosbag2 (metadata.yaml)')


def open_source(path: str | Path, *, frame_range: tuple[int, int] | None = None,
                stride: int = 1) -> Iterator[Sample]:
    """The samples of a source directory (see `source_kind`).

    Parameters
    ----------
    path : an LSPET root or a CAD-60 directory.
    frame_range : LSPET: image numbers (A, B), inclusive (required for LSPET).
    stride : keep every `stride`-th frame of a CAD-60 video.
    """
    kind = source_kind(path)
    if kind == 'lspet':
        from pose4d_ros.datasets.lspet import lspet_samples
        if frame_range is None:
            raise ValueError(f'{path}: an LSPET source needs --range A-B (e.g. 1-2500)')
        return lspet_samples(path, *frame_range)
    if kind == 'bag':
        return bag_samples(path, stride=stride)
    return cad60_samples(path, stride=stride)


def cad60_samples(root: str | Path, *, stride: int = 1) -> Iterator[Sample]:
    """Samples of a CAD-60 directory (real or synthetic): RGB, depth in metres, the 15 CAD-60
    joints projected with the OpenNI perspective model (visible = confidence > 0), and the
    person mask when the set has `Mask_<k>.png` files (synthetic sets)."""
    from pose4d_ros.core.camera import cad60_intrinsics, depth_to_metres
    from pose4d_ros.core.skeleton import CAD60_JOINTS
    from pose4d_ros.datasets import cad60

    if stride < 1:
        raise ValueError(f'stride must be >= 1, got {stride}')
    for video in cad60.list_videos(root):
        skel = cad60.read_skeleton(video.skeleton_path)
        with_mask = bool(len(skel.frames)) and cad60.frame_paths(
            video.frame_dir, int(skel.frames[0]))[2].is_file()
        uv_all = None
        for i, k in enumerate(skel.frames):
            if i % stride:
                continue
            rgb, depth = cad60.load_frame(video.frame_dir, int(k))
            h, w = depth.shape
            intr = cad60_intrinsics(w, h)
            if uv_all is None:
                uv_all = skel.pixels(intr)
            mask = cad60.load_frame_mask(video.frame_dir, int(k)) if with_mask else None
            yield Sample(color=rgb, depth_m=depth_to_metres(depth),
                         joints_uv=np.asarray(uv_all[i], np.float64),
                         visible=np.asarray(skel.joint_conf[i]) > 0, names=CAD60_JOINTS,
                         mask=mask, intrinsics=intr,
                         key=str(cad60.frame_paths(video.frame_dir, int(k))[0]),
                         extra={'video': f'{video.person}/{video.video_id}', 'frame': int(k)})


def bag_samples(path: str | Path, *, stride: int = 1) -> Iterator[Sample]:
    """Samples of a bag with ground truth on /cad60/skeleton (`cad60_bag.read_frames`)."""
    from pose4d_ros.datasets.cad60_bag import read_frames

    if stride < 1:
        raise ValueError(f'stride must be >= 1, got {stride}')
    for i, f in enumerate(read_frames(path)):
        if i % stride:
            continue
        if f.truth is None:
            raise ValueError(f'{path}: frame at {f.stamp_ns} ns has no ground truth '
                             '(/cad60/skeleton)')
        yield Sample(color=f.color, depth_m=f.depth_m, joints_uv=f.truth.uv,
                     visible=f.truth.confidence > 0, names=f.truth.names, mask=f.mask,
                     intrinsics=f.intrinsics, key=f'{path}@{f.stamp_ns}',
                     extra={'stamp_ns': f.stamp_ns})
