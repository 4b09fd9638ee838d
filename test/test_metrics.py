"""`core.metrics` against hand-worked examples: the reference size, PCK, APK, pixel and 3-D
errors, PCK's seven-group average, and how ground truth is found."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros.core import joints as cj
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import curves, reference_size, score_groups, score_joint_sets
from pose4d_ros.core.skeleton import SKELETON_14

NAMES = ('head', 'left_shoulder', 'right_shoulder')


def three_joints() -> dict[str, np.ndarray]:
    """Two frames of head and shoulders, 2 m from the camera.

    Ground truth: every pixel is predicted exactly (PCK 100); the right shoulder is not visible
    in frame 1. 3-D errors: head 30 and 50 mm; left shoulder 120 and 40 mm; right shoulder
    without a 3-D prediction in frame 0 (infinitely far), 300 mm off in frame 1 (not scored).
    """
    gt = np.array([[[50.0, 0.0], [0.0, 100.0], [100.0, 100.0]]] * 2)
    visible = np.array([[True, True, True], [True, True, False]])
    gt_xyz = np.array([[[0.0, -0.5, 2.0], [-0.2, 0.0, 2.0], [0.2, 0.0, 2.0]]] * 2)
    pred_xyz = gt_xyz.copy()
    pred_xyz[0, 0, 0] += 0.03
    pred_xyz[1, 0, 2] -= 0.05
    pred_xyz[0, 1] += (0.0, 0.12, 0.0)
    pred_xyz[1, 1, 1] += 0.04
    pred_xyz[0, 2] = np.nan
    pred_xyz[1, 2, 2] += 0.3
    return {'pred': gt.copy(), 'scores': np.ones((2, 3)), 'gt': gt, 'visible': visible,
            'pred_xyz': pred_xyz, 'gt_xyz': gt_xyz}


def test_3d_error_median_and_within_10cm_by_hand() -> None:
    table = score_groups(**three_joints(), names=NAMES)
    # head: 30, 50 mm -> median 40, both within 10 cm
    # shoulder: 120, 40 mm and no 3-D (inf) -> median 120 mm, 1 of 3 within 10 cm
    assert_allclose(table['error_mm']['head'], 40.0, atol=1e-9)
    assert_allclose(table['error_mm']['shoulder'], 120.0, atol=1e-9)
    assert_allclose(table['error_mm']['average'], 80.0, atol=1e-9)
    assert_allclose(table['within_10cm']['head'], 100.0)
    assert_allclose(table['within_10cm']['shoulder'], 100.0 / 3)
    assert_allclose(table['within_10cm']['average'], (100.0 + 100.0 / 3) / 2)
    assert list(table) == ['pck', 'apk', 'pck@0.2', 'error_px', 'error_mm', 'within_10cm']


def test_a_group_mostly_without_3d_has_an_infinite_median() -> None:
    case = three_joints()
    case['pred_xyz'][1, 1] = np.nan  # left shoulder in frame 1: now 2 of 3 shoulders lack 3-D
    table = score_groups(**case, names=NAMES)
    assert table['error_mm']['shoulder'] == np.inf
    assert table['error_mm']['average'] == np.inf
    assert_allclose(table['within_10cm']['shoulder'], 0.0)
    assert_allclose(table['error_mm']['head'], 40.0, atol=1e-9)


def test_3d_scores_the_joints_pck_counts() -> None:
    # a joint outside the frame's reference box rule (no 2 visible joints): not scored in 3-D
    case = three_joints()
    case['visible'][1] = (True, False, False)  # frame 1 has one visible joint: not counted
    table = score_groups(**case, names=NAMES)
    assert_allclose(table['error_mm']['head'], 30.0, atol=1e-9)
    assert_allclose(table['error_mm']['shoulder'], np.inf)  # 120 mm and inf: median inf
    assert_allclose(table['within_10cm']['shoulder'], 0.0)


def test_curves_by_hand_and_equal_to_the_table_at_each_alpha() -> None:
    case = three_joints()
    # reference size: the box of the visible joints is 100 x 100 px in both frames; move the
    # head 15 px off in frame 0 and the left shoulder 30 px off in frame 1
    case['pred'][0, 0] += (15.0, 0.0)
    case['pred'][1, 1] += (0.0, 30.0)
    c = curves(**case, names=NAMES, alphas=np.array([0.0, 0.1, 0.2, 0.5]))
    assert_allclose(c['pck']['head'], [50.0, 50.0, 100.0, 100.0])  # 0 px, then 15 px off
    assert_allclose(c['pck']['shoulder'], [200 / 3, 200 / 3, 200 / 3, 100.0])  # 3 counted
    for alpha in (0.1, 0.2, 0.5):
        table = score_groups(**case, names=NAMES, alphas=(alpha,))
        k = [0.0, 0.1, 0.2, 0.5].index(alpha)
        for g in ('head', 'shoulder', 'average'):
            assert_allclose(c['pck'][g][k], table['pck'][g])
    # the 3-D distances behind within_10cm: head 30, 50 mm; shoulders 40, 120 mm and inf
    assert_allclose(c['distance_mm']['head'], [30.0, 50.0], atol=1e-9)
    assert_allclose(c['distance_mm']['shoulder'], [40.0, 120.0, np.inf], atol=1e-9)


def test_without_3d_there_are_no_3d_metrics() -> None:
    case = three_joints()
    del case['pred_xyz'], case['gt_xyz']
    table = score_groups(**case, names=NAMES)
    assert 'error_mm' not in table and 'within_10cm' not in table
    with pytest.raises(ValueError, match='both'):
        score_groups(**case, names=NAMES, gt_xyz=three_joints()['gt_xyz'])


def test_average7_is_over_all_seven_groups() -> None:
    rng = np.random.default_rng(0)
    gt = rng.uniform(0, 200, (3, 14, 2))
    pred = gt.copy()
    elbows = [SKELETON_14.index('left_elbow'), SKELETON_14.index('right_elbow')]
    pred[:, elbows] = np.nan  # every elbow missed: elbow PCK 0, the other six groups 100
    table = score_groups(pred, np.ones((3, 14)), gt, np.ones((3, 14), bool), SKELETON_14)
    assert table['pck']['elbow'] == 0.0 and table['pck']['knee'] == 100.0
    assert_allclose(table['pck']['average'], 100.0)  # the paper's five groups: no elbow
    assert_allclose(table['pck']['average7'], 600.0 / 7)
    # with groups absent (three joints: head and shoulders) there is no seven-group average
    assert np.isnan(score_groups(**three_joints(), names=NAMES)['pck']['average7'])


def test_score_joint_sets_takes_3d_from_the_joint_sets() -> None:
    case = three_joints()
    truths, preds = [], []
    for k in range(2):
        truths.append(JointSet(NAMES, case['gt'][k], case['gt_xyz'][k],
                               confidence=case['visible'][k].astype(np.float32)))
        src = np.full(3, cj.DETECTED)
        preds.append(JointSet(NAMES, case['pred'][k], case['pred_xyz'][k], source=src))
    table = score_joint_sets(preds, truths, NAMES)
    assert_allclose(table['error_mm']['average'], 80.0, atol=1e-9)
    # a MISSING joint's position is not a prediction, even when it carries numbers
    preds[1] = preds[1].with_(source=np.array([cj.DETECTED, cj.MISSING, cj.DETECTED]))
    table = score_joint_sets(preds, truths, NAMES)
    assert table['error_mm']['shoulder'] == np.inf  # 120 mm, inf, inf
    # predictions without any 3-D (an RGB-only row): no 3-D metrics
    flat = [p.with_(xyz=np.full((3, 3), np.nan)) for p in preds]
    assert 'error_mm' not in score_joint_sets(flat, truths, NAMES)


def two_frames_2d() -> dict[str, np.ndarray]:
    """Head and shoulders in two frames, worked by hand.

    Reference sizes: frame 0's joints span 30 x 40 px -> 40 px (PCK@0.1 radius 4 px, @0.2
    8 px); frame 1's span 50 x 100 px -> 100 px (10 px, 20 px). Prediction errors (px): frame 0
    head 3, left shoulder 6, right shoulder not predicted; frame 1 head 15, left shoulder 8,
    right shoulder 30.
    """
    gt = np.array([[[10.0, 20.0], [40.0, 60.0], [25.0, 30.0]],
                   [[0.0, 0.0], [0.0, 100.0], [50.0, 100.0]]])
    pred = gt + np.array([[[3.0, 0.0], [0.0, 6.0], [np.nan, np.nan]],
                          [[0.0, 15.0], [8.0, 0.0], [0.0, 30.0]]])
    scores = np.array([[0.9, 0.7, 0.5], [0.8, 0.6, 0.95]])
    return {'pred': pred, 'scores': scores, 'gt': gt, 'visible': np.ones((2, 3), bool)}


def test_reference_size_by_hand() -> None:
    case = two_frames_2d()
    assert_allclose(reference_size(case['gt'], case['visible']), [40.0, 100.0])
    # a joint that is not visible does not count; a frame with one visible joint has no size
    visible = np.array([[True, True, False], [True, False, False]])
    assert_allclose(reference_size(case['gt'], visible), [40.0, np.nan])


def test_pck_apk_and_pixel_error_by_hand() -> None:
    table = score_groups(**two_frames_2d(), names=NAMES)
    # PCK@0.1: head 3 <= 4 yes, 15 <= 10 no -> 50 %; shoulders 6 > 4, none, 8 <= 10, 30 > 10
    assert_allclose(table['pck']['head'], 50.0)
    assert_allclose(table['pck']['shoulder'], 25.0)
    assert_allclose(table['pck']['average'], 37.5)
    # PCK@0.2: head 3 <= 8, 15 <= 20 -> 100 %; shoulders 6 <= 8, none, 8 <= 20, 30 > 20
    assert_allclose(table['pck@0.2']['head'], 100.0)
    assert_allclose(table['pck@0.2']['shoulder'], 50.0)
    # APK, head: by score a hit (0.9) then a miss (0.8) of 2 visible heads: precision 1 up to
    # recall 0.5 -> 50 %. Shoulders (4 visible): by score a miss (0.95), a miss (0.7), a hit
    # (0.6) -> recall 0.25 at precision 1/3 -> 1/12; the unpredicted one is no detection.
    assert_allclose(table['apk']['head'], 50.0)
    assert_allclose(table['apk']['shoulder'], 100.0 / 12)
    assert_allclose(table['apk']['average'], (50.0 + 100.0 / 12) / 2)
    # pixel error over the predicted joints: head (3 + 15) / 2, shoulders (6 + 8 + 30) / 3
    assert_allclose(table['error_px']['head'], 9.0)
    assert_allclose(table['error_px']['shoulder'], 44.0 / 3)


def test_score_joint_sets_finds_the_truth_by_name_or_alias_and_inside_the_image() -> None:
    case = two_frames_2d()
    names = ('head', 'left_wrist', 'right_wrist')  # CAD-60 calls the wrists' joints hands
    preds = [JointSet(names, case['pred'][k], confidence=case['scores'][k]) for k in range(2)]
    cad60 = [JointSet(('head', 'left_hand', 'right_hand'), case['gt'][k]) for k in range(2)]
    lspet = [JointSet(names, case['gt'][k]) for k in range(2)]
    for truths in (cad60, lspet):
        table = score_joint_sets(preds, truths, names)
        assert_allclose(table['pck']['head'], 50.0)
        assert_allclose(table['pck']['wrist'], 25.0)
    # ground truth outside the image is not scored: in a 50 x 101 px frame 1, the right wrist
    # at u = 50 is outside (the reference size, of the visible joints, becomes 100 px anyway)
    table = score_joint_sets(preds, cad60, names, image_sizes=[(320, 240), (50, 101)])
    assert_allclose(table['pck']['wrist'], 100.0 / 3)  # 6 > 4, none, 8 <= 10
