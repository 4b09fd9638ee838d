"""Several people at once: one detector state, one SLQE and one IK per person, with stable ids.

The paper's stages extend to several people as they are: the foreground gives one candidate
per person (`core.foreground.segment_people`), the part model searches each candidate
(`PeopleDetector`), each person's parts are tracked by their own SLQE (`PeopleTracker`) and
completed by their own IK with their own learned bone lengths (`PeopleIk`).

Association (our design; the paper tracks one person). Each frame, detections are assigned to
the confirmed tracks by one global assignment (`scipy.optimize.linear_sum_assignment`), then
the detections left to the tentative tracks (`confirmed_first`), on the squared
Mahalanobis distance between torso points in 3-D: the track's torso predicted to this frame at
its velocity, its covariance the SLQE's covariance of the torso joints plus the detection's,
plus `TrackingConfig.torso_std_m` and a spread growing with the time the track went unseen
(`max_speed_mps`). A pair beyond `gate_chi2` is never assigned, and takes no part in the
assignment (`assign`). A detection left over starts a
tentative track, confirmed (and given its id) after `confirm_frames` frames matched, or at
once while no track is confirmed: every detection the part model scores at least
`trust_score`, or else the foreground's best region (trusted as the single-person tracker
always trusted its one detection). A confirmed track survives `max_unseen_s` unseen (its
parts predicted, TRACKED, as long as the SLQE keeps them), or `max_hidden_s` while held behind
a nearer person, and is matched again when the person comes back, and every track ends at
a gap in the stream (`max_gap_s`); ids count up from 1 in a run and are never reused. One
track and one detection are always paired: the SLQE's own gate then judges each part, as it
does for a single person, except the joints a nearer person's body covers in the image, whose
last estimates are kept (`hold_occluded`).

The primary person (the one `/pose4d/skeleton` carries): of the confirmed tracks seen this
frame, the longest tracked (matched in most frames; the first confirmed on a tie); when none is
seen, the longest-tracked one still predicted. Outputs are ordered primary first, then by id.

The same detector slots do the same for candidates before detection (`PeopleDetector`): each
slot keeps one person's detector state (their scale, the previous frame's parts that guide
the arms), matched to candidates by the 3-D centre of their regions.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.linalg import _umath_linalg
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics, backproject, project
from pose4d_ros.core.foreground import ForegroundResult, apply_mask
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.skeleton import tree_for

# The joints whose mean is a person's torso point, in the order they are looked for
TORSO = ('left_shoulder', 'right_shoulder', 'left_hip', 'right_hip', 'torso', 'neck')


@dataclass(frozen=True)
class TrackingConfig:
    """How people are told apart over time (module docstring).

    max_people : candidates searched per frame at most (the best first); the rest are counted.
    confirm_frames : frames a new track must be matched before it is published, while another
        confirmed track exists.
    max_unseen_s : a confirmed track unseen longer than this ends, seconds.
    max_hidden_s : the same for a track held behind a nearer person (`max_held_s`): a person
        who walks behind another and stops there is out of sight for longer than one who just
        leaves the detector for a moment, and came back under a new id after `max_unseen_s`.
        Chosen on validation (`pose4d eval DIR --model rgbd_14 --no-single-frame --config
        tracking.max_hidden_s=S`; average7 / MOTA / IDF1 / id switches per 1000 person-frames;
        false skeletons per 1000 frames the same at every value): at 1 s (`max_unseen_s`, the
        tracker before) `valid60_people2` 88.38 / 0.959 / 0.972 / 0.69, `valid60_people3`
        86.49 / 0.962 / 0.975 / 0.46, `valid30_people2b` 86.14 / 0.913 / 0.955 / 0; at 1.5, 2
        and 3 s alike 88.64 / 0.963 / 0.981 / 0, 86.78 / 0.971 / 0.985 / 0 and 86.26 / 0.915 /
        0.956 / 0 (2 s shipped, the middle of the plateau); the alone twins cannot change
        (nobody to be behind). The sweep `hidden` of `make results`.
    torso_std_m : standard deviation of a torso point's position besides the covariances,
        metres (the torso point moves within the body as arms and legs do).
    max_speed_mps : how fast an unseen person may have gone, metres a second (the spread of an
        unseen track's position grows with it).
    gate_chi2 : largest squared Mahalanobis distance of an assigned pair (3 degrees of freedom).
    max_gap_s : a gap between two frames longer than this (or a stamp going back) ends every
        track, seconds: `SlqeConfig.max_dt_s`, after which each SLQE restarts anyway.
    birth_score : while another track is confirmed, a detection starts or grows a tentative
        track only when its part model score (`JointSet.score`, the SVM's: 0 is its boundary)
        is at least this; a confirmed track takes any. A region that passes the person-size
        rules but is no person (a door jamb at the image's edge) scores low, and does not
        become a second person.
    trust_score : with no track confirmed, every detection scoring at least this is confirmed
        at its first frame (two people in view at a stream's start are both published from
        it); when none does, the foreground's best region is, as the single-person tracker
        trusts its one detection. A chair nearer and larger than the person (the foreground's
        best region) scores under it, the person over it (part model scores on validation:
        people 7-9 at the 5th percentile, 12 at the median; other regions at most 6.1).
    hold_occluded : a track's detected joints that lie on a nearer person's body (within
        `occluded_width_m` of one of their bones in the image, at their depth) are not
        measured: the track keeps its last estimate of them (TRACKED), as it keeps the whole
        pose of a person hidden behind another. What the part model puts there is a guess
        (the person's own pixels are not seen), and it pulls the skeleton onto the nearer
        person. On validation (`valid60_people2`, the detections of the shipped settings),
        average7 86.59 without, 87.36 / 87.47 / 87.23 / 88.43 with widths 0.06 / 0.09 / 0.12
        / 0.22 m (0.16 m and more lose MOTA: 0.953 -> 0.912-0.917); `valid30_people2`
        unchanged (81.02: its hidden people are never tracked). On, 0.09 m.
    quiet_frames : a candidate region whose last search scored under `birth_score` (a region
        that cannot start a track: a door jamb or a wall's edge at the image's border, a
        cabinet) and has not moved since (its pixels those of then up to `STILL_IOU`, its
        depth within `STILL_M`) keeps that detection for up to
        this many frames before it is searched again (0: every candidate searched every
        frame). Such regions cost the detector a full search each frame; a person's region
        scores over it, or moves.
    max_held_s : a person hidden behind another is published at their last pose (held, every
        joint TRACKED) for at most this long, then their track is kept unpublished until they
        are seen again (same id) or it ends (`max_hidden_s`); inf (the default): held until
        then. A pose held long is often where nobody is (the person moves on behind the
        other), but not limiting it was chosen on validation by the criterion of the settings
        above, mean MOTA (`pose4d eval DIR --model rgbd_14 --max-people 4 --config
        tracking.max_held_s=S`; average7 / MOTA / IDF1 / false skeletons per 1000 frames):
        `valid60_people2` 87.57 / 0.951 / 0.959 / 8.3 unlimited, 87.42 / 0.939 / 0.947 / 0 at
        0.65 s; a three-person set of an earlier stop (seed not recorded) 87.12 / 0.954 /
        0.977 / 9.7 and 86.92 / 0.950 / 0.972 / 0; the alone twins unchanged. (0.65 s was
        shipped for a while for its false skeletons; on the held-out sets it removed none and
        cost average7 0.3-1.2: docs/NOTES.md.)

    detector_keep_s : how long a person's detector state (`PeopleDetector`: their person scale,
        the arm prior) is kept unseen, seconds; 0 (the default): as long as their track can
        be, the longer of `max_unseen_s` and `max_hidden_s`. The detector node, which does not
        read the tracker's parameters, sets it (`detector.keep_unseen_s`) to follow a tracker
        whose lifetimes were changed.
    confirmed_first : the confirmed tracks take their detections first, the tentative ones
        share what is left. In one assignment, a track started the frame before beside a
        confirmed one (a detection that jumped out of the confirmed track's gate for a frame)
        took that person's detection whenever it was nearer, and the confirmed track went on
        unseen, predicted where nobody was, for up to `max_unseen_s`: a false skeleton every
        frame. Chosen on validation (`pose4d eval DIR --model rgbd_14 --max-people 4 --config
        tracking.confirmed_first=false`, average7 / MOTA / IDF1 / false skeletons per 1000
        frames): `valid60_people2` 87.6 / 0.951 / 0.959 / 8.3 without, 87.9 / 0.956 / 0.964 /
        0 with; `valid60_people3` (three people, s01-s06, seed 203) 86.6 / 0.943 / 0.954 /
        48.6 and 86.6 / 0.959 / 0.971 / 0.
    held_continues : a track held behind a nearer person takes a detection only where they
        come out: its torso pixel in that person's box (grown by a tenth of its height),
        whatever its score (a person coming out from behind another is partly seen and scores
        low; without it their track ended unseen and they came back under a new id), and
        nowhere else, whatever its score: the held track's gate, grown with the time unseen
        (`max_speed_mps`), reaches metres after half a second, and a wall's edge at the
        image's border (first seen on the held-out `test30_people2`, then on a new validation
        set, `valid30_people2b`: s01-s06, seed 99, 24 videos of two people) or clutter
        scoring over `birth_score` beside the pair was taken for the hidden person. False:
        a held track takes what any track unseen beside another person takes (a detection
        scoring `birth_score`, anywhere in its gate). On validation, with `confirmed_first`
        (`--config tracking.held_continues=false`; average7 / MOTA / IDF1 / false skeletons
        per 1000 frames): `valid60_people2` 87.9 / 0.956 / 0.964 / 0 without, 88.1 / 0.958 /
        0.972 / 0 with (id switches per 1000 person-frames 1.4 -> 0.7); `valid60_people3`
        86.6 / 0.959 / 0.971 / 0 and 86.5 / 0.962 / 0.975 / 0 (0.9 -> 0.5);
        `valid30_people2b` 86.0 / 0.901 / 0.948 / 22.2 and 86.1 / 0.912 / 0.954 / 13.0; the
        alone twins unchanged. (Its earlier forms on valid30_people2b: taking any detection in
        the gate 85.6 / 0.894 / 0.945 / 33.3; emerging low-scoring ones and birth-scoring ones
        anywhere 85.8 / 0.902 / 0.949 / 22.2, the other sets as now.)
    held_own_front : a track held behind a nearer person takes a detection coming out
        (`held_continues`) only from behind that person (`_Track.behind`, the track it was
        held behind), not from behind another: a wall's edge behind a third person, in the
        held track's gate (grown with the time unseen), was taken for the hidden person, a
        false skeleton for 35 frames (on `valid60_people3d`, one of two new validation sets of
        36 three-person videos each: s01-s06, seeds 207, `valid60_people3c`, and 209). False:
        from behind any nearer person (the tracker before). On validation (`pose4d eval DIR --model
        rgbd_14 --no-single-frame --config tracking.held_own_front=false`; average7 / MOTA /
        false skeletons per 1000 frames): `valid60_people3d` 86.72 / 0.950 / 16.2 without,
        87.00 / 0.960 / 0 with; `valid60_people2`, `valid60_people3`, `valid30_people2b`,
        `valid60_people3b` and `valid60_people3c` the same frames with and without. The sweep
        `held_front` of `make results`.
    emerging_score : while another track is confirmed, a detection coming out from behind a
        nearer person (its torso pixel in the box of a confirmed track's detection nearer by
        over `torso_std_m`, `_emerging`) starts or grows a tentative track from this score
        instead of `birth_score`. Partly seen, a person coming out scores under the birth
        score for many frames, and then flickers about it: a tentative track must be matched
        every frame, and `confirm_frames` in a row came late (on the validation set
        `valid60_people3b`, a person half seen from frame 43 scored 3.4-5.3 and was born at
        frame 58). Only a detection clear of the image's sides (`_clear_of_sides`): behind a
        person near the side, a wall's edge cut by the border scored 3.5-4 and became a
        person. Chosen on validation (`pose4d eval DIR --model rgbd_14 --no-single-frame
        --config tracking.emerging_score=S`; average7 / MOTA / false skeletons per 1000
        frames): 5 (`birth_score`, the tracker before) `valid60_people3b` (three people,
        s01-s06, seed 205, 24 videos) 89.35 / 0.958 / 0, `valid30_people2b` 86.45 / 0.916 /
        0, `valid60_people2` 89.13 / 0.964 / 0; 3: 89.82 / 0.972 / 0, 87.06 / 0.930 / 0,
        89.20 / 0.965 / 0; `valid60_people3` 87.13 / 0.971 / 0 at both; 2 as 3; 3 and 3.5
        without the side rule 37.5 and 56.9 false skeletons per 1000 frames on
        `valid60_people3b` and `valid60_people3`. The sweep `emerging` of `make results`.
    free_space_m, free_share : an unseen confirmed track (in the open or held behind someone)
        ends when the depth image shows nobody where it puts the person (`free_space`): at
        least `free_share` of the readings in a torso-sized square around its torso point lie
        over `free_space_m` beyond it, or the point projects outside the image (0: off, the
        tracker before; also off without a depth image). On real recordings a person who
        walked off was predicted on for `max_unseen_s` (out through the image's side, or held
        where they had stood for `max_hidden_s`), a ghost skeleton every frame. On the real
        development recording lab_walk (`pose4d eval ../shared/data/real/lab_walk --fps 10
        --labels labels/real/lab_walk.json [--colour-net lspet_convnet] --config
        tracking.free_space_m=M`; ghosts, labelled people found of 228): off 276, 160 (with the
        network 94, 159); 0.75 m with a share of 0.9 174, 154 (82, 152); 1.5 m and 0.9 209,
        167 (78, 157), shipped: the farthest, the surest the person is gone. Validation renders
        (`valid60_people2`, `valid60_people3b`, `valid60_people3d`, `valid30_people2b`): the
        same to the digit with it as without.

    `confirm_frames`, `birth_score` and `trust_score`, and the foreground's second look, were
    chosen on validation renders (training subjects s01-s06, seed 201: `valid60_people2`, two
    people, 720 frames, and its twins with each person alone) by `tools/people_sweep.py`, for
    the shipped `rgbd_14`, by the mean MOTA of the three sets: second look, birth score 5, 2
    frames, trust score 7: 0.985 (two people: average7 86.6, IDF1 0.960, MOTA 0.953, 8 false
    skeletons per 1000 frames; alone: MOTA 1.000 and 1.000); trust score 9: 0.984; birth
    score 4 with 3 frames: 0.983; without the second look, the best 0.974; the settings before
    (no second look, the best region trusted at once) 0.943, a chair trusted in one alone
    video (83 false skeletons per 1000 frames).
    """

    max_people: int = 4
    confirm_frames: int = 2
    max_unseen_s: float = 1.0
    torso_std_m: float = 0.15
    max_speed_mps: float = 1.5
    gate_chi2: float = 16.0
    birth_score: float = 5.0
    max_gap_s: float = 0.5
    trust_score: float = 7.0
    hold_occluded: bool = True
    occluded_width_m: float = 0.09
    quiet_frames: int = 4
    max_held_s: float = math.inf
    max_hidden_s: float = 2.0
    detector_keep_s: float = 0.0
    confirmed_first: bool = True
    held_continues: bool = True
    held_own_front: bool = True
    emerging_score: float = 3.0
    free_space_m: float = 1.5
    free_share: float = 0.9

    def __post_init__(self) -> None:
        if self.max_people < 1 or self.confirm_frames < 1 or self.quiet_frames < 0:
            raise ValueError(f'max_people and confirm_frames must be >= 1 and quiet_frames >= '
                             f'0, got {self.max_people}, {self.confirm_frames} and '
                             f'{self.quiet_frames}')
        for name in ('max_unseen_s', 'torso_std_m', 'max_speed_mps', 'gate_chi2', 'max_gap_s',
                     'occluded_width_m', 'max_held_s', 'max_hidden_s'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if not self.detector_keep_s >= 0:
            raise ValueError(f'detector_keep_s must be >= 0, got {self.detector_keep_s}')
        if math.isnan(self.trust_score):
            raise ValueError('trust_score must be a number (inf: only the best region), got nan')
        if not (self.free_space_m >= 0 and 0 < self.free_share <= 1):
            raise ValueError(f'need free_space_m >= 0 and 0 < free_share <= 1, got '
                             f'{self.free_space_m} and {self.free_share}')
        if math.isnan(self.emerging_score):
            raise ValueError('emerging_score must be a number (inf: birth_score only), got nan')


def torso(joints: JointSet) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A person's torso point: the mean 3-D position of the located `TORSO` joints (NaN if
    none has one) and the mean of their covariances ((3,), (3, 3))."""
    rows = _torso_rows(joints.names)
    idx = rows[(joints.source[rows] != cj.MISSING)
               & np.logical_and.reduce(np.isfinite(joints.xyz[rows]), axis=1)]
    if not len(idx):
        return np.full(3, np.nan), np.zeros((3, 3))
    # np.mean's values (the sums in `TORSO` order over the count), without its Python wrapper
    return (np.add.reduce(joints.xyz[idx], axis=0) / len(idx),
            np.add.reduce(joints.covariance[idx], axis=0) / len(idx))


@functools.lru_cache(maxsize=16)
def _torso_rows(names: tuple[str, ...]) -> NDArray[np.intp]:
    """The rows of the `TORSO` joints in `names`, in `TORSO` order (read-only)."""
    rows = np.array([names.index(n) for n in TORSO if n in names], np.intp)
    rows.setflags(write=False)
    return rows


def torso_px(joints: JointSet) -> tuple[NDArray[np.float64], float]:
    """A person's torso point in the image (the mean pixel of the located `TORSO` joints, NaN
    if none) and their size in pixels (the height of their located joints' box, NaN if under
    two): the association's fallback when there is no 3-D (no camera_info yet)."""
    located = (joints.source != cj.MISSING) & np.logical_and.reduce(np.isfinite(joints.uv),
                                                                    axis=1)
    rows = _torso_rows(joints.names)
    idx = rows[located[rows]]
    if not len(idx):
        return np.full(2, np.nan), math.nan
    v = joints.uv[located, 1]
    size = float(np.maximum.reduce(v) - np.minimum.reduce(v)) if v.size >= 2 else math.nan
    # np.mean's value (the sums in `TORSO` order over the count), without its Python wrapper
    return np.add.reduce(joints.uv[idx], axis=0) / len(idx), size


def assign(cost: NDArray[np.float64], gate: float) -> list[tuple[int, int]]:
    """The pairs (row, column) of the least-cost one-to-one assignment among the pairs whose
    cost is at most `gate` (NaN = never): as many such pairs as can be, the least total cost
    among those. A pair beyond the gate never takes part: left in the sum, it could buy a
    smaller total by taking a row's or a column's pair within the gate away (three tracks, one
    far from everything: its cost to a detection of another track makes that track lose it).
    A single row and a single column are always paired when finite."""
    cost = np.asarray(cost, np.float64)
    if cost.size == 0:
        return []
    if cost.shape == (1, 1):
        return [(0, 0)] if np.isfinite(cost[0, 0]) else []
    with np.errstate(invalid='ignore'):
        inside = cost <= gate
    # every pair outside costs more than all the pairs inside together
    big = 1.0 + np.abs(cost[inside]).sum() * 2.0
    rows, cols = linear_sum_assignment(np.where(inside, cost, big))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if inside[r, c]]


_solve = _umath_linalg.solve


def _mahalanobis2(d: NDArray[np.float64], s: NDArray[np.float64]) -> float:
    try:
        return float(d @ np.linalg.solve(s, d))
    except np.linalg.LinAlgError:
        return math.inf


def _mahalanobis2_all(d: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    """`_mahalanobis2` of each pair of `d` (K, 3) and `s` (K, 3, 3), in one solve (the same
    LAPACK solve per pair, and np.vecdot is the dot's sum); one by one when a matrix is
    singular (inf for it)."""
    # np.linalg.solve's LAPACK call without its wrapper: NaN where it would raise
    out = np.vecdot(d, _solve(s, d[:, :, None], signature='dd->d')[:, :, 0])
    if np.logical_and.reduce(np.isfinite(out)):
        return out
    return np.array([_mahalanobis2(a, b) for a, b in zip(d, s, strict=True)])


# A candidate region has not moved when its pixels overlap those of the last one searched by
# at least this share (intersection over union) and its median depth is within this many metres
# of that one's (`quiet_frames`). Its box is not compared: a wall's edge at the image's border
# is cut at a height that flickers from frame to frame (its box's top 0-56 px on the demo bag,
# its pixels 91-97 % the same), and a depth step of the renders' quantisation (2 cm at 2.7 m)
# moved it too, so it was searched every other frame
STILL_M = 0.05
STILL_IOU = 0.9


@dataclass
class _Slot:
    """One person's detector state, where their region last was, and its last search: the
    region's pixels and depth, the detection, and the frames it has been kept since."""

    stage: object
    centre: NDArray[np.float64]
    seen_s: float
    depth_m: float = math.nan
    mask: NDArray[np.bool_] | None = None
    last: JointSet | None = None
    kept: int = 0


class PeopleDetector:
    """One part-model search per person candidate, each person with their own detector state.

    Parameters
    ----------
    make : a new `core.pipeline.DetectorStage` (sharing the model) for a new person.
    config : `TrackingConfig` (max_people, max_speed_mps, torso_std_m; a person's state is
        kept unseen as long as a track can be, the longer of max_unseen_s and max_hidden_s,
        or `detector_keep_s`: a person held behind a nearer one comes back to their person
        scale and arm prior, not to a new track's three-scale warm-up). Chosen on validation
        (`pose4d eval data/synth/<set> --model rgbd_14 --no-single-frame`, `rgbd_kf_ik`
        average7, max_unseen_s before): valid60_people3 86.78 -> 86.87; valid60_people2
        (88.64) and valid30_people2b (86.26) and every tracking figure unchanged.
    """

    def __init__(self, make: Callable[[], object], config: TrackingConfig | None = None) -> None:
        self.make = make
        self.config = config or TrackingConfig()
        self.slots: list[_Slot] = []

    def reset(self) -> None:
        self.slots = []

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating],
             intrinsics: Intrinsics | None, people: Sequence[ForegroundResult], *,
             stamp_s: float) -> list[JointSet]:
        """The detected parts of each candidate in `people` (at most `max_people`, in their
        order), each searched in its own mask with its person's state, where the candidates
        nearer than them stand as what may hide their parts (`_in_front`)."""
        people = list(people)[:self.config.max_people]
        centres = [_centre(p, intrinsics) for p in people]
        cfg = self.config
        cost = np.full((len(self.slots), len(people)), np.nan)
        for i, slot in enumerate(self.slots):
            spread = cfg.torso_std_m + cfg.max_speed_mps * max(stamp_s - slot.seen_s, 0.0)
            for j, c in enumerate(centres):
                cost[i, j] = float(np.sum((slot.centre - c) ** 2)) / spread ** 2
        pairs = dict((j, i) for i, j in assign(cost, cfg.gate_chi2))
        out = []
        for j, (person, centre) in enumerate(zip(people, centres, strict=True)):
            if j in pairs:
                slot = self.slots[pairs[j]]
            else:
                slot = _Slot(self.make(), centre, stamp_s)
                self.slots.append(slot)
            slot.centre, slot.seen_s = centre, stamp_s
            if self._quiet(slot, person):
                slot.kept += 1
                out.append(slot.last)
                continue
            color_m, depth_mm = apply_mask(color, depth_m, person.mask)
            slot.last = slot.stage.step(color_m, depth_mm, intrinsics, mask=person.mask,
                                        stamp_s=stamp_s, blanked=True,
                                        occluder=_in_front(people, j, cfg.torso_std_m))
            slot.depth_m, slot.mask, slot.kept = person.depth_m, person.mask, 0
            out.append(slot.last)
        keep_s = cfg.detector_keep_s or max(cfg.max_unseen_s, cfg.max_hidden_s)
        self.slots = [s for s in self.slots if stamp_s - s.seen_s <= keep_s]
        return out

    def _quiet(self, slot: _Slot, person: ForegroundResult) -> bool:
        """Whether the slot's last detection stands for this frame (`quiet_frames`)."""
        cfg = self.config
        if not (slot.kept < cfg.quiet_frames and slot.last is not None
                and slot.last.score < cfg.birth_score and slot.mask is not None
                and abs(person.depth_m - slot.depth_m) <= STILL_M
                and slot.mask.shape == person.mask.shape):
            return False
        # a person partly hidden scores as low, but moves within their region
        union = np.count_nonzero(slot.mask | person.mask)
        return np.count_nonzero(slot.mask & person.mask) >= STILL_IOU * union


def _in_front(people: Sequence[ForegroundResult], j: int, by_m: float
              ) -> NDArray[np.bool_] | None:
    """The pixels of the candidates nearer than `people[j]` by over `by_m` (their median
    depths), or None: where a nearer person may hide them (`core.dpm.infer.OcclusionFloor`)."""
    near = [p.mask for k, p in enumerate(people)
            if k != j and p.depth_m < people[j].depth_m - by_m]
    return np.logical_or.reduce(near) if near else None


def _centre(person: ForegroundResult, intrinsics: Intrinsics | None) -> NDArray[np.float64]:
    """The 3-D centre of a candidate's box at its median depth (pixels and 1 m without
    intrinsics)."""
    x0, y0, x1, y1 = person.box or (0, 0, 0, 0)
    uv = np.array([[(x0 + x1) / 2, (y0 + y1) / 2]], float)
    if intrinsics is None or not math.isfinite(person.depth_m):
        return np.array([uv[0, 0] / 100, uv[0, 1] / 100, 1.0])
    return backproject(uv, np.array([person.depth_m]), intrinsics)[0]


@dataclass
class _Track:
    stage: object
    id: int = 0  # 0 while tentative
    hits: int = 0
    seen_s: float = -math.inf
    point: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))
    cov: NDArray[np.float64] = field(default_factory=lambda: np.zeros((3, 3)))
    pixel: NDArray[np.float64] = field(default_factory=lambda: np.full(2, np.nan))
    size_px: float = math.nan
    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    names: tuple[str, ...] = ()
    last: JointSet | None = None
    held: bool = False  # hidden behind another person: `last` is their last pose, kept
    held_s: float = math.nan  # since when
    behind: int = 0  # while held: the id of the track of the person hiding them


class PeopleTracker:
    """One SLQE per person (`core.pipeline.TrackerStage`), detections assigned to tracks each
    frame (module docstring).

    Parameters
    ----------
    make : a new TrackerStage for a new track.
    config : `TrackingConfig`.

    Attributes
    ----------
    born, ended : ids of the tracks confirmed and ended by the last `step`.
    next_id : the id the next confirmed track gets (ids are never reused).
    """

    def __init__(self, make: Callable[[], object], config: TrackingConfig | None = None) -> None:
        self.make = make
        self.config = config or TrackingConfig()
        self.tracks: list[_Track] = []
        self.last_s: float | None = None
        self._previous_s: float | None = None
        self._spare: object | None = None
        self.next_id = 1
        self.born: list[int] = []
        self.ended: list[int] = []

    def reset(self) -> None:
        """End every track (ids still count on)."""
        self.ended = [t.id for t in self.tracks if t.id]
        self.tracks = []
        self.last_s = None

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Track two people for a few frames (the first frames' paths run once), then forget
        them: ids start at 1."""
        from pose4d_ros.core.skeleton import PARTS_10

        base = np.array([[0.0, -0.7 + 0.17 * k, 2.8] for k in range(len(PARTS_10))])
        for k in range(4):
            people = []
            for dx in (-0.6, 0.6):
                xyz = base + [dx, 0.0, 0.0]
                people.append(JointSet(PARTS_10.names, project(xyz, intrinsics), xyz,
                                       source=np.full(len(xyz), cj.DETECTED, np.uint8),
                                       confidence=np.full(len(xyz), 0.9), score=10.0))
            self.step(people, k / 30, intrinsics)
        self.reset()
        self.next_id = 1
        self.born, self.ended = [], []

    def step(self, detections: Sequence[JointSet], stamp_s: float,
             intrinsics: Intrinsics | None,
             depth_m: NDArray[np.floating] | None = None) -> list[JointSet]:
        """Track one frame: the tracked parts of every confirmed track (its `track_id` set),
        primary first, then by id. `depth_m` (the camera's depth, metres, NaN = no reading):
        an unseen track whose person the depth image shows is not there ends (`free_space`)."""
        cfg = self.config
        # every detection checked before anything changes: a frame with one the SLQE would
        # refuse is refused whole (ValueError), and the tracks are untouched
        checker = self.tracks[0].stage if self.tracks else self._checker()
        for det in detections:
            checker.check(det, intrinsics)
        self.born, self.ended = [], []
        # a gap in the stream (no frame for over `max_gap_s`: a new video, a paused camera)
        # ends every track, as the SLQE restarts after one; a track unseen longer than
        # `max_unseen_s` (`max_hidden_s` held behind another) while frames came has ended and
        # is matched no more
        gap = self.last_s is not None and not 0.0 <= stamp_s - self.last_s <= cfg.max_gap_s
        self._previous_s, self.last_s = self.last_s, stamp_s
        ended = [t for t in self.tracks if gap or stamp_s - t.seen_s > (
            cfg.max_hidden_s if t.held else cfg.max_unseen_s)]
        self.ended = [t.id for t in ended if t.id]
        self.tracks = [t for t in self.tracks if t not in ended]
        points = [torso(d) for d in detections]
        cost = self._cost(detections, points, stamp_s)
        matched, trusted, emerging, refused = self._match(detections, points, cost, intrinsics)
        while refused:
            # a pair the track refuses takes no part: the detection goes to the next track
            # that fits, a tentative one among them (a person held behind another, offered the
            # detection of someone walking by, would else take it from that person's young
            # track frame after frame and refuse it: the person never confirmed); each round
            # removes a pair, so this ends
            cost[tuple(np.array(refused).T)] = np.nan
            matched, trusted, emerging, refused = self._match(detections, points, cost,
                                                              intrinsics)
        # no pair left is refused (`_match`): each detection is its track's, or may start one
        for j, det in enumerate(detections):
            born = self._born(det, j in emerging and _clear_of_sides(det, intrinsics))
            if j not in matched and (_finite(points[j][0]) or _finite(torso_px(det)[0])) \
                    and (j in trusted or born):
                stage = self.make()
                self.tracks.append(_Track(stage, names=stage.check(det, intrinsics).names))
                matched[j] = len(self.tracks) - 1
        seen = {i: j for j, i in matched.items()}
        gone: list[_Track] = []
        # the tracks seen first: a track unseen behind one of them is held (`_behind`)
        for i in sorted(range(len(self.tracks)), key=lambda i: i not in seen):
            track = self.tracks[i]
            if i not in seen and track.id and (track.held or (
                    behind := self._behind(track, stamp_s))):
                # its last pose kept until seen again (its SLQE then restarts) or ended
                if not track.held:
                    track.held, track.held_s, track.behind = True, stamp_s, behind
                track.last = _held(track.last)
                if self._left(track.last, depth_m, intrinsics):
                    gone.append(track)
                continue
            if i in seen and track.held:
                track.stage.reset()
                track.held = False
            det = detections[seen[i]] if i in seen else JointSet.missing(track.names)
            hidden = None
            if i in seen and track.id and cfg.hold_occluded and track.last is not None:
                hidden = self._hidden(det, points[seen[i]][0], [
                    (detections[j], points[j][0]) for j in seen.values() if j != seen[i]],
                    intrinsics)
            if hidden is not None:
                # the joints on a nearer person's body: their last estimates kept
                det = _without(det, hidden)
            # checked above (`_without` and `JointSet.missing` only make joints MISSING)
            out = track.stage.step(det, stamp_s, intrinsics, checked=True)
            if hidden is not None:
                out = _kept(out, track.last, hidden)
            track.names = out.names
            if i not in seen and track.id and self._left(out, depth_m, intrinsics):
                gone.append(track)
                continue
            if i in seen:
                self._seen(track, out, stamp_s)
                if not track.id and (track.hits >= cfg.confirm_frames or seen[i] in trusted):
                    track.id, self.next_id = self.next_id, self.next_id + 1
                    self.born.append(track.id)
            track.last = _with_track_id(out, track.id)
        # a tentative track must be matched every frame (confirmed ones end at the next step
        # once unseen over `max_unseen_s`)
        self.tracks = [t for t in self.tracks
                       if (t.id or t.seen_s == stamp_s) and t not in gone]
        self.ended += [t.id for t in gone]
        # a pose held too long is mostly where nobody is: kept, not published
        return [t.last for t in self._ordered(stamp_s)
                if not (t.held and stamp_s - t.held_s > cfg.max_held_s)]

    def _left(self, joints: JointSet | None, depth_m: NDArray[np.floating] | None,
              intrinsics: Intrinsics | None) -> bool:
        """Whether an unseen track's person has left: the depth image shows free space where
        `joints` put them (`free_space`; never without depth or with `free_space_m` 0)."""
        return (joints is not None and depth_m is not None and self.config.free_space_m > 0
                and free_space(joints, depth_m, intrinsics, self.config))

    def _match(self, detections: Sequence[JointSet], points: list[tuple[NDArray, NDArray]],
               cost: NDArray[np.float64], intrinsics: Intrinsics | None
               ) -> tuple[dict[int, int], set[int], dict[int, set[int]], list[tuple[int, int]]]:
        """The assignment on `cost` ({detection: track}), the detections trusted at once,
        those emerging from behind a nearer person, and the pairs (track, detection) whose
        track refuses the detection (`_refuses`)."""
        matched = {j: i for i, j in self._assign(cost)}
        trusted = self._trusted(detections, matched)
        emerging = self._emerging(detections, points, matched)
        refused = [(i, j) for j, i in matched.items() if self._refuses(
            self.tracks[i], self._born(detections[j], j in emerging and _clear_of_sides(
                detections[j], intrinsics)), emerging.get(j))]
        return matched, trusted, emerging, refused

    def _refuses(self, track: _Track, born: bool, fronts: set[int] | None) -> bool:
        """Whether `track` refuses a detection assigned to it (`born`: it may start a track;
        `fronts`: the ids of the people it comes out from behind): a held track one away
        from where its person would come out (`_elsewhere`), a tentative track or one
        unseen beside another person one that could not start a track (`_continues`)."""
        out = _out_from_behind(track, fronts, self.config.held_own_front)
        return self._elsewhere(track, out) or (not born and not self._continues(track, out))

    def _assign(self, cost: NDArray[np.float64]) -> list[tuple[int, int]]:
        """`assign` for the confirmed tracks first, then for the tentative ones on the
        detections left: a track just started beside a confirmed one never takes its person's
        detection from it (the confirmed one would go on unseen, predicted where nobody is)."""
        gate = self.config.gate_chi2
        tentative = [i for i, t in enumerate(self.tracks) if not t.id]
        if not (self.config.confirmed_first and tentative):
            return assign(cost, gate)
        rows = [i for i, t in enumerate(self.tracks) if t.id]
        pairs = [(rows[r], c) for r, c in assign(cost[rows], gate)]
        taken = {c for _, c in pairs}
        left = [c for c in range(cost.shape[1]) if c not in taken]
        if left:
            pairs += [(tentative[r], left[c])
                      for r, c in assign(cost[np.ix_(tentative, left)], gate)]
        return pairs

    def _trusted(self, detections: Sequence[JointSet], matched: dict[int, int]) -> set[int]:
        """The detections confirmed at their first frame: none while a track is confirmed;
        with nobody tracked, every one scoring at least `trust_score`, or, when none does, the
        first not matched (the foreground's best region), as the single-person tracker trusts
        its one detection, if it scores at least `birth_score` (a desk in an empty room,
        trusted at the first frame, was a ghost on real recordings: lab_walk with the
        photograph network 111 -> 94 ghosts; validation renders unchanged)."""
        if any(t.id for t in self.tracks):
            return set()
        free = [j for j in range(len(detections)) if j not in matched]
        sure = {j for j in free if detections[j].score >= self.config.trust_score}
        return sure or {j for j in free[:1] if not detections[j].score < self.config.birth_score}

    def _hidden(self, det: JointSet, point: NDArray[np.float64],
                others: list[tuple[JointSet, NDArray[np.float64]]],
                intrinsics: Intrinsics | None) -> NDArray[np.bool_] | None:
        """(J,) the joints of `det` that lie on a nearer person's body: within
        `occluded_width_m` (at that person's depth) of one of their bones in the image, that
        person's torso nearer by over `torso_std_m`; None when there is none."""
        cfg = self.config
        if intrinsics is None or not _finite(point):
            return None
        hidden = np.zeros(len(det.names), bool)
        for other, q in others:
            if not (_finite(q) and q[2] < point[2] - cfg.torso_std_m):
                continue
            ok = (other.source != cj.MISSING) & np.isfinite(other.uv).all(axis=1)
            r = cfg.occluded_width_m * intrinsics.fx / q[2]
            for a, b in tree_for(other.names).edges():
                if ok[a] and ok[b]:
                    hidden |= _near_segment(det.uv, other.uv[a], other.uv[b], r)
        return hidden if hidden.any() else None

    def _checker(self) -> object:
        """A stage to check detections with while there is no track (made once)."""
        if self._spare is None:
            self._spare = self.make()
        return self._spare

    def _born(self, det: JointSet, emerging: bool = False) -> bool:
        """Whether a detection may start or grow a tentative track (`birth_score`, or
        `emerging_score` where it comes out from behind a nearer person)."""
        cfg = self.config
        least = min(cfg.birth_score, cfg.emerging_score) if emerging else cfg.birth_score
        return not det.score < least  # NaN: no score to judge by

    def _continues(self, track: _Track, emerging: bool = False) -> bool:
        """Whether a confirmed track takes any detection: no other confirmed track exists (one
        person is tracked as the single-person tracker tracks them), or it was seen at the
        last frame, or it is held behind another and the detection is `emerging` from
        behind a nearer person (`held_continues`; elsewhere it takes none, `_elsewhere`).
        Otherwise only a detection that could start a track (`birth_score`) is its: what the
        gate of a track unseen beside another person reaches is often a part of the room."""
        if not track.id:
            return False
        if not any(t.id for t in self.tracks if t is not track):
            return True
        # a person held behind another comes out partly seen, and scores low meanwhile
        return track.seen_s == self._previous_s or (
            track.held and emerging and self.config.held_continues)

    def _elsewhere(self, track: _Track, emerging: bool) -> bool:
        """Whether a track held behind a nearer person is offered a detection away from where
        they would come out (`held_continues`), whatever its score."""
        return self.config.held_continues and track.held and not emerging

    def _emerging(self, detections: Sequence[JointSet], points: list[tuple[NDArray, NDArray]],
                  matched: dict[int, int]) -> dict[int, set[int]]:
        """The detections whose torso pixel lies in the box of a nearer person matched to a
        confirmed track (`_in_box`), farther by over `torso_std_m` in 3-D, each with the ids
        of those tracks: where a person hidden behind them comes out (a held track takes
        only a detection coming out from behind the person hiding it, `_out_from_behind`:
        its gate, grown with the time unseen, also reaches the room's clutter metres away,
        coming out from behind someone else), and where a tentative track may grow from
        `emerging_score`."""
        cfg = self.config
        if not ((cfg.held_continues and any(t.held for t in self.tracks))
                or (cfg.emerging_score < cfg.birth_score and len(detections) > 1)):
            return {}
        fronts = [(k, self.tracks[i].id, detections[k], points[k][0])
                  for k, i in matched.items() if self.tracks[i].id and _finite(points[k][0])]
        out: dict[int, set[int]] = {}
        for j, (point, _) in enumerate(points):
            pixel = torso_px(detections[j])[0]
            if not (_finite(pixel) and _finite(point)):
                continue
            ids = {t for k, t, other, q in fronts if k != j and point[2] > q[2] + cfg.torso_std_m
                   and _in_box(other, pixel)}
            if ids:
                out[j] = ids
        return out

    def _behind(self, track: _Track, stamp_s: float) -> int:
        """The id of the track of a person seen this frame whom an unseen track's person is
        hidden behind (0: nobody): their last torso pixel within that person's box (its
        located joints, grown by a tenth of its height) and their torso farther by over
        `torso_std_m` (both in 3-D)."""
        if not (_finite(track.pixel) and _finite(track.point)):
            return 0
        for other in self.tracks:
            if other is track or not other.id or other.seen_s != stamp_s or other.last is None \
                    or not _finite(other.point) \
                    or not track.point[2] > other.point[2] + self.config.torso_std_m:
                continue
            if _in_box(other.last, track.pixel):
                return other.id
        return 0

    def _cost(self, detections: Sequence[JointSet], points: list[tuple[NDArray, NDArray]],
              stamp_s: float) -> NDArray[np.float64]:
        """Squared Mahalanobis torso distances (tracks x detections) in 3-D; where a track or a
        detection has no 3-D torso, in the image, the spread a quarter of the person's height
        growing as in 3-D (at 2.5 m)."""
        cfg = self.config
        cost = np.full((len(self.tracks), len(points)), np.nan)
        seen = [j for j, (p, _) in enumerate(points) if _finite(p)]
        pairs, d, s = [], [], []
        for i, t in enumerate(self.tracks):
            if not _finite(t.point):
                continue
            dt = max(stamp_s - t.seen_s, 0.0)
            predicted = t.point + t.velocity * min(dt, cfg.max_unseen_s)
            spread = (cfg.torso_std_m ** 2 + (cfg.max_speed_mps * dt) ** 2) * _EYE3
            for j in seen:
                p, c = points[j]
                pairs.append((i, j))
                d.append(p - predicted)
                s.append(t.cov + c + spread)
        if pairs:
            rows, cols = zip(*pairs, strict=True)
            cost[rows, cols] = _mahalanobis2_all(np.array(d), np.array(s))
        # where a track or a detection has no 3-D torso: in the image
        pixels = [torso_px(d) for d in detections]
        for i, t in enumerate(self.tracks):
            if t.size_px > 0 and _finite(t.pixel):
                dt = max(stamp_s - t.seen_s, 0.0)
                sigma = 0.25 * t.size_px * (1.0 + cfg.max_speed_mps * dt / 0.5)
                for j, (uv, _) in enumerate(pixels):
                    if np.isnan(cost[i, j]) and _finite(uv):
                        cost[i, j] = float(np.sum((uv - t.pixel) ** 2)) / sigma ** 2
        return cost

    def _seen(self, track: _Track, out: JointSet, stamp_s: float) -> None:
        pixel, size = torso_px(out)
        if np.isfinite(pixel).all():
            track.pixel = pixel
            track.size_px = size if size > 0 else track.size_px
        point, cov = torso(out)
        if _finite(point):
            dt = stamp_s - track.seen_s
            if _finite(track.point) and 0 < dt <= self.config.max_unseen_s:
                track.velocity = 0.7 * track.velocity + 0.3 * (point - track.point) / dt
            track.point, track.cov = point, cov
        track.hits += 1
        track.seen_s = stamp_s

    def _ordered(self, stamp_s: float) -> list[_Track]:
        confirmed = sorted((t for t in self.tracks if t.id), key=lambda t: t.id)
        seen = [t for t in confirmed if t.seen_s == stamp_s]
        # the longest tracked: seen in most frames (the first confirmed on a tie)
        primary = sorted(seen or confirmed, key=lambda t: -t.hits)[:1]
        return primary + [t for t in confirmed if t not in primary]


def free_space(joints: JointSet, depth_m: NDArray[np.floating], intrinsics: Intrinsics | None,
               config: TrackingConfig) -> bool:
    """Whether the depth image shows that nobody is where `joints` (an unseen track's
    prediction) puts a person: its torso point projects outside the image, or at least
    `free_share` of the depth readings in a square of the torso's size (0.3 m) around it lie
    over `free_space_m` beyond it (the camera sees through where the person would be). A person
    hidden behind something nearer, or in a hole of the depth image, is not free space."""
    point, _ = torso(joints)
    if intrinsics is None or not _finite(point) or point[2] <= 0:
        return False
    u, v = project(point[None], intrinsics)[0]
    h, w = depth_m.shape
    if not (0 <= u < w and 0 <= v < h):
        return True
    r = max(int(0.15 * intrinsics.fx / point[2]), 1)
    x, y = int(u), int(v)
    window = depth_m[max(y - r, 0):y + r + 1, max(x - r, 0):x + r + 1]
    readings = window[np.isfinite(window)]
    if readings.size < 0.25 * window.size:
        return False
    return bool(np.count_nonzero(readings > point[2] + config.free_space_m)
                >= config.free_share * readings.size)


def _out_from_behind(track: _Track, fronts: set[int] | None, own_front: bool) -> bool:
    """Whether a detection coming out from behind the people of the track ids `fronts`
    (`PeopleTracker._emerging`; None: from behind nobody) comes out where `track`'s person
    would: with `own_front`, for a track held behind a person, from behind that person only
    (not seen this frame, nobody comes out from behind them); otherwise from behind anyone."""
    return bool(fronts) and (not (own_front and track.held) or track.behind in fronts)


def _finite(v: NDArray[np.float64]) -> bool:
    """Every value finite (`np.isfinite(v).all()` without its Python wrapper)."""
    return bool(np.logical_and.reduce(np.isfinite(v), axis=None))


# a detection reaching this share of the image's width from its left or right edge starts no
# track from `emerging_score` (`_clear_of_sides`)
SIDE_SHARE = 0.04


def _clear_of_sides(det: JointSet, intrinsics: Intrinsics | None) -> bool:
    """Whether every located joint of `det` lies farther than `SIDE_SHARE` of the image's
    width from its left and right edges. Behind a person near the image's side, a wall's edge
    or furniture cut by the border is a candidate that scores as a partly seen person does
    (on validation, `valid60_people3` and `valid60_people3b`: 3.5-4, where people coming out
    from behind another score 3.4-5), and the foreground already counts a region cut by the
    side borders as more often no person (`PersonConfig.border_penalty`)."""
    if intrinsics is None:
        return False
    u = det.uv[det.source != cj.MISSING, 0]
    margin = SIDE_SHARE * intrinsics.width
    return bool(u.size) and bool(np.all((u > margin) & (u < intrinsics.width - 1 - margin)))


def _in_box(joints: JointSet, pixel: NDArray[np.float64]) -> bool:
    """Whether `pixel` lies in the box of the located joints (at least two), grown by a tenth
    of its height."""
    uv = joints.uv[(joints.source != cj.MISSING) & np.isfinite(joints.uv).all(axis=1)]
    if len(uv) < 2:
        return False
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    grow = 0.1 * (hi[1] - lo[1])
    return bool(np.all(pixel >= lo - grow) and np.all(pixel <= hi + grow))


def _near_segment(p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64],
                  r: float) -> NDArray[np.bool_]:
    """(N,) points of p (N, 2) within r of the segment a-b."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-9), 0.0, 1.0)
    d = p - (a + t[:, None] * ab)
    with np.errstate(invalid='ignore'):
        return (d * d).sum(axis=1) <= r * r


def _without(det: JointSet, hidden: NDArray[np.bool_]) -> JointSet:
    """`det` with the joints `hidden` MISSING."""
    uv, xyz = det.uv.copy(), det.xyz.copy()
    source, conf = det.source.copy(), det.confidence.copy()
    uv[hidden], xyz[hidden], source[hidden], conf[hidden] = np.nan, np.nan, cj.MISSING, 0.0
    return JointSet.of_arrays(det.names, uv, xyz, conf, source, det.covariance,
                              score=det.score, track_id=det.track_id)


def _kept(out: JointSet, last: JointSet, hidden: NDArray[np.bool_]) -> JointSet:
    """The tracker's output `out` with the joints `hidden` at their estimate of `last`
    (TRACKED) where it has one."""
    keep = hidden & (last.source != cj.MISSING)
    if out.names != last.names or not keep.any():
        return out
    uv, xyz, source = out.uv.copy(), out.xyz.copy(), out.source.copy()
    uv[keep], xyz[keep], source[keep] = last.uv[keep], last.xyz[keep], cj.TRACKED
    return JointSet.of_arrays(out.names, uv, xyz, out.confidence, source, out.covariance,
                              score=out.score, track_id=out.track_id)


def _held(joints: JointSet | None) -> JointSet | None:
    """A track's last pose kept while its person is hidden: every located joint TRACKED."""
    if joints is None:
        return None
    source = np.where(joints.source == cj.MISSING, cj.MISSING, cj.TRACKED).astype(np.uint8)
    return JointSet.of_arrays(joints.names, joints.uv, joints.xyz, joints.confidence, source,
                              joints.covariance, score=joints.score, track_id=joints.track_id)


def _with_track_id(joints: JointSet, track_id: int) -> JointSet:
    """`joints` with another `track_id`, sharing its (read-only) arrays."""
    return JointSet.of_arrays(joints.names, joints.uv, joints.xyz, joints.confidence,
                              joints.source, joints.covariance, score=joints.score,
                              track_id=track_id)


_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


class PeopleIk:
    """One `core.pipeline.IkStage` per track id (each track its own learned bone lengths);
    a track's IK ends when its id is no longer given."""

    def __init__(self, make: Callable[[], object]) -> None:
        self.make = make
        self.stages: dict[int, object] = {}

    def reset(self) -> None:
        self.stages = {}

    def step(self, tracked: Sequence[JointSet], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None) -> list[JointSet]:
        """The 14-joint skeleton of each tracked person, in the order given."""
        stages = {t.track_id: self.stages.get(t.track_id) or self.make() for t in tracked}
        self.stages = stages
        return [stages[t.track_id].step(t, depth_m, intrinsics) for t in tracked]


def people_labels(people: Sequence[ForegroundResult], shape: tuple[int, int]
                  ) -> NDArray[np.uint8]:
    """The label image of the people of one frame: person k (1 = the best) is ``256 - k``,
    background 0, so that ``labels > 0`` is everyone's mask and one person's image is the
    single-person mask (255 = person) bit for bit."""
    labels = np.zeros(shape, np.uint8)
    for k, person in reversed(list(enumerate(people[:255]))):
        labels[person.mask] = 255 - k
    return labels


def people_from_labels(labels: NDArray[np.uint8], depth_m: NDArray[np.floating] | None
                       ) -> list[ForegroundResult]:
    """The people of a label image (`people_labels`: each distinct value > 0 one person, the
    highest first), their boxes and median depths from `depth_m` (metres, NaN = none)."""
    labels = np.asarray(labels)
    out = []
    values = np.flatnonzero(np.bincount(labels.ravel(), minlength=256)[1:]) + 1
    for value in values[::-1]:
        mask = labels == value
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        z = math.nan
        if depth_m is not None:
            zs = np.asarray(depth_m)[mask]
            zs = zs[np.isfinite(zs) & (zs > 0)]
            z = float(np.median(zs)) if zs.size else math.nan
        out.append(ForegroundResult(mask=mask, box=(int(cols[0]), int(rows[0]),
                                                    int(cols[-1]) + 1, int(rows[-1]) + 1),
                                    depth_m=z, found=True))
    return out
