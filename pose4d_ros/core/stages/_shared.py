"""What the stages share: a JointSet checked and put in a stage's order of names, read-only
views as a node's arrays are, the largest pixel of an image, and `ndarray.any`/`all` without
their Python wrappers."""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.joints import JointSet

# `ndarray.any` and `ndarray.all` without their Python wrappers (the per-frame path)
_any = np.logical_or.reduce
_all = np.logical_and.reduce


def check_known(joints: JointSet, names: tuple[str, ...], intrinsics: Intrinsics | None
                ) -> None:
    """`joints.check_joints`, and ValueError when none of `joints` is one of `names`."""
    cj.check_joints(joints, intrinsics)
    if not set(joints.names) & set(names):
        given = ', '.join(joints.names[:4]) + (', ...' if len(joints) > 4 else '')
        raise ValueError(f'none of the {len(joints)} joints ({given or "none"}) is one of '
                         f'{", ".join(names[:3])}, ...')


def reorder(joints: JointSet, names: tuple[str, ...]) -> JointSet:
    """`joints` in the order of `names`; names it lacks are MISSING (`joints` itself when it
    is in that order already: a JointSet is immutable)."""
    if joints.names == names:
        return joints
    return JointSet.of_arrays(names, *reordered_arrays(joints, names), score=joints.score,
                              track_id=joints.track_id)


def reordered_arrays(joints: JointSet, names: tuple[str, ...]) -> tuple[NDArray, ...]:
    """New arrays (uv, xyz, confidence, source, covariance) of `joints` in the order of
    `names`, MISSING rows for names it lacks: `reorder`'s, for a stage that changes them."""
    if joints.names == names:
        return (joints.uv.copy(), joints.xyz.copy(), joints.confidence.copy(),
                joints.source.copy(), joints.covariance.copy())
    rows, found, empty = _reordering(joints.names, names)
    uv, xyz, conf, src, cov = (empty[0].copy(), empty[1].copy(), empty[2].copy(),
                               empty[3].copy(), empty[4].copy())
    uv[rows], xyz[rows], conf[rows], src[rows], cov[rows] = (
        joints.uv[found], joints.xyz[found], joints.confidence[found], joints.source[found],
        joints.covariance[found])
    return uv, xyz, conf, src, cov


@functools.lru_cache(maxsize=64)
def _reordering(given: tuple[str, ...], names: tuple[str, ...]
                ) -> tuple[NDArray[np.intp], NDArray[np.intp], tuple[NDArray, ...]]:
    """The rows of `names` that `given` has, where `given` has them, and the arrays of
    `names` all MISSING (uv, xyz, confidence, source, covariance) to fill (read-only)."""
    pairs = [(i, given.index(name)) for i, name in enumerate(names) if name in given]
    rows, found = (np.array([p[k] for p in pairs], np.intp) for k in (0, 1))
    n = len(names)
    empty = (np.full((n, 2), np.nan), np.full((n, 3), np.nan), np.zeros(n, np.float32),
             np.full(n, cj.MISSING, np.uint8), np.zeros((n, 3, 3)))
    for a in (rows, found, *empty):
        a.setflags(write=False)
    return rows, found, empty


def _read_only(a: NDArray) -> NDArray:
    """A read-only view of `a`, as an array made on a message's buffer is."""
    view = a.view()
    view.flags.writeable = False
    return view



@functools.lru_cache(maxsize=16)
def _image_max(width: int, height: int) -> NDArray[np.float64]:
    """The largest pixel (u, v) of an image of that size (read-only; cached by two ints,
    whose hash is C's, not by the intrinsics, whose dataclass hash is a Python call)."""
    hi = np.array([width - 1, height - 1], np.float64)
    hi.setflags(write=False)
    return hi
