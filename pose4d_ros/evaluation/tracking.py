"""Offline evaluation of the tracker (SLQE, eqs. 6-16) and the IK (eqs. 17-24) on real motion.

Real Kinect v1 skeleton motion (UTKinect-Action3D) stands in for a detector's output:

- Tracking: the 10 parts of the reduced model (head, neck = shoulder centre, shoulders, wrists,
  hips, ankles) are projected into a 320x240 image with the CAD-60 intrinsics and corrupted the
  way a part detector fails (seeded): Gaussian noise, outliers (a part jumps 20-60 px away) and
  dropouts (NaN). The corrupted input as-is, a plain constant-velocity Kalman filter, the same
  filter with the innovation gate, and SLQE are scored by their mean pixel error against the
  clean projection.
- IK (`evaluation.ik`, on the segments read here): elbows and knees are hidden and inferred from
  the 3-D shoulders/hips and wrists/ankles.

UTKinect frame numbers are sparse (steps of 2-8 frames of a 30 fps stream) with some long gaps
between action clips; a take is split into segments at gaps over `max_gap_s` (no motion is
invented across a gap) and each segment is resampled to 30 fps and tracked from scratch.

This module reads files and returns numbers; the `pose4d track-eval` verb prints and saves them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics, project
from pose4d_ros.core.skeleton import PARTS_10, PartTree, group_of
from pose4d_ros.core.slqe import (
    ConstantVelocityTracker,
    CvConfig,
    SlqeConfig,
    SlqeTracker,
    Source,
)
from pose4d_ros.datasets import msraction3d
from pose4d_ros.datasets.utkinect import (
    UTKINECT_JOINTS,
    Take,
    list_takes,
    read_take,
    resample,
    to_optical,
)

# Index of each UTKinect joint by name.
_UT = {n: i for i, n in enumerate(UTKINECT_JOINTS)}

# UTKinect joint used for each part name that it spells differently.
UTKINECT_NAMES: dict[str, str] = {'neck': 'shoulder_center'}

# The constant-velocity filter with the innovation gate, tuned like SlqeConfig's defaults
# (subjects s01-s06, seed 0; `tune_tracking`).
GATED_CV = CvConfig(process_noise=30.0, measurement_noise_px=3.0, gate_chi2=20.0)

# Ablation: SLQE's tree coupling on a constant-velocity state (order 2), tuned on a small grid
# around GATED_CV (subjects s01-s06, seed 0).
SLQE_ORDER2 = SlqeConfig(order=2, coupling=0.1, process_noise=30.0, measurement_noise_px=3.0,
                         gate_chi2=20.0)

TRAIN_SUBJECTS: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
TEST_SUBJECTS: tuple[int, ...] = (7, 8)


@dataclass(frozen=True)
class Segment:
    """A stretch of one take without long gaps, resampled to a regular rate.

    Attributes
    ----------
    name : 'sNN_eMM/k', k = segment index in the take.
    subject : NN.
    times : (T,) float64 seconds.
    joints : (T, 20, 3) float64 metres, optical frame, `UTKINECT_JOINTS` order.
    """

    name: str
    subject: int
    times: NDArray[np.float64]
    joints: NDArray[np.float64]


@dataclass(frozen=True)
class Corruption:
    """Detector-like corruption of clean part pixels.

    Attributes
    ----------
    noise_px : Gaussian noise per axis, pixels (standard deviation).
    outlier_rate : fraction of detections that jump away.
    outlier_px : (min, max) distance of a jump, pixels (uniform, random direction).
    dropout_rate : fraction of detections lost (NaN).
    """

    noise_px: float = 3.0
    outlier_rate: float = 0.10
    outlier_px: tuple[float, float] = (20.0, 60.0)
    dropout_rate: float = 0.05


def split_take(take: Take, *, max_gap_s: float = 0.5, fps: float = 30.0,
               min_frames: int = 15, native: bool = False) -> list[Segment]:
    """Split a take at gaps over `max_gap_s` and resample each piece to `fps` (optical frame).

    With `native`, the pieces keep the recorded (irregular) frame times instead.
    """
    gaps = np.flatnonzero(np.diff(take.frames) / 30.0 > max_gap_s)
    bounds = np.concatenate([[0], gaps + 1, [len(take.frames)]])
    out = []
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        piece = Take(take.name, take.frames[a:b], take.joints[a:b])
        if native:
            times = (piece.frames - piece.frames[0]) / 30.0
            joints = piece.joints
        else:
            times, joints = resample(piece, fps=fps)
        if len(times) < min_frames:
            continue
        out.append(Segment(f'{take.name}/{k}', take.subject, times, to_optical(joints)))
    return out


def load_segments(directory: str | Path, subjects: Iterable[int] | None = None, *,
                  max_gap_s: float = 0.5, native: bool = False) -> list[Segment]:
    """All segments of the UTKinect takes in `directory` (optionally only some subjects)."""
    paths = list_takes(directory)
    if not paths:
        raise ValueError(f'{directory}: no joints_sNN_eMM.txt files')
    keep = None if subjects is None else set(subjects)
    out: list[Segment] = []
    for path in paths:
        take = read_take(path)
        if keep is not None and take.subject not in keep:
            continue
        out.extend(split_take(take, max_gap_s=max_gap_s, native=native))
    return out


def load_msr_segments(directory: str | Path, subjects: Iterable[int] | None = None, *,
                      actions: Iterable[int] | None = None, max_gap_s: float = 0.5
                      ) -> list[Segment]:
    """All segments of the MSR Action3D sequences in `directory` (optionally only some subjects
    and actions), as `load_segments`' (names 'aAA_sSS_eEE/k'); empty sequences give none."""
    paths = msraction3d.list_sequences(directory)
    if not paths:
        raise ValueError(f'{directory}: no aAA_sSS_eEE_skeleton3D.txt files')
    keep_s = None if subjects is None else set(subjects)
    keep_a = None if actions is None else set(actions)
    out: list[Segment] = []
    for path in paths:
        _, action, subject, _ = msraction3d.parse_name(path)
        if (keep_s is not None and subject not in keep_s) or \
                (keep_a is not None and action not in keep_a):
            continue
        seq = msraction3d.read_sequence(path)
        if len(seq.frames):
            out.extend(split_take(msraction3d.as_take(seq), max_gap_s=max_gap_s))
    return out


def part_indices(tree: PartTree = PARTS_10) -> NDArray[np.int64]:
    """Index into `UTKINECT_JOINTS` of each part of `tree`."""
    return np.array([UTKINECT_JOINTS.index(UTKINECT_NAMES.get(n, n)) for n in tree.names])


def part_pixels(segment: Segment, intrinsics: Intrinsics, tree: PartTree = PARTS_10
                ) -> NDArray[np.float64]:
    """(T, P, 2) clean pixel positions of the tree's parts."""
    pts = segment.joints[:, part_indices(tree)]
    return project(pts.reshape(-1, 3), intrinsics).reshape(len(pts), len(tree), 2)


def corrupt(uv: NDArray[np.floating], rng: np.random.Generator,
            corruption: Corruption = Corruption()) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
    """Corrupt clean pixels like a detector: noise, outliers and dropouts.

    Parameters
    ----------
    uv : (T, P, 2) float clean pixels (not modified).
    rng : the random generator (seeded by the caller).
    corruption : rates and sizes.

    Returns
    -------
    noisy : (T, P, 2) float64 pixels, NaN for dropouts.
    kind : (T, P) int8, 0 = noisy detection, 1 = outlier, 2 = dropout.
    """
    uv = np.asarray(uv, dtype=np.float64)
    shape = uv.shape[:2]
    noisy = uv + rng.normal(0.0, corruption.noise_px, uv.shape)
    u = rng.random(shape)
    kind = np.zeros(shape, np.int8)
    kind[u < corruption.outlier_rate] = 1
    kind[u >= 1.0 - corruption.dropout_rate] = 2
    angle = rng.uniform(0.0, 2.0 * math.pi, shape)
    dist = rng.uniform(*corruption.outlier_px, shape)
    jump = np.stack([np.cos(angle), np.sin(angle)], axis=-1) * dist[..., None]
    noisy = np.where((kind == 1)[..., None], noisy + jump, noisy)
    noisy[kind == 2] = np.nan
    return noisy, kind


def name_numbers(take: str) -> list[int]:
    """The numbers of a take's name: [NN, MM] of UTKinect's 'sNN_eMM', [AA, SS, EE] of MSR
    Action3D's 'aAA_sSS_eEE' (random streams are seeded by them)."""
    return [int(x) for x in re.findall(r'\d+', take)]


def segment_rng(seed: int, segment: Segment) -> np.random.Generator:
    """A generator that depends on the seed and the segment only (order-independent)."""
    take, _, k = segment.name.partition('/')
    return np.random.default_rng([seed, *name_numbers(take), int(k or 0)])


TrackerFactory = Callable[[], SlqeTracker]


def run_tracker(factory: TrackerFactory, uv: NDArray[np.floating], times: NDArray[np.floating],
                confidence: NDArray[np.floating] | None = None
                ) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Track a sequence of detections.

    Parameters
    ----------
    factory : makes a fresh tracker.
    uv : (T, P, 2) detections, pixels, NaN = missing.
    times : (T,) seconds.
    confidence : (T, P) or None.

    Returns
    -------
    positions (T, P, 2) float64 pixels (NaN = missing) and source (T, P) uint8.
    """
    tracker = factory()
    n = len(times)
    pos = np.full(np.shape(uv), np.nan)
    src = np.full(np.shape(uv)[:2], Source.MISSING, np.uint8)
    for k in range(n):
        out = tracker.step(uv[k], None if confidence is None else confidence[k], times[k])
        pos[k] = out.positions
        src[k] = out.source
    return pos, src


def _group_names(tree: PartTree) -> dict[str, list[int]]:
    groups: dict[str, list[int]] = {}
    for i, name in enumerate(tree.names):
        groups.setdefault(group_of(name) or name, []).append(i)
    return groups


@dataclass
class ErrorAccumulator:
    """Sums of pixel errors per part over many sequences (NaN estimates counted as missing)."""

    n_parts: int

    def __post_init__(self) -> None:
        self.sum = np.zeros(self.n_parts)
        self.count = np.zeros(self.n_parts, np.int64)
        self.total = np.zeros(self.n_parts, np.int64)

    def add(self, est: NDArray, truth: NDArray, counted: NDArray[np.bool_]) -> None:
        err = np.linalg.norm(np.asarray(est) - np.asarray(truth), axis=-1)
        ok = counted & np.isfinite(err)
        self.sum += np.where(ok, err, 0.0).sum(axis=0)
        self.count += ok.sum(axis=0)
        self.total += counted.sum(axis=0)

    def table(self, tree: PartTree) -> dict[str, float]:
        """{group: mean error, ..., 'average': mean over all part-frames, 'coverage': ...}."""
        out = {}
        for group, idx in _group_names(tree).items():
            out[group] = float(self.sum[idx].sum() / max(self.count[idx].sum(), 1))
        out['average'] = float(self.sum.sum() / max(self.count.sum(), 1))
        out['coverage'] = float(self.count.sum() / max(self.total.sum(), 1))
        return out


def default_methods(slqe: SlqeConfig | None = None, cv: CvConfig | None = None,
                    cv_gated: CvConfig | None = None, tree: PartTree = PARTS_10, *,
                    ablations: bool = False) -> dict[str, TrackerFactory]:
    """The compared trackers: plain CV filter, CV filter with the gate, SLQE.

    With `ablations`, also SLQE without the coupling ('slqe_no_coupling', the same filter with
    k = 0) and SLQE on a constant-velocity state ('slqe_order2', `SLQE_ORDER2`).
    """
    slqe = slqe or SlqeConfig()
    cv = cv or CvConfig()
    cv_gated = cv_gated or GATED_CV
    out: dict[str, TrackerFactory] = {
        'cv': lambda: ConstantVelocityTracker(cv, tree),
        'cv_gated': lambda: ConstantVelocityTracker(cv_gated, tree),
        'slqe': lambda: SlqeTracker(slqe, tree),
    }
    if ablations:
        uncoupled = replace(slqe, coupling=0.0)
        out['slqe_no_coupling'] = lambda: SlqeTracker(uncoupled, tree)
        out['slqe_order2'] = lambda: SlqeTracker(SLQE_ORDER2, tree)
    return out


def evaluate_tracking(segments: Sequence[Segment], methods: dict[str, TrackerFactory], *,
                      seed: int = 0, corruption: Corruption = Corruption(),
                      intrinsics: Intrinsics | None = None, tree: PartTree = PARTS_10
                      ) -> dict[str, dict[str, dict[str, float]]]:
    """Mean pixel error of the corrupted input and of each tracker on `segments`.

    Returns
    -------
    {'detected_frames': {method: table}, 'all_frames': {method: table}} where a table is
    {group: px, 'average': px, 'coverage': fraction}. 'detected_frames' scores only the frames
    where the input has a detection of the part (the input's own support, so every method is
    compared on the same part-frames); 'all_frames' scores every frame (the input is then held
    at its last detection, 'input_held').
    """
    intrinsics = intrinsics or cad60_intrinsics()
    n_parts = len(tree)
    names = ['input', 'input_held', *methods]
    det = {m: ErrorAccumulator(n_parts) for m in names}
    every = {m: ErrorAccumulator(n_parts) for m in names}
    for seg in segments:
        truth = part_pixels(seg, intrinsics, tree)
        noisy, kind = corrupt(truth, segment_rng(seed, seg), corruption)
        has_truth = np.isfinite(truth).all(axis=-1)
        detected = has_truth & (kind != 2)
        estimates = {'input': noisy, 'input_held': _hold(noisy)}
        for m, factory in methods.items():
            estimates[m] = run_tracker(factory, noisy, seg.times)[0]
        for m, est in estimates.items():
            det[m].add(est, truth, detected)
            every[m].add(est, truth, has_truth)
    return {'detected_frames': {m: a.table(tree) for m, a in det.items()},
            'all_frames': {m: a.table(tree) for m, a in every.items()}}


def _hold(uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Fill NaN detections with the part's last detection (zero-order hold)."""
    out = uv.copy()
    for k in range(1, len(out)):
        gap = ~np.isfinite(out[k]).all(axis=-1)
        out[k][gap] = out[k - 1][gap]
    return out


def reduction(table: dict[str, float], reference: dict[str, float]) -> float:
    """Relative reduction of the average error against a reference table (0.25 = 25 % lower)."""
    return 1.0 - table['average'] / reference['average']


def tune_tracking(segments: Sequence[Segment], *, seed: int = 0,
                  corruption: Corruption = Corruption(), tree: PartTree = PARTS_10,
                  rounds: int = 2, progress: Callable[[str], None] | None = None
                  ) -> tuple[SlqeConfig, CvConfig, CvConfig, list[dict]]:
    """Coordinate search of Q, R, the gate and the coupling on `segments` (training subjects).

    The objective is the mean pixel error on the detected frames. Each tracker is tuned on its
    own parameters (the plain CV filter has no gate).

    Returns
    -------
    (slqe, cv, cv_gated, log): the best configurations and every evaluated point.
    """
    log: list[dict] = []

    def score(name: str, factory: TrackerFactory, params: dict) -> float:
        res = evaluate_tracking(segments, {name: factory}, seed=seed, corruption=corruption,
                                tree=tree)
        value = res['detected_frames'][name]['average']
        log.append({'method': name, **params, 'error_px': value})
        if progress is not None:
            progress(f'{name} {params} -> {value:.3f} px')
        return value

    grids_slqe = {
        'process_noise': [30.0, 100.0, 300.0, 1000.0, 3000.0],
        'measurement_noise_px': [2.0, 3.0, 4.5, 6.0, 9.0],
        'gate_chi2': [6.0, 9.21, 13.8, 20.0],
        'coupling': [0.0, 0.05, 0.1, 0.2, 0.4],
        'output': ['filtered', 'detection'],
    }
    grids_cv = {
        'process_noise': [10.0, 30.0, 100.0, 300.0, 1000.0],
        'measurement_noise_px': [2.0, 3.0, 4.5, 6.0, 9.0, 13.0],
    }
    grids_cvg = {
        'process_noise': [10.0, 30.0, 100.0, 300.0, 1000.0],
        'measurement_noise_px': [2.0, 3.0, 4.5, 6.0, 9.0],
        'gate_chi2': [6.0, 9.21, 13.8, 20.0],
    }

    def search(name: str, config, grids: dict, make: Callable) -> object:
        cache: dict[tuple, float] = {}

        def value(cfg) -> float:
            key = tuple(getattr(cfg, k) for k in grids)
            if key not in cache:
                cache[key] = score(name, lambda: make(cfg), {k: getattr(cfg, k) for k in grids})
            return cache[key]

        best = config
        for _ in range(rounds):
            for key, values in grids.items():
                trials = [replace(best, **{key: v}) for v in values]
                best = min(trials, key=value)
        return best

    slqe = search('slqe', SlqeConfig(), grids_slqe, lambda c: SlqeTracker(c, tree))
    cv = search('cv', CvConfig(), grids_cv, lambda c: ConstantVelocityTracker(c, tree))
    cvg = search('cv_gated', CvConfig(gate_chi2=13.8), grids_cvg,
                 lambda c: ConstantVelocityTracker(c, tree))
    return slqe, cv, cvg, log  # type: ignore[return-value]


def config_dict(config: object) -> dict:
    """A JSON-friendly dict of a config dataclass (inf -> 'inf')."""
    out = {}
    for k, v in asdict(config).items():  # type: ignore[call-overload]
        out[k] = 'inf' if isinstance(v, float) and math.isinf(v) else v
    return out


def tracking_report(train: Sequence[Segment], test: Sequence[Segment],
                    native: Sequence[Segment], *, seed: int = 0, tune: bool = False,
                    ablations: bool = True, progress: Callable[[str], None] = lambda msg: None
                    ) -> dict:
    """`pose4d track-eval`'s tracking tables: the methods (`default_methods`, with the shipped
    defaults, tuned on subjects s01-s06 with seed 0, or tuned again on `train`) on the training
    and test segments and on the test takes at their recorded frame times (`native`), and
    whether SLQE meets its target (a quarter less error than its input, below the plain filter).
    """
    slqe, cv, cvg = SlqeConfig(), CvConfig(), GATED_CV
    report: dict = {}
    if tune:
        progress('tuning the trackers on the training subjects (minutes)')
        slqe, cv, cvg, report['tracking_tuning_log'] = tune_tracking(train, seed=seed,
                                                                     progress=progress)
    report['tracker_configs'] = {'slqe': config_dict(slqe), 'cv': config_dict(cv),
                                 'cv_gated': config_dict(cvg)}
    methods = default_methods(slqe, cv, cvg, ablations=ablations)
    tables, targets = {}, {}
    for name, segs in (('train', train), ('test', test), ('test_native_dt', native)):
        progress(f'tracking on the {name} segments')
        tables[name] = evaluate_tracking(segs, methods, seed=seed)
    for name in ('train', 'test'):
        det = tables[name]['detected_frames']
        red = reduction(det['slqe'], det['input'])
        targets[name] = {'slqe_reduction_vs_input': red,
                         'slqe_beats_cv': det['slqe']['average'] < det['cv']['average'],
                         'slqe_beats_cv_gated':
                             det['slqe']['average'] < det['cv_gated']['average'],
                         'meets_target': red >= 0.25 and
                         det['slqe']['average'] < det['cv']['average']}
    return {**report, 'tracking': tables, 'tracking_targets': targets}
