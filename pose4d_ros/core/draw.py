"""Overlay pictures: a skeleton drawn on its colour image, coloured by where joints came from;
several people each with their bones in their track id's colour (`PERSON_RGB`, also RViz's)."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.joints import JointSet

# RGB colours of joint sources: detected green, tracked blue, inferred orange.
SOURCE_RGB = {cj.DETECTED: (40, 220, 60), cj.TRACKED: (50, 130, 255),
              cj.INFERRED: (255, 140, 0)}
# One colour per track id (cycled: `person_rgb`), 0..1: each person's bones in the overlays and
# in RViz (`nodes.convert.people_markers`).
PERSON_RGB = ((0.95, 0.6, 0.1), (0.2, 0.8, 0.9), (0.9, 0.3, 0.8), (0.95, 0.95, 0.2),
              (0.5, 0.35, 0.95), (0.3, 0.95, 0.5))


def person_rgb(track_id: int) -> tuple[float, float, float]:
    """The colour (0..1 RGB) of a track id: `PERSON_RGB`, cycled."""
    return PERSON_RGB[int(track_id) % len(PERSON_RGB)]


def _rgb8(rgb: tuple[float, float, float]) -> tuple[int, int, int]:
    return tuple(int(round(255 * c)) for c in rgb)


def draw_skeleton(rgb: NDArray[np.uint8], joints: JointSet, bones: list[tuple[int, int]], *,
                  truth_uv: NDArray[np.floating] | None = None, truth_bones: bool = False,
                  scale: int = 2) -> NDArray[np.uint8]:
    """A copy of `rgb`, enlarged `scale` times, with the skeleton drawn on it.

    Parameters
    ----------
    rgb : (H, W, 3) uint8 colour image.
    joints : the skeleton; MISSING joints are not drawn.
    bones : (a, b) index pairs into `joints`.
    truth_uv : (K, 2) ground-truth pixels drawn as small white crosses, optional.
    truth_bones : `truth_uv` is in the order of `joints`: also draw its bones, thin and white.
    """
    img = cv2.resize(np.ascontiguousarray(rgb), None, fx=scale, fy=scale,
                     interpolation=cv2.INTER_NEAREST)
    _draw_on(img, joints, bones, scale, truth_uv=truth_uv, truth_bones=truth_bones)
    return img


def draw_people(rgb: NDArray[np.uint8], people: list[JointSet], bones: list[tuple[int, int]],
                *, truths_uv: Sequence[NDArray[np.floating]] = (), scale: int = 2
                ) -> NDArray[np.uint8]:
    """A copy of `rgb`, enlarged `scale` times, with every person drawn on it: bones in the
    colour of the person's track id (`person_rgb`), joints by source, the id by the head.

    Parameters
    ----------
    rgb : (H, W, 3) uint8 colour image.
    people : the skeletons (`track_id` set); MISSING joints are not drawn.
    bones : (a, b) index pairs into each skeleton.
    truths_uv : every ground-truth person's (K, 2) pixels, drawn as small white crosses.
    """
    img = cv2.resize(np.ascontiguousarray(rgb), None, fx=scale, fy=scale,
                     interpolation=cv2.INTER_NEAREST)
    for truth in truths_uv:
        _crosses(img, truth, scale)
    for joints in people:
        colour = _rgb8(person_rgb(joints.track_id))
        _draw_on(img, joints, bones, scale, tint=colour)
        ok = np.isfinite(joints.uv).all(axis=1) & (joints.source != cj.MISSING)
        head = joints.get('head')
        top = head if head is not None and ok[head] else (
            np.flatnonzero(ok)[np.argmin(joints.uv[ok, 1])] if ok.any() else None)
        if top is not None:  # the id beside the head (else the topmost joint)
            u, v = joints.uv[top] * scale
            at = (int(u) + 8, max(int(v) - 6, 14))
            for c, w in (((0, 0, 0), 3), (colour, 1)):
                cv2.putText(img, str(int(joints.track_id)), at, cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                            c, w, cv2.LINE_AA)
    return img


def _crosses(img: NDArray[np.uint8], truth_uv: NDArray[np.floating], scale: int) -> None:
    for u, v in np.asarray(truth_uv, dtype=np.float64):
        if np.isfinite(u) and np.isfinite(v):
            c = (int(round(u * scale)), int(round(v * scale)))
            cv2.drawMarker(img, c, (255, 255, 255), cv2.MARKER_CROSS, 6, 1)


def _draw_on(img: NDArray[np.uint8], joints: JointSet, bones: list[tuple[int, int]],
             scale: int, *, truth_uv: NDArray[np.floating] | None = None,
             truth_bones: bool = False, tint: tuple[int, int, int] | None = None) -> None:
    """Into the enlarged image `img`: the bones (by joint source, or all in `tint`), the
    truth's bones (`truth_bones`) and crosses, then the joints."""
    ok = np.isfinite(joints.uv).all(axis=1) & (joints.source != cj.MISSING)
    pts = np.round(np.nan_to_num(joints.uv) * scale + (scale - 1) / 2).astype(int)
    for a, b in bones:
        if ok[a] and ok[b]:
            worst = max(int(joints.source[a]), int(joints.source[b]))
            cv2.line(img, tuple(pts[a]), tuple(pts[b]), tint or SOURCE_RGB[worst], 2,
                     cv2.LINE_AA)
    if truth_uv is not None and truth_bones:
        tp = np.asarray(truth_uv, dtype=np.float64) * scale + (scale - 1) / 2
        for a, b in bones:
            if np.isfinite(tp[[a, b]]).all():
                cv2.line(img, tuple(np.round(tp[a]).astype(int)),
                         tuple(np.round(tp[b]).astype(int)), (255, 255, 255), 1, cv2.LINE_AA)
    if truth_uv is not None:
        _crosses(img, truth_uv, scale)
    for i in np.flatnonzero(ok):
        cv2.circle(img, tuple(pts[i]), 4, SOURCE_RGB[int(joints.source[i])], -1, cv2.LINE_AA)
        cv2.circle(img, tuple(pts[i]), 4, (0, 0, 0), 1, cv2.LINE_AA)


def legend(width: int, height: int = 22, *, track_ids: tuple[int, ...] = ()
           ) -> NDArray[np.uint8]:
    """A strip naming the joint colours (and the colours of `track_ids`' bones)."""
    strip = np.full((height, width, 3), 30, np.uint8)
    x = 8
    for src, name in ((cj.DETECTED, 'detected'), (cj.TRACKED, 'tracked'),
                      (cj.INFERRED, 'inferred (IK)')):
        cv2.circle(strip, (x + 5, height // 2), 5, SOURCE_RGB[src], -1, cv2.LINE_AA)
        cv2.putText(strip, name, (x + 14, height // 2 + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (230, 230, 230), 1, cv2.LINE_AA)
        x += 30 + 9 * len(name)
    cv2.drawMarker(strip, (x + 5, height // 2), (255, 255, 255), cv2.MARKER_CROSS, 8, 1)
    cv2.putText(strip, 'ground truth', (x + 14, height // 2 + 5), cv2.FONT_HERSHEY_SIMPLEX,
                0.45, (230, 230, 230), 1, cv2.LINE_AA)
    x += 30 + 9 * len('ground truth')
    for tid in track_ids:
        cv2.line(strip, (x, height // 2), (x + 14, height // 2), _rgb8(person_rgb(tid)), 3)
        cv2.putText(strip, f'id {tid}', (x + 18, height // 2 + 5), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, (230, 230, 230), 1, cv2.LINE_AA)
        x += 30 + 9 * len(f'id {tid}')
    return strip
