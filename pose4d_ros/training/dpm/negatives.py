"""The negatives of hard-negative mining (`training.dpm.mining`): background images without a
person, from the training frames themselves. The strips of each frame away from the person, and
for sets with person masks (synthetic) the room itself, assembled from the frames where the
person is elsewhere. A frame is a `datasets.frame.Frame` (colour, depth, mask, video, truth).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from pose4d_ros.training.dpm.samples import (
    Negative,
    TrainConfig,
    background_crops,
    part_joints,
    person_scale,
)


def room_backgrounds(samples: list, *, dilate_px: int = 5) -> list[Negative]:
    """The room behind the person, per video of a masked (synthetic) set: every pixel from the
    latest frame in which the (dilated) person mask leaves it free; pixels the person never
    leaves are cut off by keeping the widest free band of columns on either side."""
    import cv2

    by_video: dict[str, list] = defaultdict(list)
    for s in samples:
        if s.mask is not None and s.depth_m is not None:
            by_video[s.video or s.key].append(s)
    kernel = np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8)
    out = []
    for vid, ss in by_video.items():
        h, w = ss[0].color.shape[:2]
        col = np.zeros((h, w, 3), np.uint8)
        dep = np.full((h, w), np.nan, np.float32)
        free = np.zeros((h, w), bool)
        for s in ss:
            busy = cv2.dilate(s.mask.astype(np.uint8), kernel) > 0
            ok = ~busy
            col[ok] = s.color[ok]
            dep[ok] = s.depth_m[ok]
            free |= ok
        if free.all():
            out.append(Negative(col, dep, f'{vid} (room)'))
            continue
        cols_free = free.all(axis=0)
        # widest run of fully free columns
        best, start, run0 = (0, 0), None, 0
        for x in range(w + 1):
            if x < w and cols_free[x]:
                if start is None:
                    start = x
            elif start is not None:
                if x - start > best[1] - best[0]:
                    best = (start, x)
                start = None
        run0 = best[1] - best[0]
        if run0 >= w // 4:
            x0, x1 = best
            out.append(Negative(np.ascontiguousarray(col[:, x0:x1]),
                                np.ascontiguousarray(dep[:, x0:x1]), f'{vid} (room)'))
    return out


def build_negatives(samples: list, cfg: TrainConfig, max_images: int, seed: int,
                    extra: list | None = None) -> list[Negative]:
    """Background images for mining: room plates (masked sets, and the `extra` frames, which
    serve as backgrounds only) + strips beside the person."""
    negs = room_backgrounds(samples)
    if extra:
        rooms = room_backgrounds(extra)
        if not rooms:
            raise ValueError(f'--background: no room could be assembled from {len(extra)} '
                             'frames (a synthetic set with person masks and depth is needed)')
        negs += rooms
    strips: list[Negative] = []
    for s in samples:
        uv, _ = part_joints(s, cfg.tree.names)
        sc = person_scale(s, cfg.tree.names, cfg, uv)
        if np.isfinite(sc):
            strips.extend(background_crops(s, sc))
    rng = np.random.default_rng(seed)
    room = max(max_images - len(negs), 0)
    if len(strips) > room:
        strips = [strips[i] for i in np.sort(rng.choice(len(strips), room, replace=False))]
    if cfg.channels == 'rgb':
        negs = [Negative(n.color, None, n.key) for n in negs]
        strips = [Negative(n.color, None, n.key) for n in strips]
    return negs + strips
