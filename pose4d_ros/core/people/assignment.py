"""The association's maths: a person's torso point in 3-D (`torso`) and in the image
(`torso_px`), the gated least-cost assignment (`assign`) and the squared Mahalanobis distances
it is run on."""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.linalg import _umath_linalg
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from pose4d_ros.core import joints as cj
from pose4d_ros.core.joints import JointSet

# The joints whose mean is a person's torso point, in the order they are looked for
TORSO = ('left_shoulder', 'right_shoulder', 'left_hip', 'right_hip', 'torso', 'neck')


def torso(joints: JointSet) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A person's torso point: the mean 3-D position of the located `TORSO` joints (NaN if
    none has one) and the mean of their covariances ((3,), (3, 3))."""
    rows = _torso_rows(joints.names)
    idx = rows[(joints.source[rows] != cj.MISSING)
               & np.logical_and.reduce(np.isfinite(joints.xyz[rows]), axis=1)]
    if not len(idx):
        return np.full(3, np.nan), np.zeros((3, 3))
    # np.mean's values (the sums in `TORSO` order over the count), without its Python wrapper
    return (np.add.reduce(joints.xyz[idx], axis=0) / len(idx),
            np.add.reduce(joints.covariance[idx], axis=0) / len(idx))


@functools.lru_cache(maxsize=16)
def _torso_rows(names: tuple[str, ...]) -> NDArray[np.intp]:
    """The rows of the `TORSO` joints in `names`, in `TORSO` order (read-only)."""
    rows = np.array([names.index(n) for n in TORSO if n in names], np.intp)
    rows.setflags(write=False)
    return rows


def torso_px(joints: JointSet) -> tuple[NDArray[np.float64], float]:
    """A person's torso point in the image (the mean pixel of the located `TORSO` joints, NaN
    if none) and their size in pixels (the height of their located joints' box, NaN if under
    two): the association's fallback when there is no 3-D (no camera_info yet)."""
    located = (joints.source != cj.MISSING) & np.logical_and.reduce(np.isfinite(joints.uv),
                                                                    axis=1)
    rows = _torso_rows(joints.names)
    idx = rows[located[rows]]
    if not len(idx):
        return np.full(2, np.nan), math.nan
    v = joints.uv[located, 1]
    size = float(np.maximum.reduce(v) - np.minimum.reduce(v)) if v.size >= 2 else math.nan
    # np.mean's value (the sums in `TORSO` order over the count), without its Python wrapper
    return np.add.reduce(joints.uv[idx], axis=0) / len(idx), size


def assign(cost: NDArray[np.float64], gate: float) -> list[tuple[int, int]]:
    """The pairs (row, column) of the least-cost one-to-one assignment among the pairs whose
    cost is at most `gate` (NaN = never): as many such pairs as can be, the least total cost
    among those. A pair beyond the gate never takes part: left in the sum, it could buy a
    smaller total by taking a row's or a column's pair within the gate away (three tracks, one
    far from everything: its cost to a detection of another track makes that track lose it).
    A single row and a single column are always paired when finite."""
    cost = np.asarray(cost, np.float64)
    if cost.size == 0:
        return []
    if cost.shape == (1, 1):
        return [(0, 0)] if np.isfinite(cost[0, 0]) else []
    with np.errstate(invalid='ignore'):
        inside = cost <= gate
    # every pair outside costs more than all the pairs inside together
    big = 1.0 + np.abs(cost[inside]).sum() * 2.0
    rows, cols = linear_sum_assignment(np.where(inside, cost, big))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if inside[r, c]]


_solve = _umath_linalg.solve


def yielded(confirmed: NDArray[np.float64], tentative: NDArray[np.float64], margin: float
            ) -> NDArray[np.float64]:
    """The confirmed tracks' costs (tracks x detections) with NaN (no pair) where a tentative
    track's cost for the same detection is lower by more than `margin`: a confirmed track
    whose person has left, still within the gate of someone who walked in behind them and
    started a track of their own, leaves that person's detection to that track."""
    if not tentative.size:
        return confirmed
    # NaN where no tentative track reaches a detection: no comparison holds, the cost stays
    best = np.fmin.reduce(tentative, axis=0)
    return np.where(confirmed > best + margin, np.nan, confirmed)


def span_m(joints: JointSet) -> float:
    """The largest 3-D distance between two of the skeleton's located joints, metres (0 with
    fewer than two)."""
    xyz = joints.xyz[np.logical_and.reduce(np.isfinite(joints.xyz), axis=1)]
    if len(xyz) < 2:
        return 0.0
    return float(np.sqrt(((xyz[:, None] - xyz[None]) ** 2).sum(axis=-1).max()))


def shoulders_m(joints: JointSet) -> float:
    """The 3-D distance between the skeleton's shoulders, metres (NaN without both)."""
    left, right = joints.get('left_shoulder'), joints.get('right_shoulder')
    if left is None or right is None:
        return math.nan
    return float(np.sqrt(((joints.xyz[left] - joints.xyz[right]) ** 2).sum()))


def _mahalanobis2(d: NDArray[np.float64], s: NDArray[np.float64]) -> float:
    try:
        return float(d @ np.linalg.solve(s, d))
    except np.linalg.LinAlgError:
        return math.inf


def _mahalanobis2_all(d: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    """`_mahalanobis2` of each pair of `d` (K, 3) and `s` (K, 3, 3), in one solve (the same
    LAPACK solve per pair, and np.vecdot is the dot's sum); one by one when a matrix is
    singular (inf for it)."""
    # np.linalg.solve's LAPACK call without its wrapper: NaN where it would raise
    out = np.vecdot(d, _solve(s, d[:, :, None], signature='dd->d')[:, :, 0])
    if np.logical_and.reduce(np.isfinite(out)):
        return out
    return np.array([_mahalanobis2(a, b) for a, b in zip(d, s, strict=True)])
