"""The paper's Denavit-Hartenberg limbs: elbows and knees by the IK of a 4-joint chain.

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", eqs. (17)-(24). Each limb (2 arms, 2 legs)
is a serial chain (eq. 17): three revolute joints at the root (shoulder / hip), one at the middle
(elbow / knee), links of the learned bone lengths ``l1`` (upper) and ``l2`` (lower). Classic DH
convention, ``T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``:

====  ===================  =====  =====  =========
i     theta_i              d_i    a_i    alpha_i
====  ===================  =====  =====  =========
1     q1                   0      0      -pi/2
2     q2                   0      0      +pi/2
3     q3                   l1     0      +pi/2
4     q4 + pi/2            0      l2     0
====  ===================  =====  =====  =========

Frame 0 sits at the root with axes (forward, right, down) of the person (`kinematics.body_frame`,
camera optical frame, metres). Then the upper bone points along ``z2 = (cos q1 sin q2, sin q1
sin q2, cos q2)`` in frame 0: q2 lifts it from hanging straight down, q1 turns it from the forward
half-plane towards the body's right; q3 turns the limb about its upper bone (humeral / femoral
rotation) and q4 is the flexion of the middle joint (0 = straight; the lower bone bends towards
``-x3``). The end (wrist / ankle) is the origin of frame 4.

Inverse kinematics (eqs. 18-24). Given root R, end E and the lengths, q4 follows from the law of
cosines, ``|E - R|^2 = l1^2 + l2^2 + 2 l1 l2 cos q4``; the rest of the chain turns the plane of
the limb about the axis R->E by a free swivel angle, which the paper fixes through the end
effector's orientation. A part detector does not measure that orientation, so the swivel is
chosen exactly as `kinematics.solve_limb` chooses it (the depth image, the joint-limit prior as
fallback): the two solvers differ only in the formulation that follows. Here the swivel (angle
about R->E from the prior's direction) and q4 are clamped to joint limits (`DhLimits`), q1-q3
are solved from the clamped configuration, and the elbow / knee is the forward kinematics of the
chain: the bones keep the learned lengths exactly (the geometric solver's depth search may
stretch them by `IkConfig.length_scales`), and a target out of reach (or too close for the
flexion limit) leaves the limb pointing at it with the end short of it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, project
from pose4d_ros.core.kinematics import (
    Circle,
    IkConfig,
    IkFlag,
    IkResult,
    body_frame,
    circle_points,
    ik_inputs,
    middle_joint_circle,
    prior_direction,
    solve_limb,
)
from pose4d_ros.core.limb_lengths import LimbLengths
from pose4d_ros.core.skeleton import LIMBS, PARTS_10

# DH parameters (d, a, alpha) of joints 1-4 in units of (l1, l2); theta_4 carries a +pi/2 offset.
_ALPHA = (-math.pi / 2, math.pi / 2, math.pi / 2, 0.0)
_IK_CONFIG = IkConfig()  # the default of `config` (the swivel's choice)


@dataclass(frozen=True)
class DhLimits:
    """Joint limits of the DH limbs, radians.

    Attributes
    ----------
    arm_flexion, leg_flexion : (min, max) q4 of the elbow / knee (0 = straight).
    arm_swivel, leg_swivel : (min, max) swivel of the limb's plane about root->end, from the
        joint-limit prior's direction (`kinematics.prior_direction`, swivel 0); (-pi, pi) = no
        limit.
    """

    arm_flexion: tuple[float, float] = (0.0, math.radians(150.0))
    leg_flexion: tuple[float, float] = (0.0, math.radians(150.0))
    arm_swivel: tuple[float, float] = (-math.pi, math.pi)
    leg_swivel: tuple[float, float] = (-math.pi, math.pi)

    def __post_init__(self) -> None:
        for name in ('arm_flexion', 'leg_flexion'):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi <= math.pi:
                raise ValueError(f'{name} must be 0 <= min <= max <= pi radians, got {lo}, {hi}')
        for name in ('arm_swivel', 'leg_swivel'):
            lo, hi = getattr(self, name)
            if not -math.pi <= lo <= hi <= math.pi:
                raise ValueError(f'{name} must be -pi <= min <= max <= pi radians, got '
                                 f'{lo}, {hi}')


def dh_transform(theta: float, d: float, a: float, alpha: float) -> NDArray[np.float64]:
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha)``: (4, 4) float64 homogeneous transform (eq. 17)."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct],
                     [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def base_frame(frame: NDArray[np.floating]) -> NDArray[np.float64]:
    """Frame 0's rotation in the camera frame, (3, 3) columns (forward, right, down), from
    `kinematics.body_frame`'s (left, up, forward)."""
    f = np.asarray(frame, dtype=np.float64)
    return np.stack([f[:, 2], -f[:, 0], -f[:, 1]], axis=1)


def forward_kinematics(angles: NDArray[np.floating], upper: float, lower: float, *,
                       root: NDArray[np.floating] | None = None,
                       base: NDArray[np.floating] | None = None) -> NDArray[np.float64]:
    """Frames of the DH chain: (5, 4, 4) float64 transforms of frames 0-4 in the camera frame.

    Parameters
    ----------
    angles : (4,) q1-q4, radians.
    upper, lower : l1, l2, metres.
    root : (3,) frame 0's origin, metres, camera optical frame (default 0).
    base : (3, 3) frame 0's rotation (`base_frame`; default identity).

    The middle joint is ``out[3, :3, 3]``, the end ``out[4, :3, 3]``.
    """
    q = np.asarray(angles, dtype=np.float64).reshape(4)
    t = np.eye(4)
    if base is not None:
        t[:3, :3] = base
    if root is not None:
        t[:3, 3] = np.asarray(root, dtype=np.float64).reshape(3)
    params = ((q[0], 0.0, 0.0), (q[1], 0.0, 0.0), (q[2], upper, 0.0),
              (q[3] + math.pi / 2, 0.0, lower))
    out = [t]
    for (theta, d, a), alpha in zip(params, _ALPHA, strict=True):
        out.append(out[-1] @ dh_transform(theta, d, a, alpha))
    return np.stack(out)


def chain_angles(root: NDArray[np.floating], middle: NDArray[np.floating],
                 end: NDArray[np.floating], base: NDArray[np.floating], *,
                 bend: NDArray[np.floating] | None = None) -> NDArray[np.float64]:
    """q1-q4 (radians) of the chain through root, middle and end (metres, camera frame).

    The bones' lengths are |middle - root| and |end - middle|; `bend` (3,) (camera frame) is
    the direction the limb would bend to when straight (q3 is otherwise undefined).
    """
    b = np.asarray(base, dtype=np.float64)
    up_vec = b.T @ (np.asarray(middle, float) - np.asarray(root, float))
    lo_vec = b.T @ (np.asarray(end, float) - np.asarray(middle, float))
    z2 = up_vec / max(float(np.linalg.norm(up_vec)), 1e-12)
    q2 = math.acos(min(max(float(z2[2]), -1.0), 1.0))
    q1 = math.atan2(float(z2[1]), float(z2[0])) if math.sin(q2) > 1e-12 else 0.0
    r2 = forward_kinematics(np.array([q1, q2, 0.0, 0.0]), 1.0, 1.0)[2, :3, :3]
    f2 = r2.T @ (lo_vec / max(float(np.linalg.norm(lo_vec)), 1e-12))
    q4 = math.atan2(math.hypot(float(f2[0]), float(f2[1])), float(f2[2]))
    if math.hypot(float(f2[0]), float(f2[1])) > 1e-9:
        q3 = math.atan2(-float(f2[1]), -float(f2[0]))
    else:  # straight: q3 turns nothing; point the bend (-x3) at `bend`
        g = r2.T @ (b.T @ np.asarray(bend if bend is not None else b[:, 0], float))
        q3 = math.atan2(-float(g[1]), -float(g[0])) if math.hypot(g[0], g[1]) > 1e-12 else 0.0
    return np.array([q1, q2, q3, q4])


@dataclass(frozen=True)
class DhSolution:
    """One middle joint by the DH chain.

    Attributes
    ----------
    position : (3,) float64 metres, camera optical frame (the chain's frame 3); NaN when
        MISSING/BEHIND_CAMERA.
    pixel : (2,) float64 pixel (u, v); NaN when unknown or without intrinsics.
    confidence : 0..1 (the swivel's, as `kinematics.solve_limb`'s).
    flag : `IkFlag`.
    angles : (4,) float64 q1-q4, radians, within the limits; NaN when not solved.
    end : (3,) float64 metres, the chain's end (frame 4): the wrist/ankle given, unless out of
        reach or beyond the flexion limit.
    swivel : the limb plane's angle about root->end from the prior's direction, radians.
    """

    position: NDArray[np.float64]
    pixel: NDArray[np.float64]
    confidence: float
    flag: IkFlag
    angles: NDArray[np.float64]
    end: NDArray[np.float64]
    swivel: float


def _nan(flag: IkFlag) -> DhSolution:
    return DhSolution(np.full(3, np.nan), np.full(2, np.nan), 0.0, flag, np.full(4, np.nan),
                      np.full(3, np.nan), math.nan)


def swivel_of(point: NDArray[np.floating], root: NDArray[np.floating],
              end: NDArray[np.floating], reference: NDArray[np.floating]) -> float:
    """The angle (radians, (-pi, pi]) of `point` about the axis root->end, 0 in the direction of
    `reference` (`kinematics.circle_points`' convention)."""
    r0, e0 = np.asarray(root, float), np.asarray(end, float)
    circle = middle_joint_circle(r0, e0, 1.0, 1.0)
    u, w = _plane(circle.axis, reference)
    d = np.asarray(point, float) - r0
    return math.atan2(float(d @ w), float(d @ u))


def _plane(axis: NDArray[np.float64], reference: NDArray[np.floating]
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, w): the unit vectors at swivel 0 and pi/2 of `circle_points` about `axis`."""
    unit = Circle(np.zeros(3), axis, 1.0, 0.0)
    u, w = circle_points(unit, np.asarray(reference, float), np.array([0.0, math.pi / 2]))
    return u, w


def place_chain(root: NDArray[np.floating], end: NDArray[np.floating], upper: float,
                lower: float, swivel: float, *, reference: NDArray[np.floating],
                base: NDArray[np.floating], flexion: tuple[float, float] = (0.0, math.pi)
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The chain from `root` towards `end` with its plane at `swivel` (radians from
    `reference`'s direction) and the flexion q4 clamped to `flexion`.

    Returns (angles (4,), middle (3,), end (3,)): q1-q4 (radians) and the forward kinematics'
    middle joint and end, metres, camera frame. Within reach and limits, the end is `end`.
    """
    r0, e0 = np.asarray(root, float), np.asarray(end, float)
    dist = float(np.linalg.norm(e0 - r0))
    cos_q4 = (dist * dist - upper * upper - lower * lower) / (2.0 * upper * lower)
    q4 = min(max(math.acos(min(max(cos_q4, -1.0), 1.0)), flexion[0]), flexion[1])
    reach = math.sqrt(max(upper * upper + lower * lower + 2.0 * upper * lower * math.cos(q4),
                          0.0))
    n = (e0 - r0) / dist if dist > 1e-12 else np.asarray(base, float)[:, 2]
    u, w = _plane(n, reference)
    cos_b = ((upper * upper + reach * reach - lower * lower) / (2.0 * upper * reach)
             if reach > 1e-12 else 1.0)
    cos_b = min(max(cos_b, -1.0), 1.0)  # the angle at the root between upper bone and R->E
    sin_b = math.sqrt(1.0 - cos_b * cos_b)
    radial = math.cos(swivel) * u + math.sin(swivel) * w
    middle = r0 + upper * (cos_b * n + sin_b * radial)
    target = r0 + reach * n
    angles = chain_angles(r0, middle, target, base, bend=radial)
    frames = forward_kinematics(angles, upper, lower, root=r0, base=base)
    return angles, frames[3, :3, 3], frames[4, :3, 3]


def solve_limb_dh(depth_m: NDArray[np.floating] | None, root: NDArray[np.floating],
                  end: NDArray[np.floating], upper: float, lower: float,
                  intrinsics: Intrinsics | None, *, prior: NDArray[np.floating],
                  frame: NDArray[np.floating], kind: str = 'arm',
                  mask: NDArray[np.bool_] | None = None, config: IkConfig = _IK_CONFIG,
                  limits: DhLimits = DhLimits(), swivel: float | None = None) -> DhSolution:
    """Infer one elbow or knee with the DH chain (see the module docstring).

    Parameters
    ----------
    depth_m, root, end, upper, lower, intrinsics, prior, kind, mask, config : as
        `kinematics.solve_limb` (which chooses the swivel).
    frame : (3, 3) `kinematics.body_frame` of the person (frame 0 of the chain).
    limits : joint limits.
    swivel : use this swivel (radians from `prior`'s direction) instead of choosing one.
    """
    r0 = np.asarray(root, dtype=np.float64).reshape(3)
    e0 = np.asarray(end, dtype=np.float64).reshape(3)
    geo = solve_limb(depth_m, r0, e0, upper, lower, intrinsics, prior=prior, kind=kind,
                     mask=mask, config=config)
    if geo.flag in (IkFlag.MISSING, IkFlag.BEHIND_CAMERA):
        return _nan(geo.flag)
    ref = np.asarray(prior, dtype=np.float64).reshape(3)
    if swivel is None:
        dist = float(np.linalg.norm(e0 - r0))
        radial = geo.position - r0 - float((geo.position - r0) @ (e0 - r0)) / max(
            dist * dist, 1e-24) * (e0 - r0)
        swivel = (swivel_of(geo.position, r0, e0, ref)
                  if float(np.linalg.norm(radial)) > 1e-9 else 0.0)
    lo, hi = limits.arm_swivel if kind == 'arm' else limits.leg_swivel
    swivel = min(max(float(swivel), lo), hi)
    flexion = limits.arm_flexion if kind == 'arm' else limits.leg_flexion
    angles, middle, tip = place_chain(r0, e0, upper, lower, swivel, reference=ref,
                                      base=base_frame(frame), flexion=flexion)
    if not middle[2] > 0:
        return _nan(IkFlag.BEHIND_CAMERA)
    uv = np.full(2, np.nan) if intrinsics is None else project(middle[None], intrinsics)[0]
    return DhSolution(middle, uv, geo.confidence, geo.flag, angles, tip, swivel)


@dataclass(frozen=True)
class DhResult(IkResult):
    """`kinematics.IkResult` with the chains' joint angles and ends.

    Attributes
    ----------
    angles : (n, 4) float64 q1-q4 per limb, radians; NaN when not solved.
    ends : (n, 3) float64 the chains' ends (wrist / ankle), metres, camera optical frame.
    """

    angles: NDArray[np.float64]
    ends: NDArray[np.float64]


def infer_middle_joints_dh(depth_m: NDArray[np.floating] | None, points: NDArray[np.floating],
                           intrinsics: Intrinsics | None,
                           lengths: LimbLengths | Mapping[str, tuple[float, float]], *,
                           names: Sequence[str] = PARTS_10.names,
                           mask: NDArray[np.bool_] | None = None,
                           config: IkConfig = _IK_CONFIG, limits: DhLimits = DhLimits(),
                           limbs: Sequence[str] | None = None) -> DhResult:
    """Both elbows and both knees of one frame by the DH chains: the arguments and the result
    as `kinematics.infer_middle_joints`, plus `limits` and the joint angles."""
    pts, depth_m, index = ik_inputs(points, depth_m, names, mask)

    def get(name: str) -> NDArray[np.float64]:
        return pts[index[name]] if name in index else np.full(3, np.nan)

    frame = body_frame(get('left_shoulder'), get('right_shoulder'), get('left_hip'),
                       get('right_hip'))
    solved = {limb: joints for limb, joints in LIMBS.items() if limbs is None or limb in limbs}
    sols = []
    for limb, (a, _, b) in solved.items():
        upper, lower = (lengths.lengths(limb) if isinstance(lengths, LimbLengths)
                        else lengths[limb])
        sols.append(solve_limb_dh(depth_m, get(a), get(b), upper, lower, intrinsics,
                                  prior=prior_direction(limb, frame, config), frame=frame,
                                  kind='arm' if limb.endswith('arm') else 'leg', mask=mask,
                                  config=config, limits=limits))
    return DhResult(
        names=tuple(m for _, m, _ in solved.values()),
        positions=np.array([s.position for s in sols], np.float64).reshape(-1, 3),
        pixels=np.array([s.pixel for s in sols], np.float64).reshape(-1, 2),
        confidence=np.array([s.confidence for s in sols], np.float32),
        flags=np.array([s.flag for s in sols], np.uint8),
        angles=np.array([s.angles for s in sols], np.float64).reshape(-1, 4),
        ends=np.array([s.end for s in sols], np.float64).reshape(-1, 3))
