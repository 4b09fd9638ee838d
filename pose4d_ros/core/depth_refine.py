"""Where a joint centre lies behind what the camera sees, learned from the depth around it.

A detected part is lifted to 3-D with its look-up's depth plus a constant offset behind the
surface (`PartModel.depth_lookup`, `depth_offset_m`). That constant is right for a joint whose
own surface the camera sees, and wrong by tens of centimetres for one it does not: the far
shoulder of a person turned away, an elbow behind the torso, a hip behind a hand; the look-up
then reads the body in front. `DepthRefiner` learns the rest of the correction, per part, from
what the frame shows around it: boosted regression trees (`core.boost`, absolute error) on the
depths of windows of three sizes on the body at the part's pixel (their 10th, 50th and 90th
percentiles against the lifted depth), the lifted depths of its parent, of the root and the
median of the parts', its image offset from its parent in person scales, its 3-D distance from
the parent and its confidence (`features`). Its target is the joint's true depth less the lifted
one along the same pixel's ray, so the detected pixel is kept and only the depth moves.

It is fitted on the pipeline's own detections of labelled frames (`pose4d train --refine-depth`,
`fit_refiner`), a left part and its right twin pooled (one ensemble per group, the image
offsets of right parts mirrored).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.boost import BoostedTrees, fit, predict_kernel
from pose4d_ros.core.camera import Intrinsics

# Window half-sizes on the body, metres, and the quantiles of their depths
WINDOWS_M = (0.03, 0.06, 0.12)
QUANTILES = (0.1, 0.5, 0.9)
# Largest window, pixels (as camera.MAX_LIFT_RADIUS_PX); a window of a half-size over
# WINDOW_SAMPLES pixels reads every second pixel (every third beyond twice that, ...)
MAX_WINDOW_PX = 20
WINDOW_SAMPLES = 6
# Metres of body per person scale (the part models' scale_length_m)
SCALE_M = 0.5
N_FEATURES = len(WINDOWS_M) * len(QUANTILES) + 8
_WINDOWS, _QUANTILES = np.array(WINDOWS_M), np.array(QUANTILES)
_NO_MASK = np.zeros((0, 0), np.bool_)
# Largest correction learned or applied, metres
MAX_CORRECTION_M = 0.4


@nb.njit(cache=True)
def _features(depth: NDArray[np.float32], mask: NDArray[np.bool_], uv: NDArray[np.float64],
              z: NDArray[np.float64], confidence: NDArray[np.float64], up: NDArray[np.int64],
              root: int, mirror: NDArray[np.bool_], windows_m: NDArray[np.float64],
              quantiles: NDArray[np.float64], fx: float, fy: float, cx: float, cy: float
              ) -> NDArray[np.float32]:
    """The body of `features` (same arguments, `up` the parent of each part, the root its
    own)."""
    h, w = depth.shape
    n_p = len(z)
    n_w, n_q = len(windows_m), len(quantiles)
    reps = n_w * n_q
    out = np.full((n_p, reps + 8), np.nan, np.float32)
    known = np.isfinite(z) & (z > 0) & np.isfinite(uv[:, 0]) & np.isfinite(uv[:, 1])
    if not known.any():
        return out
    z_person = np.median(z[known])
    scale = fx * SCALE_M / z_person
    buf = np.empty((2 * WINDOW_SAMPLES + 1) ** 2, np.float32)
    for p in range(n_p):
        if not known[p]:
            continue
        c, r = int(np.rint(uv[p, 0])), int(np.rint(uv[p, 1]))
        for k in range(n_w):
            rad = min(max(int(np.rint(windows_m[k] * fx / z[p])), 1), MAX_WINDOW_PX)
            step = (rad + WINDOW_SAMPLES - 1) // WINDOW_SAMPLES
            n = 0
            for y in range(max(r - rad, 0), min(r + rad + 1, h), step):
                for x in range(max(c - rad, 0), min(c + rad + 1, w), step):
                    d = depth[y, x]
                    if d == d and d > 0 and (mask.size == 0 or mask[y, x]):
                        buf[n] = d
                        n += 1
            if n == 0:
                continue
            v = np.sort(buf[:n])
            for j in range(n_q):
                pos = quantiles[j] * (n - 1)
                lo = int(pos)
                hi = min(lo + 1, n - 1)
                out[p, k * n_q + j] = v[lo] + (pos - lo) * (v[hi] - v[lo]) - z[p]
        q = up[p]
        du = (uv[p, 0] - uv[q, 0]) / scale
        out[p, reps] = z[p]
        out[p, reps + 1] = z[q] - z[p]
        out[p, reps + 2] = z[root] - z[p]
        out[p, reps + 3] = z_person - z[p]
        out[p, reps + 4] = -du if mirror[p] else du
        out[p, reps + 5] = (uv[p, 1] - uv[q, 1]) / scale
        dx = (uv[p, 0] - cx) / fx * z[p] - (uv[q, 0] - cx) / fx * z[q]
        dy = (uv[p, 1] - cy) / fy * z[p] - (uv[q, 1] - cy) / fy * z[q]
        out[p, reps + 6] = np.sqrt(dx * dx + dy * dy + (z[p] - z[q]) ** 2)
        out[p, reps + 7] = confidence[p]
    return out


def group_of(name: str) -> str:
    """'left_wrist' and 'right_wrist' -> 'wrist'."""
    return name.removeprefix('left_').removeprefix('right_')


def features(names: Sequence[str], parents: Sequence[int], uv: NDArray[np.floating],
             z: NDArray[np.floating], confidence: NDArray[np.floating],
             depth_m: NDArray[np.floating], intrinsics: Intrinsics,
             mask: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
    """(P, `N_FEATURES`) float32 features of each part (NaN where unknown; a part without a
    lifted depth has NaN everywhere).

    `uv` (P, 2) pixels, `z` (P,) lifted depths, metres, `confidence` (P,), `parents` the part
    tree's (-1 for the root), `depth_m` the frame's depth (metres, NaN = no reading) and `mask`
    the person's pixels.
    """
    depth = np.asarray(depth_m, np.float32)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f'depth image {depth.shape[::-1]} is not the camera\'s '
                         f'{intrinsics.width}x{intrinsics.height}')
    if mask is not None and np.shape(mask) != depth.shape:
        raise ValueError(f'mask {np.shape(mask)} and depth {depth.shape} differ in shape')
    par = np.asarray(parents, np.int64)
    k = intrinsics
    return _features(depth, _NO_MASK if mask is None else np.asarray(mask, np.bool_),
                     np.asarray(uv, np.float64), np.asarray(z, np.float64),
                     np.asarray(confidence, np.float64),
                     np.where(par >= 0, par, np.arange(len(par))), int(np.argmin(par)),
                     _mirrored(tuple(names)), _WINDOWS, _QUANTILES, k.fx, k.fy, k.cx, k.cy)


@functools.lru_cache(maxsize=16)
def _mirrored(names: tuple[str, ...]) -> NDArray[np.bool_]:
    return np.array([n.startswith('right_') for n in names])


@dataclass(frozen=True)
class DepthRefiner:
    """One ensemble of boosted trees (`core.boost`) per group of parts (`group_of`), stacked.

    Attributes
    ----------
    groups : G group names ('wrist', ...).
    base : (G,) float32 each ensemble's starting value.
    feature, threshold : (G, T, N) int16 and float32, the trees' nodes.
    leaf : (G, T, N + 1) float32 their leaves.
    """

    groups: tuple[str, ...]
    base: NDArray[np.float32]
    feature: NDArray[np.int16]
    threshold: NDArray[np.float32]
    leaf: NDArray[np.float32]

    def __post_init__(self) -> None:
        g = len(self.groups)
        if len(set(self.groups)) != g or self.base.shape != (g,) or self.feature.ndim != 3 or \
                self.feature.shape[0] != g or self.threshold.shape != self.feature.shape or \
                self.leaf.shape != (*self.feature.shape[:2], self.feature.shape[2] + 1):
            raise ValueError(f'depth refiner: inconsistent arrays for groups {self.groups}: '
                             f'base {self.base.shape}, feature {self.feature.shape}, threshold '
                             f'{self.threshold.shape}, leaf {self.leaf.shape}')
        if self.feature.size and not (0 <= self.feature.min() and
                                      self.feature.max() < N_FEATURES):
            raise ValueError(f'depth refiner: feature indices outside 0..{N_FEATURES - 1}')
        if not (np.isfinite(self.base).all() and np.isfinite(self.leaf).all()):
            raise ValueError('depth refiner: values must be finite')

    @classmethod
    def stack(cls, groups: Sequence[str], trees: Sequence[BoostedTrees]) -> DepthRefiner:
        """One refiner of ensembles of one shape, one per group."""
        return cls(tuple(groups), np.array([t.base for t in trees], np.float32),
                   np.stack([t.feature for t in trees]), np.stack([t.threshold for t in trees]),
                   np.stack([t.leaf for t in trees]))

    def correction(self, names: Sequence[str], x: NDArray[np.floating]) -> NDArray[np.float64]:
        """(P,) metres to add to the lifted depths of parts `names` with features `x` (P, F);
        0 for a part whose group has no ensemble or whose features are unknown."""
        x = np.asarray(x, np.float32)
        ensemble = np.where(np.isfinite(x[:, 0]), _ensembles(self.groups, tuple(names)), -1)
        if x.shape != (len(names), N_FEATURES):
            raise ValueError(f'features must be ({len(names)}, {N_FEATURES}), got {x.shape}')
        # the arrays were checked when the refiner was made: straight to the kernel
        out = predict_kernel(np.ascontiguousarray(x), ensemble, self.base.astype(np.float64),
                             self.feature, self.threshold, self.leaf)
        return np.clip(out, -MAX_CORRECTION_M, MAX_CORRECTION_M)

    def arrays(self) -> dict[str, NDArray]:
        """The refiner as named arrays (for `core.dpm.model.save_model`)."""
        return {'groups': np.array(self.groups), 'base': self.base, 'feature': self.feature,
                'threshold': self.threshold, 'leaf': self.leaf}

    @classmethod
    def from_arrays(cls, a: dict[str, NDArray]) -> DepthRefiner:
        """Inverse of `arrays`; ValueError for inconsistent or out-of-range arrays."""
        return cls(tuple(str(g) for g in a['groups']), np.asarray(a['base'], np.float32),
                   np.asarray(a['feature'], np.int16), np.asarray(a['threshold'], np.float32),
                   np.asarray(a['leaf'], np.float32))


@functools.lru_cache(maxsize=16)
def _ensembles(groups: tuple[str, ...], names: tuple[str, ...]) -> NDArray[np.int64]:
    """The index in `groups` of each part's group (-1: none)."""
    index = {g: i for i, g in enumerate(groups)}
    return np.array([index.get(group_of(n), -1) for n in names], np.int64)


def fit_refiner(names: Sequence[str], x: NDArray[np.floating], part: NDArray[np.integer],
                target: NDArray[np.floating], *, trees: int = 200, depth: int = 5,
                min_samples: int = 200) -> DepthRefiner:
    """Fit one ensemble per group of `names` on samples `x` (N, F) of parts `part` (N,) (indices
    into `names`) with `target` (N,) = true depth less lifted depth, metres (clipped to
    +-`MAX_CORRECTION_M`). Groups with fewer than `min_samples` samples get none."""
    x = np.asarray(x, np.float64)
    part = np.asarray(part)
    target = np.clip(np.asarray(target, np.float64), -MAX_CORRECTION_M, MAX_CORRECTION_M)
    ok = np.isfinite(x[:, 0]) & np.isfinite(target)
    groups, ensembles = [], []
    for g in dict.fromkeys(group_of(n) for n in names):
        sel = ok & np.isin(part, [i for i, n in enumerate(names) if group_of(n) == g])
        if sel.sum() >= min_samples:
            groups.append(g)
            ensembles.append(fit(x[sel], target[sel], trees=trees, depth=depth))
    if not groups:
        raise ValueError(f'too few samples to fit a depth refiner ({int(ok.sum())})')
    return DepthRefiner.stack(groups, ensembles)
