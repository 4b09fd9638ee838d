"""Training the 4D-DPM part model (Yang & Ramanan, PAMI 2013, section 5; 4D-DPM eq. (5)).

1. Positives: every labelled frame (and its mirror image, left and right swapped) is brought to
   the model's canonical scale (the person scale, from depth or from the joints, see
   `person_scale`), and each part is placed on the HOG cell grid. A model with `masked_input`
   sees frames blanked outside the person's foreground mask, as the foreground stage
   publishes them.
2. Part types: k-means on each part's offset from its parent in canonical pixels (for the root,
   on the offsets of its children); a type's anchor is its cluster's mean cell offset.
3. Per-part templates: linear discriminant analysis on HOG ("whitened HOG", Hariharan, Malik &
   Ramanan, ECCV 2012): w = Sigma^-1 (mu_part - mu_background), mu and Sigma of random windows;
   this gives the first model w0.
4. The joint structural SVM (eq. (5); Yang & Ramanan eq. (6)),

       min_w 1/2 |w - w0|^2 + C sum_n xi_n
       s.t.  w . Phi(I_n, z_n) >= 1 - xi_n                      labelled poses (positives)
             w . Phi(I, z) <= -1 + xi                           any pose in a background image
             w . Phi(I_n, z_n) - w . Phi(I_n, z) >= D(z_n, z) - xi    any other pose in a
                                                                labelled frame (margin rescaling)
             w_dx2, w_dy2 >= spring_lb                          (springs stay concave)

   Features Phi are the stacked filter windows (whitened: x' = L^-1 (x - mu0), which makes the
   QP well conditioned and puts the LDA prior in the regulariser), the spring features
   -[dx, dx^2, dy, dy^2] and the type (co-occurrence) indicators. D(z_n, z) is 2/P per part
   farther than the PCK radius (alpha * the ground-truth joints' box size) from its label: the
   third kind of constraint teaches the model the mistakes it makes on people (a wrist put on
   the other wrist, on the torso), which background images alone cannot, and it is the only
   kind left when the frames are masked. The QP is solved in the dual by coordinate descent
   (one dual variable at a time, as Yang & Ramanan's solver and Hsieh et al., ICML 2008), the
   lower bounds being hard constraints with unbounded dual variables. The exponentially many
   constraints are handled by mining: the current model runs over the background images (poses
   scoring above -1) and, with the loss added to each part's score map (exact loss-augmented
   inference, the loss decomposes over parts), over the labelled frames; violated constraints
   join a bounded cache from which easy ones are dropped; a few rounds of mine-and-solve.
5. Calibration: per part, a logistic map from (part score, pose score) to the probability that
   the part is within the PCK@0.1 radius, fitted on detections of training frames.

Everything is deterministic for a given seed. Progress is reported through the optional
`progress` (an iterable wrapper such as tqdm) and `log` callables; this module never prints.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics
from pose4d_ros.core.dpm.infer import (
    Detector,
    LevelResult,
    SearchPlan,
    backtrack,
    best_roots,
    model_arrays,
    score_level,
    tree_dp,
)
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.hog import N_FEATURES, Level, depth_image, feature_pyramid
from pose4d_ros.core.skeleton import GROUND_TRUTH_ALIASES, PART_TREES, PartTree

Progress = Callable[[Iterable, str, int | None], Iterable]
Log = Callable[[str], None]


@dataclass(frozen=True)
class TrainConfig:
    """Training settings (defaults as shipped; see pose4d_ros/models/README.md).

    Attributes
    ----------
    parts : '10' (the paper's reduced model) or '14'.
    channels : 'rgbd' (colour + depth filter per type) or 'rgb'.
    n_types : mixture types per part (K).
    sbin : HOG cell, pixels; filter_cells : filter side, cells.
    canonical_scale_px : person scale at the model's level, pixels.
    scale_length_m : metres of body per person scale (depth -> scale).
    depth_encoding, depth_range_m : the depth image of the depth HOG (`core.hog.depth_image`).
    masked_input : train (and detect) on frames blanked outside the person's mask.
    flip : add mirrored positives.
    svm_c : C of eq. (5) (per constraint; the whitened windows have unit variance per dim).
    positive_weight : C of the labelled poses' constraints is svm_c times this (the
        background constraints outnumber them many times on real photographs).
    bias_feature : value of the type-indicator features (a larger value regularises the
        biases less).
    spring_lb : lower bound of the quadratic spring weights.
    mining_rounds : rounds of mine-and-solve.
    background_negatives : mine poses in background images (Yang & Ramanan's negatives).
    negatives_per_image : most background poses taken per image and round.
    structural_per_positive : most wrong poses taken per labelled frame and round.
    loss_alpha : a part is wrong when farther than loss_alpha * the labelled joints' box size.
    cache_limit : most cached negative constraints.
    qp_epochs, qp_tol : coordinate-descent epochs at most, and the relative duality gap at
        which a round's QP stops.
    lda_lambda : ridge of the background covariance, relative to its mean variance.
    calibration_samples : frames used to fit the confidence calibration.
    levels_per_octave : pyramid density when mining background images.
    seed : everything random is drawn from it.
    """

    parts: str = '10'
    channels: str = 'rgbd'
    n_types: int = 6
    sbin: int = 4
    filter_cells: int = 5
    canonical_scale_px: float = 32.0
    scale_length_m: float = 0.5
    depth_encoding: str = 'float'
    depth_range_m: tuple[float, float] = (0.5, 4.5)
    masked_input: bool = False
    flip: bool = True
    svm_c: float = 3e-4
    positive_weight: float = 1.0
    bias_feature: float = 1.0
    spring_lb: float = 0.01
    mining_rounds: int = 8
    background_negatives: bool = True
    negatives_per_image: int = 6
    structural_per_positive: int = 4
    loss_alpha: float = 0.1
    cache_limit: int = 20000
    qp_epochs: int = 300
    qp_tol: float = 0.01
    lda_lambda: float = 0.1
    calibration_samples: int = 300
    levels_per_octave: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        if self.parts not in PART_TREES:
            raise ValueError(f'parts must be one of {sorted(PART_TREES)}, got {self.parts!r}')
        if self.channels not in ('rgb', 'rgbd'):
            raise ValueError(f"channels must be 'rgb' or 'rgbd', got {self.channels!r}")
        if not 1 <= self.n_types <= 16:
            raise ValueError(f'n_types must be in 1..16, got {self.n_types}')
        if not 2 <= self.sbin <= 16 or not 2 <= self.filter_cells <= 12:
            raise ValueError(f'bad sbin {self.sbin} or filter_cells {self.filter_cells}')
        if not self.svm_c > 0:
            raise ValueError(f'svm_c must be > 0, got {self.svm_c}')
        if self.mining_rounds < 0:
            raise ValueError(f'mining_rounds must be >= 0, got {self.mining_rounds}')

    @property
    def tree(self) -> PartTree:
        return PART_TREES[self.parts]


# --------------------------------------------------------------------------- samples & scale

_LEFT_RIGHT = (('left_', 'right_'), ('right_', 'left_'))


def mirror_name(name: str) -> str:
    """'left_wrist' <-> 'right_wrist'; other names unchanged."""
    for a, b in _LEFT_RIGHT:
        if name.startswith(a):
            return b + name[len(a):]
    return name


def part_joints(sample, names: Sequence[str]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(P, 2) pixels and (P,) labelled flags of the model's parts in a sample, looking a part up
    under its ground-truth alias when the sample lacks it ('left_wrist' -> 'left_hand')."""
    uv = np.full((len(names), 2), np.nan)
    vis = np.zeros(len(names), bool)
    for i, n in enumerate(names):
        for cand in (n, GROUND_TRUTH_ALIASES.get(n)):
            if cand is not None and cand in sample.names:
                j = sample.names.index(cand)
                uv[i] = sample.joints_uv[j]
                vis[i] = bool(sample.visible[j]) and bool(np.isfinite(uv[i]).all())
                break
    return uv, vis


def joint_scale(uv: NDArray, names: Sequence[str]) -> float:
    """Person scale from 2-D joints: the longer of the two shoulder-to-hip segments (the torso
    side nearer to its true length; about 0.5 m of an adult). NaN when neither is labelled."""
    best = np.nan
    for side in ('left_', 'right_'):
        a, b = side + 'shoulder', side + 'hip'
        if a in names and b in names:
            d = float(np.hypot(*(np.asarray(uv[names.index(a)]) - uv[names.index(b)])))
            if np.isfinite(d) and not d <= best:
                best = d
    return best


def person_depth(depth_m: NDArray, mask: NDArray[np.bool_] | None, uv: NDArray) -> float:
    """Median depth of the person: over the mask when there is one, else over small windows at
    the labelled joints. NaN when there is no reading."""
    d = np.asarray(depth_m)
    if mask is not None and mask.any():
        vals = d[mask]
    else:
        h, w = d.shape
        vals_l = []
        for u, v in np.asarray(uv).reshape(-1, 2):
            if np.isfinite(u) and np.isfinite(v):
                c, r = int(round(u)), int(round(v))
                vals_l.append(d[max(r - 2, 0):min(r + 3, h), max(c - 2, 0):min(c + 3, w)].ravel())
        vals = np.concatenate(vals_l) if vals_l else np.zeros(0, np.float32)
    vals = vals[np.isfinite(vals) & (vals > 0)]
    return float(np.median(vals)) if vals.size else float('nan')


def person_scale(sample, names: Sequence[str], cfg: TrainConfig, uv: NDArray | None = None
                 ) -> float:
    """The person scale in image pixels: fx * scale_length_m / z from depth when the sample
    has it (as the detector predicts it at run time from the foreground mask's median depth),
    else from the joints (`joint_scale`)."""
    if uv is None:
        uv, _ = part_joints(sample, names)
    if sample.depth_m is not None:
        z = person_depth(sample.depth_m, sample.mask, uv)
        if np.isfinite(z):
            h, w = sample.depth_m.shape
            k: Intrinsics = sample.intrinsics or cad60_intrinsics(w, h)
            return k.fx * cfg.scale_length_m / z
    all_uv = np.asarray(sample.joints_uv, np.float64)
    return joint_scale(all_uv, list(sample.names))


@dataclass
class _Positive:
    patches: NDArray[np.float32]   # (P, D) raw filter windows at the labelled cells
    cells: NDArray[np.int64]       # (P, 2) row, col in the padded level
    offsets: NDArray[np.float64]   # (P, 2) (du, dv) from the parent, canonical pixels
    scale: float                   # person scale, image pixels
    level_scale: float             # level pixels per image pixel
    box: tuple[int, int, int, int]  # crop, image pixels
    tau: float                     # PCK radius of the loss, cells
    sample: int                    # index into the samples
    flipped: bool


def _crop_box(uv: NDArray, margin: float, w: int, h: int) -> tuple[int, int, int, int]:
    x0 = max(int(np.floor(np.nanmin(uv[:, 0]) - margin)), 0)
    y0 = max(int(np.floor(np.nanmin(uv[:, 1]) - margin)), 0)
    x1 = min(int(np.ceil(np.nanmax(uv[:, 0]) + margin)) + 1, w)
    y1 = min(int(np.ceil(np.nanmax(uv[:, 1]) + margin)) + 1, h)
    return x0, y0, x1, y1


def _level_of(color: NDArray, depth_m: NDArray | None, mask: NDArray[np.bool_] | None,
              box: tuple[int, int, int, int], scale: float, cfg: TrainConfig) -> Level:
    """The padded HOG level of a crop, made exactly as `Detector.pyramid` makes it."""
    x0, y0, x1, y1 = box
    col = color[y0:y1, x0:x1]
    blank = cfg.masked_input and mask is not None
    if blank:
        col = np.where(mask[y0:y1, x0:x1][:, :, None], col, np.zeros((), col.dtype))
    dep = None
    if cfg.channels == 'rgbd':
        dcrop = (np.full(col.shape[:2], np.nan, np.float32) if depth_m is None
                 else np.asarray(depth_m, np.float32)[y0:y1, x0:x1])
        if blank:
            dcrop = np.where(mask[y0:y1, x0:x1], dcrop, np.float32(np.nan))
        dep = depth_image(dcrop, cfg.depth_encoding, near_m=cfg.depth_range_m[0],
                          far_m=cfg.depth_range_m[1])
    pad = (cfg.filter_cells // 2 + 1, cfg.filter_cells // 2 + 1)
    return feature_pyramid(col, dep, [scale], sbin=cfg.sbin, pad=pad, origin=(x0, y0))[0]


def _flip(color: NDArray, depth_m: NDArray | None, mask: NDArray | None, uv: NDArray,
          names: Sequence[str]) -> tuple[NDArray, NDArray | None, NDArray | None, NDArray]:
    """Mirror image: columns reversed, u -> W-1-u, left and right parts swapped."""
    w = color.shape[1]
    col = np.ascontiguousarray(color[:, ::-1])
    dep = None if depth_m is None else np.ascontiguousarray(depth_m[:, ::-1])
    msk = None if mask is None else np.ascontiguousarray(mask[:, ::-1])
    idx = [list(names).index(mirror_name(n)) for n in names]
    fuv = uv[idx].copy()
    fuv[:, 0] = w - 1 - fuv[:, 0]
    return col, dep, msk, fuv


def _frame(sample, names: Sequence[str], cfg: TrainConfig, flipped: bool) -> tuple:
    """(colour, depth or None, mask or None, (P, 2) part pixels) of a sample, mirrored if
    asked."""
    uv, _ = part_joints(sample, names)
    depth = sample.depth_m if cfg.channels == 'rgbd' else None
    if flipped:
        return _flip(sample.color, depth, sample.mask, uv, names)
    return sample.color, depth, sample.mask, uv


def _prepare_positive(sample, index: int, flipped: bool, s: float, tree: PartTree,
                      cfg: TrainConfig) -> _Positive | None:
    color, depth, mask, uv = _frame(sample, tree.names, cfg, flipped)
    h, w = color.shape[:2]
    f = cfg.canonical_scale_px / s
    box = _crop_box(uv, 1.0 * s, w, h)
    level = _level_of(color, depth, mask, box, f, cfg)
    fs = (cfg.filter_cells, cfg.filter_cells)
    rows, cols = level.pixel_to_cell(uv[:, 0], uv[:, 1], fs)
    hh, ww, _ = level.feat.shape
    if (rows < 0).any() or (cols < 0).any() or (rows > hh - fs[0]).any() or (
            cols > ww - fs[1]).any():
        return None
    patches = np.stack([level.feat[r:r + fs[0], c:c + fs[1]].reshape(-1)
                        for r, c in zip(rows, cols, strict=True)])
    par = np.asarray(tree.parents)
    offs = np.zeros((len(tree), 2))
    offs[1:] = (uv[1:] - uv[par[1:]]) * f
    size = float(np.max(np.ptp(uv, axis=0)))
    tau = cfg.loss_alpha * size * f / cfg.sbin
    return _Positive(patches.astype(np.float32), np.stack([rows, cols], 1), offs, s, f, box,
                     tau, index, flipped)


# --------------------------------------------------------------------------- k-means


def kmeans(x: NDArray[np.float64], k: int, rng: np.random.Generator, *, iters: int = 50,
           restarts: int = 4) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Lloyd's k-means with k-means++ seeding; the best of `restarts` (lowest inertia).

    Returns
    -------
    centres : (k, d); labels : (n,) (every cluster non-empty when n >= k).
    """
    x = np.asarray(x, np.float64)
    n = len(x)
    k = min(k, n)
    best: tuple[float, NDArray, NDArray] | None = None
    for _ in range(restarts):
        centres = [x[rng.integers(n)]]
        for _ in range(1, k):
            d2 = np.min(((x[:, None, :] - np.array(centres)[None]) ** 2).sum(2), axis=1)
            p = d2 / d2.sum() if d2.sum() > 0 else np.full(n, 1.0 / n)
            centres.append(x[rng.choice(n, p=p)])
        c = np.array(centres)
        labels = np.full(n, -1, np.int64)
        for _ in range(iters):
            d2 = ((x[:, None, :] - c[None]) ** 2).sum(2)
            new = d2.argmin(1)
            for j in range(k):
                if not (new == j).any():  # re-seed an empty cluster with the worst-fit point
                    far = int(d2[np.arange(n), new].argmax())
                    new[far] = j
            if (new == labels).all():
                break
            labels = new
            c = np.array([x[labels == j].mean(0) for j in range(k)])
        inertia = float(((x - c[labels]) ** 2).sum())
        if best is None or inertia < best[0]:
            best = (inertia, c, labels)
    assert best is not None
    return best[1], best[2]


# --------------------------------------------------------------------------- examples


@dataclass(frozen=True)
class _Layout:
    """Where each parameter sits in the QP's weight vector."""

    n_parts: int
    n_types: int
    dim: int

    @property
    def n_filter(self) -> int:
        return self.n_parts * self.n_types * self.dim

    @property
    def n_spring(self) -> int:
        return self.n_parts * self.n_types * 4

    @property
    def size(self) -> int:
        return self.n_filter + self.n_spring + self.n_parts * self.n_types * self.n_types

    def filter_off(self, part: int, typ: int) -> int:
        return (part * self.n_types + typ) * self.dim

    def spring_off(self, part: int, typ: int) -> int:
        return self.n_filter + (part * self.n_types + typ) * 4

    def bias_off(self, part: int, ptype: int, typ: int) -> int:
        return (self.n_filter + self.n_spring
                + (part * self.n_types + ptype) * self.n_types + typ)


class _Examples:
    """The QP's constraints y_i w . x_i >= m_i - xi_i, stored by blocks.

    Each example owns, per part, a filter block (D floats at offset `of`), a spring block (4
    floats at `od`, -1 for the root) and a type indicator (1 float at `ob`). A structural
    constraint Phi(z_n) - Phi(z) stores -Phi(z) as its own blocks and refers (`ref`) to the
    positive example holding Phi(z_n); other examples have ref = -1. Positives come first and
    are never dropped, so references stay valid when the cache is compacted.
    """

    def __init__(self, capacity: int, n_parts: int, dim: int) -> None:
        self.n = 0
        self.xf = np.zeros((capacity, n_parts, dim), np.float32)
        self.of = np.zeros((capacity, n_parts), np.int64)
        self.xd = np.zeros((capacity, n_parts, 4), np.float32)
        self.od = np.full((capacity, n_parts), -1, np.int64)
        self.xb = np.zeros((capacity, n_parts), np.float32)
        self.ob = np.zeros((capacity, n_parts), np.int64)
        self.y = np.zeros(capacity)
        self.m = np.zeros(capacity)
        self.ref = np.full(capacity, -1, np.int64)
        self.alpha = np.zeros(capacity)
        self.keys: list[tuple] = []

    @property
    def capacity(self) -> int:
        return len(self.y)

    def add(self, blocks: tuple, label: float, margin: float, ref: int, key: tuple) -> bool:
        if self.n >= self.capacity:
            return False
        i = self.n
        self.xf[i], self.of[i], self.xd[i], self.od[i], self.xb[i], self.ob[i] = blocks
        self.y[i], self.m[i], self.ref[i], self.alpha[i] = label, margin, ref, 0.0
        self.keys.append(key)
        self.n += 1
        return True

    def keep(self, idx: NDArray[np.int64]) -> None:
        """Keep only examples `idx` (sorted, all positives included), compacting the arrays."""
        k = len(idx)
        for a in (self.xf, self.of, self.xd, self.od, self.xb, self.ob, self.y, self.m,
                  self.ref, self.alpha):
            a[:k] = a[idx]
        self.keys = [self.keys[i] for i in idx]
        self.n = k

    def arrays(self) -> tuple:
        n = self.n
        return (self.xf[:n], self.of[:n], self.xd[:n], self.od[:n], self.xb[:n], self.ob[:n],
                self.y[:n], self.m[:n], self.ref[:n])


def _pose_blocks(feat: NDArray[np.float32], parts: NDArray[np.int64], parents: NDArray,
                 anchors: NDArray, lay: _Layout, fs: int, bias_feature: float,
                 patches: NDArray[np.float32] | None = None) -> tuple:
    """The block feature vector Phi of a pose ((type, row, col) per part) on a padded level
    (or from windows already cut, `patches`); filter blocks raw (not whitened)."""
    p_n = lay.n_parts
    xf = np.empty((p_n, lay.dim), np.float32)
    of = np.empty(p_n, np.int64)
    xd = np.zeros((p_n, 4), np.float32)
    od = np.full(p_n, -1, np.int64)
    xb = np.full(p_n, bias_feature, np.float32)
    ob = np.empty(p_n, np.int64)
    for c in range(p_n):
        t, r, q = (int(v) for v in parts[c])
        xf[c] = feat[r:r + fs, q:q + fs].reshape(-1) if patches is None else patches[c]
        of[c] = lay.filter_off(c, t)
        if c == 0:
            ob[c] = lay.bias_off(0, 0, t)
            continue
        pt, pr, pq = (int(v) for v in parts[parents[c]])
        dx = q - pq - int(anchors[c, t, 0])
        dy = r - pr - int(anchors[c, t, 1])
        xd[c] = (-dx, -dx * dx, -dy, -dy * dy)
        od[c] = lay.spring_off(c, t)
        ob[c] = lay.bias_off(c, pt, t)
    return xf, of, xd, od, xb, ob


# --------------------------------------------------------------------------- the QP


@nb.njit(cache=True)
def _own_dot(w, xf, of, xd, od, xb, ob, i):
    s = 0.0
    p_n, dim = xf.shape[1], xf.shape[2]
    for c in range(p_n):
        o = of[i, c]
        for d in range(dim):
            s += xf[i, c, d] * w[o + d]
        o = od[i, c]
        if o >= 0:
            for d in range(4):
                s += xd[i, c, d] * w[o + d]
        s += xb[i, c] * w[ob[i, c]]
    return s


@nb.njit(cache=True)
def _own_axpy(w, a, xf, of, xd, od, xb, ob, i):
    p_n, dim = xf.shape[1], xf.shape[2]
    for c in range(p_n):
        o = of[i, c]
        for d in range(dim):
            w[o + d] += a * xf[i, c, d]
        o = od[i, c]
        if o >= 0:
            for d in range(4):
                w[o + d] += a * xd[i, c, d]
        w[ob[i, c]] += a * xb[i, c]


@nb.njit(cache=True)
def _cross(xf, of, xd, od, xb, ob, i, j):
    """x_i . x_j of two examples' own blocks (part c's blocks can only meet part c's)."""
    s = 0.0
    p_n, dim = xf.shape[1], xf.shape[2]
    for c in range(p_n):
        if of[i, c] == of[j, c]:
            for d in range(dim):
                s += xf[i, c, d] * xf[j, c, d]
        if od[i, c] >= 0 and od[i, c] == od[j, c]:
            for d in range(4):
                s += xd[i, c, d] * xd[j, c, d]
        if ob[i, c] == ob[j, c]:
            s += xb[i, c] * xb[j, c]
    return s


@nb.njit(cache=True)
def _dot(w, xf, of, xd, od, xb, ob, ref, i):
    s = _own_dot(w, xf, of, xd, od, xb, ob, i)
    if ref[i] >= 0:
        s += _own_dot(w, xf, of, xd, od, xb, ob, ref[i])
    return s


@nb.njit(cache=True)
def _dcd(w, xf, of, xd, od, xb, ob, y, m, ref, alpha, cost, lb_idx, lb_val, beta, epochs,
         seed):
    """Dual coordinate descent for the constraints y_i w.x_i >= m_i - xi_i (0 <= a_i <= C_i) and
    the hard lower bounds w_k >= lb (b_k >= 0). `w` must equal w0 + sum_i a_i y_i x_i +
    sum_k b_k e_k on entry (warm start); it is kept so. Returns the largest projected gradient
    of the last epoch."""
    n = y.shape[0]
    np.random.seed(seed)  # noqa: NPY002  (numba's generator: seeded, deterministic)
    q = np.empty(n)
    for i in range(n):
        v = _cross(xf, of, xd, od, xb, ob, i, i)
        r = ref[i]
        if r >= 0:
            v += _cross(xf, of, xd, od, xb, ob, r, r) + 2.0 * _cross(xf, of, xd, od, xb, ob, i, r)
        q[i] = max(v, 1e-12)
    order = np.arange(n)
    maxpg = 0.0
    for _ in range(epochs):
        np.random.shuffle(order)  # noqa: NPY002
        maxpg = 0.0
        for i in order:
            g = y[i] * _dot(w, xf, of, xd, od, xb, ob, ref, i) - m[i]
            a = alpha[i]
            pg = g
            if a <= 0.0:
                pg = min(g, 0.0)
            elif a >= cost[i]:
                pg = max(g, 0.0)
            if abs(pg) > maxpg:
                maxpg = abs(pg)
            if abs(pg) > 1e-12:
                na = min(max(a - g / q[i], 0.0), cost[i])
                if na != a:
                    step = (na - a) * y[i]
                    _own_axpy(w, step, xf, of, xd, od, xb, ob, i)
                    if ref[i] >= 0:
                        _own_axpy(w, step, xf, of, xd, od, xb, ob, ref[i])
                    alpha[i] = na
        for j in range(lb_idx.shape[0]):
            k = lb_idx[j]
            g = w[k] - lb_val[j]
            nb_ = max(beta[j] - g, 0.0)
            w[k] += nb_ - beta[j]
            beta[j] = nb_
    return maxpg


@nb.njit(cache=True)
def _margins(w, xf, of, xd, od, xb, ob, y, ref):
    """y_i w . x_i for every example."""
    n = y.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = y[i] * _dot(w, xf, of, xd, od, xb, ob, ref, i)
    return out


# --------------------------------------------------------------------------- negatives


@dataclass(frozen=True)
class Negative:
    """A background image (no person): colour, depth (rgbd) and a name for messages."""

    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32] | None
    key: str = ''


def background_crops(sample, scale: float, *, min_size: float = 2.0, margin: float = 0.6
                     ) -> list[Negative]:
    """Background of a labelled frame: the strips left/right/above/below the person.

    The person is the mask's box when the sample has a mask, else the joints' box, grown by
    `margin` person scales; a strip is kept when both sides are at least `min_size` scales.
    """
    h, w = sample.color.shape[:2]
    if sample.mask is not None and sample.mask.any():
        rows = np.flatnonzero(sample.mask.any(1))
        cols = np.flatnonzero(sample.mask.any(0))
        box = np.array([cols[0], rows[0], cols[-1] + 1, rows[-1] + 1], float)
    else:
        uv = np.asarray(sample.joints_uv)[np.asarray(sample.visible, bool)]
        uv = uv[np.isfinite(uv).all(1)]
        if len(uv) == 0:
            return []
        box = np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
    mg = margin * scale
    x0, y0 = int(max(box[0] - mg, 0)), int(max(box[1] - mg, 0))
    x1, y1 = int(min(box[2] + mg, w)), int(min(box[3] + mg, h))
    strips = [(0, 0, x0, h), (x1, 0, w, h), (0, 0, w, y0), (0, y1, w, h)]
    out = []
    for sx0, sy0, sx1, sy1 in strips:
        if sx1 - sx0 >= min_size * scale and sy1 - sy0 >= min_size * scale:
            dep = None if sample.depth_m is None else sample.depth_m[sy0:sy1, sx0:sx1]
            out.append(Negative(np.ascontiguousarray(sample.color[sy0:sy1, sx0:sx1]),
                                None if dep is None else np.ascontiguousarray(dep),
                                f'{sample.key}[{sx0}:{sx1},{sy0}:{sy1}]'))
    return out


# --------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class _Whitening:
    """x' = W (x - mu0) with W = L^-1, L L^T = the covariance of random windows (+ ridge):
    the QP works on whitened HOG windows (Hariharan, Malik & Ramanan 2012), whose dimensions are
    decorrelated and of unit variance. That makes dual coordinate descent converge (raw HOG
    windows are strongly correlated) and puts the LDA templates' prior into the regulariser."""

    mean: NDArray[np.float64]        # (D,)
    transform: NDArray[np.float64]   # (D, D) W = L^-1
    chol: NDArray[np.float64]        # (D, D) L

    def __call__(self, x: NDArray) -> NDArray[np.float32]:
        return ((np.asarray(x, np.float64) - self.mean) @ self.transform.T).astype(np.float32)


def _whitened(blocks: tuple, white: _Whitening, sign: float = 1.0) -> tuple:
    xf, of, xd, od, xb, ob = blocks
    return (sign * white(xf), of, sign * xd, od, sign * xb, ob)


def _model_from_w(w: NDArray[np.float64], lay: _Layout, tree: PartTree, cfg: TrainConfig,
                  anchors: NDArray[np.int32], scale_range: tuple[float, float],
                  white: _Whitening) -> PartModel:
    """The model of a QP solution: filters on raw windows are w_raw = W^T w', and
    w_raw . mu0 moves into the type biases."""
    fs = cfg.filter_cells
    c = lay.dim // (fs * fs)
    wf = w[:lay.n_filter].reshape(lay.n_parts, lay.n_types, lay.dim) @ white.transform
    shift = wf @ white.mean                              # (P, K)
    filters = wf.reshape(lay.n_parts, lay.n_types, fs, fs, c)
    springs = w[lay.n_filter:lay.n_filter + lay.n_spring].reshape(lay.n_parts, lay.n_types, 4)
    springs = springs.copy()
    springs[0] = 0.0
    springs[1:, :, 1] = np.maximum(springs[1:, :, 1], cfg.spring_lb)
    springs[1:, :, 3] = np.maximum(springs[1:, :, 3], cfg.spring_lb)
    bias = w[lay.n_filter + lay.n_spring:].reshape(lay.n_parts, lay.n_types, lay.n_types)
    bias = bias * cfg.bias_feature - shift[:, None, :]
    bias[0, 1:] = 0.0
    return PartModel(
        part_names=tree.names, parents=tree.parents, channels=cfg.channels, sbin=cfg.sbin,
        filters=filters.astype(np.float32), springs=springs.astype(np.float32),
        anchors=anchors.astype(np.int32), bias=bias.astype(np.float32),
        canonical_scale_px=cfg.canonical_scale_px, scale_length_m=cfg.scale_length_m,
        scale_range_px=scale_range,
        depth_encoding=cfg.depth_encoding if cfg.channels == 'rgbd' else '',
        depth_range_m=cfg.depth_range_m, calibration=None, masked_input=cfg.masked_input)


def _w_from_model(model: PartModel, lay: _Layout, white: _Whitening, cfg: TrainConfig
                  ) -> NDArray[np.float64]:
    """The inverse of `_model_from_w`: a model's parameters in the QP's (whitened) layout."""
    w = np.zeros(lay.size)
    wraw = model.filters.reshape(lay.n_parts, lay.n_types, lay.dim).astype(np.float64)
    w[:lay.n_filter] = (wraw @ white.chol).ravel()     # w' = L^T w_raw, row-wise
    w[lay.n_filter:lay.n_filter + lay.n_spring] = model.springs.astype(np.float64).ravel()
    shift = wraw @ white.mean
    bias = (model.bias.astype(np.float64) + shift[:, None, :]) / cfg.bias_feature
    bias[0, 1:] = 0.0
    w[lay.n_filter + lay.n_spring:] = bias.ravel()
    return w


def _lda_model(pos: list[_Positive], types: NDArray[np.int64], windows: NDArray[np.float64],
               lay: _Layout, tree: PartTree, cfg: TrainConfig, anchors: NDArray[np.int32],
               spring_var: NDArray[np.float64], scale_range: tuple[float, float]
               ) -> tuple[PartModel, _Whitening]:
    """Per-part templates by LDA on HOG (whitened HOG), each scaled so that its part type's
    mean window scores +1 and the mean random window -1; springs from the types' spread.
    Also returns the windows' whitening transform."""
    if len(windows) < 10:
        raise ValueError('too few random windows for the part templates: the images are '
                         'smaller than a filter at the training scales')
    mu0 = windows.mean(0)
    cov = np.cov(windows, rowvar=False)
    cov += cfg.lda_lambda * float(np.mean(np.diag(cov))) * np.eye(lay.dim)
    chol = np.linalg.cholesky(cov)
    filters = np.zeros((lay.n_parts, lay.n_types, lay.dim))
    bias = np.zeros((lay.n_parts, lay.n_types, lay.n_types))
    for c in range(lay.n_parts):
        for t in range(lay.n_types):
            sel = [p.patches[c] for p, ty in zip(pos, types, strict=True) if ty[c] == t]
            if not sel:
                continue
            mu = np.mean(sel, axis=0, dtype=np.float64)
            wv = np.linalg.solve(chol.T, np.linalg.solve(chol, mu - mu0))
            g = float(wv @ (mu - mu0))
            wv *= 2.0 / max(g, 1e-9)
            filters[c, t] = wv
            b = -float(wv @ (mu + mu0)) / 2.0
            if c == 0:
                bias[0, 0, t] = b
            else:
                bias[c, :, t] = b
    springs = np.zeros((lay.n_parts, lay.n_types, 4))
    springs[:, :, 1] = np.maximum(0.5 / np.maximum(spring_var[:, :, 0], 1.0), cfg.spring_lb)
    springs[:, :, 3] = np.maximum(0.5 / np.maximum(spring_var[:, :, 1], 1.0), cfg.spring_lb)
    springs[0] = 0.0
    ch = lay.dim // (cfg.filter_cells ** 2)
    fs = cfg.filter_cells
    model = PartModel(
        part_names=tree.names, parents=tree.parents, channels=cfg.channels, sbin=cfg.sbin,
        filters=filters.reshape(lay.n_parts, lay.n_types, fs, fs, ch).astype(np.float32),
        springs=springs.astype(np.float32), anchors=anchors, bias=bias.astype(np.float32),
        canonical_scale_px=cfg.canonical_scale_px, scale_length_m=cfg.scale_length_m,
        scale_range_px=scale_range,
        depth_encoding=cfg.depth_encoding if cfg.channels == 'rgbd' else '',
        depth_range_m=cfg.depth_range_m, masked_input=cfg.masked_input)
    return model, _Whitening(mu0, np.linalg.inv(chol), chol)


def _random_windows(levels: Iterable[Level], fs: int, per_level: int,
                    rng: np.random.Generator) -> NDArray[np.float64]:
    out = []
    for lev in levels:
        ph, pw, _ = lev.feat.shape
        if ph < fs or pw < fs:
            continue
        rr = rng.integers(0, ph - fs + 1, per_level)
        cc = rng.integers(0, pw - fs + 1, per_level)
        out.extend(lev.feat[r:r + fs, c:c + fs].reshape(-1)
                   for r, c in zip(rr, cc, strict=True))
    return np.asarray(out, np.float64)


# --------------------------------------------------------------------------- mining


def _mine_background(model: PartModel, negatives: list[Negative], ex: _Examples, lay: _Layout,
                     cfg: TrainConfig, white: _Whitening, room: int,
                     progress: Progress | None, round_: int) -> int:
    """Add poses scoring above -1 in background images (at most `room`); returns how many."""
    det = Detector(model)
    arrays = det._arrays
    _, parents, springs, anchors, bias = arrays
    lo, hi = model.scale_range_px
    n_lev = max(int(np.ceil(np.log2(hi / lo) * cfg.levels_per_octave)) + 1, 1)
    scales = tuple(cfg.canonical_scale_px / (lo * (hi / lo) ** (i / max(n_lev - 1, 1)))
                   for i in range(n_lev))
    seen = set(ex.keys)
    added = 0
    it: Iterable = enumerate(negatives)
    if progress is not None:
        it = progress(it, f'round {round_}: background', len(negatives))
    for j, neg in it:
        h, w = neg.color.shape[:2]
        plan = SearchPlan(0, 0, w, h, scales, False)
        found = []
        for li, level in enumerate(det.pyramid(neg.color, neg.depth_m, plan)):
            res = score_level(level, model, arrays)
            if res is None:
                continue
            roots = best_roots(res, cfg.negatives_per_image, -1.0, min_dist=2)
            if len(roots) == 0:
                continue
            parts, local = backtrack(roots, parents, res.resp, res.ix, res.iy, res.ik,
                                     springs, anchors, bias)
            for k in range(len(roots)):
                found.append((float(local[k].sum()), li, level, parts[k]))
        found.sort(key=lambda f: -f[0])
        for _score, li, level, parts in found[:cfg.negatives_per_image]:
            key = ('neg', j, li, *parts.ravel().tolist())
            if key in seen:
                continue
            blocks = _pose_blocks(level.feat, parts, parents, anchors, lay, cfg.filter_cells,
                                  cfg.bias_feature)
            if not ex.add(_whitened(blocks, white), -1.0, 1.0, -1, key):
                return added
            seen.add(key)
            added += 1
            if added >= room:
                return added
    return added


def _mine_structural(model: PartModel, pos: list[_Positive], samples: Sequence,
                     types: NDArray[np.int64], w: NDArray[np.float64], ex: _Examples,
                     lay: _Layout, cfg: TrainConfig, white: _Whitening, room: int,
                     progress: Progress | None, round_: int) -> int:
    """Add violated margin-rescaling constraints from the labelled frames: the poses that
    maximise score + loss (exact, the loss decomposes over parts) and whose score is not at
    least their loss below the labelled pose's. Returns how many were added."""
    arrays = model_arrays(model)
    _, parents, springs, anchors, bias = arrays
    tree = cfg.tree
    p_n = lay.n_parts
    unit = 2.0 / p_n
    seen = set(ex.keys)
    added = 0
    arr = ex.arrays()
    it: Iterable = enumerate(pos)
    if progress is not None:
        it = progress(it, f'round {round_}: poses', len(pos))
    for i, p in it:
        color, depth, mask, _ = _frame(samples[p.sample], tree.names, cfg, p.flipped)
        level = _level_of(color, depth, mask, p.box, p.level_scale, cfg)
        res = score_level(level, model, arrays)
        if res is None:
            continue
        ny, nx = res.resp.shape[2:]
        yy, xx = np.mgrid[0:ny, 0:nx]
        far = np.hypot(yy[None] - p.cells[:, 0, None, None],
                       xx[None] - p.cells[:, 1, None, None]) > p.tau     # (P, ny, nx)
        aug = res.resp + (unit * far).astype(np.float32)[:, None]
        root, ix, iy, ik, _ = tree_dp(aug, parents, springs, anchors, bias)
        aug_res = LevelResult(level, aug, root, ix, iy, ik)
        roots = best_roots(aug_res, cfg.structural_per_positive, min_dist=2)
        if len(roots) == 0:
            continue
        poses, local = backtrack(roots, parents, aug, ix, iy, ik, springs, anchors, bias)
        gt_score = float(_dot(w, *arr[:6], arr[8], i))
        for k in range(len(roots)):
            wrong = far[np.arange(p_n), poses[k, :, 1], poses[k, :, 2]]
            loss = unit * float(wrong.sum())
            if loss <= 0:
                continue
            score = float(local[k].sum()) - loss
            if gt_score - score >= loss - 1e-6:
                continue
            key = ('pose', i, *poses[k].ravel().tolist())
            if key in seen:
                continue
            blocks = _pose_blocks(level.feat, poses[k], parents, anchors, lay,
                                  cfg.filter_cells, cfg.bias_feature)
            if not ex.add(_whitened(blocks, white, -1.0), 1.0, loss, i, key):
                return added
            seen.add(key)
            added += 1
            if added >= room:
                return added
    return added


# --------------------------------------------------------------------------- calibration


def _fit_logistic(x: NDArray[np.float64], y: NDArray[np.float64], l2: float = 1e-2
                  ) -> NDArray[np.float64]:
    """Newton's method for L2-regularised logistic regression; x (n, d), returns (d + 1,)."""
    xa = np.hstack([x, np.ones((len(x), 1))])
    beta = np.zeros(xa.shape[1])
    reg = l2 * np.eye(xa.shape[1])
    reg[-1, -1] = 0.0
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-np.clip(xa @ beta, -50, 50)))
        g = xa.T @ (p - y) + reg @ beta
        hmat = (xa * (p * (1 - p))[:, None]).T @ xa + reg + 1e-9 * np.eye(len(beta))
        step = np.linalg.solve(hmat, g)
        beta -= step
        if np.abs(step).max() < 1e-8:
            break
    return beta


def calibrate(model: PartModel, samples: Sequence, *, use_depth: bool,
              progress: Progress | None = None, alpha: float = 0.1) -> PartModel:
    """Fit the per-part logistic confidence on detections of `samples` (a part is 'right' when
    within alpha * the size of the ground-truth joints' box). With `use_depth` the frames are
    searched as at run time (depth, the sample's mask); else without depth."""
    det = Detector(model)
    xs, ys = [], []
    it: Iterable = samples
    if progress is not None:
        it = progress(it, 'calibration', len(samples))
    for s in it:
        uv, vis = part_joints(s, model.part_names)
        if vis.sum() < 2:
            continue
        if use_depth and s.depth_m is not None:
            mask = s.mask
            box = None
            if mask is None:
                p = uv[vis]
                box = (p[:, 0].min(), p[:, 1].min(), p[:, 0].max() + 1, p[:, 1].max() + 1)
            poses = det.detect(s.color, s.depth_m, mask=mask, box=box, intrinsics=s.intrinsics)
        else:
            poses = det.detect(s.color, None)
        if not poses:
            continue
        p = poses[0]
        size = np.max(np.ptp(uv[vis], axis=0))
        dist = np.hypot(*(p.uv - uv).T)
        for i in np.flatnonzero(vis):
            xs.append((i, p.part_scores[i], p.score))
            ys.append(float(dist[i] <= alpha * size))
    cal = np.zeros((model.n_parts, 3), np.float32)
    if xs:
        arr = np.asarray(xs)
        yv = np.asarray(ys)
        for i in range(model.n_parts):
            sel = arr[:, 0] == i
            if sel.sum() >= 10 and 0 < yv[sel].mean() < 1:
                cal[i] = _fit_logistic(arr[sel, 1:], yv[sel])
            elif sel.any():
                rate = float(np.clip(yv[sel].mean(), 0.01, 0.99))
                cal[i] = (0.0, 0.0, np.log(rate / (1 - rate)))
    return replace(model, calibration=cal)


# --------------------------------------------------------------------------- train


@dataclass
class TrainReport:
    """What happened during training (for the model's metadata and the CLI)."""

    n_samples: int = 0
    n_positives: int = 0
    n_negative_images: int = 0
    rounds: list[dict] = field(default_factory=list)
    seconds: float = 0.0


def train(samples: Sequence, negatives: Sequence[Negative], cfg: TrainConfig, *,
          progress: Progress | None = None, log: Log | None = None,
          metadata: dict[str, str] | None = None) -> tuple[PartModel, TrainReport]:
    """Train a part model.

    Parameters
    ----------
    samples : labelled frames (`datasets.sources.Sample`); frames without every part of the
        model labelled are skipped (the model is fully supervised). For `cfg.masked_input`,
        `sample.mask` is the foreground mask the frame is blanked with.
    negatives : background images without people (see `background_crops`); may be empty when
        `cfg.background_negatives` is off.
    cfg : the settings.
    progress : wraps an iterable with a progress bar: progress(iterable, description, total).
    log : receives one-line messages.
    metadata : strings stored in the model (data, command, ...); training adds its own.

    Returns
    -------
    The model and a `TrainReport`.
    """
    t_start = time.perf_counter()
    say = log or (lambda _m: None)
    rng = np.random.default_rng(cfg.seed)
    tree = cfg.tree
    names = tree.names
    fs = cfg.filter_cells
    dim = fs * fs * N_FEATURES * (2 if cfg.channels == 'rgbd' else 1)
    report = TrainReport(n_samples=len(samples), n_negative_images=len(negatives))
    if cfg.channels == 'rgbd' and not any(s.depth_m is not None for s in samples):
        raise ValueError('an rgbd model needs samples with depth (the source has none); '
                         'train with channels rgb')
    negs = list(negatives) if cfg.background_negatives else []
    if cfg.background_negatives and not negs:
        raise ValueError('no background images to mine negatives from')

    # 1. positives at the canonical scale (+ mirror images)
    pos: list[_Positive] = []
    scales = []
    it: Iterable = enumerate(samples)
    if progress is not None:
        it = progress(it, 'positives', len(samples))
    for idx, s in it:
        uv, vis = part_joints(s, names)
        if not vis.all():
            continue
        sc = person_scale(s, names, cfg, uv)
        if not (np.isfinite(sc) and sc > 2):
            continue
        scales.append(sc)
        for flipped in (False, True) if cfg.flip else (False,):
            p = _prepare_positive(s, idx, flipped, sc, tree, cfg)
            if p is not None:
                pos.append(p)
    need = max(2 * cfg.n_types, 10)
    if len(pos) < need:
        raise ValueError(f'only {len(pos)} usable positives (frames with every one of the '
                         f'{len(names)} parts labelled); need at least {need}')
    report.n_positives = len(pos)
    sc_arr = np.asarray(scales)
    scale_range = (float(np.percentile(sc_arr, 1) / 1.15),
                   float(np.percentile(sc_arr, 99) * 1.15))
    say(f'{len(pos)} positives from {len(samples)} frames; person scale '
        f'{np.median(sc_arr):.1f} px (search {scale_range[0]:.1f}-{scale_range[1]:.1f} px)')

    # 2. part types by k-means on offsets; anchors from the quantised cells
    k = cfg.n_types
    types = np.zeros((len(pos), len(tree)), np.int64)
    offs = np.stack([p.offsets for p in pos])          # (N, P, 2)
    cells = np.stack([p.cells for p in pos])           # (N, P, 2) row, col
    for c in range(1, len(tree)):
        _, types[:, c] = kmeans(offs[:, c], k, rng)
    kids = tree.children(0)
    _, types[:, 0] = kmeans(offs[:, kids].reshape(len(pos), -1), k, rng)
    par = np.asarray(tree.parents)
    anchors = np.zeros((len(tree), k, 2), np.int32)
    spring_var = np.ones((len(tree), k, 2))
    for c in range(1, len(tree)):
        d = cells[:, c] - cells[:, par[c]]              # (N, 2) drow, dcol
        for t in range(k):
            sel = types[:, c] == t
            if sel.any():
                mean = d[sel].mean(0)
                anchors[c, t] = (int(np.rint(mean[1])), int(np.rint(mean[0])))
                spring_var[c, t] = (d[sel, 1].var() + 0.25, d[sel, 0].var() + 0.25)
    lay = _Layout(len(tree), k, dim)

    # 3. per-part templates (LDA) against random windows -> the first model w0
    want = 20000
    sources: list[Level] = []
    sub = rng.choice(len(pos), min(len(pos), 400), replace=False)
    for i in np.sort(sub):
        p = pos[i]
        color, depth, mask, _ = _frame(samples[p.sample], names, cfg, p.flipped)
        sources.append(_level_of(color, depth, mask, p.box, p.level_scale, cfg))
    lo, hi = scale_range
    for n in (negs[j] for j in np.sort(rng.choice(len(negs), min(len(negs), 400),
                                                  replace=False))) if negs else ():
        f = cfg.canonical_scale_px / float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        h, w_ = n.color.shape[:2]
        sources.append(_level_of(n.color, n.depth_m, None, (0, 0, w_, h), f, cfg))
    windows = _random_windows(sources, fs, max(want // max(len(sources), 1), 4), rng)
    del sources
    model, white = _lda_model(pos, types, windows, lay, tree, cfg, anchors, spring_var,
                              scale_range)
    say(f'part templates by LDA on {len(windows)} random windows')

    # 4. structural SVM with mining
    cap = len(pos) + cfg.cache_limit
    ex = _Examples(cap, lay.n_parts, dim)
    for i, p in enumerate(pos):
        parts = np.concatenate([types[i][:, None], p.cells], axis=1)
        blocks = _pose_blocks(np.zeros((0, 0, 0), np.float32), parts, par, anchors, lay, fs,
                              cfg.bias_feature, patches=p.patches)
        ex.add(_whitened(blocks, white), 1.0, 1.0, -1, ('pos', i))
    n_pos = ex.n
    # the regulariser is |w - w0|^2 with w0 = the LDA model: the SVM corrects the whitened-HOG
    # templates rather than starting from nothing (w = w0 + sum a y x + sum b e)
    w0 = _w_from_model(model, lay, white, cfg)
    w = w0.copy()
    lb_idx = np.array([lay.spring_off(c, t) + j for c in range(1, len(tree)) for t in range(k)
                       for j in (1, 3)], np.int64)
    lb_val = np.full(len(lb_idx), cfg.spring_lb)
    beta = np.zeros(len(lb_idx))
    for rnd in range(1, cfg.mining_rounds + 1):
        t0 = time.perf_counter()
        # make room: drop cached constraints that are inactive and satisfied with some slack
        if ex.n - n_pos > cfg.cache_limit // 2:
            arr = ex.arrays()
            marg = _margins(w, *arr[:7], arr[8])
            keep = np.flatnonzero((np.arange(ex.n) < n_pos) | (ex.alpha[:ex.n] > 0)
                                  | (marg < arr[7] + 0.05))
            if len(keep) < ex.n:
                ex.keep(keep)
        added_bg = 0
        if negs:
            added_bg = _mine_background(model, negs, ex, lay, cfg, white,
                                        max((cap - ex.n) // 2, 0), progress, rnd)
        added_st = _mine_structural(model, pos, samples, types, w, ex, lay, cfg, white,
                                    cap - ex.n, progress, rnd)
        t1 = time.perf_counter()
        arr = ex.arrays()
        alpha = ex.alpha[:ex.n]
        epochs = 0
        gap = np.inf
        obj = np.nan
        marg = np.zeros(ex.n)
        cost = np.where(np.arange(ex.n) < n_pos, cfg.svm_c * cfg.positive_weight, cfg.svm_c)
        while epochs < cfg.qp_epochs:
            _dcd(w, *arr[:9], alpha, cost, lb_idx, lb_val, beta, 10,
                 cfg.seed + 1000 * rnd + epochs)
            epochs += 10
            marg = _margins(w, *arr[:7], arr[8])
            loss = float(cost @ np.maximum(0.0, arr[7] - marg))
            u = w - w0
            obj = 0.5 * float(u @ u) + loss
            dual = float(alpha @ arr[7] + beta @ lb_val) - 0.5 * float(u @ u) - float(w0 @ u)
            gap = (obj - dual) / max(abs(obj), 1e-12)
            if gap < cfg.qp_tol:
                break
        ok = marg >= arr[7] - 1e-9
        kind = np.where(np.arange(ex.n) < n_pos, 0, np.where(arr[8] >= 0, 2, 1))
        t2 = time.perf_counter()
        info = dict(round=rnd, background_added=added_bg, poses_added=added_st,
                    cache=ex.n - n_pos, qp_epochs=epochs, qp_gap=round(gap, 4),
                    objective=round(obj, 4),
                    positives_ok=round(float(ok[kind == 0].mean()), 3),
                    background_ok=round(float(ok[kind == 1].mean()), 3) if (kind == 1).any()
                    else None,
                    poses_ok=round(float(ok[kind == 2].mean()), 3) if (kind == 2).any()
                    else None,
                    mine_s=round(t1 - t0, 1), qp_s=round(t2 - t1, 1))
        report.rounds.append(info)
        say(' '.join(f'{a}={b}' for a, b in info.items()))
        model = _model_from_w(w, lay, tree, cfg, anchors, scale_range, white)

    # 5. calibration on training frames (a deterministic subset)
    usable = [s for s in samples if part_joints(s, names)[1].sum() >= 2]
    if len(usable) > cfg.calibration_samples:
        idx = np.sort(rng.choice(len(usable), cfg.calibration_samples, replace=False))
        usable = [usable[i] for i in idx]
    model = calibrate(model, usable, use_depth=cfg.channels == 'rgbd', progress=progress)
    report.seconds = time.perf_counter() - t_start
    meta = dict(metadata or {})
    meta.update({
        'train_config': json.dumps(asdict(cfg), sort_keys=True),
        'positives': str(report.n_positives), 'frames': str(report.n_samples),
        'negative_images': str(len(negs)),
        'rounds': json.dumps(report.rounds, sort_keys=True),
        'train_seconds': f'{report.seconds:.1f}',
    })
    return replace(model, metadata=meta), report
