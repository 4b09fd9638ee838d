"""Offline evaluation of the IK (eqs. 17-24) on real motion (UTKinect-Action3D or MSR Action3D,
split into segments by `evaluation.tracking`): elbows and knees are hidden and inferred from the
3-D shoulders/hips and wrists/ankles with limb lengths (learned from the take or fixed), with
the joint-limit prior alone and with the support of a depth image, by the geometric solver or
the DH chains (`core.dh`); scored by the 3-D error in millimetres.

This module reads files and returns numbers; the `pose4d track-eval` verb prints and saves them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics, depth_to_metres
from pose4d_ros.core.dh import DhLimits, infer_middle_joints_dh
from pose4d_ros.core.kinematics import (
    IkConfig,
    IkFlag,
    body_frame,
    infer_middle_joints,
    middle_joint_circle,
)
from pose4d_ros.core.limb_lengths import LimbLengths
from pose4d_ros.core.skeleton import LIMBS, PARTS_10
from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS
from pose4d_ros.evaluation.tracking import (
    Segment,
    config_dict,
    name_numbers,
    part_indices,
    segment_rng,
)
from pose4d_ros.synth.render import PARENTS, capsule_depth, random_body, render

# Index of each UTKinect joint by name.
_UT = {n: i for i, n in enumerate(UTKINECT_JOINTS)}

# `IkConfig.prior_shrink` fitted with the defaults' prior directions on subjects s01-s06
# (`fit_swivel_prior`): without depth, elbows at 0.68 and knees at 0.16 of the circle's radius
# from its centre are closer on average to Kinect's joints than points on the circle.
SHRUNK_PRIOR: tuple[float, float] = (0.68, 0.16)

# UTKinect joints of each limb (root, middle, end), in `LIMBS` order.
LIMB_JOINTS: dict[str, tuple[str, str, str]] = {
    limb: (root, middle, end) for limb, (root, middle, end) in LIMBS.items()
}

# Bones of the stand-in depth body: (joint a, joint b, radius in metres).
CAPSULE_BONES: tuple[tuple[str, str, float], ...] = (
    ('head', 'shoulder_center', 0.09), ('shoulder_center', 'spine', 0.13),
    ('spine', 'hip_center', 0.13), ('left_shoulder', 'right_shoulder', 0.06),
    ('left_hip', 'right_hip', 0.08), ('left_shoulder', 'left_hip', 0.08),
    ('right_shoulder', 'right_hip', 0.08),
    ('left_shoulder', 'left_elbow', 0.045), ('left_elbow', 'left_wrist', 0.038),
    ('left_wrist', 'left_hand', 0.035),
    ('right_shoulder', 'right_elbow', 0.045), ('right_elbow', 'right_wrist', 0.038),
    ('right_wrist', 'right_hand', 0.035),
    ('left_hip', 'left_knee', 0.07), ('left_knee', 'left_ankle', 0.05),
    ('left_ankle', 'left_foot', 0.04),
    ('right_hip', 'right_knee', 0.07), ('right_knee', 'right_ankle', 0.05),
    ('right_ankle', 'right_foot', 0.04),
)


def capsule_body(joints: NDArray[np.floating], intrinsics: Intrinsics, *,
               rng: np.random.Generator | None = None) -> NDArray[np.float32]:
    """A depth image of a capsule body on a UTKinect skeleton (20, 3), metres, optical frame."""
    j = np.asarray(joints, dtype=np.float64)
    idx = {n: i for i, n in enumerate(UTKINECT_JOINTS)}
    ends = np.stack([[j[idx[a]], j[idx[b]]] for a, b, _ in CAPSULE_BONES])
    radii = np.array([r for _, _, r in CAPSULE_BONES])
    return capsule_depth(ends, radii, intrinsics, rng=rng)


def take_lengths(segments: Sequence[Segment], mode: str) -> dict[str, dict[str, tuple]]:
    """Bone lengths per take for the IK evaluation.

    mode 'take': learned from each take's frames with the elbows/knees visible (medians);
    'reach': learned without them (the reach percentile of `LimbLengths`);
    'fixed': `DEFAULT_LIMB_LENGTHS_M`.
    """
    if mode not in ('take', 'reach', 'fixed'):
        raise ValueError(f"lengths mode must be 'take', 'reach' or 'fixed', got {mode!r}")
    out: dict[str, dict[str, tuple]] = {}
    by_take: dict[str, list[Segment]] = {}
    for seg in segments:
        by_take.setdefault(seg.name.partition('/')[0], []).append(seg)
    for take, segs in by_take.items():
        learner = LimbLengths(window=10 ** 6)
        if mode != 'fixed':
            for seg in segs:
                for limb, (a, m, b) in LIMB_JOINTS.items():
                    learner.observe_many(limb, seg.joints[:, _UT[a]],
                                         seg.joints[:, _UT[m]] if mode == 'take' else None,
                                         seg.joints[:, _UT[b]])
        out[take] = learner.as_dict()
    return out



def _limb_samples(segments: Sequence[Segment], lengths: dict[str, dict[str, tuple]],
                  stride: int) -> dict[str, dict[str, NDArray[np.float64]]]:
    """Per limb: root, middle, end (F, 3), body frames (F, 3, 3) and lengths (F,) x 2."""
    out: dict[str, dict[str, list]] = {limb: {} for limb in LIMB_JOINTS}
    for seg in segments:
        j = seg.joints[::stride]
        frames = np.stack([body_frame(f[_UT['left_shoulder']], f[_UT['right_shoulder']],
                                      f[_UT['left_hip']], f[_UT['right_hip']]) for f in j])
        take = seg.name.partition('/')[0]
        for limb, (a, m, b) in LIMB_JOINTS.items():
            upper, lower = lengths[take][limb]
            for key, value in (('root', j[:, _UT[a]]), ('middle', j[:, _UT[m]]),
                               ('end', j[:, _UT[b]]), ('frame', frames),
                               ('upper', np.full(len(j), upper)),
                               ('lower', np.full(len(j), lower))):
                out[limb].setdefault(key, []).append(value)
    return {limb: {k: np.concatenate(v) for k, v in d.items()} for limb, d in out.items()}


def fit_swivel_prior(segments: Sequence[Segment], lengths: dict[str, dict[str, tuple]], *,
                     stride: int = 3, n_directions: int = 2000, shrink: bool = True,
                     directions: dict[str, tuple[float, float, float]] | None = None
                     ) -> dict[str, tuple[tuple[float, float, float], float]]:
    """Fit the joint-limit prior on (training) segments: direction and shrink per limb type.

    For each of `n_directions` unit vectors (a Fibonacci sphere) of (outward, up, forward)
    coefficients, the middle joint is put at ``centre + s * radius * u`` (u = the direction in
    the circle's plane) with s fitted by least squares (or 1 if not `shrink`); the direction
    with the lowest mean 3-D error wins. Arms and legs separately. With `directions`
    ({'arm': (out, up, forward), 'leg': ...}) only the shrink is fitted, for those directions.

    Returns
    -------
    {'arm': ((out, up, forward), s), 'leg': (...)}.
    """
    k = np.arange(n_directions) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / n_directions)
    azim = math.pi * (1.0 + 5.0 ** 0.5) * k
    dirs = np.stack([np.sin(polar) * np.cos(azim), np.sin(polar) * np.sin(azim),
                     np.cos(polar)], axis=1)
    data = _limb_samples(segments, lengths, stride)
    kind_dirs = {kind: dirs if directions is None else
                 np.asarray([directions[kind]], dtype=np.float64) for kind in ('arm', 'leg')}
    parts: dict[str, list] = {'arm': [], 'leg': []}
    for limb, d in data.items():
        kind = 'arm' if limb.endswith('arm') else 'leg'
        circles = [middle_joint_circle(r0, e0, u, lo) for r0, e0, u, lo in zip(
            d['root'], d['end'], d['upper'], d['lower'], strict=True)]
        centre = np.stack([c.centre for c in circles])
        axis = np.stack([c.axis for c in circles])
        radius = np.array([c.radius for c in circles])
        side = 1.0 if limb.startswith('left') else -1.0
        v = np.einsum('fij,dj->dfi', d['frame'], kind_dirs[kind] * np.array([side, 1.0, 1.0]))
        v = v - np.einsum('dfi,fi->df', v, axis)[..., None] * axis[None]
        v /= np.maximum(np.linalg.norm(v, axis=2, keepdims=True), 1e-9)
        parts[kind].append((centre, radius, v, d['middle']))
    out = {}
    for kind, items in parts.items():
        centre = np.concatenate([c for c, _, _, _ in items])
        radius = np.concatenate([r for _, r, _, _ in items])
        v = np.concatenate([x for _, _, x, _ in items], axis=1)
        truth = np.concatenate([m for _, _, _, m in items])
        e = truth - centre
        if shrink:
            proj = np.einsum('dfi,fi->df', v, e)
            s = np.clip((proj * radius).sum(axis=1) / max(float((radius ** 2).sum()), 1e-12),
                        0.0, 1.0)
        else:
            s = np.ones(len(v))
        err = np.linalg.norm(centre[None] + (s[:, None] * radius[None])[..., None] * v
                             - truth[None], axis=2).mean(axis=1)
        best = int(np.argmin(err))
        out[kind] = (tuple(float(x) for x in np.round(kind_dirs[kind][best], 3)),
                     round(float(s[best]), 3))
    return out


@dataclass
class IkErrors:
    """Sums of 3-D errors (metres) per middle joint and flag counts."""

    def __post_init__(self) -> None:
        self.sum: dict[str, float] = {}
        self.count: dict[str, int] = {}
        self.flags = np.zeros(len(IkFlag), np.int64)

    def add(self, limb: str, err: float, flag: int) -> None:
        self.flags[flag] += 1
        if math.isfinite(err):
            self.sum[limb] = self.sum.get(limb, 0.0) + err
            self.count[limb] = self.count.get(limb, 0) + 1

    def table(self) -> dict[str, object]:
        """{'elbow': mm, 'knee': mm, 'average': mm, 'n': frames, 'flags': {name: count}}."""
        out: dict[str, object] = {}
        for kind, limbs in (('elbow', ('left_arm', 'right_arm')),
                            ('knee', ('left_leg', 'right_leg'))):
            s = sum(self.sum.get(limb, 0.0) for limb in limbs)
            n = sum(self.count.get(limb, 0) for limb in limbs)
            out[kind] = 1000.0 * s / max(n, 1)
        total = sum(self.count.values())
        out['average'] = 1000.0 * sum(self.sum.values()) / max(total, 1)
        out['n'] = int(total)
        out['flags'] = {f.name.lower(): int(self.flags[f]) for f in IkFlag}
        return out


IkFrame = tuple[str, NDArray | None, NDArray | None, NDArray[np.float64]]


def take_bones(segments: Sequence[Segment]) -> dict[str, NDArray[np.float64]]:
    """Median length of the bone ending at each Kinect joint, per take: (20,) metres."""
    by_take: dict[str, list[NDArray]] = {}
    for seg in segments:
        by_take.setdefault(seg.name.partition('/')[0], []).append(seg.joints)
    out = {}
    for take, parts in by_take.items():
        j = np.concatenate(parts)
        bones = np.zeros(len(UTKINECT_JOINTS))
        for i, p in enumerate(PARENTS):
            if p >= 0:
                bones[i] = float(np.median(np.linalg.norm(j[:, i] - j[:, p], axis=1)))
        out[take] = bones
    return out


def synth_renderer(segments: Sequence[Segment], *, seed: int = 0,
                   intrinsics: Intrinsics | None = None, kinect_noise: bool = True
                   ) -> tuple[Callable, dict[str, dict[str, tuple]]]:
    """A renderer for `ik_frames(depth='render')` and the bone lengths of what it renders.

    One random body per take (`synth.render.random_body`, seeded by `seed` and the take)
    with the take's real median bone lengths; each frame is the real pose retargeted to it and
    rendered alone (no room) with the Kinect v1 depth model. The rendered joints, not the
    recorded ones, are the truth of that depth image; the returned lengths (per take, per limb)
    are that body's bones, i.e. what `LimbLengths` learns from the take's rendered frames.
    """
    intrinsics = intrinsics or cad60_intrinsics()
    bodies = {}
    lengths: dict[str, dict[str, tuple]] = {}
    for take, bones in take_bones(segments).items():
        rng = np.random.default_rng([seed, *name_numbers(take), 7])
        bodies[take] = replace(random_body(rng), bones=bones)
        lengths[take] = {limb: (float(bones[_UT[m]]), float(bones[_UT[b]]))
                         for limb, (_, m, b) in LIMB_JOINTS.items()}

    def renderer(take: str, joints: NDArray, rng: np.random.Generator
                 ) -> tuple[NDArray, NDArray, NDArray]:
        out = render(joints, bodies[take], None, intrinsics, rng=rng,
                     kinect_noise=kinect_noise)
        return depth_to_metres(out.depth_mm), out.mask, out.joints

    return renderer, lengths


def ik_frames(segments: Sequence[Segment], *, depth: str = 'none', stride: int = 1,
              seed: int = 0, intrinsics: Intrinsics | None = None,
              renderer: Callable | None = None) -> Iterator[IkFrame]:
    """The frames of an IK evaluation: (take, depth_m or None, mask or None, truth (20, 3)).

    depth : 'none' (joint-limit prior only), 'capsules' (capsules ray-cast on the real
        skeleton with Kinect noise, `capsule_body`; the real joints are the truth) or 'render'
        (``renderer(take, joints (20, 3), rng) -> (depth_m, mask, truth (20, 3))``, e.g.
        `synth_renderer`, whose joints are the truth of its depth image).
    """
    if depth not in ('none', 'capsules', 'render'):
        raise ValueError(f"depth must be 'none', 'capsules' or 'render', got {depth!r}")
    if depth == 'render' and renderer is None:
        raise ValueError("depth='render' needs a renderer")
    if stride < 1:
        raise ValueError(f'stride must be >= 1, got {stride}')
    intrinsics = intrinsics or cad60_intrinsics()
    for seg in segments:
        rng = segment_rng(seed, seg)
        take = seg.name.partition('/')[0]
        for frame in seg.joints[::stride]:
            if depth == 'capsules':
                depth_m = capsule_body(frame, intrinsics, rng=rng)
                yield take, depth_m, np.isfinite(depth_m), frame
            elif depth == 'render':
                depth_m, mask, truth = renderer(take, frame, rng)  # type: ignore[misc]
                yield take, depth_m, mask, np.asarray(truth, dtype=np.float64)
            else:
                yield take, None, None, frame


IK_METHODS = ('geometric', 'dh')


def score_ik(frames: Iterable[IkFrame], lengths: dict[str, dict[str, tuple]], *,
             config: IkConfig | None = None, intrinsics: Intrinsics | None = None,
             method: str = 'geometric', limits: DhLimits | None = None) -> dict[str, object]:
    """Hide elbows and knees, infer them with `infer_middle_joints` (method 'geometric') or
    `dh.infer_middle_joints_dh` ('dh', with `limits`), score in millimetres.

    The inputs are the truth's shoulders, hips, wrists and ankles (3-D) and the frame's depth.
    """
    if method not in IK_METHODS:
        raise ValueError(f'IK method must be one of {IK_METHODS}, got {method!r}')
    intrinsics = intrinsics or cad60_intrinsics()
    config = config or IkConfig()
    extra = {'limits': limits or DhLimits()} if method == 'dh' else {}
    solver = infer_middle_joints_dh if method == 'dh' else infer_middle_joints
    acc = IkErrors()
    pidx = part_indices(PARTS_10)
    for take, depth_m, mask, truth in frames:
        res = solver(depth_m, truth[pidx], intrinsics, lengths[take],
                     names=PARTS_10.names, mask=mask, config=config, **extra)
        for k, (limb, (_, m, _)) in enumerate(LIMB_JOINTS.items()):
            acc.add(limb, float(np.linalg.norm(res.positions[k] - truth[_UT[m]])),
                    int(res.flags[k]))
    return acc.table()


def evaluate_ik(segments: Sequence[Segment], lengths: dict[str, dict[str, tuple]], *,
                depth: str = 'none', config: IkConfig | None = None, stride: int = 1,
                seed: int = 0, intrinsics: Intrinsics | None = None,
                renderer: Callable | None = None, method: str = 'geometric',
                limits: DhLimits | None = None) -> dict[str, object]:
    """`score_ik` over `ik_frames` (see both)."""
    frames = ik_frames(segments, depth=depth, stride=stride, seed=seed, intrinsics=intrinsics,
                       renderer=renderer)
    return score_ik(frames, lengths, config=config, intrinsics=intrinsics, method=method,
                    limits=limits)


def tune_ik_depth(frames: Sequence[IkFrame], lengths: dict[str, dict[str, tuple]],
                  config: IkConfig, *, rounds: int = 2,
                  progress: Callable[[str], None] | None = None
                  ) -> tuple[IkConfig, list[dict]]:
    """Coordinate search of the depth-support parameters on (training) frames with depth.

    The objective is the mean 3-D error of elbows and knees.
    """
    grids: dict[str, list] = {
        'occluded_weight': [0.15, 0.3, 0.6, 1.0],
        'surface_offset_m': [(0.02, 0.04), (0.03, 0.05), (0.04, 0.06), (0.03, 0.07)],
        'depth_scale_m': [0.02, 0.03, 0.05, 0.08],
        'unknown_cost': [0.5, 0.8, 1.0],
        'scale_weight': [0.0, 0.1, 0.3],
        'prior_weight': [0.05, 0.15, 0.4],
        'length_scales': [(1.0,), (0.9, 1.0, 1.1), (0.85, 0.9, 0.95, 1.0, 1.05, 1.1),
                          (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15)],
    }
    log: list[dict] = []
    cache: dict[tuple, float] = {}

    def value(cfg: IkConfig) -> float:
        key = tuple(getattr(cfg, k) for k in grids)
        if key not in cache:
            cache[key] = float(score_ik(frames, lengths, config=cfg)['average'])  # type: ignore
            params = {k: getattr(cfg, k) for k in grids}
            log.append({**params, 'error_mm': cache[key]})
            if progress is not None:
                progress(f'ik {params} -> {cache[key]:.1f} mm')
        return cache[key]

    best = config
    for _ in range(rounds):
        for key, values in grids.items():
            best = min((replace(best, **{key: v}) for v in values), key=value)
    return best, log


def ik_tables(sets: dict[str, Sequence[Segment]], *, methods: Sequence[str] = IK_METHODS,
              tune: bool = False, seed: int = 0, stride: int = 3, depth_stride: int = 15,
              render: bool = True, progress: Callable[[str], None] = lambda msg: None) -> dict:
    """`pose4d track-eval`'s IK tables: for each named set of segments (its first, 'train', the
    one `tune` fits the swivel prior and the depth cost on), each solver of `methods` with the
    prior alone (lengths of the take and fixed), with depth (capsules ray-cast on the real
    skeleton, every `depth_stride`-th frame) and, if `render`, on the synthetic renderer; with
    the configuration, the shrunk prior and the lengths used."""
    say = progress
    config = IkConfig()
    out: dict = {}
    first = next(iter(sets))
    train = sets[first]
    lengths = {name: {mode: take_lengths(segs, mode) for mode in ('take', 'fixed')}
               for name, segs in sets.items()}
    out['lengths'] = {'take': 'per take: medians of the bone lengths over the take\'s frames '
                              '(elbows/knees visible there)',
                      'fixed': 'DEFAULT_LIMB_LENGTHS_M (medians of subjects s01-s06)',
                      'render': 'the rendered body\'s bones (= the take\'s median bones)'}
    if tune:
        say('fitting the IK prior on the training subjects')
        prior = fit_swivel_prior(train, lengths[first]['take'], shrink=False)
        config = replace(config, arm_prior=prior['arm'][0], leg_prior=prior['leg'][0])
        out['prior_fit'] = prior
        say('tuning the depth cost on training frames (minutes)')
        frames = list(ik_frames(train, depth='capsules', stride=30, seed=seed))
        config, log = tune_ik_depth(frames, lengths[first]['take'], config,
                                       progress=say)
        out['tuning_log'] = log
    shrink = SHRUNK_PRIOR
    if tune:
        fit = fit_swivel_prior(train, lengths[first]['take'], directions={
            'arm': config.arm_prior, 'leg': config.leg_prior})
        shrink = (fit['arm'][1], fit['leg'][1])
    out['config'] = config_dict(config)
    out['prior_shrink'] = shrink
    shrunk = replace(config, prior_shrink=shrink)
    renderer = None if not render else {
        name: synth_renderer(segs, seed=seed) for name, segs in sets.items()}
    out['methods'] = {'geometric': 'kinematics.infer_middle_joints (rows without prefix)',
                      'dh': "dh.infer_middle_joints_dh, DhLimits() (rows 'dh: ...')"}
    for name, segs in sets.items():
        rows: dict = {}
        for method in methods:
            pre = 'dh: ' if method == 'dh' else ''
            for mode in ('take', 'fixed'):
                say(f'IK ({method}) on the {name} subjects, prior only, lengths {mode}')
                rows[f'{pre}prior, lengths {mode}'] = evaluate_ik(
                    segs, lengths[name][mode], config=config, stride=stride,
                    method=method)
            if method == 'geometric':
                rows['prior shrunk, lengths take'] = evaluate_ik(
                    segs, lengths[name]['take'], config=shrunk, stride=stride)
            say(f'IK ({method}) on the {name} subjects, depth (capsules ray-cast on the real '
                'skeleton)')
            rows[f'{pre}depth capsules, lengths take'] = evaluate_ik(
                segs, lengths[name]['take'], depth='capsules', config=config,
                stride=depth_stride, seed=seed, method=method)
        if renderer is not None:
            render, render_lengths = renderer[name]
            say(f'IK on the {name} subjects, synthetic renderer (prior only and depth)')
            frames = list(ik_frames(segs, depth='render', stride=depth_stride,
                                       seed=seed, renderer=render))
            no_depth = [(take, None, None, truth) for take, _, _, truth in frames]
            for method in methods:
                pre = 'dh: ' if method == 'dh' else ''
                rows[f'{pre}render: prior'] = score_ik(no_depth, render_lengths,
                                                          config=config, method=method)
                rows[f'{pre}render: depth'] = score_ik(frames, render_lengths,
                                                          config=config, method=method)
        out[name] = rows
    return out
