"""Exact inference in the 4D-DPM part model: the best poses of a colour (+ depth) image.

Yang & Ramanan (PAMI 2013), section 4: a feature pyramid of the search box, then per level the
filter GEMM, the tree DP of eq. 4 and backtracking (`core.dpm.dp`); the best poses over all
levels, non-maximum suppressed.

The 4D-DPM's use of depth (Martinez Berti et al.): the person's median depth z over the
foreground mask gives the person's scale in pixels, fx * L / z (L = `model.scale_length_m`), so
only the 1-3 pyramid levels that bring it to the model's canonical size are searched, and only
inside the foreground box plus a margin. Without depth the scales of the middle 90 % of the
training people are searched (`PartModel.search_range_px`, `SearchConfig.levels_per_octave`), as
in Yang & Ramanan over the trained range.

Tracking prior (`SearchConfig.arm_prior`): in a video, the previous frame's elbows and wrists
(`Detector.detect(prior=...)`) choose each arm among the few best the tree allows
(`limb_candidates`: the best elbow cells given the chosen shoulder, each with its best wrists),
scored by the tree less the prior's weight times the squared distance to the previous
positions in person scales. The rest of the pose is the exact optimum; the DP's own arm wins
ties.

Parallelism on the 2-core target: the GEMM is the only heavy dense kernel, so BLAS owns the
threads (OpenBLAS's default); HOG, the distance transforms and backtracking are single-threaded
numba (no `parallel=True`). Measured with `pose4d bench` (see the models' README): a second
BLAS thread and numba threads never made the per-frame detector faster on the shared 2 cores.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics
from pose4d_ros.core.dpm.dp import (
    LIMB_CANDIDATES,
    LevelResult,
    backtrack,
    best_roots,
    limb_candidates,
    model_arrays,
    score_level,
    subcell_offsets,
)
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.dpm.net_unary import NetMaps, NetUnary
from pose4d_ros.core.foreground import apply_mask
from pose4d_ros.core.hog import Level, depth_image, feature_pyramid
from pose4d_ros.core.stats import median

# rows of the depth image read for the person's depth (the foreground's working height)
WORKING_ROWS = 240


@dataclass(frozen=True)
class SearchConfig:
    """Where and at which scales the detector looks.

    Attributes
    ----------
    n_levels : levels searched around the depth-predicted scale (1-3).
    level_step : scale ratio between neighbouring levels (depth-guided search).
    levels_per_octave : pyramid density of the depth-free search.
    margin : search-box margin around the foreground box, in person scales (fx * L / z).
    low_score : poses scoring below this are flagged 'low_score' (0 = the SVM's boundary).
    nms_overlap : top-k suppression: pose boxes overlapping more than this (IoU) are dropped.
    subcell : refine each part below the cell size: a parabola through its subtree score (less
        its spring) at the chosen cell and its two neighbours, per axis (at most half a cell).
    arm_prior : weight of the previous frame's elbows and wrists when a prior is given (score
        units per squared person scale of distance); 0 = the tree's choice alone.
    occluded_quantile : where a nearer person hides this one (`Detector.detect(occluder=...)`),
        each part's response is at least this quantile of its responses over the person's own
        pixels (`OcclusionFloor`); 0 = off.
    """

    n_levels: int = 1
    level_step: float = 2.0 ** 0.2
    levels_per_octave: int = 5
    margin: float = 0.4
    low_score: float = 0.0
    nms_overlap: float = 0.5
    subcell: bool = True
    arm_prior: float = 1.0
    occluded_quantile: float = 0.5

    def __post_init__(self) -> None:
        if not 1 <= self.n_levels <= 9:
            raise ValueError(f'n_levels must be in 1..9, got {self.n_levels}')
        if not self.level_step > 1.0:
            raise ValueError(f'level_step must be > 1, got {self.level_step}')
        if not 1 <= self.levels_per_octave <= 20:
            raise ValueError(f'levels_per_octave must be in 1..20, got {self.levels_per_octave}')
        if not self.margin >= 0:
            raise ValueError(f'margin must be >= 0, got {self.margin}')
        if not 0 < self.nms_overlap <= 1:
            raise ValueError(f'nms_overlap must be in (0, 1], got {self.nms_overlap}')
        if not self.arm_prior >= 0:
            raise ValueError(f'arm_prior must be >= 0, got {self.arm_prior}')
        if not 0 <= self.occluded_quantile <= 1:
            raise ValueError(f'occluded_quantile must be in [0, 1], got {self.occluded_quantile}')


@dataclass(frozen=True)
class Pose:
    """One detected pose.

    Attributes
    ----------
    names : P part names (the model's).
    uv : (P, 2) float64 pixel (u, v) of each part's centre in the full colour image.
    part_scores : (P,) float64 each part's share of the score (filter + spring + bias).
    confidence : (P,) float64 in [0, 1] (the model's logistic calibration).
    score : whole-pose score (the sum of `part_scores`; with the photograph network in the
        unary, that sum brought onto the scale of the model's own maxima,
        `NetUnary.calibrated`).
    search_score : the score the search ranked the pose by: `score` plus, with the photograph
        network in the colour unary (`core.dpm.net_unary`), the network's term at the parts'
        cells (which `score`, `part_scores` and `confidence` leave out, so that they keep the
        part model's scale that every threshold downstream was set on); NaN = `score`.
    scale : level pixels per image pixel of the level the pose was found on.
    types : (P,) int mixture type of each part.
    flags : why the pose is doubtful: 'low_score' (score < SearchConfig.low_score),
        'no_depth' (an rgbd model ran without usable depth). Empty when all is well.
    """

    names: tuple[str, ...]
    uv: NDArray[np.float64]
    part_scores: NDArray[np.float64]
    confidence: NDArray[np.float64]
    score: float
    scale: float
    types: NDArray[np.int64]
    flags: tuple[str, ...] = ()
    search_score: float = math.nan

    @property
    def low_confidence(self) -> bool:
        return bool(self.flags)

    @property
    def rank(self) -> float:
        """What the search ranks poses by (`search_score`, or `score` without a network)."""
        return self.score if math.isnan(self.search_score) else self.search_score


# --------------------------------------------------------------------------- the detector


def _sigmoid(x: NDArray) -> NDArray:
    # np.clip's values, without its Python wrapper
    return 1.0 / (1.0 + np.exp(-np.minimum(np.maximum(x, -50), 50)))


def _box_iou(a: NDArray, b: NDArray) -> float:
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


# How far beyond its trained scale range the depth-guided search may look (a ratio).
_SCALE_SLACK = 1.25


@dataclass(frozen=True)
class SearchPlan:
    """Where a frame is searched: the crop (full-image pixels) and the level scales."""

    x0: int
    y0: int
    x1: int
    y1: int
    scales: tuple[float, ...]
    depth_guided: bool


def arm_limbs(names: tuple[str, ...], parents: tuple[int, ...] | NDArray
              ) -> tuple[tuple[int, int], ...]:
    """(mid, end) part indices of the arms the tracking prior re-chooses, a subtree of one or
    two parts ending at a wrist: (elbow, wrist) in the 14-part tree, (forearm, wrist) with limb
    midpoints, (wrist, -1) where the wrist's parent has other children (the 10-part tree's
    shoulder). Arms whose wrist is not a leaf are left alone."""
    parents = [int(p) for p in parents]
    limbs = []
    for side in ('left_', 'right_'):
        if side + 'wrist' not in names:
            continue
        w = names.index(side + 'wrist')
        if w in parents:
            continue
        p = parents[w]
        only_child = p > 0 and parents.count(p) == 1
        limbs.append((p, w) if only_child else (w, -1))
    return tuple(limbs)


class SearchWork:
    """The filter positions (cells of the levels searched) scored by every `Detector` of this
    process: the search's work, which its GEMM and tree DP grow with, counted the same on any
    machine and under any load. `pose4d eval` records it per frame (`search_cells`), and the
    validation sweeps' CPU rule reads it beside the CPU time (`evaluation.results`)."""

    cells: int = 0


class OcclusionFloor:
    """The responses of the filter positions a nearer person hides, raised to a floor.

    A person partly hidden behind a nearer one is searched in their own mask, so where the
    nearer one stands their features are blank, as beyond a silhouette's edge: every part
    scores as on the background there, and the tree pulls the whole pose onto the visible half
    (the torso 10-12 px sideways on validation's crossings). Here a position whose window
    centre lies on the `occluder`'s pixels scores, for each part, at least the `quantile` of
    that part's best-type responses over the positions on the person's own `mask`: as well as
    a middling place on their visible body, so a hidden part lies where the springs put it and
    the visible parts where their filters do. Chosen on validation (`make results`' sweep
    `occluded`; `SearchConfig.occluded_quantile`).
    """

    def __init__(self, mask: NDArray[np.bool_], occluder: NDArray[np.bool_], quantile: float,
                 filter_shape: tuple[int, int]) -> None:
        if mask.shape != occluder.shape:
            raise ValueError(f'occluder {occluder.shape} and mask {mask.shape} differ in shape')
        self.mask, self.occluder = mask, occluder
        self.quantile, self.filter_shape = quantile, filter_shape

    def __call__(self, level: Level, resp: NDArray[np.float32]) -> None:
        """Raise `resp` (P, K, ny, nx) of `level` in place."""
        ny, nx = resp.shape[2:]
        h, w = self.mask.shape
        u, v = level.cell_to_pixel(np.arange(ny)[:, None], np.arange(nx)[None, :],
                                   self.filter_shape)
        cols = np.clip(np.rint(u).astype(np.intp), 0, w - 1)
        rows = np.clip(np.rint(v).astype(np.intp), 0, h - 1)
        rows, cols = np.broadcast_arrays(rows, cols)
        hidden = self.occluder[rows, cols]
        own = self.mask[rows, cols]
        if not (hidden.any() and own.any()):
            return
        best = resp.max(axis=1)  # (P, ny, nx)
        floor = np.quantile(best[:, own], self.quantile, axis=1).astype(np.float32)
        resp[:, :, hidden] = np.maximum(resp[:, :, hidden], floor[:, None, None])


class Detector:
    """A part model ready to run (its arrays prepared once), with its search settings.

    `Detector(model).detect(color, depth_m, mask=...)` is the call the ROS node makes per frame.
    """

    def __init__(self, model: PartModel, config: SearchConfig | None = None,
                 unary: NetUnary | None = None) -> None:
        self.model = model
        self.config = config or SearchConfig()
        self.unary = unary
        self._arrays = model_arrays(model)
        self._limbs = arm_limbs(model.part_names, model.parents)
        if unary is not None:
            self._arrays = (unary.filter_matrix(self._arrays[0], model.n_channels),
                            *self._arrays[1:])
            self._net_joints = unary.joints_of(model.part_names)

    # ---------------------------------------------------------------- planning
    def plan(self, shape: tuple[int, int], depth_m: NDArray | None, *,
             mask: NDArray[np.bool_] | None = None, box: tuple | None = None,
             intrinsics: Intrinsics | None = None, scale: float = 1.0) -> SearchPlan | None:
        """Choose the crop and the levels for a frame of `shape` = (H, W); None if there is
        nothing to search (empty mask, frame too small). `scale` multiplies the person scale
        that depth predicts (`core.dpm.scale`: a person larger than the training bodies)."""
        h, w = shape
        m, cfg = self.model, self.config
        if mask is not None:
            if mask.shape != (h, w):
                raise ValueError(f'mask shape {mask.shape} does not match the image {(h, w)}')
            # np.flatnonzero(mask.any(axis=...)), without their Python wrappers
            rows = np.logical_or.reduce(mask, axis=1).nonzero()[0]
            if rows.size == 0:
                return None
            cols = np.logical_or.reduce(mask, axis=0).nonzero()[0]
            bx = (float(cols[0]), float(rows[0]), float(cols[-1] + 1), float(rows[-1] + 1))
        elif box is not None:
            bx = tuple(float(v) for v in box)
            if len(bx) != 4 or not (bx[2] > bx[0] and bx[3] > bx[1]):
                raise ValueError(f'box must be (x0, y0, x1, y1) with x1 > x0, y1 > y0, got {box}')
        else:
            bx = None

        z = np.nan
        if depth_m is not None:
            d = np.asarray(depth_m)
            if d.shape != (h, w):
                raise ValueError(f'depth shape {d.shape} does not match the image {(h, w)}')
            # the person's median depth from every n-th pixel of every n-th row, n such that
            # about WORKING_ROWS rows are read: as much work at any camera resolution
            n = max(h // WORKING_ROWS, 1)
            if mask is not None:
                vals = d[::n, ::n][mask[::n, ::n]]
            elif bx is not None:
                x0, y0, x1, y1 = (int(round(v)) for v in bx)
                vals = d[max(y0, 0):max(y1, 0):n, max(x0, 0):max(x1, 0):n].ravel()
            else:
                vals = np.zeros(0, np.float32)  # no person region: depth cannot give the scale
            vals = vals[np.isfinite(vals) & (vals > 0)]
            if vals.size:
                z = median(vals)
        if np.isfinite(z):
            k = intrinsics or cad60_intrinsics(w, h)
            # Bounded work whatever the input: a person the depth puts outside the scales the
            # model was trained on is searched at the nearest trained scale, never on a pyramid
            # blown up by a depth or focal length no camera gives.
            lo, hi = m.scale_range_px
            s_pred = min(max(k.fx * m.scale_length_m / z * scale, lo / _SCALE_SLACK),
                         hi * _SCALE_SLACK)
            f0 = m.canonical_scale_px / s_pred
            n = cfg.n_levels
            scales = tuple(f0 * cfg.level_step ** (i - (n - 1) / 2) for i in range(n))
            margin = cfg.margin * s_pred
            guided = True
        else:
            lo, hi = m.search_range_px or m.scale_range_px
            n = max(int(np.ceil(np.log2(hi / lo) * cfg.levels_per_octave)) + 1, 1)
            scales = tuple(m.canonical_scale_px / (lo * (hi / lo) ** (i / max(n - 1, 1)))
                           for i in range(n))
            margin = cfg.margin * float(np.sqrt(lo * hi))
            guided = False
        if bx is None:
            x0, y0, x1, y1 = 0, 0, w, h
        else:
            x0 = max(int(np.floor(bx[0] - margin)), 0)
            y0 = max(int(np.floor(bx[1] - margin)), 0)
            x1 = min(int(np.ceil(bx[2] + margin)), w)
            y1 = min(int(np.ceil(bx[3] + margin)), h)
        if x1 - x0 < 3 or y1 - y0 < 3:
            return None
        return SearchPlan(x0, y0, x1, y1, scales, guided)

    def pyramid(self, color: NDArray, depth_m: NDArray | None, plan: SearchPlan, *,
                mask: NDArray[np.bool_] | None = None, blanked: bool = False) -> list[Level]:
        """Padded HOG levels of the plan's crop (colour, + depth for an rgbd model); a model
        trained on masked frames blanks the crop outside `mask`, unless it is `blanked`
        already."""
        m = self.model
        sl = np.s_[plan.y0:plan.y1, plan.x0:plan.x1]
        col = np.asarray(color)[sl]
        if col.ndim == 2:
            col = col[:, :, None]
        dep = None
        keep = mask[sl] if m.masked_input and mask is not None and not blanked else None
        if m.channels == 'rgbd':
            dcrop = (np.full(col.shape[:2], np.nan, np.float32) if depth_m is None
                     else np.asarray(depth_m, np.float32)[sl])
            if keep is not None:
                col, dcrop = apply_mask(col, dcrop, keep)
            dep = depth_image(dcrop, m.depth_encoding, near_m=m.depth_range_m[0],
                              far_m=m.depth_range_m[1])
        elif keep is not None:
            col, _ = apply_mask(col, np.zeros(keep.shape, np.float32), keep)
        # Truncation padding (a part may lie partly outside the image) only where the crop
        # meets the image's border: elsewhere the crop's margin is the space around the person,
        # and padding there would only add filter positions nobody's parts lie on.
        fh, fw = m.filter_shape
        py, px = fh // 2 + 1, fw // 2 + 1
        h, w = np.shape(color)[:2]
        return feature_pyramid(col, dep, plan.scales, sbin=m.sbin,
                               pad=(py * (plan.y0 == 0), px * (plan.x0 == 0)),
                               pad_end=(py * (plan.y1 == h), px * (plan.x1 == w)),
                               origin=(plan.x0, plan.y0))

    # ---------------------------------------------------------------- detection
    def detect(self, color: NDArray, depth_m: NDArray | None = None, *,
               mask: NDArray[np.bool_] | None = None, box: tuple | None = None,
               intrinsics: Intrinsics | None = None, top_k: int = 1, scale: float = 1.0,
               blanked: bool = False, prior: NDArray[np.floating] | None = None,
               occluder: NDArray[np.bool_] | None = None,
               photo: NDArray | None = None) -> list[Pose]:
        """The best `top_k` poses in a frame.

        Parameters
        ----------
        color : (H, W, 3) uint8 colour (channel order does not matter), or (H, W) grey.
        depth_m : (H, W) float32 metres, NaN = no reading, registered to `color`; None for
            colour only (then the whole trained scale range is searched).
        mask : (H, W) bool person mask (from `core.foreground`): bounds the search and gives
            the person's depth.
        box : (x0, y0, x1, y1) pixels, used when no mask is given.
        intrinsics : the colour camera; default CAD-60's at the image size.
        top_k : poses returned at most (non-maximum suppressed by pose-box overlap).
        scale : factor on the person scale that depth predicts (see `plan`).
        blanked : colour and depth are already blanked outside `mask` (NaN depth, zero
            colour), as the foreground stage publishes them: not blanked again.
        prior : (P, 2) pixels of the parts in the previous frame of the video (NaN rows =
            unknown): its elbows and wrists guide the arms (`SearchConfig.arm_prior`).
        occluder : (H, W) bool pixels of nearer people in front of this one (with `mask`):
            a part may lie there, hidden (`SearchConfig.occluded_quantile`).
        photo : the camera's colour image, not blanked: what the photograph network reads
            when its `UnaryConfig.masked` is off (default: `color`).

        Returns
        -------
        Poses, best first; empty when there is nothing to search (empty mask, a frame smaller
        than a filter). Doubtful poses carry `flags` (see `Pose`).
        """
        color = np.asarray(color)
        if color.ndim not in (2, 3) or color.shape[0] == 0 or color.shape[1] == 0:
            raise ValueError(f'color must be (H, W, 3) or (H, W), got shape {color.shape}')
        if top_k < 1:
            raise ValueError(f'top_k must be >= 1, got {top_k}')
        plan = self.plan(color.shape[:2], depth_m, mask=mask, box=box, intrinsics=intrinsics,
                         scale=scale)
        if plan is None:
            return []
        flags: tuple[str, ...] = ()
        if self.model.channels == 'rgbd' and not plan.depth_guided:
            d = None if depth_m is None else np.asarray(depth_m, np.float32)
            if d is None or not (np.isfinite(d) & (d > 0)).any():
                flags = ('no_depth',)
        levels = self.pyramid(color, depth_m, plan, mask=mask, blanked=blanked)
        maps = None if self.unary is None else self.net_maps(color, plan, mask=mask,
                                                             blanked=blanked, photo=photo)
        floor = None
        if occluder is not None and mask is not None and self.config.occluded_quantile > 0:
            floor = OcclusionFloor(mask, occluder, self.config.occluded_quantile,
                                   self.model.filter_shape)
        return self.poses_from_levels(
            levels, top_k=top_k, flags=flags, prior=prior,
            scale_prior=0.0 if plan.depth_guided else self.model.scale_prior, net_maps=maps,
            floor=floor)

    def net_maps(self, color: NDArray, plan: SearchPlan, *,
                 mask: NDArray[np.bool_] | None = None, blanked: bool = False,
                 photo: NDArray | None = None) -> NetMaps:
        """The network's maps of the plan's crop (`NetUnary.maps`), blanked outside `mask` as
        the pyramid is for a model trained on masked frames; of `photo`'s crop instead (the
        camera's colour, not blanked) when given and the network is not masked
        (`UnaryConfig.masked` off)."""
        assert self.unary is not None
        box = (plan.x0, plan.y0, plan.x1, plan.y1)
        if photo is not None and not self.unary.config.masked:
            return self.unary.maps(np.asarray(photo), box)
        if self.model.masked_input and mask is not None and not blanked:
            sl = np.s_[plan.y0:plan.y1, plan.x0:plan.x1]
            crop = np.zeros_like(np.asarray(color))
            crop[sl], _ = apply_mask(np.asarray(color)[sl], np.zeros(mask[sl].shape, np.float32),
                                     mask[sl])
            color = crop
        return self.unary.maps(color, box)

    def _unary(self, maps: NetMaps) -> Callable[[Level, int, int], NDArray[np.float32]]:
        """The (P, ny, nx) network term of a level's parts (`dp.score_level`'s `unary`)."""
        assert self.unary is not None
        joints = self._net_joints
        known = joints >= 0

        def term(level: Level, ny: int, nx: int) -> NDArray[np.float32]:
            per_joint = self.unary.level_unary(maps, level, self.model.filter_shape, ny, nx)
            out = np.zeros((len(joints), ny, nx), np.float32)
            out[known] = per_joint[joints[known]]
            return out
        return term

    def poses_from_levels(self, levels: list[Level], *, top_k: int = 1,
                          threshold: float = -np.inf, flags: tuple[str, ...] = (),
                          prior: NDArray[np.floating] | None = None,
                          scale_prior: float = 0.0, net_maps: NetMaps | None = None,
                          floor: OcclusionFloor | None = None) -> list[Pose]:
        """Run every level and return the best poses over all of them, ranked by their score
        plus `scale_prior` per octave of the person scale they were found at (the search
        without depth, `PartModel.scale_prior`; the poses keep their own scores). `net_maps`:
        the frame's network maps, for a detector with a `NetUnary`; `floor`: the responses
        raised where a nearer person hides this one (`OcclusionFloor`)."""
        cands: list[Pose] = []
        per_level = 1 if top_k == 1 else 4 * top_k
        unary = None if net_maps is None else self._unary(net_maps)
        for level in levels:
            res = score_level(level, self.model, self._arrays, unary, floor)
            if res is None:
                continue
            SearchWork.cells += res.root.shape[1] * res.root.shape[2]
            roots = best_roots(res, per_level, threshold, min_dist=2)
            cands.extend(self._poses(res, roots, flags, prior))
        canonical = self.model.canonical_scale_px
        cands.sort(key=lambda p: -(p.rank + scale_prior * np.log2(canonical / p.scale)))
        if top_k == 1:
            return cands[:1]
        kept: list[Pose] = []
        boxes: list[NDArray] = []
        for p in cands:
            b = np.array([p.uv[:, 0].min(), p.uv[:, 1].min(), p.uv[:, 0].max(),
                          p.uv[:, 1].max()])
            if all(_box_iou(b, q) <= self.config.nms_overlap for q in boxes):
                kept.append(p)
                boxes.append(b)
            if len(kept) >= top_k:
                break
        return kept

    def _follow_prior(self, res: LevelResult, parts: NDArray[np.int64], local: NDArray,
                      prior: NDArray[np.float64]) -> None:
        """Re-choose each arm of a backtracked pose (`parts`, `local`: updated in place) among
        its `limb_candidates` by score less `arm_prior` x the squared distance of its elbow and
        wrist to `prior`, in person scales."""
        _, parents, springs, anchors, bias = self._arrays
        person_px = self.model.canonical_scale_px / res.level.scale
        shape = self.model.filter_shape
        for mid, end in self._limbs:
            cand, loc = limb_candidates(res.resp, res.score, res.ix, res.iy, res.ik, parents,
                                        springs, anchors, bias, parts, mid, end,
                                        LIMB_CANDIDATES)
            cost = -np.add.reduce(loc, axis=1)  # loc.sum's, without its Python wrapper
            for slot, part in ((0, mid), (1, end)):
                if part < 0 or not (math.isfinite(prior[part, 0])
                                    and math.isfinite(prior[part, 1])):
                    continue
                u, v = res.level.cell_to_pixel(cand[:, slot, 1], cand[:, slot, 2], shape)
                cost += self.config.arm_prior * ((u - prior[part, 0]) ** 2 +
                                                 (v - prior[part, 1]) ** 2) / person_px ** 2
            best = int(cost.argmin())  # the DP's own arm is first: it wins ties
            if best:
                parts[mid] = cand[best, 0]
                local[mid] = loc[best, 0]
                if end >= 0:
                    parts[end] = cand[best, 1]
                    local[end] = loc[best, 1]

    def _poses(self, res: LevelResult, roots: NDArray[np.int64], flags: tuple[str, ...],
               prior: NDArray[np.floating] | None = None) -> list[Pose]:
        if len(roots) == 0:
            return []
        _, parents, springs, anchors, bias = self._arrays
        parts, local = backtrack(roots, parents, res.resp, res.ix, res.iy, res.ik, springs,
                                 anchors, bias)
        m = self.model
        if prior is not None and self.config.arm_prior > 0 and res.score is not None:
            prior = np.asarray(prior, np.float64)
            if prior.shape != (m.n_parts, 2):
                raise ValueError(f'prior must be ({m.n_parts}, 2) pixels, got {prior.shape}')
            for j in range(len(roots)):
                self._follow_prior(res, parts[j], local[j], prior)
        out = []
        for j in range(len(roots)):
            rows = parts[j, :, 1].astype(np.float64)
            cols = parts[j, :, 2].astype(np.float64)
            if self.config.subcell and res.score is not None:
                dr, dc = subcell_offsets(res.score, parts[j], parents, springs, anchors)
                rows += dr
                cols += dc
            u, v = res.level.cell_to_pixel(rows, cols, m.filter_shape)
            loc = local[j].astype(np.float64)
            search = math.nan
            if res.unary is not None:
                # the network's share out of the part scores, kept in the ranking alone
                search = float(loc.sum())
                loc = loc - res.unary[np.arange(m.n_parts), parts[j, :, 1], parts[j, :, 2]]
            total = float(loc.sum())
            # the pose's score for what comes after (`Pose.score`: the tracker's thresholds):
            # with the network in the unary, the part model's score at the pose the network
            # chose, brought onto the scale of the model's own maxima (`UnaryConfig`)
            score = total if res.unary is None else self.unary.calibrated(total)
            if m.calibration is not None:
                c = m.calibration.astype(np.float64)
                conf = _sigmoid(c[:, 0] * loc + c[:, 1] * total + c[:, 2])
            else:
                conf = _sigmoid(loc)
            f = flags + (('low_score',) if score < self.config.low_score else ())
            out.append(Pose(m.part_names, np.stack([u, v], axis=1), loc, conf, score,
                            res.level.scale, parts[j, :, 0].copy(), f, search))
        return out


def detect(color: NDArray, depth_m: NDArray | None, model: PartModel, *,
           mask: NDArray[np.bool_] | None = None, box: tuple | None = None,
           intrinsics: Intrinsics | None = None, top_k: int = 1,
           config: SearchConfig | None = None) -> list[Pose]:
    """The best poses of a frame (see `Detector.detect`; build a `Detector` once to skip the
    per-call preparation of the model's arrays)."""
    return Detector(model, config).detect(color, depth_m, mask=mask, box=box,
                                          intrinsics=intrinsics, top_k=top_k)
