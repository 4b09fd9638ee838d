"""`pose4d eval --draw DIR`: every frame drawn with each row's skeleton and the ground truth,
and a grid of each row's worst and best frames (what a user looks at first).

    DIR/<row>/<frame number>_<PCK>.jpg   one picture per frame (PCK@0.1 of the frame, %)
    DIR/<row>_worst_best.jpg             top: the worst frames, bottom: the best

A frame's PCK is the share of its scored joints (those `score_rows` scores) within 0.1 of the
ground truth's box size, the table's rule. The prediction is drawn by joint source
(`core.draw`), the ground truth as thin white bones with crosses.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.draw import draw_people, draw_skeleton, legend
from pose4d_ros.core.files import write_atomic
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import pck_per_frame
from pose4d_ros.core.skeleton import SKELETON_14, limb_bones
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.evaluation.pipeline import Row, row_arrays

TILE = 240  # grid tile side, pixels


def frame_pck(name: str, row: Row, frames: Sequence[Frame], alpha: float = 0.1
              ) -> NDArray[np.float64]:
    """(F,) PCK@alpha of each frame in percent over its scored joints; NaN where none is."""
    _, arrays = row_arrays(name, row, frames)
    return pck_per_frame(arrays['pred'], arrays['gt'], arrays['visible'], alpha=alpha)


def _on_skeleton(joints: JointSet) -> JointSet:
    """The joints in `SKELETON_14` order (names it lacks missing), for `limb_bones`."""
    full = JointSet.missing(SKELETON_14)
    idx = [i for i, n in enumerate(SKELETON_14) if n in joints.names]
    src = [joints.index(SKELETON_14[i]) for i in idx]
    uv, source = full.uv.copy(), full.source.copy()
    uv[idx], source[idx] = joints.uv[src], joints.source[src]
    return full.with_(uv=uv, source=source)


def picture(frame: Frame, pred: JointSet, pck: float, scale: int = 2) -> NDArray[np.uint8]:
    """One frame (RGB, `scale` times enlarged): the prediction, the ground truth, its PCK."""
    truth, _, labelled = frame.truth.labelled(SKELETON_14)
    truth = np.where(labelled[:, None], truth, np.nan)
    img = draw_skeleton(frame.color, _on_skeleton(pred), limb_bones(), truth_uv=truth,
                        truth_bones=True, scale=scale)
    text = f'PCK {pck:.0f}' if np.isfinite(pck) else 'PCK -'
    for colour, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(img, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, width,
                    cv2.LINE_AA)
    return img


def _tile(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    h, w = img.shape[:2]
    f = TILE / max(h, w)
    small = cv2.resize(img, (max(int(w * f), 1), max(int(h * f), 1)),
                       interpolation=cv2.INTER_AREA)
    out = np.full((TILE, TILE, 3), 20, np.uint8)
    out[:small.shape[0], :small.shape[1]] = small
    return out


def _jpeg(img_rgb: NDArray[np.uint8]) -> bytes:
    ok, buf = cv2.imencode('.jpg', np.ascontiguousarray(img_rgb[:, :, ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise ValueError(f'could not encode a picture of shape {img_rgb.shape}')
    return buf.tobytes()


def _file_name(i: int, frame: Frame, pck: float) -> str:
    stem = re.sub(r'[^A-Za-z0-9._-]+', '_', Path(frame.key).stem)[-40:] if frame.key else ''
    tag = f'{pck:03.0f}' if np.isfinite(pck) else 'nan'
    return f'{i:05d}_{stem}_pck{tag}.jpg' if stem else f'{i:05d}_pck{tag}.jpg'


def draw_rows(rows: dict[str, Row], frames: Sequence[Frame], out_dir: Path, *,
              grid: int = 8) -> list[Path]:
    """Write every row's pictures and its worst/best grid (`grid` frames each) under
    `out_dir`; returns the grids' paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, row in rows.items():
        pck = frame_pck(name, row, frames)
        row_dir = out_dir / name
        row_dir.mkdir(exist_ok=True)
        for i, (frame, pred) in enumerate(zip(frames, row.preds, strict=True)):
            write_atomic(row_dir / _file_name(i, frame, pck[i]),
                         _jpeg(picture(frame, pred, pck[i])))
        scored = np.flatnonzero(np.isfinite(pck))
        if scored.size == 0:
            continue
        order = scored[np.argsort(pck[scored], kind='stable')]
        n = min(grid, len(order))
        lines = [order[:n], order[::-1][:n]]
        grid_img = np.vstack([np.hstack([_tile(picture(frames[i], row.preds[i], pck[i]))
                                         for i in line]) for line in lines])
        path = out_dir / f'{name}_worst_best.jpg'
        write_atomic(path, _jpeg(grid_img))
        written.append(path)
    return written


def overlay_frame(frame: Frame, skeleton: JointSet, latency_ms: float | None,
                  people: tuple[JointSet, ...] | None = None) -> np.ndarray:
    """One video frame (RGB): the skeleton by joint source on the frame, the ground truth
    crossed, the frame's latency from camera to /pose4d/skeleton, and the legend. `people`
    (every person's skeleton of a several-person run): each drawn with its bones in its track
    id's colour (`core.draw.draw_people`), every ground-truth person crossed."""
    img = _overlay(frame, skeleton, people)
    text = f'latency {latency_ms:.0f} ms' if latency_ms is not None else 'latency unknown'
    for colour, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(img, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, width,
                    cv2.LINE_AA)
    ids = tuple(sorted({int(p.track_id) for p in people or ()}))
    return np.vstack([img, legend(img.shape[1], track_ids=ids)])


def _overlay(frame: Frame, skeleton: JointSet, people: tuple[JointSet, ...] | None
             ) -> np.ndarray:
    if people is None:
        return draw_skeleton(frame.color, skeleton, limb_bones(), truth_uv=frame.truth.uv)
    truths = [t.uv for t in frame.people] or [frame.truth.uv]
    return draw_people(frame.color, list(people), limb_bones(), truths_uv=truths)


def write_video(path: Path, frames: Iterable[np.ndarray], *, fps: float) -> int:
    """RGB frames of one size into an MPEG-4 video (OpenCV's `mp4v`, which OpenCV, ffmpeg and
    common players read), written under a temporary name and renamed when complete; returns
    the number of frames. `fps` that is not finite and positive becomes 30."""
    fps = fps if np.isfinite(fps) and fps > 0 else 30.0
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'.{path.stem}.{os.getpid()}.tmp{path.suffix}')
    writer, n = None, 0
    try:
        for img in frames:
            if writer is None:
                h, w = img.shape[:2]
                writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*'mp4v'), fps, (w, h))
                if not writer.isOpened():
                    raise OSError(f'{path}: OpenCV cannot write an mp4v video here')
            writer.write(np.ascontiguousarray(img[:, :, ::-1]))
            n += 1
        if writer is None:
            raise ValueError(f'{path}: no frames to write')
        writer.release()
        os.replace(tmp, path)
    finally:
        if writer is not None:
            writer.release()
        tmp.unlink(missing_ok=True)
    return n


def overlay_picture(frames: list[Frame], skeletons: list[JointSet], n: int = 4,
                    people: list[tuple[JointSet, ...]] | None = None) -> np.ndarray:
    """n frames spread over the bag, skeletons drawn by joint source, ground truth crossed
    (`people`: every person's skeletons of each frame, bones in their ids' colours)."""
    shown = np.linspace(0, len(frames) - 1, n).astype(int)
    row = np.hstack([_overlay(frames[i], skeletons[i], None if people is None else people[i])
                     for i in shown])
    ids = tuple(sorted({int(p.track_id) for i in shown for p in (people[i] if people else ())}))
    return np.vstack([row, legend(row.shape[1], track_ids=ids)])
