"""Training frames of the part model: the settings, each frame's part joints and person scale,
positives cut at the canonical scale (and mirrored), background crops (`train`, steps 1 and 4).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics
from pose4d_ros.core.hog import Level, depth_image, feature_pyramid
from pose4d_ros.core.skeleton import PART_TREES, PartTree, mirror_index

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
    latent_radius : 0: each labelled pose is fixed at its labelled cells; r > 0: before every
        mining round each part of a labelled pose moves to the cell within r cells (Chebyshev)
        of its label, its type kept, that the current model scores best (Yang & Ramanan's latent
        positives: it absorbs label noise and the cell grid's phase).
    partial_labels : also train on frames with some parts unlabelled (a torso side labelled,
        at least `min_labelled` parts): their unlabelled parts are latent, placed anywhere and
        of any type by the current model (needs latent_radius > 0); they carry no loss.
    min_labelled : fewest labelled parts of a frame used with partial_labels.
    jitter : extra copies of every positive, each cut from a crop whose origin is shifted by a
        random whole number of image pixels below one HOG cell (at least 1) in x and y: the
        cell grid's phase differs between a crop and the searched whole image, and HOG
        changes by about 20 % for a one-pixel shift.
    loss_alpha : a part is wrong when farther than loss_alpha * the labelled joints' box size.
    cache_limit : most cached negative constraints.
    qp_epochs, qp_tol : coordinate-descent epochs at most, and the relative duality gap at
        which a round's QP stops.
    lda_lambda : ridge of the background covariance, relative to its mean variance.
    calibration_samples : frames used to fit the confidence calibration.
    search_percent : the search without depth covers the training people's person scales from
        this percentile to 100 - it (`PartModel.search_range_px`, widened by a margin).
    bone_ratios : how a frame without depth gets its person scale from its joints. None: the
        longer shoulder-to-hip side (`joint_scale`); else each bone of the part tree
        (`PartTree.edges` order) as a typical fraction of that torso side (`bone_ratios`, set by
        `pose4d train --scale-from bones`), the scale being the upper quartile of the labelled
        bones' lengths over their fractions (`bone_scale`, as Yang & Ramanan size their parts):
        a torso seen end-on or a bent-over body no longer makes a small person.
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
    latent_radius: int = 0
    partial_labels: bool = False
    min_labelled: int = 10
    jitter: int = 0
    loss_alpha: float = 0.1
    cache_limit: int = 20000
    qp_epochs: int = 300
    qp_tol: float = 0.01
    lda_lambda: float = 0.1
    calibration_samples: int = 300
    search_percent: float = 5.0
    levels_per_octave: int = 5
    bone_ratios: tuple[float, ...] | None = None
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
        if not 0 <= self.latent_radius <= 8:
            raise ValueError(f'latent_radius must be in 0..8 cells, got {self.latent_radius}')
        if self.partial_labels and self.latent_radius <= 0:
            raise ValueError('partial_labels needs latent_radius > 0 (unlabelled parts are '
                             f'latent), got latent_radius {self.latent_radius}')
        if not 0 <= self.jitter <= 8:
            raise ValueError(f'jitter must be in 0..8 copies, got {self.jitter}')
        if not 0 <= self.search_percent < 50:
            raise ValueError(f'search_percent must be in [0, 50), got {self.search_percent}')
        if self.mining_rounds < 0:
            raise ValueError(f'mining_rounds must be >= 0, got {self.mining_rounds}')
        r = self.bone_ratios
        if r is not None and (len(r) != len(self.tree.edges())
                              or not all(math.isfinite(x) and x > 0 for x in r)):
            raise ValueError(f'bone_ratios must be {len(self.tree.edges())} positive numbers '
                             f'(one per bone of the {self.parts}-part tree), got {r}')

    @property
    def tree(self) -> PartTree:
        return PART_TREES[self.parts]

    @classmethod
    def of_model(cls, metadata: Mapping[str, str]) -> TrainConfig:
        """The settings a model was trained with, from its metadata's `train_config` (fields
        this version does not know are left out; a model without it: the defaults)."""
        saved = json.loads(metadata.get('train_config', '{}'))
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in saved.items()
                      if k in cls.__dataclass_fields__})


def part_joints(frame, names: Sequence[str]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(P, 2) pixels and (P,) labelled flags of the model's parts in a frame's ground truth
    (`JointSet.labelled`: 'left_wrist' is CAD-60's 'left_hand')."""
    uv, _, labelled = frame.truth.labelled(names)
    return uv, labelled


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


# fewest labelled bones `bone_scale` takes a scale from
MIN_BONES = 3


def bone_lengths(uv: NDArray, labelled: NDArray[np.bool_], tree: PartTree) -> NDArray[np.float64]:
    """(E,) pixel length of each bone (parent, child) of `tree.edges()`; NaN where an end is
    unlabelled or the two ends coincide."""
    out = np.full(len(tree.edges()), np.nan)
    for k, (p, c) in enumerate(tree.edges()):
        if labelled[p] and labelled[c]:
            d = float(np.hypot(*(np.asarray(uv[c], float) - uv[p])))
            out[k] = d if d >= 1.0 else np.nan
    return out


def bone_ratios(joints: Iterable[tuple[NDArray, NDArray[np.bool_]]], tree: PartTree
                ) -> tuple[float, ...]:
    """Each bone's typical length as a fraction of the torso side (`joint_scale`): the
    geometric median, over the frames' `(uv, labelled)` part joints where both are labelled,
    of bone / torso (Yang & Ramanan's `point2box`). A torso side's own ratio is 1."""
    logs: list[list[float]] = [[] for _ in tree.edges()]
    for uv, lab in joints:
        torso = joint_scale(np.where(lab[:, None], uv, np.nan), tree.names)
        if not torso >= 1.0:
            continue
        for k, d in enumerate(bone_lengths(uv, lab, tree)):
            if np.isfinite(d):
                logs[k].append(math.log(d / torso))
    if not all(logs):
        missing = [tree.names[c] for (_, c), x in zip(tree.edges(), logs, strict=True) if not x]
        raise ValueError(f'no frame labels both ends of the bones to {", ".join(missing)} '
                         'with a torso side: bone ratios need them')
    return tuple(round(math.exp(float(np.median(x))), 4) for x in logs)


def bone_scale(uv: NDArray, labelled: NDArray[np.bool_], tree: PartTree,
               ratios: Sequence[float]) -> float:
    """Person scale from 2-D joints (torso-side units): the upper quartile over the labelled
    bones of length / `ratios` (foreshortening only shortens a bone, so the longer ones tell
    the size best). NaN with fewer than `MIN_BONES` bones labelled."""
    d = bone_lengths(uv, labelled, tree) / np.asarray(ratios, float)
    d = d[np.isfinite(d)]
    return float(np.quantile(d, 0.75)) if len(d) >= MIN_BONES else float('nan')


def person_scale(sample, names: Sequence[str], cfg: TrainConfig, uv: NDArray | None = None
                 ) -> float:
    """The person scale in image pixels: fx * scale_length_m / z from depth when the sample
    has it (as the detector predicts it at run time from the foreground mask's median depth),
    else from the joints (`bone_scale` with `cfg.bone_ratios`, else `joint_scale`)."""
    if uv is None:
        uv, _ = part_joints(sample, names)
    if sample.depth_m is not None:
        z = person_depth(sample.depth_m, sample.mask, uv)
        if np.isfinite(z):
            h, w = sample.depth_m.shape
            k: Intrinsics = sample.intrinsics or cad60_intrinsics(w, h)
            return k.fx * cfg.scale_length_m / z
    if cfg.bone_ratios is not None:
        puv, lab = part_joints(sample, cfg.tree.names)
        return bone_scale(puv, lab, cfg.tree, cfg.bone_ratios)
    return joint_scale(sample.truth.uv, list(sample.truth.names))


@dataclass
class Positive:
    patches: NDArray[np.float32]   # (P, D) raw filter windows at the labelled cells
    cells: NDArray[np.int64]       # (P, 2) row, col in the padded level
    offsets: NDArray[np.float64]   # (P, 2) (du, dv) from the parent, canonical pixels
    scale: float                   # person scale, image pixels
    level_scale: float             # level pixels per image pixel
    box: tuple[int, int, int, int]  # crop, image pixels
    tau: float                     # PCK radius of the loss, cells
    sample: int                    # index into the samples
    flipped: bool
    labelled: NDArray[np.bool_] | None = None   # (P,) parts with a label (None: all)

    def known(self) -> NDArray[np.bool_]:
        return (np.ones(len(self.cells), bool) if self.labelled is None
                else np.asarray(self.labelled, bool))


def _crop_box(uv: NDArray, margin: float, w: int, h: int) -> tuple[int, int, int, int]:
    x0 = max(int(np.floor(np.nanmin(uv[:, 0]) - margin)), 0)
    y0 = max(int(np.floor(np.nanmin(uv[:, 1]) - margin)), 0)
    x1 = min(int(np.ceil(np.nanmax(uv[:, 0]) + margin)) + 1, w)
    y1 = min(int(np.ceil(np.nanmax(uv[:, 1]) + margin)) + 1, h)
    return x0, y0, x1, y1


def level_of(color: NDArray, depth_m: NDArray | None, mask: NDArray[np.bool_] | None,
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
    idx = mirror_index(names)
    fuv = uv[idx].copy()
    fuv[:, 0] = w - 1 - fuv[:, 0]
    return col, dep, msk, fuv


def frame_of(sample, names: Sequence[str], cfg: TrainConfig, flipped: bool) -> tuple:
    """(colour, depth or None, mask or None, (P, 2) part pixels) of a sample, mirrored if
    asked."""
    uv, _ = part_joints(sample, names)
    depth = sample.depth_m if cfg.channels == 'rgbd' else None
    if flipped:
        return _flip(sample.color, depth, sample.mask, uv, names)
    return sample.color, depth, sample.mask, uv


def prepare_positive(sample, index: int, flipped: bool, s: float, tree: PartTree,
                      cfg: TrainConfig, shift: tuple[int, int] = (0, 0)) -> Positive | None:
    """A labelled frame at the canonical scale; None when a labelled part's window leaves the
    level. Parts without a label (`cfg.partial_labels`) get the cell of the first labelled
    part, a zero window and NaN offsets: training makes them latent. `shift` (dx, dy) >= 0
    moves the crop's origin by that many image pixels (`cfg.jitter`: another phase of the HOG
    cell grid)."""
    color, depth, mask, uv = frame_of(sample, tree.names, cfg, flipped)
    known = np.isfinite(uv).all(axis=1)
    if not known.any():
        return None
    h, w = color.shape[:2]
    f = cfg.canonical_scale_px / s
    box = _crop_box(uv[known], 1.0 * s, w, h)
    dx, dy = int(shift[0]), int(shift[1])
    if dx < 0 or dy < 0:
        raise ValueError(f'shift must be >= 0 pixels, got {shift}')
    box = (min(box[0] + dx, box[2] - 1), min(box[1] + dy, box[3] - 1), box[2], box[3])
    level = level_of(color, depth, mask, box, f, cfg)
    fs = (cfg.filter_cells, cfg.filter_cells)
    first = uv[int(np.argmax(known))]
    filled = np.where(known[:, None], uv, first[None])
    rows, cols = level.pixel_to_cell(filled[:, 0], filled[:, 1], fs)
    hh, ww, _ = level.feat.shape
    if (rows < 0).any() or (cols < 0).any() or (rows > hh - fs[0]).any() or (
            cols > ww - fs[1]).any():
        return None
    patches = np.stack([level.feat[r:r + fs[0], c:c + fs[1]].reshape(-1)
                        for r, c in zip(rows, cols, strict=True)])
    patches[~known] = 0.0
    par = np.asarray(tree.parents)
    offs = np.zeros((len(tree), 2))
    offs[1:] = (uv[1:] - uv[par[1:]]) * f
    size = float(np.max(np.ptp(uv[known], axis=0)))
    tau = cfg.loss_alpha * size * f / cfg.sbin
    return Positive(patches.astype(np.float32), np.stack([rows, cols], 1), offs, s, f, box,
                     tau, index, flipped, known)


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
        uv = sample.truth.uv[sample.truth.confidence > 0]
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
