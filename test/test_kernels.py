"""The one-pass kernels that replaced chains of numpy operations on whole images give the same
bytes as the numpy expressions they replaced (written out here as the statement of each rule),
on the values at the edges of each rule: no reading (0, NaN, inf), beyond range, halfway
millimetres, both float precisions and non-contiguous views."""

from __future__ import annotations

import numpy as np
import pytest

from pose4d_ros.core import boost
from pose4d_ros.core.camera import (
    MAX_DEPTH_M,
    cad60_intrinsics,
    depth_to_metres,
    depth_to_millimetres,
)
from pose4d_ros.core.foreground import floor
from pose4d_ros.core.foreground.regions import DEFAULT, depth_to_levels
from pose4d_ros.core.hog import depth_image

K = cad60_intrinsics()


def _depths() -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    d = rng.uniform(-1.0, 25.0, (K.height, K.width))
    d[rng.random(d.shape) < 0.1] = np.nan
    d[0, :12] = [np.nan, np.inf, -np.inf, 1e300, -0.0, 0.0, MAX_DEPTH_M,
                 np.nextafter(MAX_DEPTH_M, 30.0), 0.0005, 0.0015, 0.0025, 70.0]
    d[1] = (np.arange(K.width) + 0.5) / 1000.0  # halfway between millimetres
    with np.errstate(over='ignore'):
        f32 = d.astype(np.float32)
    return [d, f32, d[:, ::2], f32.T.copy().T]


def _metres(depth: np.ndarray) -> np.ndarray:
    if depth.dtype == np.uint16:
        out = depth.astype(np.float32) * np.float32(0.001)
    else:
        with np.errstate(over='ignore'):
            out = depth.astype(np.float32, copy=True)
    out[~((out > 0) & (out <= MAX_DEPTH_M))] = np.nan
    return out


def test_depth_to_metres_is_its_rule() -> None:
    mm = np.random.default_rng(6).integers(0, 65536, (K.height, K.width)).astype(np.uint16)
    mm[0, :4] = [0, 1, 20000, 20001]
    for depth in [mm, mm[::2], *_depths()]:
        assert depth_to_metres(depth).tobytes() == _metres(depth).tobytes()


def test_depth_to_millimetres_is_its_rule() -> None:
    for depth in [*_depths(), np.full((3, 4, 2), np.nan, np.float32)]:
        d = np.asarray(depth, np.float64)
        with np.errstate(invalid='ignore'):
            expect = np.clip(np.where(np.isfinite(d) & (d > 0), np.rint(d * 1000.0), 0.0),
                             0, 65535).astype(np.uint16)
        got = depth_to_millimetres(depth)
        assert got.shape == expect.shape and got.tobytes() == expect.tobytes()
    # and back: every millimetre survives the round trip through metres
    mm = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    assert (depth_to_millimetres(depth_to_metres(mm)) == np.where(
        mm <= MAX_DEPTH_M * 1000, mm, 0)).all()


@pytest.mark.parametrize('with_drop', [False, True])
def test_depth_to_levels_is_its_rule(with_drop: bool) -> None:
    drop = np.random.default_rng(7).random((K.height, K.width)) < 0.3
    for depth in _depths():
        dr = drop[:, :depth.shape[1]] if with_drop else None
        scale = np.float32(254.0 / (DEFAULT.depth_far_m - DEFAULT.depth_near_m))
        with np.errstate(invalid='ignore', over='ignore'):
            g = np.float32(255.5) - (depth - np.float32(DEFAULT.depth_near_m)) * scale
            valid = (g >= 1.0) & (g < 256.0)
            if dr is not None:
                valid &= ~dr
            expect = np.where(valid, g, 0).astype(np.uint8)
        assert depth_to_levels(depth, drop=dr).tobytes() == expect.tobytes()


def test_floor_height_is_its_rule() -> None:
    rng = np.random.default_rng(8)
    rx, ry = floor._rays(K)
    for depth in _depths()[:2]:
        for _ in range(5):
            n = rng.normal(size=4).astype(np.float32)
            with np.errstate(invalid='ignore', over='ignore'):
                expect = depth * (n[0] * rx + n[1] * ry + n[2]) + n[3]
                got = floor.floor_height(depth, K, n)
            assert got.dtype == expect.dtype and got.tobytes() == expect.tobytes()


def test_depth_image_float_is_its_rule() -> None:
    for depth in _depths():
        with np.errstate(invalid='ignore', over='ignore'):
            d = np.asarray(depth, np.float32)
            expect = np.where(np.isfinite(d) & (d > 0), np.minimum(d, np.float32(4.5)),
                              np.float32(4.5)).astype(np.float32)
            got = depth_image(depth, far_m=4.5)
        assert got.tobytes() == expect.tobytes()


def test_tree_ensembles_predict_as_their_branches_say() -> None:
    """The branch-free walk down the trees: right when x >= threshold, missing values left."""
    rng = np.random.default_rng(9)
    n_trees, depth = 7, 3
    n_nodes = 2 ** depth - 1
    feature = rng.integers(0, 4, (2, n_trees, n_nodes)).astype(np.int16)
    threshold = rng.normal(size=(2, n_trees, n_nodes)).astype(np.float32)
    leaf = rng.normal(size=(2, n_trees, n_nodes + 1)).astype(np.float32)
    base = np.array([0.5, -1.0])
    x = rng.normal(size=(50, 4)).astype(np.float32)
    x[rng.random(x.shape) < 0.2] = np.nan
    ensemble = rng.integers(-1, 2, 50)
    expect = np.zeros(50)
    for i in range(50):
        e = ensemble[i]
        if e < 0:
            continue
        s = base[e]
        for t in range(n_trees):
            k = 0
            while k < n_nodes:
                k = 2 * k + 2 if x[i, feature[e, t, k]] >= threshold[e, t, k] else 2 * k + 1
            s += leaf[e, t, k - n_nodes]
        expect[i] = s
    got = boost.predict_kernel(x, ensemble, base, feature, threshold, leaf)
    assert got.tobytes() == expect.tobytes()


def test_kernels_refuse_images_of_another_size() -> None:
    """What numpy's broadcasting refused, the loops refuse too (instead of reading past an
    array)."""
    depth = np.ones((K.height, K.width), np.float32)
    with pytest.raises(ValueError, match='intrinsics'):
        floor.floor_height(depth[:, :-1], K, np.array([0, -1, 0, 1.0]))
    with pytest.raises(ValueError, match='drop'):
        depth_to_levels(depth, drop=np.zeros((K.height, K.width - 1), bool))
