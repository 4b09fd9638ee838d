"""Elbow/knee inference (core.kinematics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros.core.camera import cad60_intrinsics, lift_depth, robust_depth
from pose4d_ros.core.kinematics import (
    IkConfig,
    IkFlag,
    body_frame,
    circle_points,
    infer_middle_joints,
    middle_joint_circle,
    solve_limb,
)
from pose4d_ros.core.limb_lengths import DEFAULT_LIMB_LENGTHS_M, LimbLengths
from pose4d_ros.core.skeleton import PARTS_10
from pose4d_ros.synth.render import capsule_depth

K = cad60_intrinsics()
UPPER, LOWER = 0.28, 0.25


def random_limb(rng: np.random.Generator, root, upper: float = UPPER, lower: float = LOWER
                ) -> np.ndarray:
    """Root, middle and end (3, 3) of a limb with random bone directions, bent by 0.35-2.6 rad
    (the angle between the two bones: 0 = straight)."""
    root = np.asarray(root, float)
    d1 = rng.normal(size=3)
    d1 /= np.linalg.norm(d1)
    side = np.cross(d1, rng.normal(size=3))
    side /= np.linalg.norm(side)
    bend = rng.uniform(0.35, 2.6)
    mid = root + upper * d1
    return np.stack([root, mid, mid + lower * (math.cos(bend) * d1 + math.sin(bend) * side)])


def test_ik_returns_a_point_on_the_true_circle() -> None:
    rng = np.random.default_rng(2)
    for _ in range(30):
        root, mid, end = random_limb(rng, [0, 0, 2.5])
        circle = middle_joint_circle(root, end, UPPER, LOWER)
        # The true middle joint is on it ...
        assert_allclose(np.linalg.norm(mid - circle.centre), circle.radius, atol=1e-9)
        assert abs((mid - circle.centre) @ circle.axis) < 1e-9
        # ... and so is whatever the prior picks, at the right bone lengths.
        prior = rng.normal(size=3)
        on = IkConfig(prior_shrink=(1.0, 1.0))
        sol = solve_limb(None, root, end, UPPER, LOWER, K, prior=prior, config=on)
        assert sol.flag == IkFlag.PRIOR
        assert_allclose(np.linalg.norm(sol.position - root), UPPER, rtol=1e-9)
        assert_allclose(np.linalg.norm(end - sol.position), LOWER, rtol=1e-9)
        # Shrunk: the same direction from the centre, at the shrink's fraction of the radius.
        half = IkConfig(prior_shrink=(0.5, 0.5))
        inner = solve_limb(None, root, end, UPPER, LOWER, K, prior=prior, config=half)
        assert_allclose(inner.position - circle.centre, 0.5 * (sol.position - circle.centre),
                        atol=1e-12)


def test_prior_direction_is_followed() -> None:
    root, end = np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.4, 2.0])
    sol = solve_limb(None, root, end, UPPER, LOWER, K, prior=np.array([0.0, 0.0, -1.0]))
    assert sol.position[2] < 2.0 - 0.1  # bent towards the camera, as asked
    assert 0 < sol.confidence < 1


def arm_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A bent arm beside a torso, in front of the camera; returns root, middle, end, depth."""
    shoulder = np.array([0.15, -0.25, 2.2])
    while True:
        root, mid, end = random_limb(rng, shoulder)
        # Keep the arm beside the torso (no self-occlusion by it) and the bend clear.
        bend = math.acos(np.clip((mid - root) @ (end - mid) / (UPPER * LOWER), -1, 1))
        if mid[0] > shoulder[0] - 0.05 and end[0] > shoulder[0] - 0.1 and 0.6 < bend < 2.2:
            break
    torso = [[shoulder[0] - 0.2, shoulder[1] + 0.05, 2.22], [shoulder[0] - 0.2, 0.3, 2.22]]
    depth = capsule_depth(np.array([[root, mid], [mid, end], torso]),
                          np.array([0.045, 0.04, 0.13]), K, rng=rng)
    return root, mid, end, depth


def test_depth_recovers_the_true_elbow() -> None:
    """With a depth image of the arm, the swivel comes from depth whatever the prior says."""
    rng = np.random.default_rng(3)
    cfg = IkConfig(length_scales=(1.0,))
    errors, prior_errors = [], []
    for _ in range(12):
        root, mid, end, depth = arm_scene(rng)
        prior = rng.normal(size=3)
        sol = solve_limb(depth, root, end, UPPER, LOWER, K, prior=prior,
                         mask=np.isfinite(depth), config=cfg)
        assert sol.flag == IkFlag.DEPTH
        assert np.isfinite(sol.pixel).all()
        errors.append(np.linalg.norm(sol.position - mid))
        alone = solve_limb(None, root, end, UPPER, LOWER, K, prior=prior, config=cfg)
        prior_errors.append(np.linalg.norm(alone.position - mid))
    errors = np.array(errors)
    # Tolerance: 2 cm for most arms (Kinect noise ~6 mm at 2.2 m, 10/5 degree swivel steps).
    assert np.median(errors) < 0.02, errors
    assert np.mean(errors < 0.04) >= 0.75, errors
    assert np.median(errors) < 0.25 * np.median(prior_errors)


def test_depth_without_support_falls_back_on_the_prior() -> None:
    root, end = np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.4, 2.0])
    holes = np.full((240, 320), np.nan, np.float32)
    prior = np.array([0.0, 0.0, -1.0])
    sol = solve_limb(holes, root, end, UPPER, LOWER, K, prior=prior)
    ref = solve_limb(None, root, end, UPPER, LOWER, K, prior=prior)
    assert sol.flag == IkFlag.PRIOR
    assert_allclose(sol.position, ref.position)


@pytest.mark.parametrize('stretch', [1.2, 2.0])
def test_unreachable_is_on_the_line_and_flagged(stretch: float) -> None:
    root = np.array([0.1, -0.2, 2.0])
    end = root + np.array([0.6, 0.8, 0.0]) * (UPPER + LOWER) * stretch
    sol = solve_limb(None, root, end, UPPER, LOWER, K, prior=np.array([0.0, 0.0, -1.0]))
    assert sol.flag == IkFlag.UNREACHABLE
    assert sol.confidence <= 0.25
    assert_allclose(sol.position, root + (end - root) * UPPER / (UPPER + LOWER))


@pytest.mark.parametrize('root, end, flag', [
    ([np.nan, 0.0, 2.0], [0.0, 0.4, 2.0], IkFlag.MISSING),
    ([0.0, 0.0, 2.0], [0.0, np.nan, 2.0], IkFlag.MISSING),
    ([0.0, 0.0, -0.5], [0.0, 0.4, 2.0], IkFlag.BEHIND_CAMERA),
    ([0.0, 0.0, 2.0], [0.0, 0.4, 0.0], IkFlag.BEHIND_CAMERA),
])
def test_invalid_input_is_flagged_never_nan_valid(root, end, flag) -> None:
    sol = solve_limb(None, np.array(root), np.array(end), UPPER, LOWER, K,
                     prior=np.array([0.0, 0.0, -1.0]))
    assert sol.flag == flag
    assert np.isnan(sol.position).all() and np.isnan(sol.pixel).all()
    assert sol.confidence == 0.0


def test_middle_joint_behind_the_camera_is_flagged() -> None:
    # Root and end just in front of the camera, the prior bends the elbow behind it.
    sol = solve_limb(None, np.array([0.0, 0.0, 0.05]), np.array([0.0, 0.4, 0.05]), UPPER,
                     LOWER, K, prior=np.array([0.0, 0.0, -1.0]))
    assert sol.flag == IkFlag.BEHIND_CAMERA
    assert np.isnan(sol.position).all() and sol.confidence == 0.0


def test_nan_lengths_are_missing() -> None:
    sol = solve_limb(None, np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.4, 2.0]), math.nan,
                     LOWER, K, prior=np.array([0.0, 0.0, -1.0]))
    assert sol.flag == IkFlag.MISSING


def standing_person() -> np.ndarray:
    """The 10 parts (PARTS_10 order) of a person facing the camera at 2.5 m, arms bent."""
    p = {
        'neck': [0.0, -0.45, 2.5], 'head': [0.0, -0.65, 2.5],
        'left_shoulder': [0.18, -0.42, 2.5], 'right_shoulder': [-0.18, -0.42, 2.5],
        'left_wrist': [0.25, -0.1, 2.25], 'right_wrist': [-0.25, -0.1, 2.25],
        'left_hip': [0.1, 0.05, 2.5], 'right_hip': [-0.1, 0.05, 2.5],
        'left_ankle': [0.12, 0.85, 2.45], 'right_ankle': [-0.12, 0.85, 2.45],
    }
    return np.array([p[n] for n in PARTS_10.names])


def test_body_frame_of_a_person_facing_the_camera() -> None:
    pts = dict(zip(PARTS_10.names, standing_person(), strict=True))
    frame = body_frame(pts['left_shoulder'], pts['right_shoulder'], pts['left_hip'],
                       pts['right_hip'])
    assert_allclose(frame, np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]]).T, atol=0.05)
    nan = np.full(3, np.nan)
    assert_allclose(body_frame(nan, nan, nan, nan), np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_infer_middle_joints_frame() -> None:
    pts = standing_person()
    pts[PARTS_10.index('right_ankle')] = np.nan
    res = infer_middle_joints(None, pts, K, DEFAULT_LIMB_LENGTHS_M)
    assert res.names == ('left_elbow', 'right_elbow', 'left_knee', 'right_knee')
    assert res.positions.shape == (4, 3) and res.pixels.shape == (4, 2)
    assert res.flags[3] == IkFlag.MISSING and np.isnan(res.positions[3]).all()
    valid = res.flags != IkFlag.MISSING
    assert np.isfinite(res.positions[valid]).all() and np.isfinite(res.pixels[valid]).all()
    # Elbows hang below the shoulder-wrist line, towards their own side.
    for k, side in ((0, 1.0), (1, -1.0)):
        shoulder = pts[PARTS_10.index(('left' if side > 0 else 'right') + '_shoulder')]
        assert res.positions[k][1] > shoulder[1]
        assert side * (res.positions[k][0] - shoulder[0]) > -0.05


def test_infer_middle_joints_refuses_bad_input() -> None:
    with pytest.raises(ValueError, match='shape'):
        infer_middle_joints(None, np.zeros((9, 3)), K, DEFAULT_LIMB_LENGTHS_M)
    with pytest.raises(ValueError, match='left_wrist'):
        infer_middle_joints(None, np.zeros((2, 3)), K, DEFAULT_LIMB_LENGTHS_M,
                            names=('left_shoulder', 'neck'))
    with pytest.raises(ValueError, match='intrinsics'):
        solve_limb(np.zeros((240, 320)), np.array([0, 0, 2.0]), np.array([0, 0.4, 2.0]),
                   UPPER, LOWER, None, prior=np.ones(3))


def _median_window(depth, uv, radius, mask):
    """A plain per-pixel reference of `robust_depth`."""
    h, w = depth.shape
    out = np.full(len(uv), np.nan)
    for i, (u, v) in enumerate(uv):
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        c, r = int(round(u)), int(round(v))
        if not (0 <= c < w and 0 <= r < h):
            continue
        win = depth[max(r - radius, 0):r + radius + 1, max(c - radius, 0):c + radius + 1]
        ok = np.isfinite(win) & (win > 0)
        if mask is not None:
            ok &= mask[max(r - radius, 0):r + radius + 1, max(c - radius, 0):c + radius + 1]
        if ok.any():
            out[i] = np.median(win[ok])
    return out


@pytest.mark.parametrize('use_mask', [False, True])
def test_robust_depth_matches_a_per_pixel_median(use_mask: bool) -> None:
    rng = np.random.default_rng(4)
    depth = rng.uniform(1.0, 3.0, (40, 50)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    depth[10:20, 10:20] = np.nan  # a hole bigger than the window
    mask = rng.random(depth.shape) < 0.7 if use_mask else None
    uv = np.concatenate([rng.uniform(-3, 53, (200, 2)), [[np.nan, 4.0], [15.0, 15.0],
                                                         [0.0, 0.0], [49.4, 39.5]]])
    got = robust_depth(depth, uv, radius=2, mask=mask)
    assert_allclose(got, _median_window(depth, uv, 2, mask), rtol=1e-6)
    assert np.isnan(got[-3]) and np.isfinite(got).sum() > 100  # not vacuous



def test_robust_depth_quantiles_and_per_pixel_windows() -> None:
    rng = np.random.default_rng(6)
    depth = rng.uniform(1.0, 3.0, (40, 50)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = np.nan
    uv = rng.uniform(3, [46, 36], (50, 2))
    radius = rng.integers(0, 6, len(uv))
    q = rng.uniform(0, 1, len(uv))
    got = robust_depth(depth, uv, radius=radius, quantile=q)
    want = []
    for (u, v), r, qi in zip(uv, radius, q, strict=True):
        c, w = int(np.rint(u)), int(np.rint(v))
        win = depth[max(w - r, 0):w + r + 1, max(c - r, 0):c + r + 1]
        win = win[np.isfinite(win)]
        want.append(np.quantile(win.astype(np.float64), qi) if len(win) else np.nan)
    assert_allclose(got, want, rtol=1e-6)
    assert np.isfinite(got).sum() > 40
    # 0.5 is the median (numpy's, in the image's dtype), 1 the farthest
    assert_allclose(robust_depth(depth, uv, radius=3, quantile=0.5), robust_depth(depth, uv))
    assert_allclose(robust_depth(depth, uv, radius=3, quantile=1.0),
                    [np.nanmax(depth[max(int(np.rint(v)) - 3, 0):int(np.rint(v)) + 4,
                                     max(int(np.rint(u)) - 3, 0):int(np.rint(u)) + 4])
                     for u, v in uv], rtol=1e-6)
    with pytest.raises(ValueError, match='quantile'):
        robust_depth(depth, uv, quantile=1.5)
    with pytest.raises(ValueError, match='radius'):
        robust_depth(depth, uv, radius=-1)


def test_lift_depth_finds_the_torso_behind_an_arm_at_any_distance() -> None:
    """A forearm 25 cm in front of the torso covers the shoulder's pixel: the median of a small
    window reads the arm; the 0.9 quantile of a window 8 cm wide on the body reads the torso,
    at 2 m and at 4 m, in a 320x240 and a 640x480 image alike."""
    for width, dist in ((320, 2.0), (320, 4.0), (640, 2.0), (640, 4.0)):
        intr = cad60_intrinsics(width, width * 3 // 4)
        depth = np.full((intr.height, intr.width), dist, np.float32)
        col, row = intr.width // 2, intr.height // 2
        arm = max(1, round(0.03 * intr.fx / dist))  # an arm 6 cm wide across the shoulder
        depth[:, col - arm:col + arm + 1] = dist - 0.25
        uv = np.array([[col, row]], float)
        assert robust_depth(depth, uv, radius=3)[0] == pytest.approx(dist - 0.25)
        assert lift_depth(depth, uv, intr, 0.08, 0.9)[0] == pytest.approx(dist)
        assert lift_depth(depth, uv, intr, 0.08, 0.5)[0] == pytest.approx(dist)  # most: torso
        assert lift_depth(depth, uv, intr, 0.03, 0.5)[0] == pytest.approx(dist - 0.25)
    assert np.isnan(lift_depth(np.full((240, 320), np.nan, np.float32), uv[:1] * 0 + 5,
                               cad60_intrinsics(), 0.08, 0.9)[0])

def test_limb_lengths_learn_and_fall_back() -> None:
    rng = np.random.default_rng(5)
    lengths = LimbLengths(min_samples=10)
    assert lengths.lengths('left_arm') == DEFAULT_LIMB_LENGTHS_M['left_arm']
    for _ in range(50):  # a 14-part detector sees the elbow: bone lengths ~ (0.3, 0.2)
        root, mid, end = random_limb(rng, [0, 0, 2], 0.3, 0.2)
        noise = rng.normal(0, 0.005, (3, 3))
        lengths.observe('left_arm', root + noise[0], mid + noise[1], end + noise[2])
    assert_allclose(lengths.lengths('left_arm'), (0.3, 0.2), atol=0.005)
    # Only root-end distances: the longest reach, split like the defaults.
    for d in np.linspace(0.5, 0.9, 40):
        lengths.observe('right_leg', np.zeros(3), None, np.array([0.0, d, 0.0]))
    a, b = lengths.lengths('right_leg')
    da, db = DEFAULT_LIMB_LENGTHS_M['right_leg']
    assert_allclose(a + b, np.percentile(np.linspace(0.5, 0.9, 40), 95))
    assert_allclose(a / b, da / db)
    lengths.observe('left_leg', np.full(3, np.nan), None, np.zeros(3))  # ignored
    assert lengths.lengths('left_leg') == DEFAULT_LIMB_LENGTHS_M['left_leg']
    with pytest.raises(ValueError):
        lengths.lengths('tail')


def test_limb_lengths_keep_the_last_window() -> None:
    """The rings hold the last `window` observations: the learned bones follow a limb whose
    lengths changed once the old ones have left the window, a frame at a time or many."""
    one, many = LimbLengths(window=7, min_samples=3), LimbLengths(window=7, min_samples=3)
    root, ends = np.zeros(3), []
    for k in range(20):
        upper, lower = (0.30, 0.25) if k < 13 else (0.20, 0.15)
        mid, end = np.array([0.0, upper, 0.0]), np.array([0.0, upper + lower, 0.0])
        one.observe('left_arm', root, mid, end)
        ends.append((mid, end))
    mids, tips = (np.array(a) for a in zip(*ends, strict=True))
    many.observe_many('left_arm', np.zeros((20, 3)), mids, tips)
    for learner in (one, many):
        assert_allclose(learner.lengths('left_arm'), (0.20, 0.15))
        assert_allclose(learner.as_dict()['left_arm'], (0.20, 0.15))
    one.observe('left_arm', root, np.array([0.0, 0.3, 0.0]), np.array([0.0, 0.55, 0.0]))
    assert_allclose(one.lengths('left_arm'), (0.20, 0.15))  # 6 of the last 7 still short


def test_circle_points_are_on_the_circle() -> None:
    circle = middle_joint_circle(np.array([0.0, 0.0, 2.0]), np.array([0.3, 0.2, 2.1]),
                                 UPPER, LOWER)
    pts = circle_points(circle, np.array([0.0, 0.0, -1.0]), np.linspace(-3, 3, 13))
    assert_allclose(np.linalg.norm(pts - circle.centre, axis=1), circle.radius)
    assert_allclose((pts - circle.centre) @ circle.axis, 0.0, atol=1e-12)


@pytest.mark.parametrize('kwargs', [{'n_candidates': 2}, {'arm_prior': (0, 0, 0)},
                                    {'length_scales': ()}, {'prior_shrink': (1.5, 1.0)}])
def test_bad_ik_config_is_refused(kwargs) -> None:
    with pytest.raises(ValueError):
        IkConfig(**kwargs)
