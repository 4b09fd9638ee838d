"""The tracker and IK stages that nodes and offline tools share (core/stages/)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers import BODY, INTR
from numpy.testing import assert_allclose

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import backproject, cad60_intrinsics, project
from pose4d_ros.core.dpm import load_model
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.lifting import medoid_parts, person_scale_px
from pose4d_ros.core.skeleton import (
    MIDPOINTS,
    PARTS_10,
    PARTS_14,
    PARTS_22,
    SKELETON_14,
    limb_bones,
)
from pose4d_ros.core.slqe import SlqeConfig
from pose4d_ros.core.stages import PRIOR_MAX_GAP_S, DetectorStage, IkStage, TrackerStage, reorder
from pose4d_ros.core.warm_up import warm_up_frame
from pose4d_ros.models import model_path


def _parts(offset=(0.0, 0.0, 0.0), noise_px=0.0, rng=None, drop=()):
    names = PARTS_10.names
    xyz = np.array([BODY[n] for n in names]) + offset
    uv = project(xyz, INTR)
    if noise_px:
        uv = uv + rng.normal(0, noise_px, uv.shape)
    src = np.full(len(names), cj.DETECTED, np.uint8)
    for n in drop:
        i = names.index(n)
        uv[i], xyz[i], src[i] = np.nan, np.nan, cj.MISSING
    return JointSet(names, uv, xyz, confidence=np.where(src == cj.DETECTED, 0.9, 0.0),
                    source=src)


def test_tracker_reduces_noise_and_lifts_to_3d():
    rng = np.random.default_rng(0)
    stage = TrackerStage()
    velocity = np.array([0.3, 0.0, 0.0])  # m/s sideways
    raw, filt = [], []
    for k in range(90):
        t = k / 30
        truth = project(np.array([BODY[n] for n in PARTS_10.names]) + velocity * t, INTR)
        det = _parts(velocity * t, 3.0, rng)
        out = stage.step(det, 100.0 + t, INTR)
        if k >= 30:
            raw.append(np.linalg.norm(det.uv - truth, axis=1).mean())
            filt.append(np.linalg.norm(out.uv - truth, axis=1).mean())
    assert out.names == PARTS_10.names and out.track_id == 1
    assert np.mean(filt) < 0.75 * np.mean(raw), (np.mean(filt), np.mean(raw))
    # 3-D: the tracked pixel back-projected at the detection's depth
    assert_allclose(out.xyz, backproject(out.uv, det.xyz[:, 2], INTR), atol=1e-9)
    assert (out.covariance[:, 2, 2] > 0).all()


def test_the_tracker_sees_a_person_at_any_camera_resolution_alike():
    """The same noisy motion seen by a 320x240 and a 640x480 camera: the tracked pixels of
    the larger image are twice those of the smaller (the filter's pixel parameters follow the
    person's scale, `person_scale_px`), and its 3-D is the same."""
    big = cad60_intrinsics(2 * INTR.width, 2 * INTR.height)
    assert person_scale_px(np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 3.0]]), INTR) == \
        pytest.approx(INTR.fx * 0.5 / 2.5)
    assert person_scale_px(np.full((3, 3), np.nan), INTR) is None
    assert person_scale_px(np.ones((3, 3)), None) is None
    rng = np.random.default_rng(3)
    small, large = TrackerStage(), TrackerStage()
    for k in range(60):
        det = _parts(np.array([0.4 * np.sin(k / 5), 0.0, 0.0]), 2.0, rng)
        if k % 7 == 3:  # an outlier the gate must reject in both
            uv = det.uv.copy()
            uv[4] += 25.0
            det = replace(det, uv=uv)
        det2 = replace(det, uv=2.0 * det.uv)  # as `cad60_intrinsics` scales the camera
        a = small.step(det, 10.0 + k / 30, INTR)
        b = large.step(det2, 10.0 + k / 30, big)
        assert (a.source == b.source).all()
        assert_allclose(2.0 * a.uv, b.uv, atol=1e-6)
        assert_allclose(a.xyz, b.xyz, atol=1e-9)


def test_tracker_coasts_through_dropouts_and_restarts_after_a_gap():
    stage = TrackerStage()
    for k in range(10):
        stage.step(_parts(), 10.0 + k / 30, INTR)
    out = stage.step(_parts(drop=('left_wrist',)), 10.0 + 10 / 30, INTR)
    i = PARTS_10.index('left_wrist')
    assert out.source[i] == cj.TRACKED
    assert np.isfinite(out.xyz[i]).all() and out.xyz[i, 2] == pytest.approx(2.35)
    out = stage.step(_parts(), 20.0, INTR)  # 10 s later: the track was lost, a new one starts
    assert out.track_id == 2



def test_a_rejected_detection_does_not_give_the_tracked_part_its_depth():
    stage = TrackerStage()
    for k in range(10):
        stage.step(_parts(), 10.0 + k / 30, INTR)
    i = PARTS_10.index('left_wrist')
    wrong = _parts()
    uv, xyz = wrong.uv.copy(), wrong.xyz.copy()
    uv[i] += (80.0, 0.0)  # an outlier on something 1 m behind the person
    xyz[i] = backproject(uv[i:i + 1], [xyz[i, 2] + 1.0], INTR)[0]
    out = stage.step(wrong.with_(uv=uv, xyz=xyz), 10.0 + 10 / 30, INTR)
    assert out.source[i] == cj.TRACKED
    assert out.xyz[i, 2] == pytest.approx(2.35)  # the last accepted detection's depth
    assert np.hypot(*(out.uv[i] - _parts().uv[i])) < 5

def test_tracker_follows_the_parts_it_gets_ten_or_fourteen():
    stage = TrackerStage()
    assert stage.step(_parts(), 1.0, INTR).names == PARTS_10.names
    names = PARTS_14.names
    xyz = np.array([BODY[n] for n in names])
    out = stage.step(JointSet(names, project(xyz, INTR), xyz, confidence=np.full(14, 0.9)),
                     1.0 + 1 / 30, INTR)
    assert out.names == names and out.track_id == 2  # a new filter, a new track
    assert (out.source == cj.DETECTED).all()
    assert_allclose(out.xyz, xyz, atol=1e-9)



def test_limb_midpoints_are_labelled_from_their_joints_and_tracked_with_them():
    xyz = np.array([BODY[n] for n in SKELETON_14])
    truth = JointSet(SKELETON_14, project(xyz, INTR), xyz,
                     confidence=np.where(np.array(SKELETON_14) == 'left_wrist', 0.0, 1.0))
    uv, pos, labelled = truth.labelled(PARTS_22.names)
    for name, (a, b) in MIDPOINTS.items():
        i = PARTS_22.index(name)
        assert PARTS_22.names[PARTS_22.parents[i]] == a  # between its joints in the tree
        assert PARTS_22.parents[PARTS_22.index(b)] == i
        ja, jb = SKELETON_14.index(a), SKELETON_14.index(b)
        assert_allclose(pos[i], (xyz[ja] + xyz[jb]) / 2)
        assert_allclose(uv[i], (truth.uv[ja] + truth.uv[jb]) / 2)
        assert labelled[i] == (name != 'left_forearm')  # its wrist is not labelled
    # the 22 detected parts: tracked as they come, completed to the 14 joints
    parts = JointSet(PARTS_22.names, np.where(labelled[:, None], uv, np.nan),
                     np.where(labelled[:, None], pos, np.nan),
                     confidence=np.where(labelled, 0.9, 0.0).astype(np.float32),
                     source=np.where(labelled, cj.DETECTED, cj.MISSING).astype(np.uint8))
    tracked = TrackerStage().step(parts, 1.0, INTR)
    assert tracked.names == PARTS_22.names
    out = IkStage().step(tracked, None, INTR)
    assert out.names == SKELETON_14 and (out.source[[SKELETON_14.index(n) for n in
                                                       ('left_elbow', 'right_wrist')]]
                                         == cj.DETECTED).all()

def test_a_part_coasting_off_the_image_is_lost():
    stage = TrackerStage()
    i = PARTS_10.index('left_ankle')
    for k in range(12):  # the ankle runs down the image at 3 m/s
        stage.step(_parts(offset=np.where(np.arange(10)[:, None] == i, [0, 0.1 * k, 0], 0)),
                   5.0 + k / 30, INTR)
    # undetected for longer than the filter coasts (`SlqeConfig.max_missed_frames`)
    n = SlqeConfig().max_missed_frames + 2
    outs = [stage.step(_parts(drop=('left_ankle',)), 5.4 + k / 30, INTR) for k in range(n)]
    v = [o.uv[i, 1] for o in outs if o.source[i] == cj.TRACKED]
    assert v and max(v) <= 2 * INTR.height  # predicted on or near the image, then lost
    assert outs[-1].source[i] == cj.MISSING and np.isnan(outs[-1].uv[i]).all()


def test_tracker_with_no_detection_gives_missing_not_nan_as_valid():
    stage = TrackerStage()
    empty = JointSet.missing(PARTS_10.names)
    out = stage.step(empty, 1.0, INTR)
    assert (out.source == cj.MISSING).all() and out.track_id == 0
    assert np.isnan(out.uv).all() and (out.confidence == 0).all()


def _tracked():
    parts = _parts()
    return parts.with_(source=np.full(10, cj.TRACKED, np.uint8), track_id=1)


def test_ik_completes_fourteen_joints_with_inferred_elbows_and_knees():
    lengths = {}
    for limb, (a, m, b) in {'left_arm': ('left_shoulder', 'left_elbow', 'left_wrist'),
                            'right_arm': ('right_shoulder', 'right_elbow', 'right_wrist'),
                            'left_leg': ('left_hip', 'left_knee', 'left_ankle'),
                            'right_leg': ('right_hip', 'right_knee', 'right_ankle')}.items():
        pa, pm, pb = (np.array(BODY[x]) for x in (a, m, b))
        lengths[limb] = (float(np.linalg.norm(pm - pa)), float(np.linalg.norm(pb - pm)))
    stage = IkStage(lengths=lengths, learn=False, use_depth=False)
    out = stage.step(_tracked(), None, INTR)
    assert out.names == SKELETON_14
    for name in ('left_elbow', 'right_elbow', 'left_knee', 'right_knee'):
        i = SKELETON_14.index(name)
        assert out.source[i] == cj.INFERRED and 0 < out.confidence[i] <= 1
        limb = {'left_elbow': 'left_arm', 'right_elbow': 'right_arm',
                'left_knee': 'left_leg', 'right_knee': 'right_leg'}[name]
        root = 'left_shoulder right_shoulder left_hip right_hip'.split()[
            ['left_arm', 'right_arm', 'left_leg', 'right_leg'].index(limb)]
        # on the circle: the upper bone has its length
        assert np.linalg.norm(out.xyz[i] - np.array(BODY[root])) == \
            pytest.approx(lengths[limb][0], abs=1e-6)
        assert_allclose(out.uv[i], project(out.xyz[i][None], INTR)[0], atol=1e-6)
    i = SKELETON_14.index('head')
    assert out.source[i] == cj.TRACKED


def test_ik_places_an_ankle_hidden_below_a_table_by_the_legs_lengths():
    """The person's masked depth has no pixel at the ankles (a table in front hides the
    legs): the detected ankles are guesses, not measurements; each is placed a leg's length
    straight down from its hip (no knee seen), INFERRED, and the knee solved between."""
    parts = _tracked()
    lengths = {limb: (0.45, 0.4) for limb in ('left_arm', 'right_arm', 'left_leg', 'right_leg')}
    depth = np.full((INTR.height, INTR.width), 2.5, np.float32)
    top = int(min(parts.uv[PARTS_10.index(a), 1] for a in ('left_ankle', 'right_ankle'))) - 8
    depth[top:] = np.nan  # the table: nothing of the person below this row
    stage = IkStage(lengths=lengths, learn=False, use_depth=False)
    out = stage.step(parts, depth, INTR)
    for side in ('left', 'right'):
        a, h = SKELETON_14.index(f'{side}_ankle'), SKELETON_14.index(f'{side}_hip')
        assert out.source[a] == cj.INFERRED
        assert_allclose(out.xyz[a], out.xyz[h] + [0.0, 0.85, 0.0], atol=1e-9)
        assert_allclose(out.uv[a], project(out.xyz[a][None], INTR)[0], atol=1e-9)
        assert out.source[SKELETON_14.index(f'{side}_knee')] == cj.INFERRED
    # with the person's pixels there (or the rule off), the detection stands
    for depth_m, hidden_legs in ((np.full_like(depth, 2.5), True), (depth, False)):
        out = IkStage(lengths=lengths, learn=False, use_depth=False,
                      hidden_legs=hidden_legs).step(parts, depth_m, INTR)
        a = SKELETON_14.index('left_ankle')
        assert out.source[a] != cj.INFERRED
        assert_allclose(out.uv[a], parts.uv[PARTS_10.index('left_ankle')], atol=1e-9)


def test_ik_flags_bad_joints_missing():
    parts = _tracked()
    xyz = parts.xyz.copy()
    xyz[PARTS_10.index('left_wrist'), 2] = -1.0  # behind the camera
    out = IkStage(use_depth=False).step(parts.with_(xyz=xyz), None, INTR)
    i = SKELETON_14.index('left_wrist')
    assert out.source[i] == cj.MISSING and np.isnan(out.xyz[i]).all()
    e = SKELETON_14.index('left_elbow')  # its end is unknown: no elbow either
    assert out.source[e] == cj.MISSING and np.isnan(out.xyz[e]).all()
    r = SKELETON_14.index('right_elbow')
    assert out.source[r] == cj.INFERRED


def test_ik_with_an_all_nan_depth_image_falls_back_on_the_prior():
    depth = np.full((INTR.height, INTR.width), np.nan, np.float32)
    out = IkStage().step(_tracked(), depth, INTR)
    for name in ('left_elbow', 'left_knee'):
        assert out.source[SKELETON_14.index(name)] == cj.INFERRED


def test_reorder_and_bones():
    js = reorder(_parts(), SKELETON_14)
    assert js.source[SKELETON_14.index('left_elbow')] == cj.MISSING
    assert js.source[SKELETON_14.index('head')] == cj.DETECTED
    bones = limb_bones()
    assert len(bones) == 14 and all(0 <= a < 14 and 0 <= b < 14 for a, b in bones)


def test_foreground_holds_the_person_through_a_frame_or_two_without_one(monkeypatch):
    from pose4d_ros.core import foreground
    from pose4d_ros.core.stages import ForegroundStage
    from pose4d_ros.core.stages import foreground as pl

    color, depth, person = warm_up_frame(INTR)
    stage = ForegroundStage()
    first, _, _ = stage.step(color, depth, INTR)
    assert first.found and (first.mask & person).sum() > 0.9 * person.sum()
    monkeypatch.setattr(pl, 'segment', lambda depth_m, intrinsics, **kw: foreground.segment(
        np.full_like(depth_m, np.nan), intrinsics, **kw))  # the segmentation fails
    held = [stage.step(color, depth, INTR)[0] for _ in range(ForegroundStage.HOLD_FRAMES + 1)]
    assert all(fg.found for fg in held[:-1]) and not held[-1].found
    assert (held[0].mask & person).sum() > 0.9 * person.sum()
    assert held[0].mask.sum() < 1.5 * first.mask.sum()  # grown a little, not the background
    assert held[0].depth_m == pytest.approx(first.depth_m, abs=0.05)


def test_a_nearly_unconfident_detection_gives_the_ik_a_joint_it_accepts() -> None:
    """A part detected with confidence 1e-6 starts a track with a bounded variance, so the
    tracked joints pass the next stage's checks (a variance of millions of pixels, lifted to
    3-D, exceeded 400 m^2 and the IK refused the whole frame)."""
    k = cad60_intrinsics()
    names = PARTS_10.names
    uv = np.column_stack([np.linspace(120, 200, len(names)), np.linspace(40, 200, len(names))])
    xyz = backproject(uv, np.full(len(names), 2.8), k)
    conf = np.ones(len(names), np.float32)
    conf[0] = 1e-6
    parts = JointSet(names, uv, xyz, confidence=conf,
                     source=np.full(len(names), cj.DETECTED, np.uint8))
    tracked = TrackerStage().step(parts, 0.0, k)
    assert np.all(np.abs(tracked.covariance) <= 20.0 ** 2)
    skeleton = IkStage(use_depth=False).step(tracked, None, k)
    assert skeleton.source[SKELETON_14.index(names[0])] != cj.MISSING


def test_the_detector_stage_guides_a_frame_by_the_previous_one_only_when_recent() -> None:
    """The previous frame's parts are the arms' prior (`SearchConfig.arm_prior`) when at most
    `PRIOR_MAX_GAP_S` old; a gap, a stamp going back, a frame without a stamp or `reset` drop
    it."""
    stage = DetectorStage(load_model(model_path('rgbd_10')))
    seen = []
    detect = stage.detector.detect

    def spy(*args, prior=None, **kwargs):
        seen.append(None if prior is None else prior.copy())
        return detect(*args, prior=prior, **kwargs)

    stage.detector.detect = spy
    color, depth, mask = warm_up_frame(INTR)
    step = 1.0 / 30.0
    stamps = [0.0, step, 2 * step, 2 * step + PRIOR_MAX_GAP_S + 0.01, 0.5 * step, None, 1.0]
    outputs = []
    for stamp in stamps:
        seen.clear()
        out = stage.step(color, depth, INTR, mask=mask, stamp_s=stamp)
        outputs.append((out, seen[0]))
    guided = [prior is not None for _, prior in outputs]
    assert guided == [False, True, True, False, False, False, False]
    assert_allclose(outputs[1][1], outputs[0][0].uv)  # the previous frame's parts
    stage.step(color, depth, INTR, mask=mask, stamp_s=2.0)
    stage.reset()
    seen.clear()
    stage.step(color, depth, INTR, mask=mask, stamp_s=2.0 + step)
    assert seen[0] is None


def test_medoid_parts_takes_each_part_where_the_poses_agree() -> None:
    a = np.array([[10.0, 10.0], [50.0, 50.0]])
    b = a + [[1.0, 0.0], [0.0, 1.0]]
    c = a + [[0.0, 2.0], [40.0, 0.0]]  # its second part elsewhere
    assert_allclose(medoid_parts([c, a, b]), [[10.0, 10.0], [50.0, 50.0]])
    assert_allclose(medoid_parts([b, c]), b)  # two poses: the first on a tie


@pytest.mark.parametrize('odd', range(len(ScaleConfig.factors)))
def test_while_the_scale_is_undecided_a_part_one_factor_puts_elsewhere_is_not_taken(odd) -> None:
    """In a track's first frames every person-scale factor is searched; one factor's pose
    putting a part far from where the others agree does not decide that part."""
    stage = DetectorStage(load_model(model_path('rgbd_10')))
    detect = stage.detector.detect
    calls = []

    def spy(*args, **kwargs):
        poses = detect(*args, **kwargs)
        calls.append(kwargs['scale'])
        if poses and len(calls) - 1 == odd:
            uv = poses[0].uv.copy()
            uv[3] += 60.0
            poses = [replace(poses[0], uv=uv), *poses[1:]]
        return poses

    stage.detector.detect = spy
    color, depth, mask = warm_up_frame(INTR)
    out = stage.step(color, depth, INTR, mask=mask, stamp_s=0.0)
    assert len(calls) == len(stage.person_scale.config.factors) > 2
    truth = [detect(color, depth, mask=mask, intrinsics=INTR, scale=f)[0].uv[3] for f in calls]
    assert np.linalg.norm(out.uv[3] - (truth[odd] + 60.0)) > 20.0


def test_a_part_placed_beyond_the_image_edge_is_put_on_the_edge() -> None:
    """The model may place a part whose filter hangs over the border just outside the image (an
    ankle at v = 241.9 in a 240-row frame): the detection is put on the image's edge."""
    stage = DetectorStage(load_model(model_path('rgbd_10')))
    color, depth, mask = warm_up_frame(INTR)
    (pose,) = stage.detector.detect(color, depth, mask=mask, intrinsics=INTR)
    k = pose.names.index('left_ankle')
    for axis, value, want in ((1, INTR.height + 1.9, INTR.height - 1.0), (0, -0.4, 0.0),
                              (0, INTR.width - 1.0, INTR.width - 1.0)):
        moved = pose.uv.copy()
        moved[k, axis] = value
        stage.detector.detect = lambda *a, moved=moved, **kw: [replace(pose, uv=moved)]
        out = stage.step(color, depth, INTR, mask=mask)
        assert out.source[k] == cj.DETECTED
        assert out.uv[k, axis] == want
        assert_allclose(out.uv[:, 1 - axis], pose.uv[:, 1 - axis])
        others = np.arange(len(pose.names)) != k
        assert_allclose(out.uv[others], pose.uv[others])


def test_an_accepted_detection_at_the_edge_stays_on_the_image() -> None:
    """A part moving fast towards the bottom edge: the filter's prediction overshoots, and the
    estimate of the accepted detection on the last row must not leave the image (it did: an
    ankle at v = 241.9 in a 240-row frame, labelled DETECTED)."""
    k = cad60_intrinsics()
    names = PARTS_10.names
    stage = TrackerStage()
    base = np.column_stack([np.linspace(120, 200, len(names)), np.linspace(40, 200, len(names))])
    for i in range(13):
        uv = base.copy()
        uv[-1, 1] = min(160.0 + 8.0 * i, k.height - 1.0)  # the last part runs to the edge
        parts = JointSet(names, uv, backproject(uv, np.full(len(names), 2.8), k),
                         confidence=np.ones(len(names), np.float32),
                         source=np.full(len(names), cj.DETECTED, np.uint8))
        out = stage.step(parts, i / 30.0, k)
    assert out.source[-1] == cj.DETECTED
    assert 0 <= out.uv[-1, 1] <= k.height - 1
