"""Several people (`core.people`, `core.foreground.segment_people`, `FramePipeline(people=)`):
association on synthetic detections, and the whole core on rendered two-person frames."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from fuzz import valid_frame
from helpers import BODY, INTR, standing_pose

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import project
from pose4d_ros.core.foreground import segment_people
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people import PeopleTracker, TrackingConfig, assign, torso
from pose4d_ros.core.people.tracker import LEGS_M, axis_position
from pose4d_ros.core.skeleton import PARTS_10
from pose4d_ros.core.stages import TrackerStage

DT = 1 / 30


def person(x: float, z: float = 2.5) -> JointSet:
    """The 10 detected parts of `BODY` moved to lateral offset x and depth z, metres."""
    xyz = np.array([BODY[n] for n in PARTS_10.names]) + [x, 0.0, z - 2.5]
    return JointSet(PARTS_10.names, project(xyz, INTR), xyz,
                    source=np.full(10, cj.DETECTED, np.uint8), confidence=np.full(10, 0.9))


def tracker(**kw) -> PeopleTracker:
    return PeopleTracker(TrackerStage(), TrackingConfig(**kw))


def ids_by_x(out: list[JointSet]) -> dict[int, float]:
    return {t.track_id: round(float(torso(t)[0][0]), 2) for t in out}


def test_assign_is_one_to_one_and_gated():
    cost = np.array([[1.0, 9.0], [2.0, 30.0], [np.nan, 3.0]])
    assert sorted(assign(cost, 10.0)) == [(0, 0), (2, 1)]  # the least total cost
    assert assign(cost, 2.5) == [(0, 0)]  # (2, 1) costs more than the gate
    assert assign(np.array([[np.nan]]), 10.0) == []
    assert assign(np.array([[1e6]]), 10.0) == [(0, 0)]  # one and one: the SLQE judges
    assert assign(np.zeros((0, 3)), 1.0) == []


def test_a_pair_beyond_the_gate_takes_no_pair_within_it_away():
    # three tracks, three detections (a frame of a three-person validation video): the
    # second track unseen (its person hidden), the third detection a wall's edge. Summed
    # with the pairs beyond the gate, the least total would give the third track's own
    # detection (cost 0) to the second track (95.9) and the wall (50.8) to the third: both
    # beyond the gate, so the third track lost its person to a new track
    cost = np.array([[0.0, 132.9, 309.5], [83.2, 95.9, 175.8], [135.1, 0.0, 50.8]])
    assert sorted(assign(cost, 16.0)) == [(0, 0), (2, 1)]
    # as many pairs within the gate as can be, then the least total among them
    assert sorted(assign(np.array([[1.0, 2.0], [3.0, 40.0]]), 16.0)) == [(0, 1), (1, 0)]


def test_two_people_crossing_keep_their_ids():
    """Two people walk past each other at different depths (1 m apart in depth): the ids
    follow the people, not their order in the image."""
    tr = tracker()
    seen = []
    for k in range(60):
        a = person(-0.8 + 0.03 * k, z=2.2)
        b = person(0.8 - 0.03 * k, z=3.2)
        out = tr.step([b, a] if k % 2 else [a, b], k * DT, INTR)
        seen.append({t.track_id: torso(t)[0][2] for t in out})
    assert set(seen[-1]) == {1, 2}
    # the id of the near person (z 2.2) is the same all along
    near = [min(s, key=s.get) for s in seen[1:]]
    assert len(set(near)) == 1, near


def test_a_person_hidden_20_frames_comes_back_with_their_id_and_a_third_is_confirmed():
    tr = tracker(confirm_frames=3)
    for k in range(10):
        out = tr.step([person(-0.6), person(0.6)], k * DT, INTR)
    assert sorted(ids_by_x(out)) == [1, 2]
    right = next(i for i, x in ids_by_x(out).items() if x > 0)
    for k in range(10, 30):  # the right person hidden 20 frames (0.67 s)
        out = tr.step([person(-0.6)], k * DT, INTR)
        assert right in {t.track_id for t in out}  # still tracked (predicted)
    assert tr.ended == []
    out = tr.step([person(-0.6), person(0.62)], 30 * DT, INTR)
    assert ids_by_x(out) == {1 if right == 2 else 2: -0.6, right: pytest.approx(0.62, abs=0.03)}
    # a third person: tentative for 2 frames, confirmed (id 3) at the third
    for k in range(31, 34):
        out = tr.step([person(-0.6), person(0.6), person(1.6, z=3.5)], k * DT, INTR)
        assert (3 in {t.track_id for t in out}) == (k == 33)
    # the first person leaves for good: their track ends after 1 s, and the id is not reused
    for k in range(34, 70):
        out = tr.step([person(0.6), person(1.6, z=3.5)], k * DT, INTR)
    assert {t.track_id for t in out} == {right, 3}
    for k in range(70, 75):
        out = tr.step([person(0.6), person(1.6, z=3.5), person(-0.6)], k * DT, INTR)
    assert max(t.track_id for t in out) == 4


def test_primary_person_is_the_longest_tracked_one_in_view():
    tr = tracker()
    for k in range(5):
        out = tr.step([person(0.5)], k * DT, INTR)
    for k in range(5, 12):
        out = tr.step([person(-0.5, z=2.0), person(0.5)], k * DT, INTR)
    assert [t.track_id for t in out] == [1, 2]  # the first one, although the other is nearer
    assert ids_by_x(out)[1] == pytest.approx(0.5, abs=0.02)
    out = tr.step([person(-0.5, z=2.0)], 12 * DT, INTR)  # the first one unseen this frame
    assert out[0].track_id == 2


def test_nobody_and_bad_configs():
    tr = tracker()
    assert tr.step([], 0.0, INTR) == []
    assert tr.step([JointSet.missing(PARTS_10.names)], DT, INTR) == []
    with pytest.raises(ValueError, match='max_people'):
        TrackingConfig(max_people=0)
    with pytest.raises(ValueError, match='max_unseen_s'):
        TrackingConfig(max_unseen_s=0)
    with pytest.raises(ValueError, match='occluded_width_m'):
        TrackingConfig(occluded_width_m=-0.1)
    with pytest.raises(ValueError, match='trust_score'):
        TrackingConfig(trust_score=float('nan'))
    with pytest.raises(ValueError, match='max_shoulders_m'):
        TrackingConfig(max_shoulders_m=-0.5)
    with pytest.raises(ValueError, match='facing_away_m'):
        TrackingConfig(facing_away_m=-0.1)
    for spans in ({'min_span_m': -0.1}, {'min_span_m': 3.0}, {'max_span_m': 0.0}):
        with pytest.raises(ValueError, match='min_span_m < max_span_m'):
            TrackingConfig(**spans)


# --------------------------------------------------------------- rendered frames
def _two_people(offset: float = 0.55, z: tuple[float, float] = (2.6, 3.3)):
    """Two rendered people side by side (the nearer one in front where they overlap), with
    their ground-truth joints' pixels."""
    from pose4d_ros.synth import render

    rng = np.random.default_rng(3)
    frames, truths = [], []
    for k, (dx, dz) in enumerate(((-offset, z[0]), (offset, z[1]))):
        pose = standing_pose(z=dz, cam_height=1.0, arm=0.4)
        pose[:, 0] += dx
        body = render.random_body(np.random.default_rng(k))
        out = render.render(pose, body, None, INTR, rng=rng, kinect_noise=False)
        frames.append(out)
        truths.append(project(out.joints, INTR))
    d0, d1 = (f.depth_mm.astype(np.int64) for f in frames)
    first = (d0 > 0) & ((d1 == 0) | (d0 <= d1))
    depth = np.where(first, d0, d1).astype(np.uint16)
    rgb = np.where(first[..., None], frames[0].rgb, frames[1].rgb)
    return rgb, depth, truths


def test_segment_people_finds_both_people():
    _, depth, truths = _two_people()
    people, found = segment_people(depth, INTR)
    assert found == 2 and len(people) == 2
    centres = sorted((p.box[0] + p.box[2]) / 2 for p in people)
    truth_x = sorted(float(np.nanmean(t[:, 0])) for t in truths)
    assert np.allclose(centres, truth_x, atol=25), (centres, truth_x)
    assert not (people[0].mask & people[1].mask).any()
    one, found = segment_people(depth, INTR, max_people=1)
    assert len(one) == 1 and found == 2


def test_pipeline_tracks_two_rendered_people():
    from pose4d_ros.core.dpm.model import load_model
    from pose4d_ros.core.pipeline import FramePipeline
    from pose4d_ros.core.stages import DetectorStage
    from pose4d_ros.models import model_path

    rgb, depth, truths = _two_people()
    pipeline = FramePipeline(DetectorStage(load_model(model_path('rgbd_14'))),
                             people=TrackingConfig())
    for k in range(6):
        out = pipeline.step(rgb, depth.astype(np.float32) / 1000, INTR, k * DT)
    assert [s.track_id for s in out.people] == [1, 2] and out.candidates == 2
    # each skeleton's head on its own person's head
    heads = sorted(float(s.uv[s.get('head'), 0]) for s in out.people)
    truth_heads = sorted(float(t[3, 0]) for t in truths)  # UTKinect joint 3: head
    assert np.allclose(heads, truth_heads, atol=12), (heads, truth_heads)
    assert out.skeleton.track_id == 1


def test_one_person_the_several_person_path_gives_the_single_persons_skeleton():
    from pose4d_ros.core.dpm.model import load_model
    from pose4d_ros.core.pipeline import FramePipeline
    from pose4d_ros.core.stages import DetectorStage
    from pose4d_ros.models import model_path

    model = load_model(model_path('rgbd_14'))
    single = FramePipeline(DetectorStage(model))
    several = FramePipeline(DetectorStage(model), people=TrackingConfig())
    # a rendered person (the start-up warm-up's slab figure scores under the birth score)
    color, depth, _ = valid_frame()
    for k in range(4):
        a = single.step(color, depth, INTR, k * DT).skeleton
        b = several.step(color, depth, INTR, k * DT)
        assert len(b.people) == 1
        np.testing.assert_array_equal(a.uv, b.skeleton.uv)
        np.testing.assert_array_equal(a.source, b.skeleton.source)


def test_work_is_bounded_by_max_people():
    """Ten person regions: the detector searches max_people of them, in their order."""
    from pose4d_ros.core.foreground import ForegroundResult
    from pose4d_ros.core.people import PeopleDetector

    searched = []

    class Counting:
        def spawn(self):
            return type(self)()

        def step(self, color, depth, intrinsics, *, mask, stamp_s, blanked, occluder=None,
                     photo=None):
            searched.append(int(np.flatnonzero(mask.any(axis=0))[0]))
            return JointSet.missing(PARTS_10.names)

    color = np.zeros((INTR.height, INTR.width, 3), np.uint8)
    depth = np.full((INTR.height, INTR.width), 3.0, np.float32)
    people = []
    for k in range(10):
        mask = np.zeros(depth.shape, bool)
        mask[50:200, 30 * k:30 * k + 20] = True
        people.append(ForegroundResult(mask=mask, box=(30 * k, 50, 30 * k + 20, 200),
                                       depth_m=3.0, found=True))
    detector = PeopleDetector(Counting(), TrackingConfig(max_people=4))
    out = detector.step(color, depth, INTR, people, stamp_s=0.0)
    assert len(out) == 4 and searched == [0, 30, 60, 90]
    assert len(detector.slots) == 4


def test_a_person_is_searched_with_the_nearer_people_in_front_of_them():
    """The candidates nearer by over `torso_std_m` are passed as the occluder of a person's
    search (`core.dpm.infer.OcclusionFloor`); a person with nobody in front gets none."""
    from pose4d_ros.core.foreground import ForegroundResult
    from pose4d_ros.core.people import PeopleDetector

    given = {}

    class Recording:
        def spawn(self):
            return type(self)()

        def step(self, color, depth, intrinsics, *, mask, stamp_s, blanked, occluder=None,
                     photo=None):
            given[int(np.flatnonzero(mask.any(axis=0))[0])] = occluder
            return JointSet.missing(PARTS_10.names)

    color = np.zeros((INTR.height, INTR.width, 3), np.uint8)
    depth = np.full((INTR.height, INTR.width), 3.0, np.float32)
    people = []
    for x, z in ((0, 4.0), (60, 2.0), (120, 3.9), (180, 3.0)):
        mask = np.zeros(depth.shape, bool)
        mask[50:200, x:x + 40] = True
        people.append(ForegroundResult(mask=mask, box=(x, 50, x + 40, 200), depth_m=z,
                                       found=True))
    PeopleDetector(Recording(), TrackingConfig(torso_std_m=0.15)).step(
        color, depth, INTR, people, stamp_s=0.0)
    assert given[60] is None                                     # the nearest
    assert (given[180] == people[1].mask).all()                  # 2 m in front of 3 m
    # 4 m: those at 2 and 3 m, not the one at 3.9 m (within torso_std_m)
    assert (given[0] == (people[1].mask | people[3].mask)).all()
    assert (given[120] == (people[1].mask | people[3].mask)).all()


def test_a_persons_detector_state_lives_as_long_as_their_track():
    """A person gone from the foreground (hidden behind a nearer one) comes back to their own
    detector state (person scale, arm prior) within `max_hidden_s`, as their track does; gone
    longer, they get a new one."""
    from pose4d_ros.core.foreground import ForegroundResult
    from pose4d_ros.core.people import PeopleDetector

    made = []

    class Stage:
        def spawn(self):
            made.append(Stage())
            return made[-1]

        def step(self, color, depth, intrinsics, *, mask, stamp_s, blanked, occluder=None,
                     photo=None):
            return JointSet.missing(PARTS_10.names).with_(score=12.0)

    color = np.zeros((INTR.height, INTR.width, 3), np.uint8)
    depth = np.full((INTR.height, INTR.width), 3.0, np.float32)
    mask = np.zeros(depth.shape, bool)
    mask[50:200, 100:140] = True
    person = ForegroundResult(mask=mask, box=(100, 50, 140, 200), depth_m=3.0, found=True)
    cfg = TrackingConfig(max_unseen_s=1.0, max_hidden_s=2.0)
    detector = PeopleDetector(Stage(), cfg)
    detector.step(color, depth, INTR, [person], stamp_s=0.0)
    detector.step(color, depth, INTR, [], stamp_s=1.5)
    detector.step(color, depth, INTR, [person], stamp_s=1.5 + DT)
    assert len(made) == 1
    detector.step(color, depth, INTR, [], stamp_s=4.0)
    detector.step(color, depth, INTR, [person], stamp_s=4.0 + DT)
    assert len(made) == 2
    # the detector node's own lifetime (`detector.keep_unseen_s`) for a tracker set otherwise
    detector = PeopleDetector(Stage(), replace(cfg, detector_keep_s=5.0))
    detector.step(color, depth, INTR, [person], stamp_s=0.0)
    detector.step(color, depth, INTR, [], stamp_s=4.5)
    detector.step(color, depth, INTR, [person], stamp_s=4.5 + DT)
    assert len(made) == 3
    with pytest.raises(ValueError, match='detector_keep_s'):
        TrackingConfig(detector_keep_s=-1.0)


def test_a_still_region_that_scored_low_keeps_its_detection_a_few_frames():
    """`quiet_frames`: a region scoring under the birth score that has not moved is searched
    every (quiet_frames + 1)-th frame; a person (scoring over it), or a region that moves (a
    tenth of its pixels, or STILL_M in depth), every frame. A region whose top is cut at
    another height (a wall's edge at the image's border), its pixels otherwise the same, has
    not moved."""
    from pose4d_ros.core.foreground import ForegroundResult
    from pose4d_ros.core.people import STILL_IOU, STILL_M, PeopleDetector

    searched = []

    class Scoring:
        def spawn(self):
            return type(self)()

        def step(self, color, depth, intrinsics, *, mask, stamp_s, blanked, occluder=None,
                     photo=None):
            x = int(np.flatnonzero(mask.any(axis=0))[0])
            searched.append((round(stamp_s / DT), x))
            # the region at x < 100 is a wall's edge (score 1), the one at x 100 a person (12)
            return JointSet.missing(PARTS_10.names).with_(score=1.0 if x < 100 else 12.0)

    color = np.zeros((INTR.height, INTR.width, 3), np.uint8)
    depth = np.full((INTR.height, INTR.width), 3.0, np.float32)

    def region(x: int, depth_m: float = 3.0, top: int = 50) -> ForegroundResult:
        mask = np.zeros(depth.shape, bool)
        mask[top:200, x:x + 40] = True
        return ForegroundResult(mask=mask, box=(x, top, x + 40, 200), depth_m=depth_m,
                                found=True)

    detector = PeopleDetector(Scoring(), TrackingConfig(quiet_frames=3))
    for k in range(10):
        # the edge's top flickers by 6 rows of its 150 (96 % of its pixels the same)
        edge = region(0, top=50 + 6 * (k % 2))
        out = detector.step(color, depth, INTR, [edge, region(100)], stamp_s=k * DT)
        assert [d.score for d in out] == [1.0, 12.0]
    assert [k for k, x in searched if x == 100] == list(range(10))
    assert [k for k, x in searched if x == 0] == [0, 4, 8]
    # moved sideways by 3 of its 40 columns, farther by more than STILL_M, or a fifth of
    # its pixels changed within the same box (an arm of a person partly hidden): searched
    searched.clear()
    detector.step(color, depth, INTR, [region(3)], stamp_s=10 * DT)
    assert 1 - STILL_IOU < 1 - 37 / 43
    detector.step(color, depth, INTR, [region(3, 3.0 + 2 * STILL_M)], stamp_s=11 * DT)
    moved = region(3, 3.0 + 2 * STILL_M)
    moved.mask[60:90, 3:43] = False
    assert 1 - STILL_IOU < 1 - moved.mask.sum() / region(0).mask.sum() < 0.25
    detector.step(color, depth, INTR, [moved], stamp_s=12 * DT)
    assert [x for _, x in searched] == [3] * 3
    # quiet_frames 0: every region every frame
    searched.clear()
    detector = PeopleDetector(Scoring(), TrackingConfig(quiet_frames=0))
    for k in range(3):
        detector.step(color, depth, INTR, [region(0)], stamp_s=k * DT)
    assert len(searched) == 3
    with pytest.raises(ValueError, match='quiet_frames'):
        TrackingConfig(quiet_frames=-1)


def test_without_camera_info_people_are_told_apart_in_the_image():
    """No intrinsics (no camera_info yet): no 3-D out of the tracker, the association works
    on the torso's pixel; two people keep their two tracks."""
    tr = tracker()
    for k in range(30):
        out = tr.step([person(-0.6 + 0.005 * k), person(0.6)], k * DT, None)
    assert sorted(t.track_id for t in out) == [1, 2] and len(tr.tracks) == 2


def _scored(joints: JointSet, score: float) -> JointSet:
    return JointSet(joints.names, joints.uv, joints.xyz, source=joints.source,
                    confidence=joints.confidence, score=score)


def test_a_person_hidden_behind_a_nearer_one_keeps_their_last_pose():
    """The far person walks behind the near one and is not detected for 15 frames: their
    track keeps their last pose (TRACKED), where a constant-velocity prediction would drift
    on, and takes their detection again with their id."""
    tr = tracker()
    for k in range(10):
        out = tr.step([person(0.0, z=2.2), person(-0.2 + 0.03 * k, z=3.4)], k * DT, INTR)
    far = max(out, key=lambda t: torso(t)[0][2])
    last = torso(far)[0]
    for k in range(10, 25):
        out = tr.step([person(0.0, z=2.2)], k * DT, INTR)
        held = next(t for t in out if t.track_id == far.track_id)
        assert np.allclose(torso(held)[0], last, atol=1e-9)
        assert set(held.source[held.source != cj.MISSING].tolist()) == {cj.TRACKED}
    out = tr.step([person(0.0, z=2.2), person(0.8, z=3.4)], 25 * DT, INTR)  # out in the open
    back = next(t for t in out if t.track_id == far.track_id)
    assert torso(back)[0][0] == pytest.approx(0.8, abs=0.03)


def test_a_person_hidden_behind_another_longer_than_max_unseen_s_keeps_their_id():
    """Behind the near person for 1.5 s (45 frames): longer than `max_unseen_s` (1 s), which
    ends a track unseen in the open, within `max_hidden_s` (2 s): they come back with their
    id, and no new one is born."""
    def far_walks_behind(tr: PeopleTracker) -> int:
        """Ten frames of two people, the far one walking towards the near one: its id."""
        for k in range(10):
            out = tr.step([person(0.0, z=2.2), person(-0.2 + 0.03 * k, z=3.4)], k * DT, INTR)
        return max(out, key=lambda t: torso(t)[0][2]).track_id

    tr = tracker()
    far = far_walks_behind(tr)
    for k in range(10, 55):
        assert far in [t.track_id for t in tr.step([person(0.0, z=2.2)], k * DT, INTR)]
    out = tr.step([person(0.0, z=2.2), person(0.8, z=3.4)], 55 * DT, INTR)
    assert sorted(t.track_id for t in out) == sorted([far, 3 - far])
    assert tr.born == [] and tr.ended == []
    # and past `max_hidden_s` the track ends
    tr2 = tracker(max_hidden_s=1.0)
    assert far_walks_behind(tr2) == far
    ended = []
    for k in range(10, 55):
        tr2.step([person(0.0, z=2.2)], k * DT, INTR)
        ended += tr2.ended
    assert ended == [far]


@pytest.mark.parametrize('needs_front', [True, False])
def test_a_held_track_with_nobody_in_front_any_more_is_only_unseen(needs_front):
    """The far person is held behind the near one, who then walks away (seen, far to the
    side) while the far one stays unseen: with `held_needs_front` the far track is held no
    more and ends as an unseen track does (it was last seen over `max_unseen_s` before);
    without, it stays held (published at its last pose) until `max_hidden_s`."""
    tr = tracker(held_needs_front=needs_front)
    for k in range(10):
        out = tr.step([person(0.0, z=2.2), person(-0.2 + 0.03 * k, z=3.4)], k * DT, INTR)
    far = max(out, key=lambda t: torso(t)[0][2]).track_id
    for k in range(10, 45):  # 1.2 s behind the near person: held
        assert far in [t.track_id for t in tr.step([person(0.0, z=2.2)], k * DT, INTR)]
    ended, published = [], []
    for k in range(45, 55):  # the near person walks off to the side, the far one unseen
        out = tr.step([person(0.12 * (k - 44), z=2.2)], k * DT, INTR)
        ended += tr.ended
        published.append(far in [t.track_id for t in out])
    if needs_front:
        assert far in ended and not any(published[-5:])
    else:
        assert ended == [] and all(published)


@pytest.mark.parametrize('offset, one_body_m, piece_published', [
    ((0.05, 0.2, 0.4), 0.6, False),   # a piece 0.45 m from the torso, 0.40 m off the axis
    ((0.05, 0.8, 0.4), 0.6, False),   # the legs: 0.9 m from the torso, 0.40 m off the axis
    ((0.05, 1.2, 0.4), 0.6, False),   # the feet, below the skeleton's own box
    ((0.05, 0.8, 0.4), 0.0, True),    # the rule off
    ((0.05, 0.8, 0.75), 0.6, True),   # 0.75 m off the axis: another person
    ((0.05, -0.2, 0.4), 0.6, True),   # above the torso in the image: another person
    ((0.05, 0.2, -0.4), 0.6, True),   # nearer the camera: another person
    ((0.05, LEGS_M + 0.6, 0.4), 0.6, True),  # lower than any legs reach
])
def test_a_second_skeleton_on_a_persons_body_is_not_published(offset, one_body_m,
                                                              piece_published):
    """A person and a second track whose torso lies at `offset` (x, y down, z deeper; metres)
    from theirs. Seen from above, a person's legs are found as a person of their own: below
    the torso in the image, deeper, on the body's (vertical) axis however far below, down to
    the feet. Such a track is kept, not published (`one_body_m`); one off the axis, above the
    torso, nearer the camera or farther below the hips than legs reach is another person's.
    Another person 1 m away is published either way."""
    tr = tracker(one_body_m=one_body_m)
    z = 4.5  # far enough for the piece to be in the image however low
    piece = person(0.0, z)
    xyz = piece.xyz + offset
    piece = JointSet(piece.names, project(xyz, INTR), xyz, source=piece.source,
                     confidence=piece.confidence)
    for k in range(10):
        out = tr.step([_scored(person(0.0, z), 9.0), _scored(piece, 8.0),
                       _scored(person(1.0, z), 8.0)], k * DT, INTR)
    assert len(tr.tracks) == 3 and all(t.id for t in tr.tracks)
    xs = sorted(round(float(torso(t)[0][0]), 2) for t in out)
    assert xs == ([0.0, 0.05, 1.0] if piece_published else [0.0, 1.0])


def test_axis_position_is_off_the_line_through_hips_and_shoulders_and_below_the_hips():
    body = person(0.0)
    hips = body.xyz[[body.names.index('left_hip'), body.names.index('right_hip')]].mean(axis=0)
    top = body.xyz[[body.names.index(n) for n in ('left_shoulder', 'right_shoulder', 'neck')]]
    up = (top.mean(axis=0) - hips) / np.linalg.norm(top.mean(axis=0) - hips)
    side = np.cross(up, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    assert axis_position(hips - 1.5 * up + 0.5 * side, body) == pytest.approx((0.5, 1.5))
    assert axis_position(hips + 0.2 * up, body) == pytest.approx((0.0, -0.2), abs=1e-9)
    # without hips: the distance to the torso point
    source = body.source.copy()
    source[[body.names.index('left_hip'), body.names.index('right_hip')]] = cj.MISSING
    no_hips = JointSet(body.names, body.uv, body.xyz, source=source,
                       confidence=body.confidence)
    point = torso(no_hips)[0] + [0.0, 2.0, 0.0]
    assert axis_position(point, no_hips) == pytest.approx((2.0, 0.0))


def test_a_pose_held_longer_than_max_held_s_is_kept_but_not_published():
    """Hidden 25 frames: the far person's last pose is published for `max_held_s` (0.31 s
    here: the first 10 held frames), then not, and they come back with their id."""
    tr = tracker(max_held_s=0.31)
    for k in range(10):
        out = tr.step([person(0.0, z=2.2), person(-0.2 + 0.03 * k, z=3.4)], k * DT, INTR)
    far = max(out, key=lambda t: torso(t)[0][2]).track_id
    published = [any(t.track_id == far for t in tr.step([person(0.0, z=2.2)], k * DT, INTR))
                 for k in range(10, 35)]
    assert published == [True] * 10 + [False] * 15
    out = tr.step([person(0.0, z=2.2), person(0.1, z=3.4)], 35 * DT, INTR)
    assert far in [t.track_id for t in out]


def test_an_unseen_track_beside_another_is_taken_back_only_by_a_persons_detection():
    """Two people; the right one unseen for 5 frames (not behind anyone). A detection there
    scoring under `birth_score` (a part of the room) is not theirs; one scoring above is."""
    tr = tracker()
    for k in range(6):
        out = tr.step([_scored(person(-0.6), 8.0), _scored(person(0.8), 8.0)], k * DT, INTR)
    right = next(i for i, x in ids_by_x(out).items() if x > 0)
    for k in range(6, 11):
        tr.step([_scored(person(-0.6), 8.0)], k * DT, INTR)
    out = tr.step([_scored(person(-0.6), 8.0), _scored(person(0.85), 0.2)], 11 * DT, INTR)
    track = next(t for t in out if t.track_id == right)
    assert not (track.source == cj.DETECTED).any()
    out = tr.step([_scored(person(-0.6), 8.0), _scored(person(0.85), 6.0)], 12 * DT, INTR)
    track = next(t for t in out if t.track_id == right)
    assert (track.source == cj.DETECTED).any()
    assert torso(track)[0][0] == pytest.approx(0.85, abs=0.03)


def test_with_nobody_tracked_every_sure_detection_is_confirmed_at_once():
    """No track yet: detections scoring at least `trust_score` are confirmed at their first
    frame, and a better region (first) scoring under it (a chair) is not; without a sure one,
    the foreground's best region is trusted as the single-person tracker trusts it, if it
    could start a track at all (`birth_score`: a desk in an empty room is no one to trust)."""
    tr = tracker(trust_score=7.0, birth_score=5.0, confirm_frames=2)
    out = tr.step([_scored(person(-1.0), 4.5), _scored(person(0.0), 10.0),
                   _scored(person(1.0), 8.0)], 0.0, INTR)
    assert sorted(ids_by_x(out).values()) == [0.0, 1.0]
    assert tr.tracks and all(t.id for t in tr.tracks)  # the chair started no track
    alone = tracker(trust_score=7.0)
    out = alone.step([_scored(person(-1.0), 5.5), _scored(person(0.0), 6.0)], 0.0, INTR)
    assert list(ids_by_x(out).values()) == [-1.0]
    # the default trusts the first region only (what the single-person tracker does)
    out = tracker(trust_score=np.inf).step([_scored(person(-1.0), 5.5),
                                            _scored(person(0.0), 10.0)], 0.0, INTR)
    assert list(ids_by_x(out).values()) == [-1.0]
    # ... unless it scores under the birth score: then nobody is published at once
    empty = tracker(trust_score=7.0, birth_score=5.0)
    assert empty.step([_scored(person(-1.0), 4.5), _scored(person(0.0), 6.0)], 0.0, INTR) == []
    assert empty.step([_scored(person(-1.0), 4.5), _scored(person(0.0), 6.0)], DT,
                      INTR)[0].track_id == 1  # the second region, confirmed at its 2nd frame


def test_the_second_look_runs_where_someone_may_be_hidden(monkeypatch):
    """`segment_people` looks again for people hidden behind those found (`_behind`) at a
    stream's start, while that look finds someone, or when someone of the previous frame is
    missing beside a person found; not while the same people stand in the open, nor for a
    region gone far from everyone found. What it finds is marked
    `behind` and comes after the people found in the open."""
    from dataclasses import replace

    from pose4d_ros.core.foreground import ForegroundConfig
    from pose4d_ros.core.foreground import segmentation as seg

    _, depth, _ = _two_people(offset=0.8)
    depth_m = depth.astype(np.float32) / 1000
    both, _ = segment_people(depth_m, INTR, config=ForegroundConfig(second_look=False))
    far = max(both, key=lambda p: p.depth_m)
    near = np.where(far.mask, np.nan, depth_m).astype(np.float32)  # the far one left out
    config = ForegroundConfig(second_look=False)
    part = max((pt for pt in seg._parts(depth_m, INTR, config, *seg._floor(
        depth_m, INTR, config, None)[1:])[0] if seg.person_rules(pt, config)),
        key=lambda pt: pt.z)
    calls = []

    def look(*args):  # the second look, as if it found the far person
        calls.append(1)
        return [(part, seg._part_mask(part, depth_m.shape))]

    monkeypatch.setattr(seg, '_behind', look)
    people, found = segment_people(near, INTR)
    assert len(calls) == 1  # a stream's start
    assert found == 2 and [p.behind for p in people] == [False, True]
    assert people[1].box == far.box
    segment_people(near, INTR, previous=people)
    assert len(calls) == 2  # while it finds someone
    alone = [replace(people[0])]
    segment_people(near, INTR, previous=alone)
    assert len(calls) == 2  # the same person in the open: no second look
    segment_people(near, INTR, previous=alone + [replace(people[0], box=(0, 0, 9, 9))])
    assert len(calls) == 2  # two before, one now, the other gone far from them: no look
    x0, y0, x1, y1 = people[0].box
    beside = (x1 + 2, y0, x1 + 2 + (x1 - x0), y1)  # just beside, not overlapping
    segment_people(near, INTR, previous=alone + [replace(people[0], box=beside)])
    assert len(calls) == 3  # two before, one now, the other gone where this one stands
    segment_people(near, INTR, config=config)
    assert len(calls) == 3  # off


def test_joints_on_a_nearer_persons_body_keep_their_last_estimate():
    """A far person half behind a near one: the far person's detected joints that lie on the
    near person's body (within `occluded_width_m` of one of their bones in the image) keep
    the track's last estimate (TRACKED); the others follow the detection."""
    from pose4d_ros.core.people.tracker import _near_segment
    from pose4d_ros.core.skeleton import tree_for

    tr = tracker()
    near = _scored(person(0.0, z=2.2), 10.0)
    for k in range(6):
        out = tr.step([near, _scored(person(0.3, z=3.4), 10.0)], k * DT, INTR)
    far_id = max(out, key=lambda t: torso(t)[0][2]).track_id
    before = next(t for t in out if t.track_id == far_id)
    moved = _scored(person(0.34, z=3.4), 10.0)
    out = tr.step([near, moved], 6 * DT, INTR)
    after = next(t for t in out if t.track_id == far_id)
    r = TrackingConfig().occluded_width_m * INTR.fx / torso(near)[0][2]
    hidden = np.zeros(10, bool)
    for a, b in tree_for(near.names).edges():
        hidden |= _near_segment(moved.uv, near.uv[a], near.uv[b], r)
    assert 0 < hidden.sum() < 10, hidden
    np.testing.assert_array_equal(after.uv[hidden], before.uv[hidden])
    assert (after.source[hidden] == cj.TRACKED).all()
    assert (after.source[~hidden] == cj.DETECTED).all()
    assert (after.uv[~hidden, 0] > before.uv[~hidden, 0] + 1.0).all()  # followed the detection
    # off: every joint follows the detection
    off = tracker(hold_occluded=False)
    for k in range(6):
        off.step([near, _scored(person(0.3, z=3.4), 10.0)], k * DT, INTR)
    out = off.step([near, moved], 6 * DT, INTR)
    assert (max(out, key=lambda t: torso(t)[0][2]).source == cj.DETECTED).all()


@pytest.mark.parametrize('confirmed_first', [True, False])
def test_a_track_just_started_does_not_take_a_confirmed_persons_detection(confirmed_first):
    """Two people confirmed; the right one's detection jumps 1 m for a frame (out of their
    gate: a tentative track starts there), then comes back between the two (the tentative
    track not far nearer: `tentative_margin`). The confirmed track takes it
    (`confirmed_first`), the tentative one ends, and no third id is given; in
    one assignment the nearer tentative track took it and went on as a new id while the
    right person's track went on unseen, predicted where nobody was."""
    tr = tracker(confirmed_first=confirmed_first)
    for k in range(6):
        out = tr.step([_scored(person(-0.6), 8.0), _scored(person(0.6), 8.0)], k * DT, INTR)
    right = next(i for i, x in ids_by_x(out).items() if x > 0)
    tr.step([_scored(person(-0.6), 8.0), _scored(person(1.6), 8.0)], 6 * DT, INTR)
    assert len(tr.tracks) == 3  # the jump started a tentative track
    for k in range(7, 12):
        out = tr.step([_scored(person(-0.6), 8.0), _scored(person(1.15), 8.0)], k * DT, INTR)
    ids = ids_by_x(out)
    if confirmed_first:
        assert sorted(ids) == [1, 2] and ids[right] == pytest.approx(1.15, abs=0.05)
        assert len(tr.tracks) == 2
    else:
        assert ids[3] == pytest.approx(1.15, abs=0.1)
        assert ids[right] == pytest.approx(0.6, abs=0.05)  # unseen, where nobody is


@pytest.mark.parametrize('tentative_margin', [TrackingConfig().tentative_margin, math.inf])
def test_a_track_whose_person_left_leaves_the_person_behind_them_their_own_track(
        tentative_margin):
    """`tentative_margin`: a person walks out (their last frame beside the one who walked in
    0.6 m behind them, whose track starts); the confirmed track is still within the gate of
    the newcomer's detection, and took it every frame when confirmed tracks always took
    first: the newcomer was never confirmed and their skeleton published under the first
    person's id. Now the newcomer's own track, fitting far better, keeps it: a new id."""
    from pose4d_ros.core.people.assignment import yielded

    costs = yielded(np.array([[15.3, 2.0, np.nan]]), np.array([[1.1, 1.5, np.nan]]), 9.0)
    assert np.isnan(costs[0, 0]) and costs[0, 1] == 2.0 and np.isnan(costs[0, 2])
    tr = tracker(tentative_margin=tentative_margin)
    for k in range(10):
        (first,) = tr.step([_scored(person(0.0, z=2.0), 9.0)], k * DT, INTR)
    tr.step([_scored(person(0.0, z=2.0), 9.0), _scored(person(0.0, z=2.6), 9.0)], 10 * DT,
            INTR)
    ids = set()
    for k in range(11, 16):
        out = tr.step([_scored(person(0.0, z=2.6), 9.0)], k * DT, INTR)
        ids |= {t.track_id for t in out if abs(torso(t)[0][2] - 2.6) < 0.1}
    assert ids == ({first.track_id} if math.isinf(tentative_margin) else {first.track_id + 1})


def _held_far(tr) -> int:
    """Two people seen for 10 frames, then the far one behind the near one for 9 (held): the
    far one's track id."""
    for k in range(10):
        out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(person(0.3, z=3.4), 8.0)],
                      k * DT, INTR)
    far = max(out, key=lambda t: torso(t)[0][2]).track_id
    for k in range(10, 19):
        tr.step([_scored(person(0.0, z=2.2), 8.0)], k * DT, INTR)
    return far


@pytest.mark.parametrize('held_continues', [True, False])
def test_a_held_person_is_not_taken_for_clutter_scoring_high(held_continues):
    """A region scoring over `birth_score` in the gate of a track held behind a nearer
    person, but away from that person (clutter beside the pair, seen on validation): with
    `held_continues` the held track does not take it (it would be published there as the
    hidden person), the region starts only a tentative track and the held one stays held;
    without, the held track takes it as any track unseen beside another person does."""
    tr = tracker(held_continues=held_continues)
    far = _held_far(tr)
    clutter = _scored(person(1.4, z=3.6), 6.5)
    i_far = next(i for i, t in enumerate(tr.tracks) if t.id == far)
    assert tr._cost([clutter], [torso(clutter)], 19 * DT)[i_far, 0] < 16  # in its gate
    out = tr.step([_scored(person(0.0, z=2.2), 8.0), clutter], 19 * DT, INTR)
    held = next(t for t in tr.tracks if t.id == far)
    assert held.held == held_continues
    published = next(t for t in out if t.track_id == far)
    assert (published.source == cj.DETECTED).any() != held_continues
    assert len(out) == 2 and sorted(t.track_id for t in out) == sorted({1, 2})


def test_a_walker_passing_a_held_person_is_confirmed_though_the_held_track_is_nearer():
    """Someone walking by (scoring over `birth_score`) in the gate of a track held behind a
    nearer person, away from where the held person would come out: the held track refuses
    the detection, which then goes to the walker's own young track, confirmed at its second
    frame (before, the held track took it in the assignment frame after frame and refused it:
    a new tentative track each frame, the walker never confirmed; seen on real recordings)."""
    tr = tracker()
    far = _held_far(tr)
    ids = set()
    for k in range(19, 23):
        walker = _scored(person(1.2 + 0.04 * (k - 19), z=3.5), 6.5)
        i_far = next(i for i, t in enumerate(tr.tracks) if t.id == far)
        assert tr._cost([walker], [torso(walker)], k * DT)[i_far, 0] < 16  # in its gate
        out = tr.step([_scored(person(0.0, z=2.2), 8.0), walker], k * DT, INTR)
        assert next(t for t in tr.tracks if t.id == far).held  # still held, untouched
        ids |= {t.track_id for t in out if torso(t)[0][0] > 1.0}
    assert len(ids) == 1 and ids.pop() not in (1, 2)  # one new id, from the second frame
    assert len([t for t in tr.tracks if not t.id]) == 0


@pytest.mark.parametrize('held_continues', [True, False])
def test_a_held_person_coming_out_partly_seen_is_taken_back(held_continues):
    """The far person is held behind the near one for 10 frames, then comes out partly
    seen: a detection scoring under `birth_score` where they were. Their held track takes
    it (`held_continues`); otherwise it is left (nobody's) and the track stays held. A
    low-scoring region away from the near person is never theirs."""
    tr = tracker(held_continues=held_continues)
    far = _held_far(tr)
    assert next(t for t in tr.tracks if t.id == far).held
    # a low-scoring region far from the near person (a wall's edge), in the gate that 0.6 s
    # unseen has grown: not theirs, they stay held
    out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(person(1.4, z=3.6), 2.0)],
                  19 * DT, INTR)
    assert all(tr.tracks[i].held for i, t in enumerate(tr.tracks) if t.id == far)
    assert tr._cost([_scored(person(1.4, z=3.6), 2.0)], [torso(person(1.4, z=3.6))],
                    19 * DT)[[i for i, t in enumerate(tr.tracks) if t.id == far][0], 0] < 16
    out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(person(0.35, z=3.4), 2.0)],
                  20 * DT, INTR)
    track = next(t for t in out if t.track_id == far)
    assert (track.source == cj.DETECTED).any() == held_continues
    assert len(out) == 2


@pytest.mark.parametrize('emerging_score', [5.0, 3.0])
def test_a_person_coming_out_from_behind_is_born_from_emerging_score(emerging_score):
    """A person never seen before comes out from behind a confirmed nearer one, partly seen,
    scoring 4 (under `birth_score`, over `emerging_score` 3): born after `confirm_frames`
    frames at 3, never at 5 (the birth score). The same score away from the near person (a
    region of the room) starts nothing at either."""
    tr = tracker(emerging_score=emerging_score)
    for k in range(5):
        out = tr.step([_scored(person(0.0, z=2.2), 8.0)], k * DT, INTR)
    assert [t.track_id for t in out] == [1]
    for k in range(5, 10):  # a low-scoring region of the room, 1.4 m beside the person
        out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(person(1.4, z=3.4), 4.0)],
                      k * DT, INTR)
    assert [t.track_id for t in out] == [1]
    for k in range(10, 15):  # coming out from behind the near person
        out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(person(0.2, z=3.4), 4.0)],
                      k * DT, INTR)
    assert sorted(t.track_id for t in out) == ([1, 2] if emerging_score < 5 else [1])
    if emerging_score < 5:
        assert tr.born == [] and ids_by_x(out)[2] == pytest.approx(0.2, abs=0.03)


@pytest.mark.parametrize('near, band, born', [(True, 8, True), (True, None, False),
                                               (False, 8, False)])
def test_a_person_cut_by_the_image_bottom_is_born_from_emerging_score(near, band, born):
    """A person too near to be seen whole (joints at or below the last row of the depth
    image's readings: a depth image registered to the colour camera has none in a band along
    its bottom), scoring 4 (under `birth_score`, over `emerging_score` 3), beside a confirmed
    person: born after `confirm_frames` frames. Not without a depth image to tell where the
    image ends, nor a whole person at the same score."""
    tr = tracker(emerging_score=3.0)
    depth = None
    if band is not None:
        depth = np.full((INTR.height, INTR.width), 3.0, np.float32)
        depth[-band:] = np.nan
    for k in range(5):
        tr.step([_scored(person(-0.7, z=3.0), 8.0)], k * DT, INTR, depth)
    other = _scored(person(0.15, z=1.6 if near else 3.0), 4.0)
    assert (other.uv[:, 1].max() >= INTR.height - 9) == near
    for k in range(5, 10):
        out = tr.step([_scored(person(-0.7, z=3.0), 8.0), other], k * DT, INTR, depth)
    assert len(out) == (2 if born else 1)


@pytest.mark.parametrize('far_x, born', [(1.0, True), (1.3, False)])
def test_a_region_cut_by_the_image_side_behind_a_person_is_not_born_from_emerging_score(
        far_x, born):
    """Behind a near person standing towards the image's right side, a detection scoring 4
    coming out from behind them is born from `emerging_score` (3) when it lies clear of the
    side, not when its joints reach the image's edge (a wall's edge or furniture cut by the
    border scores as a partly seen person does)."""
    tr = tracker(emerging_score=3.0)
    for k in range(5):
        tr.step([_scored(person(0.6, z=2.2), 8.0)], k * DT, INTR)
    far = _scored(person(far_x, z=3.4), 4.0)
    assert (far.uv[:, 0].max() > 0.96 * INTR.width) != born
    for k in range(5, 10):
        out = tr.step([_scored(person(0.6, z=2.2), 8.0), far], k * DT, INTR)
    assert len(out) == (2 if born else 1)


def test_a_held_person_is_not_taken_for_what_comes_out_from_behind_someone_else():
    """The far person is held behind the near one; a third, confirmed person stands 1.4 m
    to the side. A low-scoring region coming out from behind the third (in the held track's
    gate, grown with the time unseen: seen on validation, `valid60_people3d`, a wall's edge
    behind another person taken for the hidden one for 35 frames) is not the held person's:
    their track stays held, and takes the region coming out from behind the near person."""
    tr = tracker()
    side = person(-1.4, z=2.6)
    for k in range(10):
        out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(person(0.3, z=3.4), 8.0),
                       _scored(side, 8.0)], k * DT, INTR)
    far = max(out, key=lambda t: torso(t)[0][2]).track_id
    for k in range(10, 25):
        tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(side, 8.0)], k * DT, INTR)
    held = next(i for i, t in enumerate(tr.tracks) if t.id == far)
    assert tr.tracks[held].held
    behind_side = _scored(person(-1.5, z=3.6), 2.0)
    assert tr._cost([behind_side], [torso(behind_side)], 25 * DT)[held, 0] < 16  # in its gate
    out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(side, 8.0), behind_side],
                  25 * DT, INTR)
    assert next(t for t in tr.tracks if t.id == far).held
    assert not (next(t for t in out if t.track_id == far).source == cj.DETECTED).any()
    out = tr.step([_scored(person(0.0, z=2.2), 8.0), _scored(side, 8.0),
                   _scored(person(0.35, z=3.4), 2.0)], 26 * DT, INTR)
    assert (next(t for t in out if t.track_id == far).source == cj.DETECTED).any()


def _wall(z: float | None = None, person_at: tuple[float, float] | None = None
          ) -> np.ndarray:
    """A depth image of a wall `z` metres away (None: no reading anywhere), with a person's
    box at (x, z) in front of it."""
    depth = np.full((INTR.height, INTR.width), np.nan if z is None else z, np.float32)
    if person_at is not None:
        x, pz = person_at
        u0, v0 = project(np.array([[x - 0.3, -0.8, pz]]), INTR)[0].astype(int)
        u1, v1 = project(np.array([[x + 0.3, 0.9, pz]]), INTR)[0].astype(int)
        depth[max(v0, 0):v1, max(u0, 0):u1] = pz
    return depth


@pytest.mark.parametrize('held', [False, True])
def test_an_unseen_person_whose_place_the_camera_sees_through_has_left(held):
    """The far person stops being detected. In the open (walked off): while the depth image
    shows them (a reading at their place) or shows nothing (no readings), their track lives
    on; once it reads the wall 3 m behind their place, the track ends at once, where it would
    else be published for `max_unseen_s` (every unseen frame a ghost). Behind the near person
    (held), the depth reads the near person where they would be: they may be there, and live."""
    far_x = 0.1 if held else 1.0
    for depth, lives in ((_wall(6.5, (far_x, 3.4)), True), (_wall(None), True),
                         (_wall(6.5), held)):
        tr = tracker()
        for k in range(10):
            out = tr.step([person(0.0, z=2.2), person(far_x, z=3.4)], k * DT, INTR,
                          _wall(6.5, (far_x, 3.4)))
        far = max(out, key=lambda t: torso(t)[0][2]).track_id
        depth = depth.copy()
        depth[_wall(None, (0.0, 2.2)) == 2.2] = 2.2  # the near person, always seen
        out = tr.step([person(0.0, z=2.2)], 10 * DT, INTR, depth)
        assert (far in [t.track_id for t in out]) == lives
        assert tr.ended == ([] if lives else [far])
    # off by config: the tracker before
    tr = tracker(free_space_m=0.0)
    for k in range(10):
        out = tr.step([person(0.0, z=2.2), person(far_x, z=3.4)], k * DT, INTR, _wall(6.5))
    assert len(tr.step([person(0.0, z=2.2)], 10 * DT, INTR, _wall(6.5))) == 2


def test_an_unseen_person_predicted_out_of_the_image_has_left():
    tr = tracker()
    for k in range(10):  # walking right at 3 m/s, towards the image's right side
        tr.step([person(0.1 * k)], k * DT, INTR, _wall(6.5, (0.1 * k, 2.5)))
    out = tr.step([], 10 * DT, INTR, _wall(6.5, (0.9, 2.5)))
    assert [t.track_id for t in out] == [1]  # predicted at 1.0 m: still in the image
    # far beyond the side 0.5 s later; the depth there unknown, no reading is needed
    assert tr.step([], 25 * DT, INTR, _wall(None)) == [] and tr.ended == [1]


@pytest.mark.parametrize('max_unseen_at_side_s', [TrackingConfig().max_unseen_at_side_s, math.inf])
def test_an_unseen_person_at_the_images_side_is_kept_but_not_published(max_unseen_at_side_s):
    """`max_unseen_at_side_s`: a person last seen reaching the image's side and unseen since
    has most often walked out (on lab_walk, ghosts at the border): kept, not published after
    that long, and published again under their id when seen. Unseen in the middle of the
    image, a person is published as before (predicted)."""
    for x, at_side in ((-1.0, True), (0.0, False)):  # the image spans about -1.2..1.2 m at 2.5
        tr = tracker(max_unseen_at_side_s=max_unseen_at_side_s)
        for k in range(6):
            (first,) = tr.step([person(x)], k * DT, INTR)
        unseen = [len(tr.step([], k * DT, INTR)) for k in range(6, 10)]
        hidden = at_side and math.isfinite(max_unseen_at_side_s)
        assert unseen == ([1, 1, 0, 0] if hidden else [1] * 4), (x, unseen)
        out = tr.step([person(x)], 10 * DT, INTR)
        assert [t.track_id for t in out] == [first.track_id]


def test_a_setting_changed_live_reaches_every_persons_stage_and_the_next_person():
    """`configure` on the several-person stages (what the nodes and `FramePipeline.configure`
    call on a live parameter change) sets the template and every person's stage; a person
    who comes later gets it through `spawn`."""
    from pose4d_ros.core.slqe import SlqeConfig

    tr = tracker()
    for k in range(3):
        tr.step([person(-0.6), person(0.6)], k * DT, INTR)
    assert len(tr.tracks) == 2
    tr.configure(slqe=SlqeConfig(gate_chi2=20.0), depth_std_m=0.2)
    for stage in [tr.template, *(t.stage for t in tr.tracks)]:
        assert stage.slqe_config.gate_chi2 == 20.0 and stage.depth_std_m == 0.2
    for k in range(3, 6):
        tr.step([person(-0.6), person(0.6), person(1.6, z=3.5)], k * DT, INTR)
    assert len(tr.tracks) == 3
    assert {t.stage.slqe_config.gate_chi2 for t in tr.tracks} == {20.0}


@pytest.mark.parametrize('same_person_m', [0.0, 0.3])
def test_an_unseen_track_on_a_person_seen_under_another_id_ends(same_person_m):
    """Two tracks at one depth: the right one walks left onto where the left one, unseen from
    frame 10, is predicted. A person at the same depth is not hidden behind the one seen
    there: it is that person, under another id (two skeletons on one person). With
    `same_person_m` the unseen track ends at once; off, it coasts on under the other."""
    tr = tracker(same_person_m=same_person_m, one_body_m=0.0)
    for k in range(10):
        out = tr.step([person(0.03 * k), person(1.0 - 0.05 * k)], k * DT, INTR)
    assert sorted(ids_by_x(out)) == [1, 2]
    left = min(ids_by_x(out).items(), key=lambda kv: kv[1])[0]
    out = tr.step([person(0.5)], 10 * DT, INTR)
    right = next(t for t in out if t.track_id != left)
    assert abs(torso(right)[0][0] - 0.5) < 0.05  # the seen one took the detection
    assert (left in [t.track_id for t in out]) == (same_person_m == 0.0)
    assert tr.ended == ([] if same_person_m == 0.0 else [left])


def test_a_track_spanning_more_than_a_body_is_kept_but_not_published():
    """`max_span_m`: a skeleton whose located joints lie farther apart in 3-D than a body's
    (a track coasting on after its person left, its predicted joints flung apart) is not
    published; its track goes on, and is published again, with its id, once its joints span a
    body's size. A standing person's skeleton spans well under the default."""
    from pose4d_ros.core.people.assignment import span_m

    body = span_m(person(0.0))
    assert 1.0 < body < TrackingConfig().max_span_m
    tr = tracker(max_span_m=0.9 * body)
    for k in range(5):
        assert tr.step([person(0.0)], k * DT, INTR) == []
    (track,) = [t for t in tr.tracks if t.id]
    tr.config = replace(tr.config, max_span_m=1.1 * body)
    out = tr.step([person(0.0)], 5 * DT, INTR)
    assert [t.track_id for t in out] == [track.id]
    assert span_m(out[0]) == pytest.approx(body, rel=0.05)


def test_a_track_spanning_less_than_a_body_is_kept_but_not_published():
    """`min_span_m`: a skeleton whose located joints all lie within a few tenths of a metre
    (seen from above, a person's feet found as a person of their own) is not published; the
    person beside it is."""
    feet = person(0.0, z=3.0)
    xyz = feet.xyz.mean(axis=0) + 0.1 * (feet.xyz - feet.xyz.mean(axis=0))
    feet = JointSet(feet.names, project(xyz, INTR), xyz, source=feet.source,
                    confidence=feet.confidence)
    for min_span_m, published in ((0.5, [1.0]), (0.0, [0.0, 1.0])):
        tr = tracker(min_span_m=min_span_m)
        for k in range(5):
            out = tr.step([_scored(person(1.0), 9.0), _scored(feet, 9.0)], k * DT, INTR)
        assert sorted(round(float(torso(t)[0][0]), 2) for t in out) == published


def test_a_track_whose_shoulders_lie_a_metre_apart_is_kept_but_not_published():
    """`max_shoulders_m`: a skeleton whose shoulders lie a metre apart in 3-D (on a real
    recording, a track on a monitor and the chair beside it: one shoulder on each) is not
    published, from its first frame; the person beside it is. A standing person's shoulders
    lie well under the default apart."""
    from pose4d_ros.core.people.assignment import shoulders_m

    wide = person(0.0, z=3.0)
    xyz = wide.xyz.copy()
    left, right = wide.index('left_shoulder'), wide.index('right_shoulder')
    apart = (xyz[left] - xyz[right]) / np.linalg.norm(xyz[left] - xyz[right])
    xyz[left] += 0.35 * apart
    xyz[right] -= 0.35 * apart
    wide = JointSet(wide.names, project(xyz, INTR), xyz, source=wide.source,
                    confidence=wide.confidence)
    assert shoulders_m(person(1.0)) < 0.5 < TrackingConfig().max_shoulders_m < shoulders_m(wide)
    for max_shoulders_m, published in ((0.9, [[1.0]] * 5), (0.0, [[0.0, 1.0]] * 5)):
        tr = tracker(max_shoulders_m=max_shoulders_m)
        seen = []
        for k in range(5):
            out = tr.step([_scored(person(1.0), 9.0), _scored(wide, 9.0)], k * DT, INTR)
            seen.append(sorted(round(float(torso(t)[0][0]), 2) for t in out))
        assert seen == published


def _is_swapped(out: JointSet, det: JointSet) -> bool:
    """Whether `out` (the tracker's) has `det`'s left and right shoulders exchanged."""
    left, right = det.index('left_shoulder'), det.index('right_shoulder')
    return bool(np.allclose(out.uv[left], det.uv[right], atol=5.0)
                and np.allclose(out.uv[right], det.uv[left], atol=5.0))


@pytest.mark.parametrize('facing_away_m', [TrackingConfig().facing_away_m, 0.0])
def test_a_person_walking_away_is_published_by_their_own_sides(facing_away_m):
    """`core.people.facing`: the part model names the parts by the image's sides. A person
    walking away from the camera (1.2 m/s) faces away: published with left and right
    exchanged once they walked `facing_away_m` within the window, until they walk back
    towards the camera; walking across it or standing, nothing changes (`facing_away_m` 0:
    never). A torso jumping faster than a walk is no walk."""
    from pose4d_ros.core.people.facing import swapped

    body = person(0.0)
    twice = swapped(swapped(body))
    assert np.array_equal(twice.uv, body.uv) and swapped(body).names == body.names
    head = body.index('head')
    assert np.array_equal(swapped(body).uv[head], body.uv[head])
    tr = tracker(facing_away_m=facing_away_m)
    path = ([(0.0, 2.0)] * 10 + [(0.0, 2.0 + 0.04 * k) for k in range(1, 31)]  # away
            + [(0.0, 3.2)] * 20  # standing
            + [(0.0, 3.2 - 0.04 * k) for k in range(1, 21)]  # back towards the camera
            + [(0.04 * k, 2.4) for k in range(1, 21)])  # across
    flags = []
    for k, (x, z) in enumerate(path):
        det = _scored(person(x, z=z), 9.0)
        (out,) = tr.step([det], k * DT, INTR)
        flags.append(_is_swapped(out, det))
    away = [i for i, f in enumerate(flags) if f]
    if not facing_away_m:
        assert away == []
        return
    # swapped from about half a metre walked (the medians of the window's thirds apart by
    # 0.45 m: 14 frames in) through the standing, until back towards the camera
    assert away[0] in range(20, 27) and away[-1] in range(62, 70), away
    assert away == list(range(away[0], away[-1] + 1)) and not any(flags[70:]), away
    # a torso jumping 1.5 m away in a frame is no walk
    tr = tracker(facing_away_m=facing_away_m)
    jumps = [_is_swapped(tr.step([_scored(person(0.0, z=z), 9.0)], k * DT, INTR)[0],
                         person(0.0, z=z)) for k, z in enumerate([2.0] * 12 + [3.5] * 12)]
    assert not any(jumps)


def test_people_from_labels_gives_each_label_from_the_lowest_up_the_highest_first():
    from pose4d_ros.core.people import people_from_labels

    labels = np.zeros((40, 60), np.uint8)
    labels[5:20, 10:20] = 255  # the best person
    labels[22:30, 40:52] = 254  # the next
    labels[0:3, 0:3] = 37  # under the lowest value asked for: background
    depth = np.full(labels.shape, 2.0, np.float32)
    depth[22:30, 40:46] = np.nan  # no reading on half of the second person
    depth[22:30, 46:52] = 3.0
    people = people_from_labels(labels, depth, lowest=128)
    assert [p.box for p in people] == [(10, 5, 20, 20), (40, 22, 52, 30)]
    assert [p.depth_m for p in people] == [2.0, 3.0]
    assert people[0].mask.sum() == 150 and not people[0].mask[22:30, 40:52].any()
    assert len(people_from_labels(labels, None)) == 3  # from 1 up by default
    assert people_from_labels(np.zeros_like(labels), depth) == []
