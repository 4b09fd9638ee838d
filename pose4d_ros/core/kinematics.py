"""Inverse kinematics of elbows and knees (the paper's Denavit-Hartenberg limbs).

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", eqs. (17)-(24). The reduced part model
detects shoulders, wrists, hips and ankles; elbows and knees are completed here, in 3-D, in the
camera optical frame (x right, y down, z forward, metres).

The paper writes each limb (2 arms, 2 legs) as a DH chain (eq. 17): three revolute joints at
the root (shoulder / hip), one at the middle (elbow / knee), then a fixed link to the end
(wrist / ankle). Completing the middle joint needs only that chain's geometry: two bones of
fixed lengths joined at the middle joint.

Inverse kinematics (eqs. 18-24)
-------------------------------
Given the root R and end E in 3-D and the bone lengths ``l1`` (upper) and ``l2`` (lower), the
middle joint lies on a circle about the axis R->E: with ``D = |E - R|`` and ``n = (E - R) / D``,
the law of cosines puts its centre at ``C = R + c n``, ``c = (D^2 + l1^2 - l2^2) / (2 D)``, radius
``sqrt(l1^2 - c^2)``. The paper fixes the position on the circle (the swivel angle) through the
end effector's orientation, which a part detector does not measure. Here the swivel is chosen
by the depth image: N candidate points on the circle, and points along the two bones they
imply, are projected into the depth image and compared with the measured robust depth (the
joint centre sits `surface_offset_m` behind the visible surface; a candidate in front of the
measured surface contradicts the free space the camera saw, one behind it would be hidden;
both are penalised). When depth is missing or does not discriminate, a joint-limit prior
decides: a preferred direction for the middle joint in the body frame (from shoulders and hips;
elbows bend down and back-out, knees forward). Targets out of reach (``D > l1 + l2``) put the
middle joint on the segment R->E at ``l1 / (l1 + l2)`` and are flagged UNREACHABLE.

Bone lengths come from parameters or are learned per track by `core.limb_lengths.LimbLengths`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pose4d_ros.core.camera import NO_MASK, Intrinsics, project, robust_depth_at
from pose4d_ros.core.limb_lengths import DEFAULT_LIMB_LENGTHS_M, LimbLengths  # noqa: F401 (nodes.ik)
from pose4d_ros.core.skeleton import LIMBS, PARTS_10


class IkFlag(IntEnum):
    """How a middle joint (elbow/knee) was obtained."""

    DEPTH = 0          # on the circle, swivel chosen by the depth image
    PRIOR = 1          # on the circle, swivel from the joint-limit prior
    UNREACHABLE = 2    # |end - root| out of reach: on the straight line, low confidence
    MISSING = 3        # root, end or a length unknown: NaN
    BEHIND_CAMERA = 4  # root or end with z <= 0: NaN


# ---------------------------------------------------------------------------------------------
# Body frame and the circle of the middle joint


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64] | None:
    n = math.sqrt(float(v @ v))  # np.linalg.norm's value (the same dot), without its wrapper
    return v / n if math.isfinite(n) and n > 1e-9 else None


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """np.cross of two 3-vectors, the same products and differences, without its wrapper."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


def body_frame(left_shoulder: NDArray[np.floating], right_shoulder: NDArray[np.floating],
               left_hip: NDArray[np.floating], right_hip: NDArray[np.floating]
               ) -> NDArray[np.float64]:
    """The person's frame from shoulders and hips, as a rotation in the camera frame.

    Parameters
    ----------
    left_shoulder, right_shoulder, left_hip, right_hip : (3,) metres, camera optical frame;
        NaN = unknown.

    Returns
    -------
    (3, 3) float64 with columns (left, up, forward): towards the person's left, from hips to
    shoulders, and the way the chest faces (left x up). Missing joints fall back on a person
    upright and facing the camera (left = +x, up = -y, forward = -z).
    """
    ls, rs, lh, rh = (np.asarray(p, dtype=np.float64) for p in
                      (left_shoulder, right_shoulder, left_hip, right_hip))
    left = _unit(ls - rs)
    if left is None:
        left = _unit(lh - rh)
    if left is None:
        left = np.array([1.0, 0.0, 0.0])
    up = _unit(0.5 * (ls + rs) - 0.5 * (lh + rh))
    if up is None:
        up = np.array([0.0, -1.0, 0.0])
    up = _unit(up - (up @ left) * left)
    if up is None:  # shoulders stacked vertically: keep a camera-upright guess
        up = _unit(np.array([0.0, -1.0, 0.0]) - (-left[1]) * left)
        if up is None:
            up = np.array([0.0, 0.0, -1.0])
    forward = _cross(left, up)
    frame = np.empty((3, 3))
    frame[:, 0], frame[:, 1], frame[:, 2] = left, up, forward
    return frame


@dataclass(frozen=True)
class Circle:
    """Where a middle joint can be: centre (3,), axis n (3,), radius, metres.

    `reach` is D / (upper + lower); > 1 means out of reach.
    """

    centre: NDArray[np.float64]
    axis: NDArray[np.float64]
    radius: float
    reach: float


def middle_joint_circle(root: NDArray[np.floating], end: NDArray[np.floating], upper: float,
                        lower: float) -> Circle:
    """The circle of middle-joint positions (law of cosines; eqs. 18-21).

    Out of reach (D > upper + lower) the circle degenerates to the point at ``upper / (upper +
    lower)`` of the segment; too close (D < |upper - lower|) the centre is clamped so that the
    middle joint stays `upper` from the root.
    """
    r0, e0 = np.asarray(root, dtype=np.float64), np.asarray(end, dtype=np.float64)
    if not (upper > 0 and lower > 0):
        raise ValueError(f'bone lengths must be positive metres, got {upper}, {lower}')
    centre, axis, radius = _circle(r0, e0, float(upper), float(lower))
    return Circle(centre, axis, radius, float(np.linalg.norm(e0 - r0)) / (upper + lower))


@njit(cache=True)
def _circle(r0: NDArray[np.float64], e0: NDArray[np.float64], upper: float, lower: float
            ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """`middle_joint_circle`'s centre, axis and radius."""
    v = e0 - r0
    dist = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if dist < 1e-9:
        return r0.copy(), np.array([0.0, 0.0, 1.0]), upper
    n = v / dist
    if dist >= upper + lower:
        return r0 + v * (upper / (upper + lower)), n, 0.0
    c = (dist * dist + upper * upper - lower * lower) / (2.0 * dist)
    c = min(max(c, -upper), upper)
    return r0 + c * n, n, math.sqrt(max(upper * upper - c * c, 0.0))


def circle_points(circle: Circle, reference: NDArray[np.floating], angles: NDArray[np.floating]
                  ) -> NDArray[np.float64]:
    """Points of the circle at swivel `angles` (radians) from the direction `reference`.

    Returns (N, 3) metres; angle 0 is the point closest to ``centre + reference``.
    """
    u, w = _plane_basis(circle.axis, np.asarray(reference, dtype=np.float64).reshape(3))
    return _circle_points(circle.centre, circle.radius, u, w,
                          np.asarray(angles, dtype=np.float64).reshape(-1))


@njit(cache=True)
def _circle_points(centre: NDArray[np.float64], radius: float, u: NDArray[np.float64],
                   w: NDArray[np.float64], angles: NDArray[np.float64]) -> NDArray[np.float64]:
    out = np.empty((len(angles), 3))
    for i in range(len(angles)):
        c, s = math.cos(angles[i]), math.sin(angles[i])
        for j in range(3):
            out[i, j] = centre[j] + radius * (c * u[j] + s * w[j])
    return out


@njit(cache=True)
def _plane_basis(axis: NDArray[np.float64], reference: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """An orthonormal (u, w) of the plane normal to `axis`, u as close to `reference` as can be
    (else to -z, else to +y: one of them is off a unit axis)."""
    refs = np.array([[reference[0], reference[1], reference[2]], [0.0, 0.0, -1.0],
                     [0.0, 1.0, 0.0]])
    u = refs[2] - refs[2] @ axis * axis
    for k in range(3):
        u = refs[k] - (refs[k] @ axis) * axis
        n = math.sqrt(u @ u)
        if math.isfinite(n) and n > 1e-9:
            break
    u = u / n
    return u, np.cross(axis, u)


# ---------------------------------------------------------------------------------------------
# Depth support


@dataclass(frozen=True)
class IkConfig:
    """Parameters of the middle-joint inference.

    The prior's directions (`arm_prior`, `leg_prior`) were fitted and the depth cost
    (`surface_offset_m`, `depth_scale_m`, `occluded_weight`, `unknown_cost`, `prior_weight`,
    `length_scales`, `scale_weight`) tuned on real Kinect motion of UTKinect subjects s01-s06
    (`evaluation.ik.fit_swivel_prior`, `tune_ik_depth`; depth from capsules around the
    recorded skeletons): what ``pose4d track-eval --tune --seed 0`` finds, rounded.

    Attributes
    ----------
    n_candidates : swivel angles sampled on the circle (coarse search).
    refine_steps : extra samples each side of the best coarse angle (fine search).
    bone_samples : points sampled inside each bone (besides the middle joint) for depth support.
    depth_radius_px : window half-size of the robust depth, pixels.
    surface_offset_m : (arm, leg) how far the joint centre and the bone axes lie behind the
        visible surface, metres (about the limb's radius).
    depth_scale_m : scale of the robust (Welsch) cost of a depth disagreement r,
        ``1 - exp(-r^2 / (2 scale^2))``: smooth near 0, saturating at 1 for outliers; metres.
    free_space_weight : cost of a sample in front of the measured surface (the camera saw past
        it), 0..1 per sample.
    occluded_weight : cost of a sample behind the measured surface (hidden or wrong), per sample.
    unknown_cost : cost of a sample without depth (hole, off-image), per sample.
    min_valid_fraction : below this fraction of samples with depth, the prior decides.
    ambiguity_margin : the depth decides only if its cost over the circle varies by more.
    prior_weight : weight of the prior's cost next to the depth's (breaks ties).
    length_scales : factors applied to both bone lengths to make the depth search's circles.
    scale_weight : cost per unit of |log(scale)| (prefers the given lengths).
    prior_shrink : (arm, leg) fraction of the radius at which the prior puts the joint (1 = on
        the circle, the default; less = the expected position under the swivel's uncertainty,
        closer on average but off the bone lengths; `evaluation.ik.SHRUNK_PRIOR` was
        fitted on Kinect skeletons).
    arm_prior, leg_prior : preferred direction of the elbow / knee from the circle's centre, as
        (outward, up, forward) coefficients in the body frame (outward = away from the body's
        midline on that limb's side).
    prior_angle_std_rad : swivel uncertainty assumed for the prior, for the confidence.
    confidence_scale_m : positional uncertainty at which the confidence is 1/e, metres.
    reach_tolerance : a target beyond reach by less than this fraction counts as straight.
    unreachable_confidence : confidence of an UNREACHABLE middle joint.
    """

    n_candidates: int = 36
    refine_steps: int = 4
    bone_samples: int = 3
    depth_radius_px: int = 2
    surface_offset_m: tuple[float, float] = (0.03, 0.05)
    depth_scale_m: float = 0.03
    free_space_weight: float = 1.0
    occluded_weight: float = 0.3
    unknown_cost: float = 0.5
    min_valid_fraction: float = 0.3
    ambiguity_margin: float = 0.05
    prior_weight: float = 0.15
    length_scales: tuple[float, ...] = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15)
    scale_weight: float = 0.1
    prior_shrink: tuple[float, float] = (1.0, 1.0)
    arm_prior: tuple[float, float, float] = (0.50, -0.82, -0.29)
    leg_prior: tuple[float, float, float] = (0.27, -0.22, 0.94)
    prior_angle_std_rad: float = 0.6
    confidence_scale_m: float = 0.1
    reach_tolerance: float = 0.05
    unreachable_confidence: float = 0.2

    def __post_init__(self) -> None:
        if self.n_candidates < 4:
            raise ValueError(f'n_candidates must be >= 4, got {self.n_candidates}')
        if self.refine_steps < 0 or self.bone_samples < 0 or self.depth_radius_px < 0:
            raise ValueError(f'refine_steps ({self.refine_steps}), bone_samples '
                             f'({self.bone_samples}) and depth_radius_px '
                             f'({self.depth_radius_px}) must be >= 0')
        for name in ('depth_scale_m', 'confidence_scale_m'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')
        if not self.length_scales or min(self.length_scales) <= 0:
            raise ValueError(f'length_scales must be positive factors, got {self.length_scales}')
        if len(self.prior_shrink) != 2 or not all(0 <= x <= 1 for x in self.prior_shrink):
            raise ValueError(f'prior_shrink must be 2 factors in [0, 1], got {self.prior_shrink}')
        if len(self.surface_offset_m) != 2:
            raise ValueError(f'surface_offset_m must be (arm, leg), got {self.surface_offset_m}')
        for name in ('arm_prior', 'leg_prior'):
            v = getattr(self, name)
            if len(v) != 3 or not np.any(np.asarray(v, float) != 0):
                raise ValueError(f'{name} must be 3 coefficients, not all zero, got {v}')


@dataclass(frozen=True)
class LimbSolution:
    """One inferred middle joint.

    Attributes
    ----------
    position : (3,) float64 metres, camera optical frame; NaN when MISSING/BEHIND_CAMERA.
    pixel : (2,) float64 pixel (u, v); NaN when unknown or without intrinsics.
    confidence : 0..1.
    flag : `IkFlag`.
    """

    position: NDArray[np.float64]
    pixel: NDArray[np.float64]
    confidence: float
    flag: IkFlag


def _nan_solution(flag: IkFlag) -> LimbSolution:
    return LimbSolution(np.full(3, np.nan), np.full(2, np.nan), 0.0, flag)


def prior_direction(limb: str, frame: NDArray[np.floating], config: IkConfig = IkConfig()
                    ) -> NDArray[np.float64]:
    """The joint-limit prior's preferred direction of a limb's middle joint, camera frame (3,).

    `frame` is `body_frame`'s (3, 3) (left, up, forward) rotation.
    """
    if limb not in LIMBS:
        raise ValueError(f'unknown limb {limb!r}; expected one of {tuple(LIMBS)}')
    coeffs = config.arm_prior if limb.endswith('arm') else config.leg_prior
    side = 1.0 if limb.startswith('left') else -1.0
    out, up, fwd = coeffs
    f = np.asarray(frame, dtype=np.float64)
    return side * out * f[:, 0] + up * f[:, 1] + fwd * f[:, 2]


# Smallest sine of the angle between a viewing ray and a bone used for the bone's surface depth.
_MIN_SIN = 0.3


@njit(cache=True)
def _surface_in_front(x: float, y: float, z: float, bx: float, by: float, bz: float,
                      offset: float) -> float:
    """How far (in z) before a bone's axis the ray through (x, y, z) enters the bone's cylinder
    of radius `offset`: ``offset / sin(theta) * ray_z``, theta the angle between the ray and the
    bone's direction (bx, by, bz)."""
    norm = max(math.sqrt(x * x + y * y + z * z), 1e-9)
    rx, ry, rz = x / norm, y / norm, z / norm
    cx, cy, cz = ry * bz - rz * by, rz * bx - rx * bz, rx * by - ry * bx
    return offset / max(math.sqrt(cx * cx + cy * cy + cz * cz), _MIN_SIN) * rz


@njit(cache=True)
def _memo_depth(keys: NDArray[np.int64], values: NDArray[np.float64], depth_m: NDArray,
                mask: NDArray[np.bool_], col: int, row: int, radius: int, buf: NDArray) -> float:
    """`robust_depth_at`, remembered per pixel in an open-addressing table (`keys` -1 = free;
    at most half full)."""
    key = row * depth_m.shape[1] + col
    slot = (key * 2654435761) & (len(keys) - 1)
    while keys[slot] != -1:
        if keys[slot] == key:
            return values[slot]
        slot = (slot + 1) & (len(keys) - 1)
    keys[slot] = key
    values[slot] = robust_depth_at(depth_m, mask, col, row, radius, buf)
    return values[slot]


@njit(cache=True)
def _depth_cost(depth_m: NDArray, mask: NDArray[np.bool_], root: NDArray[np.float64],
                end: NDArray[np.float64], cands: NDArray[np.float64], k: NDArray[np.float64],
                bone_samples: int, radius: int, offset: float, depth_scale: float,
                free_w: float, occluded_w: float, unknown_cost: float
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean per-sample cost of each candidate middle joint, and its fraction of samples with depth.

    Samples: the middle joint and `bone_samples` interior points of each bone it implies. A bone
    is a cylinder of radius `offset` about its axis: the ray through a sample's pixel enters it
    ``offset / sin(theta)`` before the axis, theta being the angle between the ray and the bone
    (capped at 1 / `_MIN_SIN`), so a limb pointing at the camera shows its surface well in front
    of its axis. At the middle joint the nearer of the two bones' surfaces counts. A sample's
    measured depth is `camera.robust_depth`'s (window `radius`, the mask's pixels only; an empty
    `mask` = none); one without depth costs `unknown_cost`, or `free_w` when it falls inside the
    image but off the person's mask (the camera saw background there). `k` = (fx, fy, cx, cy).
    """
    h, w = depth_m.shape
    n, n_samples = len(cands), 1 + 2 * bone_samples
    cost, known = np.zeros(n), np.zeros(n)
    buf = np.empty((2 * radius + 1) ** 2, depth_m.dtype)
    # many samples fall on the same pixels: look each pixel's depth up once (a hash table)
    size = 16
    while size < 2 * n * n_samples:
        size *= 2
    memo_keys = np.full(size, -1, np.int64)
    memo_values = np.empty(len(memo_keys))
    for i in range(n):
        mx, my, mz = cands[i, 0], cands[i, 1], cands[i, 2]
        ux, uy, uz = mx - root[0], my - root[1], mz - root[2]
        lx, ly, lz = end[0] - mx, end[1] - my, end[2] - mz
        nu = max(math.sqrt(ux * ux + uy * uy + uz * uz), 1e-9)
        nl = max(math.sqrt(lx * lx + ly * ly + lz * lz), 1e-9)
        total, n_known = 0.0, 0
        for s in range(n_samples):
            if s == 0:
                x, y, z = mx, my, mz
                in_front = max(_surface_in_front(x, y, z, ux / nu, uy / nu, uz / nu, offset),
                               _surface_in_front(x, y, z, lx / nl, ly / nl, lz / nl, offset))
            elif s <= bone_samples:
                f = s / (bone_samples + 1.0)
                x, y, z = root[0] + f * ux, root[1] + f * uy, root[2] + f * uz
                in_front = _surface_in_front(x, y, z, ux / nu, uy / nu, uz / nu, offset)
            else:
                f = (s - bone_samples) / (bone_samples + 1.0)
                x, y, z = mx + f * lx, my + f * ly, mz + f * lz
                in_front = _surface_in_front(x, y, z, lx / nl, ly / nl, lz / nl, offset)
            measured, off = math.nan, False
            if z > 0:
                u, v = k[2] + k[0] * x / z, k[3] + k[1] * y / z
                if math.isfinite(u) and math.isfinite(v):
                    col, row = int(np.rint(u)), int(np.rint(v))
                    if 0 <= col < w and 0 <= row < h:
                        measured = _memo_depth(memo_keys, memo_values, depth_m, mask, col, row,
                                               radius, buf)
                        off = mask.size > 0 and not mask[row, col]
            if math.isfinite(measured):
                resid = measured - (z - in_front)  # > 0: the camera saw past the surface
                excess = 1.0 - math.exp(-0.5 * (resid / depth_scale) ** 2)
                total += (free_w if resid > 0 else occluded_w) * excess
                n_known += 1
            elif off:
                total += free_w
                n_known += 1
            else:
                total += unknown_cost
        cost[i], known[i] = total / n_samples, n_known / n_samples
    return cost, known


def _depth_search(depth_m: NDArray, r0: NDArray[np.float64], e0: NDArray[np.float64],
                  upper: float, lower: float, intrinsics: Intrinsics, ref: NDArray[np.float64],
                  mask: NDArray | None, config: IkConfig, offset: float
                  ) -> tuple[NDArray[np.float64], float] | None:
    """The depth-supported middle joint and its confidence, or None if depth does not decide."""
    c = config
    found, p, confidence = _depth_search_kernel(
        np.asarray(depth_m), NO_MASK if mask is None else np.asarray(mask, bool),
        r0, e0, float(upper), float(lower),
        np.array([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy]), ref,
        np.asarray(c.length_scales, np.float64), c.n_candidates, c.refine_steps, c.bone_samples,
        c.depth_radius_px, float(offset), c.depth_scale_m, c.free_space_weight,
        c.occluded_weight, c.unknown_cost, c.min_valid_fraction, c.ambiguity_margin,
        c.prior_weight, c.scale_weight, c.confidence_scale_m)
    return (p, confidence) if found else None


@njit(cache=True)
def _depth_search_kernel(depth_m: NDArray, mask: NDArray[np.bool_], r0: NDArray[np.float64],
                         e0: NDArray[np.float64], upper: float, lower: float,
                         k: NDArray[np.float64], ref: NDArray[np.float64],
                         scales: NDArray[np.float64], n_candidates: int, refine_steps: int,
                         bone_samples: int, radius: int, offset: float, depth_scale: float,
                         free_w: float, occluded_w: float, unknown_cost: float,
                         min_valid: float, margin: float, prior_w: float, scale_w: float,
                         confidence_scale: float) -> tuple[bool, NDArray[np.float64], float]:
    """`_depth_search`: candidates on the circle of each length scale (the prior's direction at
    swivel 0), the best by depth cost + prior + scale penalties, its swivel refined."""
    angles = _swivel_angles(n_candidates)
    step = 2.0 * math.pi / n_candidates
    cands = np.empty((len(scales) * n_candidates, 3))
    penalty = np.empty(len(cands))
    scale_of, angle_of = np.empty(len(cands)), np.empty(len(cands))
    v = e0 - r0
    dist = math.sqrt(v @ v)
    n = 0
    for scale in scales:
        if dist < abs(upper - lower) * scale:  # too close for these lengths
            continue
        centre, axis, rad = _circle(r0, e0, upper * scale, lower * scale)
        scale_cost = scale_w * abs(math.log(scale))
        if rad < 1e-6:
            cands[n], penalty[n], scale_of[n], angle_of[n] = centre, scale_cost, scale, math.nan
            n += 1
            continue
        u, w = _plane_basis(axis, ref)
        m = len(angles)
        cands[n:n + m] = _circle_points(centre, rad, u, w, angles)
        penalty[n:n + m] = scale_cost + prior_w * 0.5 * (1.0 - np.cos(angles))
        scale_of[n:n + m], angle_of[n:n + m] = scale, angles
        n += m
    if n == 0:
        return False, r0, 0.0
    cands, penalty = cands[:n], penalty[:n]
    cost, known = _depth_cost(depth_m, mask, r0, e0, cands, k, bone_samples, radius, offset,
                              depth_scale, free_w, occluded_w, unknown_cost)
    if known.mean() < min_valid or cost.max() - cost.min() <= margin:
        return False, r0, 0.0
    total = cost + penalty
    best = int(np.argmin(total))
    p = cands[best].copy()
    angle, scale = angle_of[best], scale_of[best]
    if refine_steps > 0 and math.isfinite(angle):
        centre, axis, rad = _circle(r0, e0, upper * scale, lower * scale)
        u, w = _plane_basis(axis, ref)
        fine = angle + np.arange(-refine_steps, refine_steps + 1) * (step / (refine_steps + 1))
        fpts = _circle_points(centre, rad, u, w, fine)
        fcost, _ = _depth_cost(depth_m, mask, r0, e0, fpts, k, bone_samples, radius, offset,
                               depth_scale, free_w, occluded_w, unknown_cost)
        ftotal = fcost + scale_w * abs(math.log(scale)) + prior_w * 0.5 * (1.0 - np.cos(fine))
        p = fpts[int(np.argmin(ftotal))].copy()
    # Uncertainty: how far the candidates about as good as the best lie from it.
    near = total <= total.min() + margin
    spread = 0.0
    for i in np.flatnonzero(near):
        d = cands[i] - p
        spread += math.sqrt(d @ d)
    return True, p, math.exp(-spread / near.sum() / confidence_scale)


@njit(cache=True)
def _swivel_angles(n: int) -> NDArray[np.float64]:
    """n swivel angles in (-pi, pi], 0 (the prior's direction) included."""
    angles = np.arange(n) * (2.0 * math.pi / n)
    return np.where(angles > math.pi, angles - 2.0 * math.pi, angles)


def solve_limb(depth_m: NDArray[np.floating] | None, root: NDArray[np.floating],
               end: NDArray[np.floating], upper: float, lower: float,
               intrinsics: Intrinsics | None, *, prior: NDArray[np.floating],
               kind: str = 'arm', mask: NDArray[np.bool_] | None = None,
               config: IkConfig = IkConfig()) -> LimbSolution:
    """Infer one elbow or knee.

    Parameters
    ----------
    depth_m : (H, W) float metres (NaN = no reading) registered to `intrinsics`, or None
        (prior only).
    root, end : (3,) metres, camera optical frame (shoulder/hip and wrist/ankle); NaN = unknown.
    upper, lower : bone lengths, metres.
    intrinsics : the depth image's camera (also used for the output pixel); may be None when
        `depth_m` is None.
    prior : (3,) preferred direction of the middle joint (`prior_direction`), camera frame.
    kind : 'arm' or 'leg': which of the config's (arm, leg) parameters apply.
    mask : (H, W) bool person mask, optional.
    config : parameters.

    Notes
    -----
    With depth, candidates are taken on the circles of the bone lengths scaled by each of
    `config.length_scales` (the lengths are uncertain and a Kinect skeleton is not rigid) and
    the one the depth image supports best wins (ties broken by the prior and by the scale's
    distance from 1). Without depth, or when the depth does not discriminate, the prior puts
    the joint at ``centre + shrink * radius * u``, u being the prior direction in the circle's
    plane and shrink `config.prior_shrink`: ``shrink < 1`` is the expected position under the
    prior's swivel uncertainty rather than a point on the circle.
    """
    r0 = np.asarray(root, dtype=np.float64).reshape(3)
    e0 = np.asarray(end, dtype=np.float64).reshape(3)
    if depth_m is not None and intrinsics is None:
        raise ValueError('intrinsics are needed to use a depth image')
    if not (np.isfinite(r0).all() and np.isfinite(e0).all()
            and math.isfinite(upper) and math.isfinite(lower) and upper > 0 and lower > 0):
        return _nan_solution(IkFlag.MISSING)
    if r0[2] <= 0 or e0[2] <= 0:
        return _nan_solution(IkFlag.BEHIND_CAMERA)
    if kind not in ('arm', 'leg'):
        raise ValueError(f"kind must be 'arm' or 'leg', got {kind!r}")
    k = 0 if kind == 'arm' else 1
    ref = np.asarray(prior, dtype=np.float64).reshape(3)

    def finish(p: NDArray[np.float64], confidence: float, flag: IkFlag) -> LimbSolution:
        if not p[2] > 0:  # the inferred joint itself would be behind the camera
            return _nan_solution(IkFlag.BEHIND_CAMERA)
        uv = np.full(2, np.nan) if intrinsics is None else project(p[None], intrinsics)[0]
        return LimbSolution(p, uv, float(confidence), flag)

    dist = float(np.linalg.norm(e0 - r0))
    if depth_m is not None and dist > 1e-6:
        found = _depth_search(depth_m, r0, e0, upper, lower, intrinsics, ref, mask, config,
                              config.surface_offset_m[k])
        if found is not None:
            return finish(found[0], found[1], IkFlag.DEPTH)
    circle = middle_joint_circle(r0, e0, upper, lower)
    too_close = dist < abs(upper - lower) * (1.0 - config.reach_tolerance)
    if circle.reach > 1.0 + config.reach_tolerance or too_close or dist < 1e-6:
        p = circle.centre if circle.radius == 0.0 else circle_points(circle, ref, np.zeros(1))[0]
        return finish(p, config.unreachable_confidence, IkFlag.UNREACHABLE)
    u, _ = _plane_basis(circle.axis, ref)
    p = circle.centre + config.prior_shrink[k] * circle.radius * u
    spread = circle.radius * config.prior_angle_std_rad
    return finish(p, math.exp(-spread / config.confidence_scale_m), IkFlag.PRIOR)


# ---------------------------------------------------------------------------------------------
# All four limbs


@dataclass(frozen=True)
class IkResult:
    """Elbows and knees of one frame, in `LIMBS` order (left arm, right arm, left leg, right leg;
    the limbs asked for, all four by default: the shapes below are then (n, ...)).

    Attributes
    ----------
    names : the middle joints' names ('left_elbow', ...).
    positions : (4, 3) float64 metres, camera optical frame; NaN when not inferred.
    pixels : (4, 2) float64 pixel (u, v); NaN when unknown.
    confidence : (4,) float32, 0..1.
    flags : (4,) uint8 `IkFlag` values.
    """

    names: tuple[str, ...]
    positions: NDArray[np.float64]
    pixels: NDArray[np.float64]
    confidence: NDArray[np.float32]
    flags: NDArray[np.uint8]


def ik_inputs(points: NDArray[np.floating], depth_m: NDArray[np.floating] | None,
              names: Sequence[str], mask: NDArray[np.bool_] | None
              ) -> tuple[NDArray[np.float64], NDArray | None, dict[str, int]]:
    """The checked inputs of an IK solver (`infer_middle_joints`, `dh.infer_middle_joints_dh`):
    the points as float64, the depth image as an array, each name's row; ValueError naming what
    is wrong (shapes, a shoulder, wrist, hip or ankle missing from `names`)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape != (len(names), 3):
        raise ValueError(f'points must have shape ({len(names)}, 3), got {pts.shape}')
    if depth_m is not None:
        depth_m = np.asarray(depth_m)
        if depth_m.ndim != 2:
            raise ValueError(f'depth image must be 2-D, got shape {depth_m.shape}')
        if mask is not None and np.shape(mask) != depth_m.shape:
            raise ValueError(f'mask {np.shape(mask)} and depth {depth_m.shape} differ in shape')
    index = {n: i for i, n in enumerate(names)}
    for limb, (a, _, b) in LIMBS.items():
        for joint in (a, b):
            if joint not in index:
                raise ValueError(f'joint {joint!r} (needed for {limb}) not in names {names}')
    return pts, depth_m, index


def infer_middle_joints(depth_m: NDArray[np.floating] | None, points: NDArray[np.floating],
                        intrinsics: Intrinsics | None,
                        lengths: LimbLengths | Mapping[str, tuple[float, float]], *,
                        names: Sequence[str] = PARTS_10.names,
                        mask: NDArray[np.bool_] | None = None,
                        config: IkConfig = IkConfig(),
                        limbs: Sequence[str] | None = None) -> IkResult:
    """Infer both elbows and both knees of one frame (what the `ik` node calls).

    Parameters
    ----------
    depth_m : (H, W) float metres, NaN = no reading, or None for the prior alone.
    points : (J, 3) float metres, camera optical frame, NaN = unknown; named by `names` (must
        include shoulders, wrists, hips and ankles).
    intrinsics : the camera of `depth_m` and of the output pixels (None: no pixels, no depth).
    lengths : a `LimbLengths` or {limb: (upper, lower)} metres.
    names : joint names of `points` (default: the 10 parts).
    mask : (H, W) bool person mask, optional.
    config : parameters.
    limbs : the limbs to solve (`LIMBS` keys, in `LIMBS` order in the result); default all.
    """
    pts, depth_m, index = ik_inputs(points, depth_m, names, mask)

    def get(name: str) -> NDArray[np.float64]:
        return pts[index[name]] if name in index else np.full(3, np.nan)

    solved = {limb: joints for limb, joints in LIMBS.items() if limbs is None or limb in limbs}
    if not solved:  # every middle joint measured (a 14-part detector's frame)
        return NOTHING_SOLVED
    frame = body_frame(get('left_shoulder'), get('right_shoulder'), get('left_hip'),
                       get('right_hip'))
    sols = []
    for limb, (a, _, b) in solved.items():
        upper, lower = (lengths.lengths(limb) if isinstance(lengths, LimbLengths)
                        else lengths[limb])
        sols.append(solve_limb(depth_m, get(a), get(b), upper, lower, intrinsics,
                               prior=prior_direction(limb, frame, config),
                               kind='arm' if limb.endswith('arm') else 'leg', mask=mask,
                               config=config))
    return IkResult(
        names=tuple(m for _, m, _ in solved.values()),
        positions=np.array([s.position for s in sols], np.float64).reshape(-1, 3),
        pixels=np.array([s.pixel for s in sols], np.float64).reshape(-1, 2),
        confidence=np.array([s.confidence for s in sols], np.float32),
        flags=np.array([s.flag for s in sols], np.uint8))


# `infer_middle_joints` with no limb to solve (its arrays read-only: shared)
NOTHING_SOLVED = IkResult(names=(), positions=np.zeros((0, 3)), pixels=np.zeros((0, 2)),
                           confidence=np.zeros(0, np.float32), flags=np.zeros(0, np.uint8))
for _a in (NOTHING_SOLVED.positions, NOTHING_SOLVED.pixels, NOTHING_SOLVED.confidence,
           NOTHING_SOLVED.flags):
    _a.setflags(write=False)
