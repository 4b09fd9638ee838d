"""Bone lengths per limb, learned per track (for the inverse kinematics of `core.kinematics`).

Robust medians of the observed bone lengths when the 14-part model sees elbows and knees;
otherwise the longest observed reach split in the default ratio; otherwise the defaults.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import LIMBS

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
        self.window = window
        # the last `window` upper, lower and reach lengths of each limb (rows `_UPPER + k`,
        # `_LOWER + k`, `_REACH + k` for the k-th of LIMBS), each row a ring: `_count` values
        # held, the next written at `_head`
        self._values = np.empty((3 * len(LIMBS), window))
        self._count = np.zeros(3 * len(LIMBS), np.int64)
        self._head = np.zeros(3 * len(LIMBS), np.int64)

    def _held(self, row: int) -> NDArray[np.float64]:
        """The values of a row, oldest first."""
        n, head = int(self._count[row]), int(self._head[row])
        if n < self.window:
            return self._values[row, :n].copy()
        return np.roll(self._values[row, :n], -head)

    def observe(self, limb: str, root: NDArray[np.floating], middle: NDArray[np.floating] | None,
                end: NDArray[np.floating]) -> None:
        """Record one frame of a limb (metres); NaN or None joints are skipped."""
        if limb not in LIMBS:
            raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
        nan3 = np.full(3, np.nan)
        points = np.array([np.asarray(root, float).reshape(3),
                           (nan3 if middle is None else np.asarray(middle, float)).reshape(3),
                           np.asarray(end, float).reshape(3)])
        _observe_rows(self._values, self._count, self._head, np.array([_LIMB_ROW[limb]]),
                      np.array([0]), np.array([1]), np.array([2]), points)

    def observe_many(self, limb: str, roots: NDArray[np.floating],
                     middles: NDArray[np.floating] | None, ends: NDArray[np.floating]) -> None:
        """Record many frames of a limb at once: (F, 3) arrays, metres; NaN rows are skipped."""
        if limb not in LIMBS:
            raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
        r0 = np.asarray(roots, float).reshape(-1, 3)
        e0 = np.asarray(ends, float).reshape(-1, 3)
        ok = np.isfinite(r0).all(axis=1) & np.isfinite(e0).all(axis=1)
        k = _LIMB_ROW[limb]
        if middles is not None:
            m0 = np.asarray(middles, float).reshape(-1, 3)
            both = ok & np.isfinite(m0).all(axis=1)
            self._extend(_UPPER + k, np.linalg.norm(m0[both] - r0[both], axis=1))
            self._extend(_LOWER + k, np.linalg.norm(e0[both] - m0[both], axis=1))
        self._extend(_REACH + k, np.linalg.norm(e0[ok] - r0[ok], axis=1))

    def _extend(self, row: int, values: NDArray[np.float64]) -> None:
        """Many values into a row (the last `window` of what it held and them, kept)."""
        kept = np.concatenate([self._held(row), values])[-self.window:]
        self._values[row, :len(kept)] = kept
        self._count[row] = len(kept)
        self._head[row] = len(kept) % self.window

    def observe_skeleton(self, names: Sequence[str], points: NDArray[np.floating]) -> None:
        """Record every limb of one frame: `points` (J, 3) metres named by `names`."""
        limbs, roots, middles, ends = _skeleton_rows(tuple(names))
        if len(limbs):
            _observe_rows(self._values, self._count, self._head, limbs, roots, middles, ends,
                          np.asarray(points, dtype=np.float64))

    def lengths(self, limb: str) -> tuple[float, float]:
        """(upper, lower) metres for `limb`."""
        if limb not in LIMBS:
            raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
        k = _LIMB_ROW[limb]
        if self._count[_UPPER + k] >= self.min_samples:
            up, lo = _row_medians(self._values, self._count, np.array([_UPPER + k, _LOWER + k]))
            return float(up), float(lo)
        return self._fallback(limb)

    def _fallback(self, limb: str) -> tuple[float, float]:
        """The lengths of a limb whose bones are not observed often enough."""
        a, b = self.defaults[limb]
        row = _REACH + _LIMB_ROW[limb]
        if self._count[row] >= self.min_samples:
            reach = self._values[row, :self._count[row]]
            total = float(np.percentile(reach, self.reach_percentile))
            return total * a / (a + b), total * b / (a + b)
        return a, b

    def as_dict(self) -> dict[str, tuple[float, float]]:
        """Every limb's (upper, lower), metres (the medians of all limbs in one pass)."""
        medians = _row_medians(self._values, self._count, _MEDIAN_ROWS).tolist()
        learned = (self._count[_UPPER:_UPPER + len(LIMBS)] >= self.min_samples).tolist()
        n = len(LIMBS)
        return {limb: ((medians[k], medians[n + k]) if learned[k] else self._fallback(limb))
                for k, limb in enumerate(LIMBS)}


# each limb's row in the rings of `LimbLengths`: upper bones, lower bones, reaches
_LIMB_ROW = {limb: k for k, limb in enumerate(LIMBS)}
_UPPER, _LOWER, _REACH = 0, len(LIMBS), 2 * len(LIMBS)
_MEDIAN_ROWS = np.arange(2 * len(LIMBS))


@functools.lru_cache(maxsize=16)
def _skeleton_rows(names: tuple[str, ...]) -> tuple[NDArray[np.intp], ...]:
    """The limbs `names` has the root and end of (indices into LIMBS), and the rows of their
    roots, middles (-1: none) and ends in `names`."""
    index = {n: i for i, n in enumerate(names)}
    rows = [(k, index[a], index.get(m, -1), index[b])
            for k, (a, m, b) in enumerate(LIMBS.values()) if a in index and b in index]
    out = tuple(np.array([r[j] for r in rows], np.intp) for j in range(4))
    for a in out:
        a.setflags(write=False)
    return out


@njit(cache=True)
def _observe_rows(values, count, head, limbs, roots, middles, ends, points):
    """One frame of the limbs `limbs` (indices into LIMBS) into the rings of a `LimbLengths`
    (`values`, `count`, `head`, in place): each limb's root, middle (-1: none) and end rows
    of `points` (J, 3); its bones' lengths where all three are finite, its reach where the
    root and end are (|v| as np.linalg.norm gives it: the square root of the BLAS dot)."""
    window = values.shape[1]
    n = len(count) // 3
    for j in range(len(limbs)):
        r, e = points[roots[j]], points[ends[j]]
        if not (np.isfinite(r).all() and np.isfinite(e).all()):
            continue
        if middles[j] >= 0 and np.isfinite(points[middles[j]]).all():
            m = points[middles[j]]
            _ring_append(values, count, head, limbs[j], math.sqrt(np.dot(m - r, m - r)), window)
            _ring_append(values, count, head, n + limbs[j], math.sqrt(np.dot(e - m, e - m)),
                         window)
        _ring_append(values, count, head, 2 * n + limbs[j], math.sqrt(np.dot(e - r, e - r)),
                     window)


@njit(cache=True)
def _ring_append(values, count, head, row, value, window):
    values[row, head[row]] = value
    head[row] = (head[row] + 1) % window
    count[row] = min(count[row] + 1, window)


@njit(cache=True)
def _row_medians(values: NDArray[np.float64], count: NDArray[np.int64],
                 rows: NDArray[np.int64]) -> NDArray[np.float64]:
    """The median of the first `count[r]` values of each row r of `rows` (NaN when none), as
    `core.stats.median` gives it (the middle order statistic, or the mean of the two)."""
    out = np.full(len(rows), np.nan)
    for j in range(len(rows)):
        n = count[rows[j]]
        if n == 0:
            continue
        a = np.sort(values[rows[j], :n])
        k = n // 2
        out[j] = a[k] if n % 2 else (a[k - 1] + a[k]) / 2.0
    return out
