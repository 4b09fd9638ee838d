"""`core.metrics` against hand-worked examples: the 3-D errors and PCK's seven-group average."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros.core import joints as cj
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import score_groups, score_joint_sets
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
