"""The people of one frame as one label image (`people_labels`) and back (`people_from_labels`):
how the foreground hands several people's masks to the detector in one mono8 image."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.foreground import ForegroundResult


def people_labels(people: Sequence[ForegroundResult], shape: tuple[int, int]
                  ) -> NDArray[np.uint8]:
    """The label image of the people of one frame: person k (1 = the best) is ``256 - k``,
    background 0, so that ``labels > 0`` is everyone's mask and one person's image is the
    single-person mask (255 = person) bit for bit."""
    labels = np.zeros(shape, np.uint8)
    for k, person in reversed(list(enumerate(people[:255]))):
        labels[person.mask] = 255 - k
    return labels


def people_from_labels(labels: NDArray[np.uint8], depth_m: NDArray[np.floating] | None, *,
                       lowest: int = 1) -> list[ForegroundResult]:
    """The people of a label image (`people_labels`: each distinct value from `lowest` up one
    person, the highest first; lower values are background), their boxes and median depths
    from `depth_m` (metres, NaN = none)."""
    labels = np.ascontiguousarray(labels, np.uint8)
    # which values are there: OpenCV's histogram is a tenth of np.bincount's CPU on a frame
    counts = cv2.calcHist([labels], [0], None, [256], [0, 256]).ravel()
    first = max(lowest, 1)
    out = []
    for value in np.flatnonzero(counts[first:])[::-1] + first:
        mask = labels == value
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        z = math.nan
        if depth_m is not None:
            zs = np.asarray(depth_m)[mask]
            zs = zs[np.isfinite(zs) & (zs > 0)]
            z = float(np.median(zs)) if zs.size else math.nan
        out.append(ForegroundResult(mask=mask, box=(int(cols[0]), int(rows[0]),
                                                    int(cols[-1]) + 1, int(rows[-1]) + 1),
                                    depth_m=z, found=True))
    return out
