"""Bone lengths per limb, learned per track (for the inverse kinematics of `core.kinematics`).

Robust medians of the observed bone lengths when the 14-part model sees elbows and knees;
otherwise the longest observed reach split in the default ratio; otherwise the defaults.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import LIMBS
from pose4d_ros.core.stats import median

# Default bone lengths (upper, lower), metres: medians of the Kinect v1 skeletons of UTKinect
# subjects s01-s06 (shoulder-elbow, elbow-wrist, hip-knee, knee-ankle), rounded to 5 mm.
DEFAULT_LIMB_LENGTHS_M: dict[str, tuple[float, float]] = {
    'left_arm': (0.26, 0.235), 'right_arm': (0.26, 0.235),
    'left_leg': (0.47, 0.37), 'right_leg': (0.47, 0.37),
}


class LimbLengths:
    """Bone lengths per limb, learned from a track's observations (falls back on parameters).

    - When the middle joint is observed (a 14-part detector), each bone's length is the median
      of the last `window` observations.
    - Otherwise, once `min_samples` root-end distances are seen, the total length is their
      `reach_percentile` (a limb is sometimes nearly straight) split in the defaults' ratio.
    - Otherwise the defaults.

    This object is a learner and changes as it observes (unlike the pure functions here).
    """

    def __init__(self, defaults: Mapping[str, tuple[float, float]] | None = None, *,
                 window: int = 300, min_samples: int = 15,
                 reach_percentile: float = 95.0) -> None:
        self.defaults = dict(DEFAULT_LIMB_LENGTHS_M if defaults is None else defaults)
        for limb, (a, b) in self.defaults.items():
            if limb not in LIMBS or not (a > 0 and b > 0):
                raise ValueError(f'bad default lengths {limb!r}: ({a}, {b})')
        if window < 1 or min_samples < 1 or not 0 < reach_percentile <= 100:
            raise ValueError(f'window ({window}) and min_samples ({min_samples}) must be >= 1, '
                             f'reach_percentile ({reach_percentile}) in (0, 100]')
        self.min_samples = min_samples
        self.reach_percentile = reach_percentile
        # upper and lower bone lengths, each a deque of floats (read back with np.fromiter)
        self._upper: dict[str, deque[float]] = {k: deque(maxlen=window) for k in LIMBS}
        self._lower: dict[str, deque[float]] = {k: deque(maxlen=window) for k in LIMBS}
        self._reach: dict[str, deque[float]] = {k: deque(maxlen=window) for k in LIMBS}

    def observe(self, limb: str, root: NDArray[np.floating], middle: NDArray[np.floating] | None,
                end: NDArray[np.floating]) -> None:
        """Record one frame of a limb (metres); NaN or None joints are skipped."""
        if limb not in LIMBS:
            raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
        r0, e0 = np.asarray(root, float), np.asarray(end, float)
        if middle is not None and np.isfinite(middle).all() and np.isfinite(r0).all() \
                and np.isfinite(e0).all():
            m0 = np.asarray(middle, float)
            self._upper[limb].append(float(np.linalg.norm(m0 - r0)))
            self._lower[limb].append(float(np.linalg.norm(e0 - m0)))
        if np.isfinite(r0).all() and np.isfinite(e0).all():
            self._reach[limb].append(float(np.linalg.norm(e0 - r0)))

    def observe_many(self, limb: str, roots: NDArray[np.floating],
                     middles: NDArray[np.floating] | None, ends: NDArray[np.floating]) -> None:
        """Record many frames of a limb at once: (F, 3) arrays, metres; NaN rows are skipped."""
        if limb not in LIMBS:
            raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
        r0 = np.asarray(roots, float).reshape(-1, 3)
        e0 = np.asarray(ends, float).reshape(-1, 3)
        ok = np.isfinite(r0).all(axis=1) & np.isfinite(e0).all(axis=1)
        if middles is not None:
            m0 = np.asarray(middles, float).reshape(-1, 3)
            both = ok & np.isfinite(m0).all(axis=1)
            up = np.linalg.norm(m0[both] - r0[both], axis=1)
            lo = np.linalg.norm(e0[both] - m0[both], axis=1)
            self._upper[limb].extend(up.tolist())
            self._lower[limb].extend(lo.tolist())
        self._reach[limb].extend(np.linalg.norm(e0[ok] - r0[ok], axis=1).tolist())

    def observe_skeleton(self, names: Sequence[str], points: NDArray[np.floating]) -> None:
        """Record every limb of one frame: `points` (J, 3) metres named by `names`."""
        pts = np.asarray(points, dtype=np.float64)
        index = {n: i for i, n in enumerate(names)}
        for limb, (a, m, b) in LIMBS.items():
            if a in index and b in index:
                middle = pts[index[m]] if m in index else None
                self.observe(limb, pts[index[a]], middle, pts[index[b]])

    def lengths(self, limb: str) -> tuple[float, float]:
        """(upper, lower) metres for `limb`."""
        if limb not in LIMBS:
            raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
        upper, lower = self._upper[limb], self._lower[limb]
        if len(upper) >= self.min_samples:
            # np.fromiter: converting the deque is most of the work of a median of 300
            return (median(np.fromiter(upper, float, len(upper))),
                    median(np.fromiter(lower, float, len(lower))))
        a, b = self.defaults[limb]
        reach = self._reach[limb]
        if len(reach) >= self.min_samples:
            total = float(np.percentile(np.asarray(reach), self.reach_percentile))
            return total * a / (a + b), total * b / (a + b)
        return a, b

    def as_dict(self) -> dict[str, tuple[float, float]]:
        return {limb: self.lengths(limb) for limb in LIMBS}
