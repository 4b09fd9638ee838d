"""Felzenszwalb's 32-dimensional HOG cell features, on colour and on depth, and their pyramid.

The features are those of Felzenszwalb et al., "Object detection with discriminatively trained
part-based models" (PAMI 2010), as computed by voc-release's and Yang & Ramanan's `features.cc`:
per cell of `sbin` x `sbin` pixels, gradient orientations are snapped to 18 contrast-sensitive
directions and voted (bilinearly between the four nearest cells) with the gradient magnitude;
each cell histogram is normalised by the energy of the four 2x2-cell blocks around it, clipped
at 0.2, and summarised as

- 18 contrast-sensitive orientation features (the four normalisations summed, halved),
- 9 contrast-insensitive features (opposite directions pooled),
- 4 texture (energy) features (the clipped histogram summed per normalisation, x 0.2357),
- 1 truncation feature, 0 inside the image and 1 in the padding of a pyramid level.

On a colour image the gradient of the channel with the largest magnitude is used at each pixel.
Depth is a single channel; `depth_image` gives the two encodings compared in the project:
float gradients in metres (holes filled with a far value) and depth scaled to 8 bits.

Parallelism: these loops are single-threaded numba. On the project's 2-core machine the
detector's one owner of parallelism is BLAS (its GEMM, see `core.dpm.infer`); measured per-frame
HOG on a person crop takes about a millisecond, which threads would not shorten enough to pay for
fighting the GEMM over two cores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np
from numpy.typing import NDArray

N_FEATURES = 32
TRUNCATION = 31  # index of the truncation feature

_UU = np.array([1.0000, 0.9397, 0.7660, 0.500, 0.1736, -0.1736, -0.5000, -0.7660, -0.9397],
               dtype=np.float32)
_VV = np.array([0.0000, 0.3420, 0.6428, 0.8660, 0.9848, 0.9848, 0.8660, 0.6428, 0.3420],
               dtype=np.float32)
_EPS = 0.0001


@nb.njit(cache=True, fastmath=False)
def _hog_kernel(im: NDArray[np.float32], sbin: int, uu: NDArray[np.float32],
                vv: NDArray[np.float32]) -> NDArray[np.float32]:
    """Felzenszwalb's HOG of `im` in one pass (numba). One kernel of more than 100 lines:
    split into calls, its per-pixel loops would pay for them."""
    h, w, nch = im.shape
    bh = int(math.floor(h / sbin + 0.5))
    bw = int(math.floor(w / sbin + 0.5))
    hist = np.zeros((bh, bw, 18), dtype=np.float32)
    oh = max(bh - 2, 0)
    ow = max(bw - 2, 0)
    feat = np.zeros((oh, ow, 32), dtype=np.float32)
    if oh == 0 or ow == 0:
        return feat
    vis_h = bh * sbin
    vis_w = bw * sbin
    for y in range(1, vis_h - 1):
        yy = min(y, h - 2)
        yp = (y + 0.5) / sbin - 0.5
        iyp = int(math.floor(yp))
        vy0 = yp - iyp
        vy1 = 1.0 - vy0
        for x in range(1, vis_w - 1):
            xx = min(x, w - 2)
            # gradient of the channel with the largest magnitude
            best_v = -1.0
            dx = 0.0
            dy = 0.0
            for c in range(nch):
                gy = im[yy + 1, xx, c] - im[yy - 1, xx, c]
                gx = im[yy, xx + 1, c] - im[yy, xx - 1, c]
                v = gx * gx + gy * gy
                if v > best_v:
                    best_v = v
                    dx = gx
                    dy = gy
            if best_v == 0.0:
                continue  # votes nothing (blank background around a masked person)
            # snap to one of 18 orientations
            best_dot = 0.0
            best_o = 0
            for o in range(9):
                dot = uu[o] * dx + vv[o] * dy
                if dot > best_dot:
                    best_dot = dot
                    best_o = o
                elif -dot > best_dot:
                    best_dot = -dot
                    best_o = o + 9
            xp = (x + 0.5) / sbin - 0.5
            ixp = int(math.floor(xp))
            vx0 = xp - ixp
            vx1 = 1.0 - vx0
            mag = math.sqrt(best_v)
            if ixp >= 0 and iyp >= 0:
                hist[iyp, ixp, best_o] += vx1 * vy1 * mag
            if ixp + 1 < bw and iyp >= 0:
                hist[iyp, ixp + 1, best_o] += vx0 * vy1 * mag
            if ixp >= 0 and iyp + 1 < bh:
                hist[iyp + 1, ixp, best_o] += vx1 * vy0 * mag
            if ixp + 1 < bw and iyp + 1 < bh:
                hist[iyp + 1, ixp + 1, best_o] += vx0 * vy0 * mag

    norm = np.zeros((bh, bw), dtype=np.float32)
    for by in range(bh):
        for bx in range(bw):
            s = 0.0
            for o in range(9):
                t = hist[by, bx, o] + hist[by, bx, o + 9]
                s += t * t
            norm[by, bx] = s

    for y in range(oh):
        for x in range(ow):
            n1 = 1.0 / math.sqrt(norm[y + 1, x + 1] + norm[y + 1, x + 2] + norm[y + 2, x + 1]
                                 + norm[y + 2, x + 2] + _EPS)
            n2 = 1.0 / math.sqrt(norm[y, x + 1] + norm[y, x + 2] + norm[y + 1, x + 1]
                                 + norm[y + 1, x + 2] + _EPS)
            n3 = 1.0 / math.sqrt(norm[y + 1, x] + norm[y + 1, x + 1] + norm[y + 2, x]
                                 + norm[y + 2, x + 1] + _EPS)
            n4 = 1.0 / math.sqrt(norm[y, x] + norm[y, x + 1] + norm[y + 1, x]
                                 + norm[y + 1, x + 1] + _EPS)
            t1 = 0.0
            t2 = 0.0
            t3 = 0.0
            t4 = 0.0
            for o in range(18):
                s = hist[y + 1, x + 1, o]
                h1 = min(s * n1, 0.2)
                h2 = min(s * n2, 0.2)
                h3 = min(s * n3, 0.2)
                h4 = min(s * n4, 0.2)
                feat[y, x, o] = 0.5 * (h1 + h2 + h3 + h4)
                t1 += h1
                t2 += h2
                t3 += h3
                t4 += h4
            for o in range(9):
                s = hist[y + 1, x + 1, o] + hist[y + 1, x + 1, o + 9]
                h1 = min(s * n1, 0.2)
                h2 = min(s * n2, 0.2)
                h3 = min(s * n3, 0.2)
                h4 = min(s * n4, 0.2)
                feat[y, x, 18 + o] = 0.5 * (h1 + h2 + h3 + h4)
            feat[y, x, 27] = 0.2357 * t1
            feat[y, x, 28] = 0.2357 * t2
            feat[y, x, 29] = 0.2357 * t3
            feat[y, x, 30] = 0.2357 * t4
    return feat


def hog(image: NDArray, sbin: int) -> NDArray[np.float32]:
    """Felzenszwalb HOG features of an image.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array (any real dtype; uint8 colour, float32 depth metres...).
        Must be finite (fill depth holes first, see `depth_image`). Colour channel order does
        not matter (the strongest channel's gradient is used per pixel).
    sbin : cell size in pixels (>= 2).

    Returns
    -------
    (round(H/sbin) - 2, round(W/sbin) - 2, 32) float32. Cell (i, j) covers the pixel rows
    `(i+1)*sbin ... (i+2)*sbin - 1` and the matching columns (the border cells of
    `features.cc` are dropped). Empty along an axis when the image has fewer than 3 cells.
    """
    if sbin < 2:
        raise ValueError(f'sbin must be >= 2 pixels, got {sbin}')
    im = np.asarray(image)
    if im.ndim == 2:
        im = im[:, :, None]
    if im.ndim != 3:
        raise ValueError(f'image must be (H, W) or (H, W, C), got shape {np.shape(image)}')
    if im.shape[0] < 3 or im.shape[1] < 3:
        return np.zeros((0, 0, N_FEATURES), np.float32)
    im = np.ascontiguousarray(im, dtype=np.float32)
    if not np.isfinite(im).all():
        raise ValueError('image holds NaN or inf values; fill depth holes before hog()')
    return _hog_kernel(im, int(sbin), _UU, _VV)


def depth_image(depth_m: NDArray[np.floating], encoding: str = 'float', *,
                near_m: float = 0.5, far_m: float = 4.5) -> NDArray[np.float32]:
    """The single-channel image whose HOG is the depth channel's feature.

    Parameters
    ----------
    depth_m : (H, W) float metres, NaN (or <= 0) = no reading.
    encoding : 'float': metres, holes filled with `far_m` (a hole reads as far background, so a
        masked-out background gives the person's silhouette edge); 'u8': depth scaled to 8-bit
        within [near_m, far_m] and rounded, holes 0 (the usual Kinect visualisation).
    near_m, far_m : the valid range, metres.

    Returns
    -------
    (H, W) float32.
    """
    if not 0 <= near_m < far_m:
        raise ValueError(f'need 0 <= near_m < far_m, got {near_m}, {far_m}')
    d = np.asarray(depth_m, dtype=np.float32)
    if encoding == 'float':
        out = np.empty(d.shape, np.float32)
        _far_filled(np.ascontiguousarray(d).reshape(-1), np.float32(far_m), out.reshape(-1))
        return out
    valid = np.isfinite(d) & (d > 0)
    if encoding == 'u8':
        scaled = np.clip((d - near_m) * (255.0 / (far_m - near_m)), 0.0, 255.0)
        return np.where(valid, np.rint(scaled), 0.0).astype(np.float32)
    raise ValueError(f"depth encoding must be 'float' or 'u8', got {encoding!r}")


@nb.njit(cache=True)
def _far_filled(d: NDArray[np.float32], far: np.float32, out: NDArray[np.float32]) -> None:
    """`depth_image`'s 'float' encoding in one pass (numpy's took six): min(z, far), `far`
    where there is no reading."""
    for i in range(d.size):
        z = d[i]
        out[i] = min(z, far) if math.isfinite(z) and z > 0 else far


def pad_features(feat: NDArray[np.float32], pad_y: int, pad_x: int,
                 end: tuple[int, int] | None = None) -> NDArray[np.float32]:
    """Pad a feature map with cells that are all zero except the truncation feature (1).

    Parameters
    ----------
    feat : (h, w, 32 * n) float32, n channel groups of 32 (e.g. colour then depth).
    pad_y, pad_x : cells added above and to the left (and below and to the right, unless
        `end` says otherwise).
    end : (pad_y_end, pad_x_end) cells added below and to the right.

    Returns
    -------
    (h + pad_y + pad_y_end, w + pad_x + pad_x_end, 32 * n) float32.
    """
    h, w, c = feat.shape
    if c % N_FEATURES:
        raise ValueError(f'feature depth {c} is not a multiple of {N_FEATURES}')
    ey, ex = (pad_y, pad_x) if end is None else end
    if min(pad_y, pad_x, ey, ex) < 0:
        raise ValueError(f'padding must be >= 0 cells, got {(pad_y, pad_x, ey, ex)}')
    if (pad_y, pad_x, ey, ex) == (0, 0, 0, 0):
        return feat
    out = np.zeros((h + pad_y + ey, w + pad_x + ex, c), np.float32)
    out[:, :, TRUNCATION::N_FEATURES] = 1.0
    out[pad_y:pad_y + h, pad_x:pad_x + w] = feat
    return out


@dataclass(frozen=True)
class Level:
    """One level of a feature pyramid.

    Attributes
    ----------
    feat : (h, w, C) float32 padded features (C = 32 per channel group).
    scale : level pixels per source pixel (the source image was resized by this factor).
    pad : (pad_y, pad_x) cells of padding above and to the left.
    origin : (x0, y0) source pixel of the crop's top-left corner the level was computed on.
    sbin : cell size, level pixels.
    """

    feat: NDArray[np.float32]
    scale: float
    pad: tuple[int, int]
    origin: tuple[int, int]
    sbin: int
    pad_end: tuple[int, int] | None = None  # (below, right) cells; None = as `pad`

    @property
    def image_cells(self) -> tuple[int, int]:
        """(rows, cols) of cells of the image itself (without the padding)."""
        h, w = self.feat.shape[:2]
        ey, ex = self.pad if self.pad_end is None else self.pad_end
        return h - self.pad[0] - ey, w - self.pad[1] - ex

    def cell_to_pixel(self, row: NDArray, col: NDArray, size: tuple[int, int]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Source-image pixel (u, v) of the centre of a `size` = (rows, cols) cell window whose
        top-left cell is (row, col) in the padded map."""
        fh, fw = size
        py, px = self.pad
        s = self.sbin
        # unpadded cell i covers level pixels (i + 1) * sbin ... (i + 2) * sbin - 1
        # integer cells are exact in either type: no conversion call needed
        yl = (row - py + 1) * s + (fh * s - 1) / 2.0
        xl = (col - px + 1) * s + (fw * s - 1) / 2.0
        u = (xl + 0.5) / self.scale - 0.5 + self.origin[0]
        v = (yl + 0.5) / self.scale - 0.5 + self.origin[1]
        return u, v

    def pixel_to_cell(self, u: NDArray, v: NDArray, size: tuple[int, int]
                      ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Inverse of `cell_to_pixel`, rounded to the nearest cell: the (row, col) of the
        top-left cell of the `size` window centred nearest to source pixel (u, v)."""
        fh, fw = size
        py, px = self.pad
        s = self.sbin
        xl = (np.asarray(u, np.float64) - self.origin[0] + 0.5) * self.scale - 0.5
        yl = (np.asarray(v, np.float64) - self.origin[1] + 0.5) * self.scale - 0.5
        row = np.rint((yl - (fh * s - 1) / 2.0) / s - 1 + py).astype(np.int64)
        col = np.rint((xl - (fw * s - 1) / 2.0) / s - 1 + px).astype(np.int64)
        return row, col


def resize(image: NDArray, scale: float) -> NDArray:
    """Resize by `scale` (area averaging when shrinking, bilinear when growing)."""
    h, w = image.shape[:2]
    nh, nw = max(int(round(h * scale)), 1), max(int(round(w * scale)), 1)
    if (nh, nw) == (h, w):
        return image
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    return cv2.resize(image, (nw, nh), interpolation=interp)


def channel_features(color: NDArray | None, depth: NDArray[np.float32] | None, scale: float,
                     sbin: int) -> NDArray[np.float32]:
    """HOG of colour and/or a depth image (see `depth_image`) resized by `scale`, stacked.

    Returns
    -------
    (h, w, 32 * n) float32: colour features first, then depth, for the n inputs given.
    Both inputs must have the same size.
    """
    parts = []
    if color is not None:
        parts.append(hog(resize(np.ascontiguousarray(color, dtype=np.float32), scale), sbin))
    if depth is not None:
        # nearest-neighbour keeps depth edges sharp and never blends a hole's fill value
        h, w = depth.shape[:2]
        nh, nw = max(int(round(h * scale)), 1), max(int(round(w * scale)), 1)
        d = depth if (nh, nw) == (h, w) else cv2.resize(depth, (nw, nh),
                                                         interpolation=cv2.INTER_NEAREST)
        parts.append(hog(d, sbin))
    if not parts:
        raise ValueError('channel_features needs a colour image, a depth image, or both')
    if len(parts) == 1:
        return parts[0]
    return np.concatenate(parts, axis=2)


def feature_pyramid(color: NDArray | None, depth: NDArray[np.float32] | None,
                    scales: list[float] | tuple[float, ...] | NDArray, *, sbin: int,
                    pad: tuple[int, int], origin: tuple[int, int] = (0, 0),
                    pad_end: tuple[int, int] | None = None) -> list[Level]:
    """Padded feature maps of an image (crop) at several scales.

    Parameters
    ----------
    color : (H, W, 3) uint8/float colour, or None (depth only).
    depth : (H, W) float32 from `depth_image`, or None (colour only).
    scales : resize factors (level pixels per source pixel).
    sbin : cell size, pixels.
    pad : (pad_y, pad_x) cells of truncation padding above and to the left.
    pad_end : (pad_y, pad_x) below and to the right; None = `pad`.
    origin : (x0, y0) of the crop in the full image, so levels map back to full-image pixels.

    Returns
    -------
    One `Level` per scale; levels whose image has fewer than 3x3 cells hold an empty map.
    """
    levels = []
    for s in scales:
        feat = channel_features(color, depth, float(s), sbin)
        levels.append(Level(pad_features(feat, *pad, end=pad_end), float(s), pad, origin, sbin,
                            pad_end))
    return levels
