"""Overlay pictures: a skeleton drawn on its colour image, coloured by where joints came from."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.joints import JointSet

# RGB colours of joint sources: detected green, tracked blue, inferred orange.
SOURCE_RGB = {cj.DETECTED: (40, 220, 60), cj.TRACKED: (50, 130, 255),
              cj.INFERRED: (255, 140, 0)}


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
    ok = np.isfinite(joints.uv).all(axis=1) & (joints.source != cj.MISSING)
    pts = np.round(np.nan_to_num(joints.uv) * scale + (scale - 1) / 2).astype(int)
    for a, b in bones:
        if ok[a] and ok[b]:
            worst = max(int(joints.source[a]), int(joints.source[b]))
            cv2.line(img, tuple(pts[a]), tuple(pts[b]), SOURCE_RGB[worst], 2, cv2.LINE_AA)
    if truth_uv is not None and truth_bones:
        tp = np.asarray(truth_uv, dtype=np.float64) * scale + (scale - 1) / 2
        for a, b in bones:
            if np.isfinite(tp[[a, b]]).all():
                cv2.line(img, tuple(np.round(tp[a]).astype(int)),
                         tuple(np.round(tp[b]).astype(int)), (255, 255, 255), 1, cv2.LINE_AA)
    if truth_uv is not None:
        for u, v in np.asarray(truth_uv, dtype=np.float64):
            if np.isfinite(u) and np.isfinite(v):
                c = (int(round(u * scale)), int(round(v * scale)))
                cv2.drawMarker(img, c, (255, 255, 255), cv2.MARKER_CROSS, 6, 1)
    for i in np.flatnonzero(ok):
        cv2.circle(img, tuple(pts[i]), 4, SOURCE_RGB[int(joints.source[i])], -1, cv2.LINE_AA)
        cv2.circle(img, tuple(pts[i]), 4, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def legend(width: int, height: int = 22) -> NDArray[np.uint8]:
    """A strip naming the joint colours."""
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
    return strip
