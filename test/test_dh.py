"""The paper's Denavit-Hartenberg limbs (core/dh.py) and `IkStage(method='dh')`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros.core import dh
from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.kinematics import (
    IkFlag,
    body_frame,
    circle_points,
    infer_middle_joints,
    middle_joint_circle,
    prior_direction,
    solve_limb,
)
from pose4d_ros.core.skeleton import PARTS_10

INTR = cad60_intrinsics()
# a person 2.8 m ahead, facing the camera (optical frame: x right, y down, z forward)
LS, RS = np.array([0.2, -0.4, 2.8]), np.array([-0.2, -0.4, 2.8])
LH, RH = np.array([0.1, 0.1, 2.8]), np.array([-0.1, 0.1, 2.8])
FRAME = body_frame(LS, RS, LH, RH)


def _targets(rng: np.random.Generator, n: int, upper: float, lower: float
             ) -> list[np.ndarray]:
    """Ends within reach of a root at LS and not closer than the flexion limit allows."""
    out = []
    near = math.sqrt(upper ** 2 + lower ** 2 + 2 * upper * lower * math.cos(math.radians(150)))
    while len(out) < n:
        d = rng.normal(size=3)
        dist = rng.uniform(near + 1e-3, upper + lower - 1e-3)
        out.append(LS + dist * d / np.linalg.norm(d))
    return out


def test_dh_transform_is_a_rigid_motion() -> None:
    t = dh.dh_transform(0.3, 0.2, 0.1, -0.7)
    assert_allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-12)
    assert_allclose(t[3], [0, 0, 0, 1])
    assert np.isclose(np.linalg.det(t[:3, :3]), 1.0)


def test_zero_angles_hang_the_limb_straight_down() -> None:
    base = dh.base_frame(FRAME)
    frames = dh.forward_kinematics(np.zeros(4), 0.3, 0.25, root=LS, base=base)
    down = -FRAME[:, 1]
    assert_allclose(frames[3, :3, 3], LS + 0.3 * down, atol=1e-12)
    assert_allclose(frames[4, :3, 3], LS + 0.55 * down, atol=1e-12)


@pytest.mark.parametrize('kind, upper, lower', [('arm', 0.28, 0.25), ('leg', 0.42, 0.40)])
def test_forward_kinematics_of_the_solved_angles_reaches_the_end(kind: str, upper: float,
                                                                 lower: float) -> None:
    rng = np.random.default_rng(0)
    limb = f'left_{kind}'
    prior = prior_direction(limb, FRAME)
    limits = dh.DhLimits()
    for end in _targets(rng, 100, upper, lower):
        sol = dh.solve_limb_dh(None, LS, end, upper, lower, INTR, prior=prior, frame=FRAME,
                               kind=kind, limits=limits)
        assert sol.flag == IkFlag.PRIOR
        frames = dh.forward_kinematics(sol.angles, upper, lower, root=LS,
                                       base=dh.base_frame(FRAME))
        assert_allclose(frames[4, :3, 3], end, atol=1e-9)  # the wrist/ankle, exactly
        assert_allclose(frames[3, :3, 3], sol.position, atol=1e-12)
        assert np.isclose(np.linalg.norm(sol.position - LS), upper, atol=1e-9)
        assert np.isclose(np.linalg.norm(end - sol.position), lower, atol=1e-9)
        lo, hi = limits.arm_flexion if kind == 'arm' else limits.leg_flexion
        assert lo - 1e-12 <= sol.angles[3] <= hi + 1e-12
        assert_allclose(dh.chain_angles(LS, sol.position, end, dh.base_frame(FRAME)),
                        sol.angles, atol=1e-9)


def test_agrees_with_the_geometric_elbow_at_the_same_swivel() -> None:
    rng = np.random.default_rng(1)
    upper, lower = 0.28, 0.25
    prior = prior_direction('left_arm', FRAME)
    for end in _targets(rng, 50, upper, lower):
        swivel = rng.uniform(-math.pi, math.pi)
        geometric = circle_points(middle_joint_circle(LS, end, upper, lower), prior,
                                  np.array([swivel]))[0]
        sol = dh.solve_limb_dh(None, LS, end, upper, lower, INTR, prior=prior, frame=FRAME,
                               swivel=swivel)
        assert_allclose(sol.position, geometric, atol=1e-9)
        # and without a swivel given, the prior's choice is the geometric solver's
        free = dh.solve_limb_dh(None, LS, end, upper, lower, INTR, prior=prior, frame=FRAME)
        geo = solve_limb(None, LS, end, upper, lower, INTR, prior=prior)
        assert_allclose(free.position, geo.position, atol=1e-9)
        assert free.flag == geo.flag and free.confidence == geo.confidence


def test_limits_hold_out_of_reach_and_too_close() -> None:
    upper, lower = 0.3, 0.25
    prior = prior_direction('left_arm', FRAME)
    base = dh.base_frame(FRAME)
    far = LS + np.array([0.0, 0.8, 0.0])
    sol = dh.solve_limb_dh(None, LS, far, upper, lower, INTR, prior=prior, frame=FRAME)
    assert sol.flag == IkFlag.UNREACHABLE and abs(sol.angles[3]) < 1e-9  # straight
    assert_allclose(sol.position, LS + upper * (far - LS) / 0.8, atol=1e-9)  # rigid bones
    assert_allclose(sol.end, LS + (upper + lower) * (far - LS) / 0.8, atol=1e-9)
    near = LS + np.array([0.0, 0.06, 0.0])
    sol = dh.solve_limb_dh(None, LS, near, upper, lower, INTR, prior=prior, frame=FRAME)
    assert np.isclose(sol.angles[3], math.radians(150.0))  # the flexion limit
    frames = dh.forward_kinematics(sol.angles, upper, lower, root=LS, base=base)
    assert np.isclose(np.linalg.norm(frames[3, :3, 3] - LS), upper)
    # a swivel limit keeps the plane within it
    limits = dh.DhLimits(arm_swivel=(-0.5, 0.5))
    end = LS + np.array([0.1, 0.3, -0.1])
    sol = dh.solve_limb_dh(None, LS, end, upper, lower, INTR, prior=prior, frame=FRAME,
                           limits=limits, swivel=2.0)
    assert sol.swivel == 0.5
    assert np.isclose(dh.swivel_of(sol.position, LS, end, prior), 0.5)


def test_bad_limits_and_missing_joints() -> None:
    with pytest.raises(ValueError, match='arm_flexion'):
        dh.DhLimits(arm_flexion=(0.5, 0.1))
    with pytest.raises(ValueError, match='leg_swivel'):
        dh.DhLimits(leg_swivel=(-4.0, 0.0))
    prior = prior_direction('left_arm', FRAME)
    sol = dh.solve_limb_dh(None, LS, np.full(3, np.nan), 0.3, 0.25, INTR, prior=prior,
                           frame=FRAME)
    assert sol.flag == IkFlag.MISSING and np.isnan(sol.position).all()
    assert np.isnan(sol.angles).all()


def test_infer_middle_joints_dh_matches_the_geometric_solver_without_depth() -> None:
    rng = np.random.default_rng(2)
    names = PARTS_10.names
    pts = np.full((len(names), 3), np.nan)
    base = {'left_shoulder': LS, 'right_shoulder': RS, 'left_hip': LH, 'right_hip': RH,
            'head': np.array([0.0, -0.7, 2.8]), 'neck': np.array([0.0, -0.45, 2.8]),
            'left_wrist': np.array([0.35, -0.1, 2.7]), 'right_wrist': np.array([-0.3, 0.0, 2.6]),
            'left_ankle': np.array([0.12, 0.9, 2.75]), 'right_ankle': np.array([-0.15, 0.88, 2.9])}
    for n, p in base.items():
        pts[names.index(n)] = p + rng.normal(0, 0.01, 3)
    lengths = {'left_arm': (0.28, 0.25), 'right_arm': (0.28, 0.25), 'left_leg': (0.42, 0.40),
               'right_leg': (0.42, 0.40)}
    geo = infer_middle_joints(None, pts, INTR, lengths, names=names)
    res = dh.infer_middle_joints_dh(None, pts, INTR, lengths, names=names)
    assert res.names == geo.names
    assert_allclose(res.positions, geo.positions, atol=1e-9)
    assert_allclose(res.pixels, geo.pixels, atol=1e-6)
    assert (res.flags == geo.flags).all() and res.angles.shape == (4, 4)
    for k, b in enumerate(('left_wrist', 'right_wrist', 'left_ankle', 'right_ankle')):
        if res.flags[k] != IkFlag.UNREACHABLE:
            assert_allclose(res.ends[k], pts[names.index(b)], atol=1e-9)


def test_ik_stage_dh_method() -> None:
    from pose4d_ros.core import joints as cj
    from pose4d_ros.core.camera import project
    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.core.stages import IkStage

    names = ('left_shoulder', 'right_shoulder', 'left_wrist', 'right_wrist', 'left_hip',
             'right_hip', 'left_ankle', 'right_ankle')
    xyz = np.array([LS, RS, [0.35, -0.1, 2.7], [-0.3, 0.0, 2.6], LH, RH, [0.12, 0.9, 2.75],
                    [-0.15, 0.88, 2.9]])
    tracked = JointSet(names, project(xyz, INTR), xyz,
                       source=np.full(len(names), cj.DETECTED, np.uint8),
                       confidence=np.ones(len(names), np.float32))
    geo = IkStage(use_depth=False, learn=False).step(tracked, None, INTR)
    out = IkStage(use_depth=False, learn=False, method='dh').step(tracked, None, INTR)
    assert_allclose(out.xyz, geo.xyz, atol=1e-9)
    assert (out.source == geo.source).all()
    with pytest.raises(ValueError, match='IK method'):
        IkStage(method='fabrik')
