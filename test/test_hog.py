"""Felzenszwalb HOG (core.hog) against a plain numpy transcription of features.cc."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.core import hog as H

UU = np.array([1.0000, 0.9397, 0.7660, 0.500, 0.1736, -0.1736, -0.5000, -0.7660, -0.9397])
VV = np.array([0.0000, 0.3420, 0.6428, 0.8660, 0.9848, 0.9848, 0.8660, 0.6428, 0.3420])


def reference_hog(im: np.ndarray, sbin: int) -> np.ndarray:
    """voc-release's features.cc written out with numpy (float64), one step at a time."""
    im = np.asarray(im, np.float64)
    if im.ndim == 2:
        im = im[:, :, None]
    h, w, _ = im.shape
    bh, bw = int(np.floor(h / sbin + 0.5)), int(np.floor(w / sbin + 0.5))  # C round()
    hist = np.zeros((bh, bw, 18))
    ys, xs = np.mgrid[1:bh * sbin - 1, 1:bw * sbin - 1]
    yy, xx = np.minimum(ys, h - 2), np.minimum(xs, w - 2)
    gy = im[yy + 1, xx] - im[yy - 1, xx]          # (n, m, C)
    gx = im[yy, xx + 1] - im[yy, xx - 1]
    mag2 = gx ** 2 + gy ** 2
    best = np.argmax(mag2, axis=2)[..., None]       # strongest channel (first on ties)
    dx = np.take_along_axis(gx, best, 2)[..., 0]
    dy = np.take_along_axis(gy, best, 2)[..., 0]
    v = np.sqrt(np.take_along_axis(mag2, best, 2)[..., 0])
    dots = UU[None, None] * dx[..., None] + VV[None, None] * dy[..., None]   # (n, m, 9)
    # features.cc scans o = 0..8 keeping strict improvements of |dot|, sign picking o or o + 9
    o = np.zeros(dx.shape, int)
    bestdot = np.zeros(dx.shape)
    for k in range(9):
        pos = dots[..., k] > bestdot
        bestdot = np.where(pos, dots[..., k], bestdot)
        o = np.where(pos, k, o)
        neg = ~pos & (-dots[..., k] > bestdot)
        bestdot = np.where(neg, -dots[..., k], bestdot)
        o = np.where(neg, k + 9, o)
    xp = (xs + 0.5) / sbin - 0.5
    yp = (ys + 0.5) / sbin - 0.5
    ixp, iyp = np.floor(xp).astype(int), np.floor(yp).astype(int)
    vx0, vy0 = xp - ixp, yp - iyp
    for cy, cx, wt in ((iyp, ixp, (1 - vx0) * (1 - vy0)), (iyp, ixp + 1, vx0 * (1 - vy0)),
                       (iyp + 1, ixp, (1 - vx0) * vy0), (iyp + 1, ixp + 1, vx0 * vy0)):
        ok = (cy >= 0) & (cx >= 0) & (cy < bh) & (cx < bw)
        np.add.at(hist, (cy[ok], cx[ok], o[ok]), (wt * v)[ok])
    norm = ((hist[:, :, :9] + hist[:, :, 9:]) ** 2).sum(2)
    oh, ow = max(bh - 2, 0), max(bw - 2, 0)
    feat = np.zeros((oh, ow, 32))
    for y in range(oh):
        for x in range(ow):
            ns = [1 / np.sqrt(norm[y + a:y + a + 2, x + b:x + b + 2].sum() + 1e-4)
                  for a, b in ((1, 1), (0, 1), (1, 0), (0, 0))]
            c = hist[y + 1, x + 1]
            hs = [np.minimum(c * n, 0.2) for n in ns]
            feat[y, x, :18] = 0.5 * sum(hs)
            cc = c[:9] + c[9:]
            feat[y, x, 18:27] = 0.5 * sum(np.minimum(cc * n, 0.2) for n in ns)
            feat[y, x, 27:31] = [0.2357 * t.sum() for t in hs]
    return feat


@pytest.mark.parametrize(('shape', 'sbin'), [((37, 45, 3), 4), ((29, 23, 3), 5), ((40, 33), 6),
                                             ((24, 32, 3), 8)])
def test_hog_matches_numpy_reference(shape: tuple[int, ...], sbin: int) -> None:
    rng = np.random.default_rng(0)
    im = rng.integers(0, 256, shape).astype(np.uint8)
    im = np.ascontiguousarray(im)
    got = H.hog(im, sbin)
    want = reference_hog(im, sbin)
    cells = [int(n / sbin + 0.5) - 2 for n in shape[:2]]   # C's round(), as features.cc
    assert got.shape == want.shape == (*cells, 32)
    assert got.dtype == np.float32
    assert_allclose(got, want, atol=2e-5)  # float32 vs float64 accumulation


def test_hog_of_a_smooth_image_matches_reference() -> None:
    # a smooth ramp plus a disc: few orientations, real normalisation effects
    yy, xx = np.mgrid[0:48, 0:40]
    im = (2.0 * xx + 0.5 * yy + 80.0 * ((yy - 24) ** 2 + (xx - 20) ** 2 < 100)).astype(np.float32)
    assert_allclose(H.hog(im, 4), reference_hog(im, 4), atol=2e-5)


def test_flat_image_gives_flat_features_and_32_dims() -> None:
    feat = H.hog(np.full((40, 48, 3), 77, np.uint8), 4)
    assert feat.shape == (8, 10, H.N_FEATURES) and H.N_FEATURES == 32
    assert_array_equal(feat, 0.0)  # no gradient: no orientation, no energy, truncation 0


def test_pure_vertical_edge_votes_the_horizontal_gradient_bin() -> None:
    im = np.zeros((40, 40), np.float32)
    im[:, 20:] = 100.0   # gradient along +x: orientation 0 (contrast-sensitive), 0 (insensitive)
    f = H.hog(im, 4)
    cells = f[:, (20 // 4) - 1 - 1:(20 // 4)]     # the cells covering columns 16..23
    assert cells[..., 0].max() > 0.1
    assert_allclose(cells[..., 1:9].max(), 0.0)
    assert_allclose(cells[..., 10:18].max(), 0.0)
    assert cells[..., 18].max() > 0.1


def test_tiny_images_give_empty_maps_and_nan_is_refused() -> None:
    assert H.hog(np.zeros((2, 2)), 4).shape == (0, 0, 32)
    assert H.hog(np.zeros((9, 30)), 4).shape[0] == 0
    with pytest.raises(ValueError, match='NaN'):
        H.hog(np.full((16, 16), np.nan, np.float32), 4)
    with pytest.raises(ValueError, match='sbin'):
        H.hog(np.zeros((16, 16)), 1)


def test_pad_features_marks_truncation_only_in_the_padding() -> None:
    rng = np.random.default_rng(0)
    feat = rng.random((3, 4, 64)).astype(np.float32)
    out = H.pad_features(feat, 2, 1)
    assert out.shape == (7, 6, 64)
    assert_array_equal(out[2:5, 1:5], feat)
    border = np.ones((7, 6), bool)
    border[2:5, 1:5] = False
    assert_array_equal(out[border][:, [31, 63]], 1.0)       # both channel groups
    assert_array_equal(np.delete(out[border], [31, 63], axis=1), 0.0)


def test_depth_image_encodings() -> None:
    d = np.array([[1.0, np.nan, 0.0, 9.0]], np.float32)
    assert_allclose(H.depth_image(d, 'float', far_m=4.5), [[1.0, 4.5, 4.5, 4.5]])
    assert_allclose(H.depth_image(d, 'u8', near_m=0.5, far_m=4.5),
                    [[np.rint(0.5 * 255 / 4.0), 0.0, 0.0, 255.0]])
    with pytest.raises(ValueError, match='encoding'):
        H.depth_image(d, 'png')


@pytest.mark.parametrize('scale', [0.5, 0.73, 1.0, 1.6])
def test_cell_pixel_mapping_round_trips(scale: float) -> None:
    level = H.Level(np.zeros((30, 30, 32), np.float32), scale, (3, 2), (17, 5), 4)
    rows, cols = np.arange(0, 20), np.arange(3, 23)
    u, v = level.cell_to_pixel(rows, cols, (5, 5))
    r2, c2 = level.pixel_to_cell(u, v, (5, 5))
    assert_array_equal(r2, rows)
    assert_array_equal(c2, cols)
    # one cell is sbin level pixels = sbin / scale image pixels
    assert_allclose(np.diff(u), 4 / scale)


def test_feature_pyramid_stacks_colour_then_depth() -> None:
    rng = np.random.default_rng(0)
    col = rng.integers(0, 256, (60, 50, 3)).astype(np.uint8)
    dep = H.depth_image(rng.uniform(1, 3, (60, 50)).astype(np.float32))
    (lev,) = H.feature_pyramid(col, dep, [1.0], sbin=4, pad=(2, 2))
    assert lev.feat.shape == (15 - 2 + 4, 13 - 2 + 4, 64)  # 50 / 4 = 12.5 rounds up, as in C
    assert_allclose(lev.feat[2:-2, 2:-2, :32], H.hog(col, 4))
    assert_allclose(lev.feat[2:-2, 2:-2, 32:], H.hog(dep, 4))
