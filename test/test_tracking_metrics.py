"""`evaluation.tracking_metrics` against hand-worked sequences and numbers from py-motmetrics.

Each sequence is a list of frames (truth ids, skeleton ids, (T, P) torso distances in pixels,
NaN = beyond the threshold). The expected numbers of the hand-made sequences are worked out by
hand in their docstrings; motmetrics 1.4.0 (numpy 2.4.6, scipy 1.17.1, pandas 3.1.1, fed the same
distances through `MOTAccumulator.update`) gave the same, and gave the numbers of the seeded random
sequences of `MOTMETRICS_RANDOM`. motmetrics is not needed to run these tests.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros.core import joints as cj
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import score_joint_sets
from pose4d_ros.core.skeleton import CAD60_JOINTS, SKELETON_14
from pose4d_ros.evaluation.tracking_metrics import (
    FrameEvents,
    TrackingAccumulator,
    assign,
    assign_frame,
    match_people,
    occlusion_gaps,
    score_people,
    seen_share,
    seen_table,
    summarize,
    summarize_sequences,
    torso_distances,
    torso_point,
)

NAN = np.nan
# One frame: truth ids, skeleton ids, (T, P) torso distances in pixels (NaN = beyond reach).
IdFrame = tuple[list[int], list[int], np.ndarray]


def one(truth: int, pred: int, d: float) -> IdFrame:
    return [truth], [pred], np.array([[d]])


def perfect() -> list[IdFrame]:
    """One person, one skeleton 2 px off in 10 frames: MOTA 1, MOTP 2, IDF1 1, mostly tracked."""
    return [one(1, 7, 2.0)] * 10


def id_switch() -> list[IdFrame]:
    """One person, skeleton 7 (1 px) in frames 0-4, skeleton 8 (3 px) in 5-9: one switch,
    MOTA = 1 - 1/10 = 0.9, MOTP = (5 + 15) / 10 = 2; the best trajectory pair agrees in 5
    frames: IDTP 5, IDF1 = 2 * 5 / (10 + 10) = 0.5 = IDP = IDR."""
    return [one(1, 7, 1.0)] * 5 + [one(1, 8, 3.0)] * 5


def fragmented() -> list[IdFrame]:
    """One person in 10 frames, skeleton 7 (2 px) lost in frames 4-6 and back: 3 misses, one
    fragmentation, no switch; MOTA 0.7, MOTP 2, IDTP 7, IDF1 = 14 / 17, IDP 1, IDR 0.7;
    tracked in 70 % of its frames: partially tracked."""
    lost: IdFrame = ([1], [], np.zeros((1, 0)))
    return [one(1, 7, 2.0)] * 4 + [lost] * 3 + [one(1, 7, 2.0)] * 3


def false_positive() -> list[IdFrame]:
    """One person tracked (1 px) in 10 frames, and a skeleton 9 far from anyone in frames 2-4:
    3 false positives, 300 per 1000 frames; MOTA 0.7, MOTP 1, IDTP 10, IDF1 = 20 / 23,
    IDP = 10 / 13, IDR 1."""
    ghost: IdFrame = ([1], [7, 9], np.array([[1.0, NAN]]))
    return [one(1, 7, 1.0)] * 2 + [ghost] * 3 + [one(1, 7, 1.0)] * 5


def miss() -> list[IdFrame]:
    """Person 1 tracked (1 px) in frames 0-7 and lost for good in 8-9 (misses, no
    fragmentation: never matched again); person 2 present in all 10 frames, never tracked.
    GT 20, 12 misses (600 per 1000), MOTA 0.4, MOTP 1, IDTP 8, IDF1 = 16 / 28, IDP 1, IDR 0.4;
    person 1 mostly tracked (80 %), person 2 mostly lost."""
    both: IdFrame = ([1, 2], [7], np.array([[1.0], [NAN]]))
    alone: IdFrame = ([1, 2], [], np.zeros((2, 0)))
    return [both] * 8 + [alone] * 2


def _crossing(swap: bool) -> list[IdFrame]:
    apart = np.array([[1.0, NAN], [NAN, 1.0]])
    # Crossing (frames 5-6), all four pairs within reach; the swapped pairs are nearer. CLEAR-MOT
    # keeps the correspondences of frame 4 because they are still valid.
    close = np.array([[4.0, 2.0], [2.0, 4.0]])
    after = np.array([[NAN, 1.0], [1.0, NAN]]) if swap else apart
    return [([1, 2], [7, 8], apart)] * 5 + [([1, 2], [7, 8], close)] * 2 + \
        [([1, 2], [7, 8], after)] * 3


def crossing_swap() -> list[IdFrame]:
    """Persons 1, 2 tracked by skeletons 7, 8 (1 px); they cross in frames 5-6 (kept pairs 4 px,
    swapped pairs 2 px); from frame 7 skeleton 8 follows person 1 and 7 person 2: two switches
    (frame 7), MOTA = 1 - 2/20 = 0.9, MOTP = (10 * 1 + 4 * 4 + 6 * 1) / 20 = 1.6. Pairs within
    reach: (1,7) and (2,8) 5 + 2 = 7 frames, (1,8) and (2,7) 2 + 3 = 5: IDTP 14, IDF1 0.7."""
    return _crossing(swap=True)


def crossing_no_swap() -> list[IdFrame]:
    """As `crossing_swap`, but the tracker keeps both ids after the crossing: no switch (a
    frame-by-frame assignment without the kept correspondences would count four), MOTA 1,
    MOTP = (16 * 1 + 4 * 4) / 20 = 1.6, IDTP = 2 * (5 + 2 + 3) = 20, IDF1 1."""
    return _crossing(swap=False)


def hidden(new_id: bool) -> list[IdFrame]:
    """Person 1 tracked (1 px) in frames 0-9, hidden (no ground truth, no skeleton) in 10-29,
    back in 30-39 with skeleton 7 again or a new skeleton 8. Same id: nothing lost, MOTA 1,
    IDF1 1, no fragmentation (hidden frames are not misses). New id: one switch (frame 30),
    MOTA = 1 - 1/20 = 0.95, IDTP 10, IDF1 = 20 / 40 = 0.5."""
    empty: IdFrame = ([], [], np.zeros((0, 0)))
    return [one(1, 7, 1.0)] * 10 + [empty] * 20 + [one(1, 8 if new_id else 7, 1.0)] * 10


KEYS = ('mota', 'motp', 'idf1', 'idp', 'idr', 'id_switches', 'fragmentations', 'misses',
        'false_positives', 'gt_objects', 'mostly_tracked', 'mostly_lost')

# The hand-worked numbers (motmetrics 1.4.0 gave the same), in the order of KEYS.
HAND = {
    'perfect': (perfect(), (1.0, 2.0, 1.0, 1.0, 1.0, 0, 0, 0, 0, 10, 1, 0)),
    'id_switch': (id_switch(), (0.9, 2.0, 0.5, 0.5, 0.5, 1, 0, 0, 0, 10, 1, 0)),
    'fragmented': (fragmented(), (0.7, 2.0, 14 / 17, 1.0, 0.7, 0, 1, 3, 0, 10, 0, 0)),
    'false_positive': (false_positive(), (0.7, 1.0, 20 / 23, 10 / 13, 1.0, 0, 0, 0, 3, 10, 1, 0)),
    'miss': (miss(), (0.4, 1.0, 16 / 28, 1.0, 0.4, 0, 0, 12, 0, 20, 1, 1)),
    'crossing_swap': (crossing_swap(), (0.9, 1.6, 0.7, 0.7, 0.7, 2, 0, 0, 0, 20, 2, 0)),
    'crossing_no_swap': (crossing_no_swap(), (1.0, 1.6, 1.0, 1.0, 1.0, 0, 0, 0, 0, 20, 2, 0)),
    'hidden_same_id': (hidden(False), (1.0, 1.0, 1.0, 1.0, 1.0, 0, 0, 0, 0, 20, 1, 0)),
    'hidden_new_id': (hidden(True), (0.95, 1.0, 0.5, 0.5, 0.5, 1, 0, 0, 0, 20, 1, 0)),
}


def random_sequence(seed: int) -> list[IdFrame]:
    """A seeded random sequence: 2-6 people who come and go, skeletons that follow them with
    occasional new ids and swaps, lost skeletons, false skeletons, all distances random and
    pairs beyond a random threshold NaN."""
    rng = np.random.default_rng(seed)
    n_people, n_frames = int(rng.integers(2, 7)), int(rng.integers(5, 61))
    limit = rng.uniform(8.0, 25.0)
    follow = {p: 100 + p for p in range(n_people)}  # the skeleton id on each person
    next_id = 200
    frames = []
    for _ in range(n_frames):
        if rng.random() < 0.1:  # the tracker swaps two people
            a, b = rng.choice(n_people, 2, replace=False)
            follow[a], follow[b] = follow[b], follow[a]
        for p in range(n_people):
            if rng.random() < 0.05:  # a new track on this person
                follow[p], next_id = next_id, next_id + 1
        present = [p for p in range(n_people) if rng.random() < 0.8]
        tracked = [p for p in present if rng.random() < 0.85]
        ghosts = [300 + int(g) for g in rng.choice(5, int(rng.integers(0, 3)), replace=False)]
        preds = [follow[p] for p in tracked] + ghosts
        d = rng.uniform(0.0, 30.0, (len(present), len(preds)))
        for i, p in enumerate(present):
            if p in tracked:
                d[i, tracked.index(p)] = rng.uniform(0.0, 8.0)
        d[d > limit] = np.nan
        order = rng.permutation(len(preds))
        frames.append(([10 + p for p in present], [preds[j] for j in order], d[:, order]))
    return frames


# motmetrics 1.4.0 gave these (numpy 2.4.6, scipy 1.17.1, pandas 3.1.1), in the order of KEYS.
MOTMETRICS_RANDOM = {
    0: (0.5212765957446808, 4.374291917854987, 0.37948717948717947, 0.36633663366336633,
        0.39361702127659576, 44, 15, 16, 30, 188, 6, 0),
    1: (0.40384615384615385, 5.5624950156492945, 0.5497630331753555, 0.5420560747663551,
        0.5576923076923077, 37, 9, 11, 14, 104, 4, 0),
    2: (0.5777777777777777, 4.354018715368016, 0.6666666666666666, 0.6274509803921569,
        0.7111111111111111, 20, 2, 3, 15, 90, 6, 0),
}


# motmetrics 1.4.0 gave these for seeds 2000-2003 pooled (`compute_many(...,
# generate_overall=True)`, its OVERALL row), in the order of KEYS.
MOTMETRICS_POOLED = (0.48268839103869654, 4.993900481565111, 0.4701348747591522,
                     0.4460694698354662, 0.4969450101832994, 122, 36, 38, 94, 491, 16, 0)


def run(frames: list[IdFrame]) -> dict[str, float]:
    acc = TrackingAccumulator()
    for truth_ids, pred_ids, d in frames:
        acc.update(truth_ids, pred_ids, d)
    return acc.summary()


def check(summary: dict[str, float], expected: tuple) -> None:
    for key, value in zip(KEYS, expected, strict=True):
        assert_allclose(summary[key], value, rtol=0, atol=1e-9, err_msg=key)


@pytest.mark.parametrize('name', list(HAND))
def test_hand_worked_sequences(name: str) -> None:
    frames, expected = HAND[name]
    check(run(frames), expected)


@pytest.mark.parametrize('seed', list(MOTMETRICS_RANDOM))
def test_random_sequences_as_motmetrics(seed: int) -> None:
    check(run(random_sequence(seed)), MOTMETRICS_RANDOM[seed])


def accumulate(frames: list[IdFrame]) -> list[FrameEvents]:
    acc = TrackingAccumulator()
    for f in frames:
        acc.update(*f)
    return acc.frames


def test_pooled_sequences_as_motmetrics() -> None:
    sequences = [accumulate(random_sequence(seed)) for seed in range(2000, 2004)]
    check(summarize_sequences(sequences), MOTMETRICS_POOLED)


def test_pooled_sequences_by_hand() -> None:
    # the two halves of `hidden(True)` as two sequences: skeleton 8 is a new track on person 1 of
    # another video, no switch; the counts add up, the ratios are of the sums
    first, second = accumulate(hidden(True)[:10]), accumulate(hidden(True)[30:])
    pooled = summarize_sequences([first, second, []])
    check(pooled, (1.0, 1.0, 1.0, 1.0, 1.0, 0, 0, 0, 0, 20, 2, 0))
    mixed = summarize_sequences([accumulate(id_switch()), accumulate(miss())])
    # GT 10 + 20, errors 1 + 12, distances 5 * 1 + 5 * 3 + 8 * 1 over 18 matches, IDTP 5 + 8
    assert_allclose([mixed['mota'], mixed['motp'], mixed['idf1']],
                    [1 - 13 / 30, 28 / 18, 2 * 13 / (30 + 18)])
    assert summarize_sequences([accumulate(perfect())]) == run(perfect())


def test_rates_per_1000() -> None:
    summary = run(miss() + false_positive())  # 30 person-frames, 12 misses; 20 frames, 3 false
    assert_allclose(summary['missed_per_1000'], 1e3 * 12 / 30)
    assert_allclose(summary['false_per_1000'], 1e3 * 3 / 20)
    assert_allclose(run(id_switch())['id_switches_per_1000'], 100.0)
    assert summary['frames'] == 20 and summary['gt_objects'] == 30


def test_no_frames_and_no_people_give_nan_ratios() -> None:
    for frames in ([], [([], [], np.zeros((0, 0)))] * 3):
        summary = run(frames)
        assert all(np.isnan(summary[k]) for k in ('mota', 'motp', 'idf1', 'idp', 'idr'))
        assert summary['gt_objects'] == summary['id_switches'] == summary['misses'] == 0
    ghosts = run([([], [4], np.zeros((0, 1)))] * 2)
    assert ghosts['false_positives'] == 2 and ghosts['false_per_1000'] == 1e3
    assert np.isnan(ghosts['mota'])


def test_a_frame_keeps_the_last_correspondences_while_they_are_valid() -> None:
    d = np.array([[4.0, 2.0], [2.0, 4.0]])
    assert assign(d) == [(0, 1), (1, 0)]  # without history: the nearer, swapped pairs
    assert assign_frame([1, 2], [7, 8], d, {1: 7, 2: 8}) == [(0, 0), (1, 1)]
    # a correspondence beyond the threshold is not kept; the rest are assigned anew
    assert assign_frame([1, 2], [7, 8], [[3.0, 1.0], [NAN, 4.0]], {1: 9, 2: 8}) == [
        (1, 1), (0, 0)]
    # a kept correspondence stands even where giving it up would match one more person
    assert assign_frame([1, 2], [7, 8], [[NAN, 2.0], [2.0, 4.0]], {1: 7, 2: 8}) == [(1, 1)]
    # skeleton 7 was last matched to both people: the first keeps it, once
    assert assign_frame([1, 2], [7], [[1.0], [1.0]], {1: 7, 2: 7}) == [(0, 0)]


def test_assignment_takes_as_many_pairs_as_it_can() -> None:
    # the cheapest single pair (0, 0) would leave row 1 unmatched: two dearer pairs win
    assert assign([[1.0, 5.0], [2.0, NAN]]) == [(0, 1), (1, 0)]
    assert assign(np.full((2, 3), NAN)) == [] and assign(np.zeros((0, 2))) == []


def test_idtp_counts_every_pair_within_reach_not_only_the_matches() -> None:
    # skeleton 7 is within reach of both people in frames 0-2 (matched to person 1), and
    # matched to person 2 in frames 3-6: (2, 7) is within reach in 7 frames, matched in 4
    near = [FrameEvents((1, 2), (7,), ((1, 7, 1.0),), ((1, 7), (2, 7)))] * 3
    later = [FrameEvents((1, 2), (7,), ((2, 7, 1.0),), ((2, 7),))] * 4
    assert summarize(near + later)['idtp'] == 7
    # without `within`, the matches are the agreements
    only = [FrameEvents(f.truth_ids, f.pred_ids, f.matches) for f in near + later]
    assert summarize(only)['idtp'] == 4


@pytest.mark.parametrize(('events', 'message'), [
    (((1, 1), (7,), ()), 'truth id'),
    (((1,), (7, 7), ()), 'skeleton id'),
    (((1,), (7,), ((1, 8, 1.0),)), 'not present'),
    (((1, 2), (7,), ((1, 7, 1.0), (2, 7, 1.0))), 'matched skeleton'),
])
def test_frame_events_refuse_impossible_frames(events: tuple, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FrameEvents(*events)


def test_accumulator_refuses_a_distance_matrix_of_the_wrong_size() -> None:
    with pytest.raises(ValueError, match='2 truths and 1 skeletons'):
        TrackingAccumulator().update([1, 2], [7], np.zeros((1, 1)))


# A standing person (pixels from the centre): 170 px high, 70 px wide, so the reference size is
# 170 px and a match needs the torsos within 85 px. The CAD-60 'torso' joint is 5 px below the
# mean of the shoulders and hips.
LAYOUT = {
    'head': (0, -80), 'neck': (0, -60), 'torso': (0, -20),
    'left_shoulder': (20, -60), 'right_shoulder': (-20, -60),
    'left_elbow': (30, -30), 'right_elbow': (-30, -30),
    'left_wrist': (35, 0), 'right_wrist': (-35, 0),
    'left_hip': (12, 10), 'right_hip': (-12, 10), 'left_knee': (14, 50), 'right_knee': (-14, 50),
    'left_ankle': (15, 90), 'right_ankle': (-15, 90),
}
LAYOUT |= {'left_hand': LAYOUT['left_wrist'], 'right_hand': LAYOUT['right_wrist'],
           'left_foot': LAYOUT['left_ankle'], 'right_foot': LAYOUT['right_ankle']}


def person(names: tuple[str, ...], centre: tuple[float, float], track_id: int, *,
           labelled: bool = True) -> JointSet:
    uv = np.array([LAYOUT[n] for n in names], np.float64) + centre
    conf = np.full(len(names), 1.0 if labelled else 0.0, np.float32)
    return JointSet(names, uv, confidence=conf, track_id=track_id)


def truth(centre: tuple[float, float], track_id: int, labelled: bool = True) -> JointSet:
    return person(CAD60_JOINTS, centre, track_id, labelled=labelled)


def skeleton(centre: tuple[float, float], track_id: int) -> JointSet:
    return person(SKELETON_14, centre, track_id)


def test_torso_point_prefers_the_torso_joint_then_the_shoulders_and_hips() -> None:
    assert_allclose(torso_point(truth((100, 200), 1), labelled=True), (100, 180))
    assert_allclose(torso_point(skeleton((100, 200), 1)), (100, 175))
    one_hip = skeleton((0, 0), 1)
    keep = np.isin(one_hip.names, ('left_hip', 'head'))
    one_hip = one_hip.with_(source=np.where(keep, cj.DETECTED, cj.MISSING))
    assert_allclose(torso_point(one_hip), LAYOUT['left_hip'])
    # an unlabelled truth joint is not located; with no torso joint at all there is no point
    assert np.isnan(torso_point(truth((0, 0), 1, labelled=False), labelled=True)).all()
    head = JointSet(('head',), [[5.0, 5.0]])
    assert np.isnan(torso_point(head)).all()


def test_match_people_within_half_the_person_size() -> None:
    truths = [truth((100, 200), 1), truth((400, 200), 2)]
    # torso distance to truth 1: |(84, -5)| < 85 -> allowed; |(86, -5)| > 85 -> not
    near, far = skeleton((184, 200), 5), skeleton((486, 200), 6)
    d = torso_distances(truths, [near, far])
    assert_allclose(d[0, 0], np.hypot(84, 5))
    assert np.isnan(d[1, 1]) and np.isnan(d[0, 1])
    assert match_people(truths, [far, near]) == [(0, 1)]
    assert match_people(truths, [far, near], max_distance=1.0) == [(0, 1), (1, 0)]
    # swapped order of the skeletons: still each to the nearer person
    a, b = skeleton((402, 200), 8), skeleton((98, 200), 9)
    assert match_people(truths, [a, b]) == [(0, 1), (1, 0)]
    assert match_people(truths, []) == [] and match_people([], [a]) == []
    assert match_people([truth((100, 200), 1, labelled=False)], [b]) == []


def score_people_fixture() -> tuple[list[tuple[JointSet, ...]], list[tuple[JointSet, ...]]]:
    """Person 1 at (100, 200), person 2 at (300, 200), four frames; skeletons 5 and 6 follow them
    3 px to the right. IdFrame 1: person 2 unlabelled (hidden, between frames in which they are
    labelled: a person to track, with no joint to score), no skeleton 6. IdFrame 2:
    skeleton 6 reports no joint (no output: not a skeleton), person 2 missed. IdFrame 3: a
    skeleton 9 far from both (false positive)."""
    a, b = (100.0, 200.0), (300.0, 200.0)
    a_, b_ = (103.0, 200.0), (303.0, 200.0)
    truths = [(truth(a, 1), truth(b, 2)), (truth(a, 1), truth(b, 2, labelled=False)),
              (truth(a, 1), truth(b, 2)), (truth(a, 1), truth(b, 2))]
    preds = [(skeleton(a_, 5), skeleton(b_, 6)), (skeleton(a_, 5),),
             (skeleton(a_, 5), JointSet.missing(SKELETON_14).with_(track_id=6)),
             (skeleton(a_, 5), skeleton(b_, 6), skeleton((600.0, 200.0), 9))]
    return truths, preds


def test_score_people_by_hand() -> None:
    truths, preds = score_people_fixture()
    out = score_people(truths, preds, SKELETON_14)
    tracking = out['tracking']
    # 8 person-frames (person 2 hidden in frame 1 counts), 6 matches, 2 misses (person 2,
    # frames 1 and 2), 1 false (skeleton 9); person 2 is matched, missed twice, matched: one
    # fragmentation; torsos (3, -5) apart: MOTP sqrt(34)
    assert (tracking['gt_objects'], tracking['matches'], tracking['misses'],
            tracking['false_positives'], tracking['id_switches'],
            tracking['fragmentations']) == (8, 6, 2, 1, 0, 1)
    assert_allclose(tracking['mota'], 1 - 3 / 8)
    assert_allclose(tracking['motp'], np.sqrt(34.0))
    assert_allclose(tracking['idf1'], 2 * 6 / (8 + 7))
    found, labels = out['matched']
    assert [t.track_id for t in labels] == [1, 2, 1, 1, 2, 1, 2]
    assert [p.track_id if p is not None else None for p in found] == [5, 6, 5, 5, None, 5, 6]
    assert out['frames'] == [0, 0, 1, 2, 2, 3, 3]
    # 3 px off against a 17 px PCK threshold: every joint right but those of the missed person
    assert out['table'] == score_joint_sets(found, labels, SKELETON_14)
    assert_allclose(out['table']['pck']['average'], 100.0 * 6 / 7)
    assert_allclose(out['table']['pck']['average7'], 100.0 * 6 / 7)


def test_score_people_refuses_two_people_with_one_id() -> None:
    truths, preds = score_people_fixture()
    truths[2] = (truth((100.0, 200.0), 1), truth((300.0, 200.0), 1))
    with pytest.raises(ValueError, match=r'frame 2: truth id\(s\) repeated in one frame: \[1\]'):
        score_people(truths, preds, SKELETON_14)
    with pytest.raises(ValueError, match='3 frames of skeletons for 4'):
        score_people(truths, preds[:3], SKELETON_14)


def test_score_people_scores_no_ground_truth_outside_the_image() -> None:
    truths, preds = score_people_fixture()
    # 200 px wide: person 2 (u 285..315), missed in frame 2, is outside and not scored
    out = score_people(truths, preds, SKELETON_14, image_sizes=[(200, 480)] * 4)
    assert_allclose(out['table']['pck']['average7'], 100.0)
    assert out['tracking']['misses'] == 1  # the tracking metrics do not look at the image


def test_score_people_starts_a_sequence_at_each_video() -> None:
    truths, preds = score_people_fixture()
    one_video = score_people(truths, preds, SKELETON_14)['tracking']
    two = score_people(truths, preds, SKELETON_14, videos=['a', 'a', 'b', 'b'])['tracking']
    # person 2 is missed at the start of video b: no longer a fragmentation; each person is a
    # trajectory in each video: mostly tracked person 1 (a), 2 (a), 1 (b); partially 2 (b, 1/2)
    assert (one_video['fragmentations'], two['fragmentations']) == (1, 0)
    assert (one_video['mostly_tracked'], one_video['partially_tracked']) == (1, 1)
    assert (two['mostly_tracked'], two['partially_tracked']) == (3, 1)
    # person 2, unlabelled in frame 1, is hidden between labelled frames of one video only:
    # split there, they were last seen in frame 0 (not there in frame 1, not missed)
    assert (one_video['misses'], two['misses']) == (2, 1)
    assert_allclose(two['mota'], 1 - 2 / 7)
    for key in ('motp', 'id_switches', 'false_positives', 'matches'):
        assert_allclose(two[key], one_video[key], rtol=1e-12, err_msg=key)
    with pytest.raises(ValueError, match='3 videos for 4 frames'):
        score_people(truths, preds, SKELETON_14, videos=['a'] * 3)


def test_a_person_hidden_between_labelled_frames_is_a_person_to_track() -> None:
    """MOTChallenge counts people through occlusions: person 2, hidden (no labelled joint, the
    pixels of their ground-truth position kept) in frames 1-2 between labelled frames 0 and 3,
    is matched by the skeleton held for them; hidden again after their last labelled frame
    (frames 4-5), they are not there and the skeleton kept is a false positive. The joint
    table scores only the labelled person-frames."""
    a, b = (100.0, 200.0), (300.0, 200.0)
    labelled = [True, False, False, True, False, False]
    truths = [(truth(a, 1), truth(b, 2, labelled=lab)) for lab in labelled]
    hidden = truths[1][1].with_(source=np.full(len(CAD60_JOINTS), cj.MISSING, np.uint8))
    truths[1] = (truths[1][0], hidden)  # as `pose4d synth` writes a hidden person
    preds = [(skeleton(a, 5), skeleton((306.0, 200.0), 6)) for _ in labelled]
    assert occlusion_gaps(truths) == [set(), {2}, {2}, set(), set(), set()]
    out = score_people(truths, preds, SKELETON_14)
    tracking = out['tracking']
    assert (tracking['gt_objects'], tracking['matches'], tracking['misses'],
            tracking['false_positives']) == (10, 10, 0, 2)
    assert [t.track_id for t in out['matched'][1]] == [1, 2, 1, 1, 1, 2, 1, 1]
    # a hidden person outside the image is not there
    outside = score_people(truths, preds, SKELETON_14, image_sizes=[(200, 480)] * 6)
    assert outside['tracking']['gt_objects'] == 8
    # with no skeleton kept for them, the hidden frames are misses
    dropped = [p if k not in (1, 2) else p[:1] for k, p in enumerate(preds)]
    tracking = score_people(truths, dropped, SKELETON_14)['tracking']
    assert (tracking['matches'], tracking['misses'], tracking['false_positives']) == (8, 2, 2)


def test_seen_share_counts_the_joints_the_depth_image_shows() -> None:
    """A person 3 m away, the depth image 3.05 m everywhere but a nearer person (2 m) over the
    columns of their left side: the joints there are not seen."""
    t = truth((100.0, 200.0), 1)
    t = t.with_(xyz=np.column_stack([np.zeros((len(t.names), 2)), np.full(len(t.names), 3.0)]))
    depth = np.full((480, 640), 3.05, np.float32)
    assert seen_share(t, depth) == 1.0
    depth[:, 111:] = 2.0  # left shoulder (120), elbow (130), wrist and hand (135), hip (112),
    left = [n for n in t.names if LAYOUT[n][0] + 100 >= 111]  # knee, ankle and foot
    assert seen_share(t, depth) == pytest.approx(1 - len(left) / len(t.names))
    depth[:] = np.nan  # no reading is not seen
    assert seen_share(t, depth) == 0.0
    assert np.isnan(seen_share(t, None))
    assert np.isnan(seen_share(t.with_(xyz=np.full((len(t.names), 3), np.nan)), depth))
    # joints outside the image are not counted
    assert np.isnan(seen_share(t, depth[:50, :50]))


def test_seen_table_splits_the_person_frames_by_their_share_seen() -> None:
    truths, preds = score_people_fixture()
    out = score_people(truths, preds, SKELETON_14)
    found, labels = out['matched']
    # 7 person-frames: the missed one (index 4) half seen, the others whole
    shares = [1.0, 1.0, 1.0, 1.0, 0.4, 0.9, 0.6]
    table = seen_table(found, labels, shares, SKELETON_14)
    assert_allclose([table['share_80'], table['share_50_80'], table['share_under_50']],
                    [5 / 7, 1 / 7, 1 / 7])
    assert_allclose([table['average7_80'], table['average7_50_80'], table['average7_under_50']],
                    [100.0, 100.0, 0.0])
    table = seen_table(found, labels, [1.0] * 7, SKELETON_14)
    assert table['share_under_50'] == 0.0 and np.isnan(table['average7_under_50'])
