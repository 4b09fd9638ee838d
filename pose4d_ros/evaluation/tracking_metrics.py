"""Several-person evaluation: truths matched to skeletons, CLEAR-MOT and the identity measures.

Per frame, the ground-truth people (`JointSet`s whose `track_id` is the person's id) and the
tracker's skeletons (`JointSet`s with the tracker's `track_id`) are compared by the distance
between their torso points in pixels (`torso_point`: the located 'torso' joint, else the mean of
the located shoulders and hips). A pair may be matched only when that distance is at most
`max_distance` times the truth's reference size (max(h, w) of the box around its labelled joints,
`core.metrics.reference_size`); 0.5 by default, the MOTChallenge-like rule that a hypothesis
covers an object when it is within half the object's size. A person or a skeleton without a
located torso (or a truth without a reference size) is never matched: the truth is a miss, the
skeleton a false positive (`score_people` leaves out a skeleton without a reported joint and a
person without a labelled joint: they are not there; but a person hidden between two frames in
which they are labelled is there, at their ground-truth position, as MOTChallenge annotates
people through occlusions: `occlusion_gaps`). A CAD-60 truth's 'torso' joint lies a
few pixels from its shoulders' and hips' mean, which a skeleton without 'torso' gives: that
offset is part of MOTP.

CLEAR-MOT (Bernardin & Stiefelhagen, "Evaluating multiple object tracking performance: the
CLEAR MOT metrics", EURASIP JIVP 2008), with the frame-by-frame matching of `assign_frame`:

1. A truth keeps the skeleton it was last matched to when that skeleton is present and still
   within the threshold (truths taken in the order given). As in py-motmetrics, the last match
   is kept however many frames ago it was made (a person hidden and back), not only from the
   previous frame.
2. The remaining truths and skeletons are assigned one-to-one (`scipy.optimize.
   linear_sum_assignment`): as many pairs within the threshold as possible, of least total
   distance among those.
3. A match whose truth was last matched to another skeleton is an identity switch (IDSW); the
   truths left are misses (FN), the skeletons left false positives (FP).

MOTA = 1 - (FN + FP + IDSW) / GT (GT = person-frames); MOTP = mean torso distance of the matches
(pixels; lower is better). A fragmentation is a matched truth becoming unmatched while present
and matched again later; mostly tracked / lost: matched in >= 80 % / < 20 % of the frames the
person is present.

Identity measures (Ristani et al., "Performance measures and a data set for multi-target,
multi-camera tracking", ECCV 2016 workshops): every truth trajectory is paired
with at most one skeleton trajectory by a global bipartite matching that maximises IDTP, the
number of person-frames in which the pair is present and within the threshold
(`linear_sum_assignment` on those counts); IDFN = GT - IDTP, IDFP = skeleton-frames - IDTP,
IDP = IDTP / (IDTP + IDFP), IDR = IDTP / (IDTP + IDFN), IDF1 = 2 IDTP / (GT + skeleton-frames).

These rules are those of py-motmetrics (`MOTAccumulator.update` with NaN for the pairs beyond the
threshold; its `mota`, `motp`, `idf1`, ...). Cross-checked against motmetrics 1.4.0 (numpy 2.4.6,
scipy 1.17.1, pandas 3.1.1; it runs on numpy 2) fed the same distance matrices: mota, motp, idf1,
idp, idr, id_switches, fragmentations, misses, false_positives, matches, predictions,
gt_objects, frames, mostly_tracked, partially_tracked and mostly_lost all equal to 1e-9 (largest
difference 5e-15) on the nine hand-made sequences of test/test_tracking_metrics.py, on its
`random_sequence` seeds 0-199 and on seeds 1000-1299 with skeleton ids that reuse the truth ids;
`summarize_sequences` equal to motmetrics' pooled row (`compute_many(..., generate_overall=True)`)
on 50 groups of four random sequences (seeds 2000-2199).
Both subtleties matter there: without the kept correspondences the switches differ in 296 of
those 300 sequences, and with IDTP counted on the matches only IDF1 differs in 269. motmetrics
is not a dependency: the tests hold its numbers.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.core.metrics import reference_size, score_joint_sets

# A match needs the torsos within this many of the truth's reference sizes (MOTChallenge-like).
MATCH_FRACTION = 0.5
# The joints whose located mean is the torso point when there is no located 'torso' joint.
TORSO_JOINTS: tuple[str, ...] = ('left_shoulder', 'right_shoulder', 'left_hip', 'right_hip')
# Mostly tracked / mostly lost: matched in at least / in less than this share of the frames.
MOSTLY_TRACKED = 0.8
MOSTLY_LOST = 0.2


def _located(joints: JointSet, *, labelled: bool, positions: bool = False
             ) -> NDArray[np.bool_]:
    """(J,) joints with a finite pixel that are not MISSING (and, for a truth, labelled:
    confidence > 0); `positions`: every joint with a finite pixel (a hidden person's
    ground-truth position)."""
    ok = np.isfinite(joints.uv).all(axis=1)
    if positions:
        return ok
    ok &= joints.source != MISSING
    return ok & (joints.confidence > 0) if labelled else ok


def torso_point(joints: JointSet, *, labelled: bool = False,
                positions: bool = False) -> NDArray[np.float64]:
    """The torso of one person in pixels.

    Parameters
    ----------
    joints : one person (any skeleton naming; CAD-60 truths have 'torso').
    labelled : a ground truth: only joints with a positive confidence count as located.
    positions : a ground truth read at its positions: every joint with a finite pixel counts
        (a person hidden behind another, `score_people`).

    Returns
    -------
    (2,) float64 pixel (u, v): the located 'torso' joint, else the mean of the located
    shoulders and hips; NaN when there is neither.
    """
    ok = _located(joints, labelled=labelled, positions=positions)
    k = joints.get('torso')
    if k is not None and ok[k]:
        return joints.uv[k].copy()
    idx = [i for i in map(joints.get, TORSO_JOINTS) if i is not None and ok[i]]
    return joints.uv[idx].mean(axis=0) if idx else np.full(2, np.nan)


def person_size(truth: JointSet, *, positions: bool = False) -> float:
    """max(h, w) in pixels of the box around a truth's labelled joints
    (`core.metrics.reference_size`; `positions`: around every joint with a finite pixel);
    NaN with fewer than two."""
    ok = _located(truth, labelled=True, positions=positions)
    return float(reference_size(truth.uv[None], ok[None])[0])


def torso_distances(truths: Sequence[JointSet], preds: Sequence[JointSet], *,
                    max_distance: float = MATCH_FRACTION,
                    positions: bool = False) -> NDArray[np.float64]:
    """Torso distances of every truth-skeleton pair of one frame, NaN where no match may be.

    Parameters
    ----------
    truths : T ground-truth people.
    preds : P skeletons.
    max_distance : the largest distance of a match, in reference sizes of the truth
        (`person_size`); 0.5 = `MATCH_FRACTION`.
    positions : the truths read at their positions, labelled or not (hidden people,
        `score_people`): their torso points and sizes from every joint with a finite pixel.

    Returns
    -------
    (T, P) float64 pixels; NaN beyond `max_distance` sizes, or where the truth or the skeleton
    has no torso point, or the truth no size.
    """
    if not max_distance > 0:
        raise ValueError(f'max_distance must be positive, got {max_distance}')
    dist = np.full((len(truths), len(preds)), np.nan)
    if not len(truths) or not len(preds):
        return dist
    t = np.array([torso_point(j, labelled=True, positions=positions) for j in truths])
    p = np.array([torso_point(j) for j in preds])
    limit = max_distance * np.array([person_size(j, positions=positions) for j in truths])
    d = np.hypot(*(t[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
    with np.errstate(invalid='ignore'):
        keep = d <= limit[:, None]
    dist[keep] = d[keep]
    return dist


def assign(distances: ArrayLike) -> list[tuple[int, int]]:
    """One-to-one pairs of rows and columns: as many finite entries as possible, of least
    total among those.

    Parameters
    ----------
    distances : (T, P) float, NaN or inf = not allowed.

    Returns
    -------
    (row, column) pairs sorted by row, each on a finite entry.
    """
    d = np.array(distances, dtype=np.float64, ndmin=2)
    valid = np.isfinite(d)
    if not valid.any():
        return []
    # An allowed pair costs at most c; a forbidden one costs more than any r allowed pairs can
    # save (l > (2r - 1) c), so no solution trades an allowed pair for a cheaper total. The same
    # construction as py-motmetrics' `lap.add_expensive_edges`, so ties fall alike.
    c = float(np.abs(d[valid]).max()) + 1.0
    cost = np.where(valid, d, 2.0 * min(d.shape) * c + 1.0)
    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if valid[i, j]]


def match_people(truths: Sequence[JointSet], preds: Sequence[JointSet], *,
                 max_distance: float = MATCH_FRACTION) -> list[tuple[int, int]]:
    """One frame's people matched to its skeletons, without history (`assign` on
    `torso_distances`).

    Parameters
    ----------
    truths : T ground-truth people.
    preds : P skeletons.
    max_distance : the largest torso distance of a match, in reference sizes of the truth.

    Returns
    -------
    (truth index, skeleton index) pairs, one-to-one, sorted by truth index.
    """
    return assign(torso_distances(truths, preds, max_distance=max_distance))


def _unique(ids: Sequence[int], what: str) -> tuple[int, ...]:
    ids = tuple(int(i) for i in ids)
    if len(set(ids)) != len(ids):
        repeated = sorted({i for i in ids if ids.count(i) > 1})
        raise ValueError(f'{what} id(s) repeated in one frame: {repeated}')
    return ids


def assign_frame(truth_ids: Sequence[int], pred_ids: Sequence[int], distances: ArrayLike,
                 previous: Mapping[int, int]) -> list[tuple[int, int]]:
    """CLEAR-MOT's matching of one frame (steps 1 and 2 of the module docstring).

    Parameters
    ----------
    truth_ids : T ids of the people present.
    pred_ids : P ids of the skeletons present.
    distances : (T, P) float pixels, NaN = beyond the threshold (no match allowed).
    previous : truth id -> the skeleton id it was last matched to.

    Returns
    -------
    (row, column) index pairs into `distances`: the kept correspondences first (in the order of
    `truth_ids`), then the new assignment (by row).
    """
    truth_ids = _unique(truth_ids, 'truth')
    pred_ids = _unique(pred_ids, 'skeleton')
    d = np.array(distances, dtype=np.float64).reshape(len(truth_ids), len(pred_ids))
    column = {p: j for j, p in enumerate(pred_ids)}
    kept = []
    for i, t in enumerate(truth_ids):
        last = previous.get(t)
        j = column.get(last) if last is not None else None
        # a skeleton may be the last match of two truths (it moved from one to the other)
        if j is not None and np.isfinite(d[i, j]) and all(j != c for _, c in kept):
            kept.append((i, j))
    if kept:
        rows, cols = zip(*kept, strict=True)
        d[list(rows), :] = np.nan
        d[:, list(cols)] = np.nan
    return kept + assign(d) if d.size else kept


@dataclass(frozen=True)
class FrameEvents:
    """One frame as the metrics see it.

    Attributes
    ----------
    truth_ids : ids of the people present.
    pred_ids : ids of the skeletons present.
    matches : (truth id, skeleton id, distance in pixels) of the frame's one-to-one matches.
    within : (truth id, skeleton id) of every pair within the threshold (IDTP counts them);
        None = the matches only (the same unless a skeleton is within reach of two people).
    """

    truth_ids: tuple[int, ...]
    pred_ids: tuple[int, ...]
    matches: tuple[tuple[int, int, float], ...]
    within: tuple[tuple[int, int], ...] | None = None

    def __post_init__(self) -> None:
        truths = set(_unique(self.truth_ids, 'truth'))
        preds = set(_unique(self.pred_ids, 'skeleton'))
        _unique([m[0] for m in self.matches], 'matched truth')
        _unique([m[1] for m in self.matches], 'matched skeleton')
        for t, p, *_ in [*self.matches, *(self.within or ())]:
            if t not in truths or p not in preds:
                raise ValueError(f'pair ({t}, {p}) of ids not present in the frame '
                                 f'(truths {sorted(truths)}, skeletons {sorted(preds)})')


class TrackingAccumulator:
    """The frames of one sequence, matched frame by frame with CLEAR-MOT's rule.

    `update` takes each frame's ids and distances (`assign_frame`, given the last match of every
    truth so far) and records a `FrameEvents`; `summary` gives the metrics (`summarize`).
    """

    def __init__(self) -> None:
        self.frames: list[FrameEvents] = []
        self._last: dict[int, int] = {}

    def update(self, truth_ids: Sequence[int], pred_ids: Sequence[int], distances: ArrayLike
               ) -> FrameEvents:
        """Match one frame and record it.

        Parameters
        ----------
        truth_ids : T ids of the people present.
        pred_ids : P ids of the skeletons present.
        distances : (T, P) float pixels, NaN = beyond the threshold.

        Returns
        -------
        The frame's events (its matches by id).
        """
        truth_ids = _unique(truth_ids, 'truth')
        pred_ids = _unique(pred_ids, 'skeleton')
        d = np.array(distances, dtype=np.float64)
        if d.size != len(truth_ids) * len(pred_ids):
            raise ValueError(f'distances {d.shape} for {len(truth_ids)} truths and '
                             f'{len(pred_ids)} skeletons')
        d = d.reshape(len(truth_ids), len(pred_ids))
        pairs = assign_frame(truth_ids, pred_ids, d, self._last)
        matches = tuple((truth_ids[i], pred_ids[j], float(d[i, j])) for i, j in pairs)
        within = tuple((truth_ids[i], pred_ids[j]) for i, j in zip(*np.nonzero(np.isfinite(d)),
                                                                  strict=True))
        events = FrameEvents(truth_ids, pred_ids, matches, within)
        self._last.update((t, p) for t, p, _ in matches)
        self.frames.append(events)
        return events

    def summary(self) -> dict[str, float]:
        """The metrics of the frames so far (`summarize`)."""
        return summarize(self.frames)


def _ratio(a: float, b: float) -> float:
    return float(a) / float(b) if b else float('nan')


def summarize(frames: Sequence[FrameEvents]) -> dict[str, float]:
    """CLEAR-MOT and the identity measures of a sequence of matched frames.

    Parameters
    ----------
    frames : each frame's ids and matches, in time order (from `TrackingAccumulator.update`, or
        built by hand: an id switch is then read from the matches, as in CLEAR-MOT).

    Returns
    -------
    {'mota', 'motp' (pixels), 'idf1', 'idp', 'idr' (fractions; NaN when undefined, e.g. MOTA
    without any person), 'id_switches', 'fragmentations', 'misses', 'false_positives',
    'matches', 'gt_objects' (person-frames), 'predictions' (skeleton-frames), 'frames',
    'id_switches_per_1000', 'missed_per_1000' (per 1000 person-frames), 'false_per_1000' (false
    skeletons per 1000 frames), 'mostly_tracked', 'partially_tracked', 'mostly_lost' (people),
    'idtp'}.
    """
    return _rates(_counts(frames))


def summarize_sequences(sequences: Sequence[Sequence[FrameEvents]]) -> dict[str, float]:
    """`summarize` of several sequences pooled (as MOTChallenge's and motmetrics' overall row):
    each sequence is matched and its trajectories paired on its own (an id in one sequence is
    not the same person or track as in another), the counts are summed and the ratios taken of
    the sums (MOTP weighted by the matches, IDF1 of the summed IDTP)."""
    total: dict[str, float] = dict.fromkeys(_COUNTS, 0)
    for frames in sequences:
        for k, v in _counts(frames).items():
            total[k] += v
    return _rates(total)


_COUNTS = ('id_switches', 'fragmentations', 'misses', 'false_positives', 'matches',
           'gt_objects', 'predictions', 'frames', 'mostly_tracked', 'partially_tracked',
           'mostly_lost', 'idtp', 'distance_sum')


def _counts(frames: Sequence[FrameEvents]) -> dict[str, float]:
    """The additive counts of one sequence (`_COUNTS`)."""
    last: dict[int, int] = {}
    switches = misses = false_pos = n_truth = n_pred = n_match = 0
    dist_sum = 0.0
    present: dict[int, int] = {}
    tracked: dict[int, int] = {}
    state: dict[int, list[bool]] = {}  # per truth: matched or not in each frame it is present
    agree: dict[tuple[int, int], int] = {}
    for f in frames:
        matched = {t: (p, d) for t, p, d in f.matches}
        for t, (p, d) in matched.items():
            switches += t in last and last[t] != p
            last[t] = p
            dist_sum += d
        n_match += len(matched)
        misses += len(f.truth_ids) - len(matched)
        false_pos += len(f.pred_ids) - len(matched)
        n_truth += len(f.truth_ids)
        n_pred += len(f.pred_ids)
        for t in f.truth_ids:
            present[t] = present.get(t, 0) + 1
            tracked[t] = tracked.get(t, 0) + (t in matched)
            state.setdefault(t, []).append(t in matched)
        pairs = f.within if f.within is not None else [(t, p) for t, p, _ in f.matches]
        for pair in pairs:
            agree[pair] = agree.get(pair, 0) + 1
    ratios = [tracked[t] / present[t] for t in present]
    return {
        'id_switches': switches,
        'fragmentations': sum(_fragments(s) for s in state.values()),
        'misses': misses,
        'false_positives': false_pos,
        'matches': n_match,
        'gt_objects': n_truth,
        'predictions': n_pred,
        'frames': len(frames),
        'mostly_tracked': sum(r >= MOSTLY_TRACKED for r in ratios),
        'partially_tracked': sum(MOSTLY_LOST <= r < MOSTLY_TRACKED for r in ratios),
        'mostly_lost': sum(r < MOSTLY_LOST for r in ratios),
        'idtp': _idtp(agree),
        'distance_sum': dist_sum,
    }


def _rates(c: Mapping[str, float]) -> dict[str, float]:
    """The summary of `summarize` from the counts of `_counts`."""
    errors = c['misses'] + c['false_positives'] + c['id_switches']
    return {
        'mota': 1.0 - _ratio(errors, c['gt_objects']) if c['gt_objects'] else float('nan'),
        'motp': _ratio(c['distance_sum'], c['matches']),
        'idf1': _ratio(2 * c['idtp'], c['gt_objects'] + c['predictions']),
        'idp': _ratio(c['idtp'], c['predictions']),
        'idr': _ratio(c['idtp'], c['gt_objects']),
        **{k: c[k] for k in _COUNTS[:8]},
        'id_switches_per_1000': 1e3 * _ratio(c['id_switches'], c['gt_objects']),
        'missed_per_1000': 1e3 * _ratio(c['misses'], c['gt_objects']),
        'false_per_1000': 1e3 * _ratio(c['false_positives'], c['frames']),
        **{k: c[k] for k in ('mostly_tracked', 'partially_tracked', 'mostly_lost', 'idtp')},
    }


def _idtp(agree: Mapping[tuple[int, int], int]) -> int:
    """The largest total agreement of a one-to-one pairing of truth and skeleton ids."""
    if not agree:
        return 0
    truths = sorted({t for t, _ in agree})
    preds = sorted({p for _, p in agree})
    counts = np.zeros((len(truths), len(preds)))
    row = {t: i for i, t in enumerate(truths)}
    col = {p: j for j, p in enumerate(preds)}
    for (t, p), n in agree.items():
        counts[row[t], col[p]] = n
    rows, cols = linear_sum_assignment(counts, maximize=True)
    return int(counts[rows, cols].sum())


def _fragments(matched: Sequence[bool]) -> int:
    """Times a truth goes from matched to unmatched and is matched again later (frames where
    it is present)."""
    m = np.asarray(matched, bool)
    hits = np.flatnonzero(m)
    if hits.size < 2:
        return 0
    span = m[hits[0]:hits[-1] + 1]
    return int(np.count_nonzero(span[:-1] & ~span[1:]))


# A truth joint is seen when the depth image at its pixel is within this of its depth, metres
# (the joint lies inside the body, a few centimetres behind the surface the camera sees; a
# nearer person in front of it reads far nearer)
SEEN_TOLERANCE_M = 0.3
# The bins of `seen_table`: person-frames by the share of their joints seen, lowest bound first
SEEN_BINS: tuple[tuple[str, float, float], ...] = (
    ('80', 0.8, math.inf), ('50_80', 0.5, 0.8), ('under_50', -math.inf, 0.5))


def seen_share(truth: JointSet, depth_m: NDArray[np.floating] | None) -> float:
    """The share of a truth's labelled joints inside the image that the depth image shows
    (`SEEN_TOLERANCE_M`): what of a person a nearer one leaves in view. NaN without depth,
    3-D truth or a joint inside the image."""
    if depth_m is None:
        return math.nan
    h, w = depth_m.shape
    ok = _located(truth, labelled=True) & np.isfinite(truth.xyz[:, 2])
    uv = np.rint(truth.uv[ok]).astype(np.int64) if ok.any() else np.zeros((0, 2), np.int64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    if not inside.any():
        return math.nan
    reading = depth_m[uv[inside, 1], uv[inside, 0]]
    with np.errstate(invalid='ignore'):
        seen = np.abs(reading - truth.xyz[ok][inside, 2]) <= SEEN_TOLERANCE_M
    return float(seen.mean())


def seen_table(preds: Sequence[JointSet | None], truths: Sequence[JointSet],
               shares: Sequence[float], names: tuple[str, ...], *,
               image_sizes: Sequence[tuple[int, int]] | None = None) -> dict[str, float]:
    """PCK@0.1 average7 of the person-frames of each `SEEN_BINS` bin of `seen_share`
    (`average7_<bin>`), and each bin's share of the person-frames (`share_<bin>`): how much
    of a several-person table is lost where a person is hidden, and how much where they are
    seen. Person-frames without a share (no depth) are in no bin."""
    shares = np.asarray(shares, np.float64)
    out: dict[str, float] = {}
    for label, lo, hi in SEEN_BINS:
        idx = np.flatnonzero((shares >= lo) & (shares < hi))
        out[f'share_{label}'] = len(idx) / len(shares) if len(shares) else math.nan
        table = score_joint_sets([preds[i] for i in idx], [truths[i] for i in idx], names,
                                 image_sizes=None if image_sizes is None
                                 else [image_sizes[i] for i in idx]) if len(idx) else None
        out[f'average7_{label}'] = table['pck']['average7'] if table else math.nan
    return out


def occlusion_gaps(frames_truths: Sequence[Sequence[JointSet]],
                   videos: Sequence[Hashable] | None = None) -> list[set[int]]:
    """Per frame, the ids of the people hidden there: given but without a labelled joint, and
    labelled in an earlier and in a later frame of the same video (`videos`; None: one video).
    MOTChallenge annotates people through occlusions ("always annotate during occlusions if
    the position can be determined unambiguously", Milan et al., MOT16, table 1) and counts
    them: a skeleton kept for a person hidden behind another is a match, none a miss. Before
    a person is first seen and after they are last seen they are not there."""
    labelled = [[(t.track_id, bool(_located(t, labelled=True).any())) for t in truths]
                for truths in frames_truths]
    out: list[set[int]] = [set() for _ in frames_truths]
    start = 0
    for end in range(1, len(frames_truths) + 1):
        if end < len(frames_truths) and (videos is None or videos[end] == videos[start]):
            continue
        seen: dict[int, tuple[int, int]] = {}  # id -> first and last frame labelled
        for k in range(start, end):
            for i, lab in labelled[k]:
                if lab:
                    seen[i] = (seen.get(i, (k, k))[0], k)
        for k in range(start, end):
            out[k] = {i for i, lab in labelled[k]
                      if not lab and i in seen and seen[i][0] < k < seen[i][1]}
        start = end
    return out


def _inside(point: NDArray[np.float64], size: tuple[int, int] | None) -> bool:
    """Whether a pixel is finite and, with an image size (width, height), inside it."""
    if not np.isfinite(point).all():
        return False
    return size is None or (0 <= point[0] < size[0] and 0 <= point[1] < size[1])


def score_people(frames_truths: Sequence[Sequence[JointSet]],
                 frames_preds: Sequence[Sequence[JointSet]], names: tuple[str, ...], *,
                 max_distance: float = MATCH_FRACTION,
                 image_sizes: Sequence[tuple[int, int]] | None = None,
                 videos: Sequence[Hashable] | None = None) -> dict:
    """Several-person scores of one sequence: tracking metrics and the pooled joint table.

    Parameters
    ----------
    frames_truths : per frame, every person's ground truth (`track_id` = the person's id); a
        person without a labelled joint is not there, but between two frames of the same
        video in which they are labelled (hidden behind someone, `occlusion_gaps`): there
        they are a person to track, at their ground-truth position (inside the image when
        `image_sizes` are given), with no joint to score.
    frames_preds : per frame, the skeletons (`track_id` = the tracker's id); one without a
        reported joint (all MISSING, no output) is not there.
    names : the joints to score (predicted names, as `core.metrics.joint_arrays`).
    max_distance : the largest torso distance of a match, in reference sizes of the truth.
    image_sizes : (width, height) of each frame; ground truth outside the image is not scored.
    videos : the video (any label) of each frame: each run of frames with one label is a
        sequence of its own (a new `TrackingAccumulator`; ids are not carried over), pooled by
        `summarize_sequences`. None: the frames are one sequence.

    Returns
    -------
    {'tracking': the summary of the frames matched by `TrackingAccumulator` on
    `torso_distances`, 'matched': (predictions, truths) over every person-frame in order (the
    matched skeleton, or None for a missed person: every joint wrong), 'table':
    `core.metrics.score_joint_sets` of them (PCK, APK, errors pooled over people), 'frames':
    the frame index of each matched entry (to take other per-frame values along)}.
    """
    if len(frames_truths) != len(frames_preds):
        raise ValueError(f'{len(frames_preds)} frames of skeletons for {len(frames_truths)} '
                         f'frames of ground truth')
    for what, per_frame in (('image sizes', image_sizes), ('videos', videos)):
        if per_frame is not None and len(per_frame) != len(frames_truths):
            raise ValueError(f'{len(per_frame)} {what} for {len(frames_truths)} frames')
    accs: list[TrackingAccumulator] = []
    preds_out: list[JointSet | None] = []
    truths_out: list[JointSet] = []
    index_out: list[int] = []
    gaps = occlusion_gaps(frames_truths, videos)
    for k, (truths, preds) in enumerate(zip(frames_truths, frames_preds, strict=True)):
        if not accs or (videos is not None and videos[k] != videos[k - 1]):
            accs.append(TrackingAccumulator())
        hidden = [t for t in truths if t.track_id in gaps[k]
                  and _inside(torso_point(t, positions=True),
                              None if image_sizes is None else image_sizes[k])]
        truths = [t for t in truths if _located(t, labelled=True).any()]
        preds = [p for p in preds if _located(p, labelled=False).any()]
        distances = np.vstack((torso_distances(truths, preds, max_distance=max_distance),
                               torso_distances(hidden, preds, max_distance=max_distance,
                                               positions=True)))
        try:
            events = accs[-1].update([t.track_id for t in truths + hidden],
                                     [p.track_id for p in preds], distances)
        except ValueError as err:
            raise ValueError(f'frame {k}: {err}') from None
        by_id = {p.track_id: p for p in preds}
        matched = {t: by_id[p] for t, p, _ in events.matches}
        for t in truths:
            preds_out.append(matched.get(t.track_id))
            truths_out.append(t)
            index_out.append(k)
    sizes = None if image_sizes is None else [image_sizes[k] for k in index_out]
    table = score_joint_sets(preds_out, truths_out, names, image_sizes=sizes)
    tracking = summarize_sequences([acc.frames for acc in accs])
    return {'tracking': tracking, 'matched': (preds_out, truths_out), 'table': table,
            'frames': index_out}
