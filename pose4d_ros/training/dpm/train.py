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
   the part is within the PCK@0.1 radius, fitted on detections of training frames; and, for
   an RGB-D model, how far behind the visible surface each joint centre lies (the depth
   offset that lifts a part to its joint in 3-D).

Modules: `samples` (the settings, step 1's positives and the background crops), `solver` (the
QP of step 4: weight layout, constraint cache, whitening, dual coordinate descent), `mining`
(step 4's hard negatives); this one holds steps 2, 3 and 5 and `train`, which runs them all.

Everything is deterministic for a given seed. Progress is reported through the optional
`progress` (an iterable wrapper such as tqdm) and `log` callables; this module never prints.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import backproject, lift_depth
from pose4d_ros.core.dpm.infer import Detector
from pose4d_ros.core.dpm.model import DEFAULT_DEPTH_LOOKUP, PartModel
from pose4d_ros.core.hog import N_FEATURES, Level
from pose4d_ros.core.skeleton import PartTree
from pose4d_ros.training.dpm.mining import mine_background, mine_structural, relabel_positives
from pose4d_ros.training.dpm.samples import (
    Log,
    Negative,
    Positive,
    Progress,
    TrainConfig,
    frame_of,
    level_of,
    part_joints,
    person_scale,
    prepare_positive,
)
from pose4d_ros.training.dpm.solver import (
    Examples,
    Layout,
    Whitening,
    dcd,
    margins,
    model_from_w,
    pose_blocks,
    rebuild_w,
    w_from_model,
    whitened,
)


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


def _lda_model(pos: list[Positive], types: NDArray[np.int64], windows: NDArray[np.float64],
               lay: Layout, tree: PartTree, cfg: TrainConfig, anchors: NDArray[np.int32],
               spring_var: NDArray[np.float64], scale_range: tuple[float, float]
               ) -> tuple[PartModel, Whitening]:
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
    return model, Whitening(mu0, np.linalg.inv(chol), chol)


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


# Fewest right and fewest wrong detections of a part for its logistic confidence (fewer: the
# part's rate of being right)
MIN_OUTCOMES = 30

# The depth look-ups the calibration chooses from per part (`PartModel.depth_lookup`): window
# half-sizes, metres on the body, and quantiles of the window's depths. The first is the
# look-up of a part nothing was learned for.
LOOKUP_RADII_M = (DEFAULT_DEPTH_LOOKUP[0], 0.055, 0.08, 0.105)
LOOKUP_QUANTILES = (DEFAULT_DEPTH_LOOKUP[1], 0.7, 0.8, 0.9)
LOOKUPS = tuple((r, q) for r in LOOKUP_RADII_M for q in LOOKUP_QUANTILES)


def choose_depth_lookup(right: NDArray[np.bool_], rays: NDArray[np.float64],
                        truth: NDArray[np.float64], depths: NDArray[np.float64],
                        tolerance_m: float = 0.1) -> tuple[int, float]:
    """The look-up that lifts one part's detections best, and its depth offset.

    right : (N,) the detection is right in the image; rays : (N, 3) each detection's pixel as
    (x/z, y/z, 1); truth : (N, 3) the joints' 3-D positions; depths : (N, L) the depth each of
    the L look-ups gives. A look-up's offset is the median of truth z less its depth over the
    right detections (how far behind the surface the joint lies); its worth, the share of all
    detections it puts within `tolerance_m` of the joint in 3-D. Returns (index, offset); the
    first look-up with offset 0 when no detection was right.
    """
    best, best_offset, best_share = 0, 0.0, -1.0
    for c in range(depths.shape[1]):
        z = depths[:, c]
        behind = truth[right, 2] - z[right]
        behind = behind[np.isfinite(behind)]
        if len(behind) == 0:
            continue
        offset = float(np.median(behind))
        with np.errstate(invalid='ignore'):
            err = np.linalg.norm(rays * (z + offset)[:, None] - truth, axis=1)
            share = float(np.mean(err < tolerance_m))
        if share > best_share:
            best, best_offset, best_share = c, offset, share
    return best, best_offset


def _labelled(samples: Sequence, names: Sequence[str], progress: Progress | None, what: str
              ) -> Iterator[tuple[object, NDArray, NDArray, NDArray]]:
    """(sample, uv, xyz, visible) of each sample with at least two of `names` labelled, behind
    a progress bar named `what` when `progress` is given (the calibration's loops)."""
    it: Iterable = samples if progress is None else progress(samples, what, len(samples))
    for s in it:
        uv, xyz, vis = s.truth.labelled(names)
        if vis.sum() >= 2:
            yield s, uv, xyz, vis


def right_parts(found: NDArray[np.floating], uv: NDArray[np.floating],
                vis: NDArray[np.bool_], alpha: float) -> NDArray[np.bool_]:
    """Which of the labelled parts (`vis`) at `uv` the detected ones at `found` place within
    alpha * the size of the labelled parts' box (the calibration's 'right')."""
    size = np.max(np.ptp(uv[vis], axis=0))
    return vis & (np.hypot(*(found - uv).T) <= alpha * size)


# The scale priors the calibration of a model searched without depth chooses from (score per
# octave of person scale, `PartModel.scale_prior`)
SCALE_PRIORS = (0.0, 0.5, 1.0, 2.0, 3.0, 4.0)


def choose_scale_prior(model: PartModel, samples: Sequence, *, alpha: float = 0.1,
                       progress: Progress | None = None) -> float:
    """The `SCALE_PRIORS` value under which the search without depth places most labelled
    parts of `samples` within alpha * the size of their joints' box (the smallest on a tie).

    Each sample is searched once: the best pose of every pyramid level, then each prior ranks
    them.
    """
    det = Detector(replace(model, scale_prior=0.0))
    right = np.zeros(len(SCALE_PRIORS))
    for s, uv, _, vis in _labelled(samples, model.part_names, progress, 'scale prior'):
        plan = det.plan(s.color.shape[:2], None)
        if plan is None:
            continue
        best = [p[0] for p in (det.poses_from_levels([lev])
                               for lev in det.pyramid(s.color, None, plan)) if p]
        if not best:
            continue
        octave = np.log2(model.canonical_scale_px / np.array([p.scale for p in best]))
        score = np.array([p.score for p in best])
        for i, prior in enumerate(SCALE_PRIORS):
            p = best[int(np.argmax(score + prior * octave))]
            right[i] += np.sum(right_parts(p.uv, uv, vis, alpha))
    return float(SCALE_PRIORS[int(np.argmax(right))])


def calibrate(model: PartModel, samples: Sequence, *, use_depth: bool,
              progress: Progress | None = None, alpha: float = 0.1) -> PartModel:
    """Fit the per-part logistic confidence on detections of `samples` (a part is 'right' when
    within alpha * the size of the ground-truth joints' box). With `use_depth` the frames are
    searched as at run time (depth, the sample's mask); else without depth.

    Without depth, first the model's `scale_prior` (`choose_scale_prior`, on the same samples).
    With depth, also how each part is lifted to 3-D: the look-up (`PartModel.depth_lookup`,
    one of `LOOKUPS` by `choose_depth_lookup`) and the depth offset (`depth_offset_m`) that put
    most detected joints within 10 cm of the truth in 3-D, the offset being how far behind the
    visible surface the joint centre lies; a left and a right part share them.
    """
    if not use_depth:
        model = replace(model, scale_prior=choose_scale_prior(model, samples,
                                                              progress=progress))
    det = Detector(model)
    xs, ys = [], []
    seen: list[list] = [[] for _ in model.part_names]  # (right, ray, truth, depths) per part
    for s, uv, xyz, vis in _labelled(samples, model.part_names, progress, 'calibration'):
        mask = None
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
        right = right_parts(p.uv, uv, vis, alpha)
        for i in np.flatnonzero(vis):
            xs.append((i, p.part_scores[i], p.score))
            ys.append(float(right[i]))
        if use_depth and s.depth_m is not None and s.intrinsics is not None:
            k = s.intrinsics
            depths = np.stack([lift_depth(s.depth_m, p.uv, k, r, q, mask=mask)
                               for r, q in LOOKUPS], axis=1)
            rays = backproject(p.uv, np.ones(len(p.uv)), k)  # (x/z, y/z, 1)
            for i in np.flatnonzero(vis & np.isfinite(xyz).all(axis=1)):
                seen[i].append((right[i], rays[i], xyz[i], depths[i]))
    cal = np.zeros((model.n_parts, 3), np.float32)
    if xs:
        arr = np.asarray(xs)
        yv = np.asarray(ys)
        for i in range(model.n_parts):
            sel = arr[:, 0] == i
            # a logistic needs both outcomes often enough: fitted on a handful of misses (a
            # head is almost always right) it gives right parts a confidence near 0
            if min(yv[sel].sum(), (1 - yv[sel]).sum()) >= MIN_OUTCOMES:
                cal[i] = _fit_logistic(arr[sel, 1:], yv[sel])
            elif sel.any():
                rate = float(np.clip(yv[sel].mean(), 0.01, 0.99))
                cal[i] = (0.0, 0.0, np.log(rate / (1 - rate)))
    if not any(seen):
        return replace(model, calibration=cal, depth_offset_m=None, depth_lookup=None)
    lookup = np.array([LOOKUPS[0]] * model.n_parts, np.float32)
    offset = np.zeros(model.n_parts, np.float32)
    # a left part and its right twin share one look-up, chosen on both's detections
    sides = {}
    for i, name in enumerate(model.part_names):
        sides.setdefault(name.removeprefix('left_').removeprefix('right_'), []).append(i)
    for parts in sides.values():
        obs = [o for i in parts for o in seen[i]]
        if obs:
            right, rays, truth, depths = (np.array(a) for a in zip(*obs, strict=True))
            c, offset[parts] = choose_depth_lookup(right.astype(bool), rays, truth, depths)
            lookup[parts] = LOOKUPS[c]
    return replace(model, calibration=cal, depth_offset_m=offset, depth_lookup=lookup)


# The person scales the training people leave out at each end: 1 % for the trained range
# (`PartModel.scale_range_px`: mining, and the bounds of the depth-guided search),
# `TrainConfig.search_percent` for the search without depth (`PartModel.search_range_px`);
# each widened by SCALE_MARGIN
SCALE_MARGIN = 1.15


def scale_span(scales: NDArray[np.float64], percent: float) -> tuple[float, float]:
    """(lo, hi) person scales, pixels: the `percent` and 100 - `percent` percentiles of the
    training people's `scales`, widened by `SCALE_MARGIN`."""
    return (float(np.percentile(scales, percent) / SCALE_MARGIN),
            float(np.percentile(scales, 100 - percent) * SCALE_MARGIN))


def positive_scale(sample, names: Sequence[str], cfg: TrainConfig) -> float:
    """The person scale of a frame that makes a positive (every part labelled, or enough of
    them with `cfg.partial_labels`), pixels; NaN for a frame that does not."""
    uv, vis = part_joints(sample, names)
    if not vis.all() and not (cfg.partial_labels and vis.sum() >= cfg.min_labelled):
        return float('nan')
    return float(person_scale(sample, names, cfg, uv))


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
    samples : labelled frames (`datasets.frame.Frame`); frames without every part of the
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
    dim = cfg.filter_cells ** 2 * N_FEATURES * (2 if cfg.channels == 'rgbd' else 1)
    report = TrainReport(n_samples=len(samples), n_negative_images=len(negatives))
    if cfg.channels == 'rgbd' and not any(s.depth_m is not None for s in samples):
        raise ValueError('an rgbd model needs samples with depth (the source has none); '
                         'train with channels rgb')
    negs = list(negatives) if cfg.background_negatives else []
    if cfg.background_negatives and not negs:
        raise ValueError('no background images to mine negatives from')
    pos, sc_arr = _positives(samples, cfg, progress)
    report.n_positives = len(pos)
    scale_range = scale_span(sc_arr, 1.0)
    say(f'{len(pos)} positives from {len(samples)} frames; person scale '
        f'{np.median(sc_arr):.1f} px (trained {scale_range[0]:.1f}-{scale_range[1]:.1f} px, '
        'searched without depth {:.1f}-{:.1f} px)'.format(*scale_span(sc_arr,
                                                                     cfg.search_percent)))
    types, anchors, spring_var = _part_types(pos, cfg.tree, cfg.n_types, rng)
    lay = Layout(len(cfg.tree), cfg.n_types, dim)
    model, white = _lda_start(pos, types, samples, negs, lay, cfg, anchors, spring_var,
                              scale_range, rng, say)
    model = _structural_svm(model, pos, types, samples, negs, lay, cfg, white, anchors,
                            scale_range, report, say, progress)
    # 5. calibration on training frames (a deterministic subset), searched as at run time
    model = replace(model, search_range_px=scale_span(sc_arr, cfg.search_percent))
    usable = [s for s in samples if part_joints(s, cfg.tree.names)[1].sum() >= 2]
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


def _positives(samples: Sequence, cfg: TrainConfig, progress: Progress | None
               ) -> tuple[list[Positive], NDArray[np.float64]]:
    """1. The positives at the canonical scale (+ mirror images and jittered copies), and the
    person scale of each frame they come from, pixels."""
    tree = cfg.tree
    pos: list[Positive] = []
    scales = []
    jitter_rng = np.random.default_rng(cfg.seed + 7919)   # apart: jitter 0 keeps `rng` as was
    it: Iterable = enumerate(samples)
    if progress is not None:
        it = progress(it, 'positives', len(samples))
    for idx, s in it:
        sc = positive_scale(s, tree.names, cfg)
        if not sc > 2:
            continue
        scales.append(sc)
        for flipped in (False, True) if cfg.flip else (False,):
            p = prepare_positive(s, idx, flipped, sc, tree, cfg)
            if p is None:
                continue
            pos.append(p)
            # jittered copies: the crop's origin moved by 1 .. cell - 1 image pixels
            cell_px = cfg.sbin * sc / cfg.canonical_scale_px
            top = max(int(np.ceil(cell_px)) - 1, 1)
            for _ in range(cfg.jitter):
                dx, dy = jitter_rng.integers(1, top + 1, 2)
                pj = prepare_positive(s, idx, flipped, sc, tree, cfg, (int(dx), int(dy)))
                if pj is not None:
                    pos.append(pj)
    need = max(2 * cfg.n_types, 10)
    if len(pos) < need:
        raise ValueError(f'only {len(pos)} usable positives (frames with every one of the '
                         f'{len(tree)} parts labelled); need at least {need}')
    return pos, np.asarray(scales)


def _part_types(pos: list[Positive], tree: PartTree, k: int, rng: np.random.Generator
                ) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float64]]:
    """2. Part types by k-means on offsets (N, P), -1 = latent; the anchors (P, K, 2) (dx, dy
    cells) and spring variances (P, K, 2) from the quantised cells."""
    types = np.zeros((len(pos), len(tree)), np.int64)
    offs = np.stack([p.offsets for p in pos])          # (N, P, 2)
    cells = np.stack([p.cells for p in pos])           # (N, P, 2) row, col
    # a part whose offset is unknown (it or its parent unlabelled) gets type -1: latent
    for c in range(1, len(tree)):
        ok = np.isfinite(offs[:, c]).all(1)
        types[~ok, c] = -1
        _, types[ok, c] = kmeans(offs[ok, c], k, rng)
    kids = tree.children(0)
    root_offs = offs[:, kids].reshape(len(pos), -1)
    ok = np.isfinite(root_offs).all(1)
    types[~ok, 0] = -1
    _, types[ok, 0] = kmeans(root_offs[ok], k, rng)
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
    return types, anchors, spring_var


def _lda_start(pos: list[Positive], types: NDArray[np.int64], samples: Sequence,
               negs: list[Negative], lay: Layout, cfg: TrainConfig, anchors: NDArray[np.int32],
               spring_var: NDArray[np.float64], scale_range: tuple[float, float],
               rng: np.random.Generator, say: Log) -> tuple[PartModel, Whitening]:
    """3. Per-part templates (LDA) against random windows of positives' and background levels:
    the first model w0 and the whitening."""
    want = 20000
    fs = cfg.filter_cells
    sources: list[Level] = []
    sub = rng.choice(len(pos), min(len(pos), 400), replace=False)
    for i in np.sort(sub):
        p = pos[i]
        color, depth, mask, _ = frame_of(samples[p.sample], cfg.tree.names, cfg, p.flipped)
        sources.append(level_of(color, depth, mask, p.box, p.level_scale, cfg))
    lo, hi = scale_range
    for n in (negs[j] for j in np.sort(rng.choice(len(negs), min(len(negs), 400),
                                                  replace=False))) if negs else ():
        f = cfg.canonical_scale_px / float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        h, w_ = n.color.shape[:2]
        sources.append(level_of(n.color, n.depth_m, None, (0, 0, w_, h), f, cfg))
    windows = _random_windows(sources, fs, max(want // max(len(sources), 1), 4), rng)
    del sources
    model, white = _lda_model(pos, types, windows, lay, cfg.tree, cfg, anchors, spring_var,
                              scale_range)
    say(f'part templates by LDA on {len(windows)} random windows')
    return model, white


def _structural_svm(model: PartModel, pos: list[Positive], types: NDArray[np.int64],
                    samples: Sequence, negs: list[Negative], lay: Layout, cfg: TrainConfig,
                    white: Whitening, anchors: NDArray[np.int32],
                    scale_range: tuple[float, float], report: TrainReport, say: Log,
                    progress: Progress | None) -> PartModel:
    """4. The structural SVM of eq. (5), regularised towards w0 = the LDA model, over
    `cfg.mining_rounds` rounds of relabelling and hard-negative mining; each round's figures
    go to `report.rounds`."""
    tree, k, fs = cfg.tree, cfg.n_types, cfg.filter_cells
    par = np.asarray(tree.parents)
    cap = len(pos) + cfg.cache_limit
    ex = Examples(cap, lay.n_parts, lay.dim)
    for i, p in enumerate(pos):
        # a latent type starts as type 0 (the first relabelling replaces it)
        parts = np.concatenate([np.maximum(types[i], 0)[:, None], p.cells], axis=1)
        blocks = pose_blocks(np.zeros((0, 0, 0), np.float32), parts, par, anchors, lay, fs,
                             cfg.bias_feature, patches=p.patches)
        ex.add(whitened(blocks, white), 1.0, 1.0, -1, ('pos', i))
    n_pos = ex.n
    # the regulariser is |w - w0|^2 with w0 = the LDA model: the SVM corrects the whitened-HOG
    # templates rather than starting from nothing (w = w0 + sum a y x + sum b e)
    w0 = w_from_model(model, lay, white, cfg)
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
            marg = margins(w, *arr[:7], arr[8])
            keep = np.flatnonzero((np.arange(ex.n) < n_pos) | (ex.alpha[:ex.n] > 0)
                                  | (marg < arr[7] + 0.05))
            if len(keep) < ex.n:
                ex.keep(keep)
        moved = 0
        if cfg.latent_radius > 0:
            moved = relabel_positives(model, pos, types, samples, ex, lay, cfg, white, progress,
                                      rnd)
            arr = ex.arrays()
            w = rebuild_w(w0, *arr[:7], arr[8], ex.alpha[:ex.n], lb_idx, beta)
        added_bg = 0
        if negs:
            added_bg = mine_background(model, negs, ex, lay, cfg, white,
                                       max((cap - ex.n) // 2, 0), progress, rnd)
        added_st = mine_structural(model, pos, samples, w, ex, lay, cfg, white, cap - ex.n,
                                   progress, rnd)
        t1 = time.perf_counter()
        arr = ex.arrays()
        cost = np.where(np.arange(ex.n) < n_pos, cfg.svm_c * cfg.positive_weight, cfg.svm_c)
        epochs, gap, obj, marg = _solve_qp(w, w0, arr, ex.alpha[:ex.n], cost, lb_idx, lb_val,
                                           beta, cfg, rnd)
        ok = marg >= arr[7] - 1e-9
        kind = np.where(np.arange(ex.n) < n_pos, 0, np.where(arr[8] >= 0, 2, 1))
        t2 = time.perf_counter()
        info = dict(round=rnd, positives_moved=moved, background_added=added_bg,
                    poses_added=added_st, cache=ex.n - n_pos, qp_epochs=epochs,
                    qp_gap=round(gap, 4), objective=round(obj, 4),
                    positives_ok=round(float(ok[kind == 0].mean()), 3),
                    background_ok=round(float(ok[kind == 1].mean()), 3) if (kind == 1).any()
                    else None,
                    poses_ok=round(float(ok[kind == 2].mean()), 3) if (kind == 2).any()
                    else None,
                    mine_s=round(t1 - t0, 1), qp_s=round(t2 - t1, 1))
        report.rounds.append(info)
        say(' '.join(f'{a}={b}' for a, b in info.items()))
        model = model_from_w(w, lay, tree, cfg, anchors, scale_range, white)
    return model


def _solve_qp(w: NDArray[np.float64], w0: NDArray[np.float64], arr: tuple,
              alpha: NDArray[np.float64], cost: NDArray[np.float64], lb_idx: NDArray[np.int64],
              lb_val: NDArray[np.float64], beta: NDArray[np.float64], cfg: TrainConfig,
              rnd: int) -> tuple[int, float, float, NDArray[np.float64]]:
    """Dual coordinate descent (`w`, `alpha`, `beta` updated in place) in steps of 10 epochs
    until the relative duality gap is below `cfg.qp_tol` or `cfg.qp_epochs` are spent; returns
    the epochs run, the gap, the primal objective and the margins."""
    epochs = 0
    gap = np.inf
    obj = np.nan
    marg = np.zeros(len(alpha))
    while epochs < cfg.qp_epochs:
        dcd(w, *arr[:9], alpha, cost, lb_idx, lb_val, beta, 10,
            cfg.seed + 1000 * rnd + epochs)
        epochs += 10
        marg = margins(w, *arr[:7], arr[8])
        loss = float(cost @ np.maximum(0.0, arr[7] - marg))
        u = w - w0
        obj = 0.5 * float(u @ u) + loss
        dual = float(alpha @ arr[7] + beta @ lb_val) - 0.5 * float(u @ u) - float(w0 @ u)
        gap = (obj - dual) / max(abs(obj), 1e-12)
        if gap < cfg.qp_tol:
            break
    return epochs, gap, obj, marg
