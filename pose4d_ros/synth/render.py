"""Synthetic RGB-D people for CAD-60-style data: bodies, rooms, retargeting and rendering.

Model. A body is a set of capsules (neck, shoulders, upper and lower arms, hands, hips, upper
and lower legs, feet) and ellipsoids (head, hair, chest, abdomen, pelvis) hung on a 20-joint
Kinect v1 skeleton (`utkinect.UTKINECT_JOINTS`), with per-body bone lengths, girths and
clothes (`random_body`). A pose from real Kinect motion is retargeted to the body by keeping
every bone's direction and setting its length to the body's (`retarget`). A room is a set of
textured oriented boxes (floor, walls, ceiling, skirting, door, pictures, furniture, sometimes
an occluder between camera and person) seen by a camera at 0.85-1.35 m, pitched down a little,
lit by a directional light plus ambient (`scene.random_scene`). `render` ray-casts the body
into the room's depth buffer (numba, `raycast`), shades it Lambertian + ambient, and turns the
exact depth into a Kinect v1 measurement (`kinect`: projector shadows, disparity
quantisation, noise growing with z^2, holes at edges and beyond range).

Frames. Poses and rendered joints are metres in the camera optical frame (x right, y down,
z forward). Rooms are built in a right-handed room frame: X right, Y forward (away from the
camera), Z up, floor at Z = 0, camera at (0, 0, h); `Scene.to_optical` maps room to optical.

Ground truth for CAD-60 files (`cad60_ground_truth`): CAD-60's 15 joints from the rendered
joints, with CAD-60's hand := the Kinect wrist and foot := the ankle (the detector's wrist and
ankle, `skeleton.GROUND_TRUTH_ALIASES`), orientation matrices from bone directions.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS
from pose4d_ros.synth import textures as tex
from pose4d_ros.synth.kinect import KinectModel, ideal_depth, kinect_depth
from pose4d_ros.synth.raycast import raycast_body, shade
from pose4d_ros.synth.scene import Scene, unit

# --------------------------------------------------------------------------------------------
# The Kinect v1 skeleton
# --------------------------------------------------------------------------------------------

_J = {name: i for i, name in enumerate(UTKINECT_JOINTS)}
HC, SPINE, SC, HEAD = _J['hip_center'], _J['spine'], _J['shoulder_center'], _J['head']
LSH, LEL, LWR, LHA = _J['left_shoulder'], _J['left_elbow'], _J['left_wrist'], _J['left_hand']
RSH, REL, RWR, RHA = (_J['right_shoulder'], _J['right_elbow'], _J['right_wrist'],
                      _J['right_hand'])
LHIP, LKN, LAN, LFT = _J['left_hip'], _J['left_knee'], _J['left_ankle'], _J['left_foot']
RHIP, RKN, RAN, RFT = _J['right_hip'], _J['right_knee'], _J['right_ankle'], _J['right_foot']

# Parent of each joint in the Kinect v1 tree (hip centre is the root).
PARENTS: tuple[int, ...] = (-1, HC, SPINE, SC, SC, LSH, LEL, LWR, SC, RSH, REL, RWR,
                            HC, LHIP, LKN, LAN, HC, RHIP, RKN, RAN)

# Median bone lengths (metres) over the 16 UTKinect takes s01-s08 (the length of the bone
# ending at each joint), and the stature they roughly correspond to.
REF_BONES: NDArray[np.float64] = np.array([
    0.0, 0.068, 0.338, 0.194,
    0.198, 0.260, 0.237, 0.080,
    0.198, 0.260, 0.237, 0.080,
    0.105, 0.475, 0.372, 0.090,
    0.105, 0.475, 0.372, 0.090,
])
REF_STATURE_M = 1.72
# The statures of `random_body` unless told otherwise, metres.
STATURE_M = (1.52, 1.95)

# Bone directions of a person standing upright facing the camera (optical frame), used only
# when a pose gives no direction (coincident or missing joints).
_REST_DIR = np.array([
    [0, 0, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0],
    [1, 0.2, 0], [0.2, 1, 0], [0, 1, 0], [0, 1, 0],
    [-1, 0.2, 0], [-0.2, 1, 0], [0, 1, 0], [0, 1, 0],
    [1, 0.7, 0], [0, 1, 0], [0, 1, 0], [0, 0.6, -1],
    [-1, 0.7, 0], [0, 1, 0], [0, 1, 0], [0, 0.6, -1],
], dtype=np.float64)
_REST_DIR[1:] /= np.linalg.norm(_REST_DIR[1:], axis=1, keepdims=True)

# CAD-60 joint order (skeleton.CAD60_JOINTS) from the Kinect v1 joints: hand := wrist and
# foot := ankle, the joints the detector calls wrist and ankle.
CAD60_FROM_KINECT: tuple[int, ...] = (HEAD, SC, SPINE, LSH, LEL, RSH, REL, LHIP, LKN, RHIP,
                                      RKN, LWR, RWR, LAN, RAN)

# Body material slots.
SKIN, HAIR, SHIRT, TROUSERS, SHOES, FACE = range(6)


# --------------------------------------------------------------------------------------------
# Bodies
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Body:
    """A synthetic person's shape and clothes.

    Attributes
    ----------
    stature_m : approximate standing height, metres.
    bones : (20,) float64 length of the bone ending at each Kinect joint, metres (0 at the
        root), `UTKINECT_JOINTS` order.
    radii : capsule radii, metres: neck, upper_arm, forearm, hand, thigh, shank, foot.
    head_axes, chest_axes, abdomen_axes, pelvis_axes : (3,) ellipsoid semi-axes, metres
        (across, along the body, front-to-back).
    materials : SKIN, HAIR, SHIRT, TROUSERS, SHOES, FACE tiles.
    long_sleeves, shorts, long_hair, bald : clothing and hair style.
    """

    stature_m: float
    bones: NDArray[np.float64]
    radii: dict[str, float]
    head_axes: NDArray[np.float64]
    chest_axes: NDArray[np.float64]
    abdomen_axes: NDArray[np.float64]
    pelvis_axes: NDArray[np.float64]
    materials: tex.Materials
    long_sleeves: bool
    shorts: bool
    long_hair: bool
    bald: bool


def random_body(rng: np.random.Generator, *,
                stature_m: tuple[float, float] = STATURE_M) -> Body:
    """A random person: stature drawn uniformly from `stature_m` (metres), proportions
    jittered per body part, a build from slim to heavy, skin tone, hair and clothes (colours,
    patterns, sleeves, shorts)."""
    stature = float(rng.uniform(*stature_m))
    s = stature / REF_STATURE_M
    build = float(rng.uniform(0.85, 1.3))  # girth factor
    f_trunk, f_head, f_shoulder, f_arm, f_leg, f_hip = rng.normal(
        1.0, [0.035, 0.03, 0.06, 0.035, 0.035, 0.06])
    bones = REF_BONES * s
    bones[[SPINE, SC]] *= f_trunk
    bones[HEAD] *= f_head
    bones[[LSH, RSH]] *= f_shoulder * (0.95 + 0.1 * (build - 0.85))
    upper, fore = rng.normal(1.0, 0.02, 2)
    bones[[LEL, REL]] *= f_arm * upper
    bones[[LWR, RWR]] *= f_arm * fore
    thigh, shank = rng.normal(1.0, 0.02, 2)
    bones[[LKN, RKN]] *= f_leg * thigh
    bones[[LAN, RAN]] *= f_leg * shank
    bones[[LHIP, RHIP]] *= f_hip * (0.95 + 0.15 * (build - 0.85))
    g = s * build
    radii = {
        'neck': 0.052 * s * build ** 0.5, 'upper_arm': 0.045 * g, 'forearm': 0.036 * g,
        'hand': 0.030 * s, 'thigh': 0.072 * g, 'shank': 0.050 * g, 'foot': 0.040 * s,
    }
    head = np.array([0.076, 0.108, 0.092]) * s ** 0.4 * f_head
    shoulder_half = float(bones[LSH])
    chest = np.array([0.80 * shoulder_half + 0.03 * build, 0.0, 0.10 * g])
    abdomen = np.array([0.85 * chest[0], 0.14 * s, 0.10 * g * build ** 0.7])
    hip_half = float(bones[LHIP])
    pelvis = np.array([hip_half + 0.65 * radii['thigh'], 0.11 * s, 0.095 * g])

    mb = tex.MaterialBuilder()
    skin, _ = tex.skin_tile(rng)
    mb.add('skin', skin, 0.2)
    hair, hair_drop = tex.hair_tile(rng)
    mb.add('hair', hair, 0.15, hair_drop)
    shirt, shirt_scale, shirt_drop = tex.cloth_tile(rng, tex.SHIRT_COLOURS)
    mb.add('shirt', shirt, shirt_scale, shirt_drop)
    trousers, tr_scale, tr_drop = tex.cloth_tile(rng, tex.TROUSER_COLOURS,
                                                 ('plain', 'plain', 'denim', 'denim'))
    mb.add('trousers', trousers, tr_scale, tr_drop)
    shoe = tex.tint(tex.grain(rng, 'gravel', 0.2),
                    tex.jitter_colour(rng, tex.SHOE_COLOURS[rng.integers(len(tex.SHOE_COLOURS))]),
                    0.05)
    mb.add('shoes', shoe, 0.2)
    # the head ellipsoid's surface is exactly one tile (see `raycast`: s = angle * rx,
    # t = (y + 1) * ry)
    mb.add('face', tex.face_tile(rng, skin, hair), (2 * np.pi * head[0], 2 * head[1]))
    return Body(
        stature_m=stature, bones=bones, radii=radii, head_axes=head, chest_axes=chest,
        abdomen_axes=abdomen, pelvis_axes=pelvis, materials=mb.build(),
        long_sleeves=bool(rng.random() < 0.6), shorts=bool(rng.random() < 0.15),
        long_hair=bool(rng.random() < 0.35), bald=bool(rng.random() < 0.06),
    )


def retarget(pose: NDArray[np.floating], body: Body, *,
             up: NDArray[np.floating] | None = None) -> NDArray[np.float64]:
    """Give a pose the body's bone lengths, keeping every bone's direction.

    Parameters
    ----------
    pose : (20, 3) float, metres, optical frame, `UTKINECT_JOINTS` order.
    body : the target body.
    up : (3,) unit "up" vector in the same frame, optional. Without it the hip centre stays
        where it is; with it, the result is also moved along `up` so that its lowest ankle or
        foot joint is as high as the pose's (the feet stay on the floor).

    Returns
    -------
    (20, 3) float64 metres, same frame.
    """
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (20, 3):
        raise ValueError(f'pose must be (20, 3) metres, got shape {pose.shape}')
    if not np.all(np.isfinite(pose[HC])):
        raise ValueError('pose has no hip centre (NaN)')
    out = np.empty_like(pose)
    out[HC] = pose[HC]
    for i in range(1, 20):
        p = PARENTS[i]
        d = pose[i] - pose[p]
        n = float(np.linalg.norm(d))
        d = d / n if np.isfinite(n) and n > 1e-6 else _REST_DIR[i]
        out[i] = out[p] + d * body.bones[i]
    if up is not None:
        up = np.asarray(up, dtype=np.float64)
        feet = [LAN, LFT, RAN, RFT]
        src = pose[feet] @ up
        dst = out[feet] @ up
        if np.all(np.isfinite(src)):
            out += (src.min() - dst.min()) * up
    return out


def body_frame(joints: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """(left, up, forward) unit vectors of the trunk from Kinect joints (any right-handed
    frame): up from hip centre to shoulder centre, left from the right to the left shoulder,
    forward = left x up (towards the camera for a person facing it)."""
    up = unit(joints[SC] - joints[HC], np.array([0.0, -1.0, 0.0]))
    left = joints[LSH] - joints[RSH]
    fwd = unit(np.cross(left, up), np.array([0.0, 0.0, -1.0]))
    left = np.cross(up, fwd)
    return left, up, fwd


@dataclass(frozen=True)
class Primitives:
    """A body as ray-casting primitives (optical frame, metres); see `raycast`."""

    cap_a: NDArray[np.float64]
    cap_b: NDArray[np.float64]
    cap_r: NDArray[np.float64]
    cap_e1: NDArray[np.float64]
    ell_c: NDArray[np.float64]
    ell_rot: NDArray[np.float64]
    ell_r: NDArray[np.float64]
    mat: NDArray[np.int64]  # material per primitive, capsules first


def _perpendiculars(cap_a: NDArray[np.float64], cap_b: NDArray[np.float64],
                    fwd: NDArray[np.float64], up: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit vectors perpendicular to each capsule's axis: `fwd` made perpendicular, or `up`
    where the axis runs along `fwd` (the s = 0 direction of the capsules' texture)."""
    axes = cap_b - cap_a
    axes /= np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-9)
    e1 = fwd[None, :] - (axes @ fwd)[:, None] * axes
    bad = np.linalg.norm(e1, axis=1) < 1e-3
    e1[bad] = up - (axes[bad] @ up)[:, None] * axes[bad]
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-9)
    return e1


def capsule_depth(ends: NDArray[np.floating], radii: NDArray[np.floating],
                  intrinsics: Intrinsics, *, rng: np.random.Generator | None = None
                  ) -> NDArray[np.float32]:
    """The exact depth of a few capsules alone, ray-cast as the bodies are.

    Parameters
    ----------
    ends : (K, 2, 3) float metres, optical frame: the two ends of each capsule's axis.
    radii : (K,) float metres.
    intrinsics : the camera.
    rng : if given, the Kinect v1 axial noise (`KinectModel.axial_noise_m`) is added, without
        the sensor's holes and quantisation (`render` has the whole sensor model).

    Returns
    -------
    (H, W) float32 metres, NaN where nothing was hit.
    """
    ends = np.asarray(ends, dtype=np.float64).reshape(-1, 2, 3)
    radii = np.asarray(radii, dtype=np.float64).reshape(-1)
    if len(radii) != len(ends):
        raise ValueError(f'{len(ends)} capsules but {len(radii)} radii')
    keep = np.isfinite(ends).all(axis=(1, 2))
    cap_a, cap_b, radii = ends[keep, 0], ends[keep, 1], radii[keep]
    e1 = _perpendiculars(cap_a, cap_b, np.array([0.0, 0.0, -1.0]), np.array([0.0, -1.0, 0.0]))
    h, w = intrinsics.height, intrinsics.width
    zbuf = np.full((h, w), np.inf, np.float32)
    raycast_body(intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, zbuf,
                 cap_a, cap_b, radii, e1, np.zeros((0, 3)), np.zeros((0, 3, 3)),
                 np.zeros((0, 3)), np.full((h, w), -1, np.int32),
                 np.zeros((h, w, 3), np.float32), np.zeros((h, w, 2), np.float32))
    out = np.where(np.isfinite(zbuf), zbuf, np.float32(np.nan))
    if rng is not None:
        hit = np.isfinite(out)
        out[hit] += (rng.normal(0.0, 1.0, int(hit.sum()))
                     * KinectModel().axial_noise_m(out[hit])).astype(np.float32)
    return out


def body_primitives(joints: NDArray[np.float64], body: Body) -> Primitives:
    """The capsules and ellipsoids of `body` posed at `joints` ((20, 3) metres, optical)."""
    j = joints
    left, up, fwd = body_frame(j)
    r = body.radii
    caps: list[tuple[NDArray, NDArray, float, int]] = []
    forearm_mat = SHIRT if body.long_sleeves else SKIN
    shank_mat = SKIN if body.shorts else TROUSERS
    caps.append((j[LSH], j[RSH], 1.1 * r['upper_arm'], SHIRT))
    head_dir = unit(j[HEAD] - j[SC], up)
    caps.append((j[SC] - 0.02 * head_dir, j[SC] + 0.55 * (j[HEAD] - j[SC]), r['neck'], SKIN))
    for sh, el, wr, ha in ((LSH, LEL, LWR, LHA), (RSH, REL, RWR, RHA)):
        caps.append((j[sh], j[el], r['upper_arm'], SHIRT))
        caps.append((j[el], j[wr], r['forearm'], forearm_mat))
        caps.append((j[wr] + 0.2 * (j[ha] - j[wr]), j[wr] + 1.5 * (j[ha] - j[wr]), r['hand'],
                     SKIN))
    caps.append((j[LHIP], j[RHIP], r['thigh'], TROUSERS))
    for hip, kn, an, ft in ((LHIP, LKN, LAN, LFT), (RHIP, RKN, RAN, RFT)):
        caps.append((j[hip], j[kn], r['thigh'], TROUSERS))
        caps.append((j[kn], j[an], r['shank'], shank_mat))
        foot_dir = unit(j[ft] - j[an], fwd)
        caps.append((j[an] - 0.035 * foot_dir - 0.25 * r['foot'] * up,
                     j[ft] + 0.03 * foot_dir, r['foot'], SHOES))
    cap_a = np.array([c[0] for c in caps])
    cap_b = np.array([c[1] for c in caps])
    e1 = _perpendiculars(cap_a, cap_b, fwd, up)

    ells: list[tuple[NDArray, NDArray, NDArray, int]] = []
    h_up = head_dir
    h_fwd = unit(fwd - (fwd @ h_up) * h_up, fwd)
    h_left = np.cross(h_up, h_fwd)
    head_rot = np.stack([h_left, -h_up, h_fwd])
    ha = body.head_axes
    ells.append((j[HEAD] + 0.01 * h_fwd, head_rot, ha, FACE))
    if not body.bald:
        ells.append((j[HEAD] + 0.018 * h_up - 0.024 * h_fwd, head_rot,
                     ha + np.array([0.008, 0.01, 0.004]), HAIR))
        if body.long_hair:
            ells.append((j[HEAD] - 0.10 * h_up - 0.05 * h_fwd, head_rot,
                         np.array([0.9 * ha[0], 0.16, 0.055]), HAIR))
    trunk = j[SC] - j[SPINE]
    trunk_len = float(np.linalg.norm(trunk))
    t_up = unit(trunk, up)
    t_fwd = unit(fwd - (fwd @ t_up) * t_up, fwd)
    t_rot = np.stack([np.cross(t_up, t_fwd), -t_up, t_fwd])
    chest = body.chest_axes.copy()
    chest[1] = 0.58 * trunk_len + 0.02
    ells.append((j[SPINE] + 0.52 * trunk - 0.01 * t_fwd, t_rot, chest, SHIRT))
    ells.append((j[SPINE] + 0.06 * t_up + 0.012 * t_fwd, t_rot, body.abdomen_axes, SHIRT))
    hip_left = unit(j[LHIP] - j[RHIP], left)
    p_up = unit(up - (up @ hip_left) * hip_left, up)
    p_rot = np.stack([hip_left, -p_up, np.cross(hip_left, p_up)])
    ells.append((j[HC] - 0.015 * p_up, p_rot, body.pelvis_axes, TROUSERS))
    return Primitives(
        cap_a=cap_a, cap_b=cap_b, cap_r=np.array([c[2] for c in caps]), cap_e1=e1,
        ell_c=np.array([e[0] for e in ells]), ell_rot=np.array([e[1] for e in ells]),
        ell_r=np.array([e[2] for e in ells]),
        mat=np.array([c[3] for c in caps] + [e[3] for e in ells], dtype=np.int64),
    )


# --------------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Rendered:
    """One rendered RGB-D frame.

    Attributes
    ----------
    rgb : (H, W, 3) uint8, RGB order.
    depth_mm : (H, W) uint16 millimetres, 0 = no reading, registered to `rgb`.
    mask : (H, W) bool, True where the person is the visible surface.
    joints : (20, 3) float64 metres, optical frame: the retargeted joints actually rendered,
        `UTKINECT_JOINTS` order.
    """

    rgb: NDArray[np.uint8]
    depth_mm: NDArray[np.uint16]
    mask: NDArray[np.bool_]
    joints: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class RenderedPeople:
    """One rendered RGB-D frame of several people.

    Attributes
    ----------
    rgb : (H, W, 3) uint8, RGB order.
    depth_mm : (H, W) uint16 millimetres, 0 = no reading, registered to `rgb`.
    labels : (H, W) uint8, k where person k (1..N, the order of the poses) is the visible
        surface (the nearest over the room and all bodies), 0 elsewhere.
    joints : (N, 20, 3) float64 metres, optical frame: each person's retargeted joints,
        `UTKINECT_JOINTS` order.
    """

    rgb: NDArray[np.uint8]
    depth_mm: NDArray[np.uint16]
    labels: NDArray[np.uint8]
    joints: NDArray[np.float64]

    @property
    def mask(self) -> NDArray[np.bool_]:
        """(H, W) bool, True where any person is the visible surface."""
        return self.labels > 0

    def visible_px(self) -> NDArray[np.int64]:
        """(N,) int64 pixels on which each person is the visible surface."""
        return np.bincount(self.labels.ravel(), minlength=len(self.joints) + 1)[1:]


def _empty_background(intrinsics: Intrinsics) -> tuple[NDArray, ...]:
    h, w = intrinsics.height, intrinsics.width
    return (np.full((h, w), np.inf, np.float32), np.zeros((h, w, 3), np.float32),
            np.zeros((h, w, 3), np.float32), np.full((h, w), -1, np.int32),
            np.zeros((h, w), np.float32))


_VIGNETTE: dict[Intrinsics, NDArray[np.float32]] = {}


def _vignette(intrinsics: Intrinsics) -> NDArray[np.float32]:
    if intrinsics not in _VIGNETTE:
        u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
        r2 = ((u - intrinsics.cx) / intrinsics.fx) ** 2 + \
            ((v - intrinsics.cy) / intrinsics.fy) ** 2
        _VIGNETTE[intrinsics] = (1.0 / (1.0 + 0.5 * r2)).astype(np.float32)[:, :, None]
    return _VIGNETTE[intrinsics]


def render(pose: NDArray[np.floating], body: Body, scene: Scene | None,
           intrinsics: Intrinsics, *, rng: np.random.Generator | None = None,
           kinect_noise: bool = True, sensor: KinectModel | None = None) -> Rendered:
    """Render a person in a pose, in a room, as a Kinect v1 would see it.

    Parameters
    ----------
    pose : (20, 3) float metres, optical frame, `UTKINECT_JOINTS` order (e.g. real Kinect
        motion placed in the room). It is retargeted to `body` first (`retarget`; with a scene
        the feet keep their height above the floor).
    body : from `random_body`.
    scene : from `random_scene`, or None for the body alone (depth 0 elsewhere, black RGB).
    intrinsics : the camera (the scene is re-rendered if it was made for another one).
    rng : noise source; None = a fixed seed (the output is then a function of the inputs).
    kinect_noise : apply the Kinect depth model and camera noise; False gives exact depth
        (0 only where nothing is hit) and noise-free colour.
    sensor : Kinect model parameters (default `KinectModel()`).

    Returns
    -------
    Rendered (rgb, depth_mm, mask, joints).
    """
    out = render_people([pose], [body], scene, intrinsics, rng=rng, kinect_noise=kinect_noise,
                        sensor=sensor)
    return Rendered(rgb=out.rgb, depth_mm=out.depth_mm, mask=out.mask, joints=out.joints[0])


def render_people(poses: Sequence[NDArray[np.floating]], bodies: Sequence[Body],
                  scene: Scene | None, intrinsics: Intrinsics, *,
                  rng: np.random.Generator | None = None, kinect_noise: bool = True,
                  sensor: KinectModel | None = None) -> RenderedPeople:
    """Render several people, each in its pose, in one room, as a Kinect v1 would see them.

    All bodies' primitives are ray-cast in one pass against one depth buffer holding the room
    (`raycast.raycast_body`), so every pixel shows the nearest surface over the room and all
    bodies, in depth and in colour alike; the Kinect model then sees the composed depth (its
    projector shadows and edge holes fall between people as between a person and the room).
    With one person this is exactly `render` (the same arrays, the same random draws).

    Parameters
    ----------
    poses : N (20, 3) float metres, optical frame, `UTKINECT_JOINTS` order; each is
        retargeted to its body (`retarget`).
    bodies : N bodies from `random_body`, in the order of `poses`.
    scene, intrinsics, rng, kinect_noise, sensor : as in `render`.

    Returns
    -------
    RenderedPeople (rgb, depth_mm, labels: person k = k, joints (N, 20, 3)).
    """
    if len(poses) != len(bodies) or len(poses) == 0:
        raise ValueError(f'need one body per pose and at least one person, got {len(poses)} '
                         f'poses and {len(bodies)} bodies')
    if len(poses) > 255:
        raise ValueError(f'at most 255 people, got {len(poses)}')
    rng = rng if rng is not None else np.random.default_rng(0)
    if scene is not None:
        scene = scene.for_intrinsics(intrinsics)
        bg = (scene.bg_depth, scene.bg_normal, scene.bg_albedo, scene.bg_ids, scene.bg_dropout)
        up = scene.up_optical
    else:
        bg = _empty_background(intrinsics)
        up = None
    joints = np.array([retarget(p, b, up=up) for p, b in zip(poses, bodies, strict=True)])
    prims, owner, tiles, scale, ir_dropout = _merge_bodies(
        [body_primitives(j, b) for j, b in zip(joints, bodies, strict=True)], bodies)
    h, w = intrinsics.height, intrinsics.width
    zbuf = bg[0].copy()
    ids = np.full((h, w), -1, np.int32)
    normal = np.zeros((h, w, 3), np.float32)
    st = np.zeros((h, w, 2), np.float32)
    raycast_body(intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, zbuf,
                 prims.cap_a, prims.cap_b, prims.cap_r, prims.cap_e1, prims.ell_c,
                 prims.ell_rot, prims.ell_r, ids, normal, st)
    mask = ids >= 0
    labels = np.where(mask, owner[np.maximum(ids, 0)], 0).astype(np.uint8)

    if scene is not None:
        light = scene.light_optical
        ambient, diffuse, colour = scene.ambient, scene.diffuse, scene.light_colour
        floor_id = scene.floor_index
        blobs = np.concatenate([_contact_shadows(j, b, scene)
                                for j, b in zip(joints, bodies, strict=True)])
    else:
        light = np.array([0.3, -0.5, -0.8]) / np.linalg.norm([0.3, -0.5, -0.8])
        ambient, diffuse, colour, floor_id = 0.45, 0.6, np.ones(3), -2
        blobs = np.zeros((0, 5))  # no floor
    img = np.empty((h, w, 3), np.float32)
    shade(bg[2], bg[1], bg[3], zbuf, ids, normal, st, prims.mat, tiles, scale, light, ambient,
          diffuse, colour, floor_id, blobs, intrinsics.fx, intrinsics.fy, intrinsics.cx,
          intrinsics.cy, img)
    all_normal = np.where(mask[:, :, None], normal, bg[1])
    if kinect_noise:
        img *= _vignette(intrinsics)
        img = cv2.GaussianBlur(img, (0, 0), 0.65)
        img += rng.normal(0.0, 0.012, img.shape).astype(np.float32)
        dropout = np.where(mask, ir_dropout[prims.mat[np.maximum(ids, 0)]],
                           bg[4]).astype(np.float32)
        depth = kinect_depth(zbuf, all_normal, intrinsics, rng, dropout=dropout, model=sensor)
    else:
        depth = ideal_depth(zbuf)
    rgb = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return RenderedPeople(rgb=rgb, depth_mm=depth, labels=labels, joints=joints)


def _merge_bodies(prims: list[Primitives], bodies: Sequence[Body]
                  ) -> tuple[Primitives, NDArray[np.int64], NDArray[np.float32],
                             NDArray[np.float32], NDArray[np.float32]]:
    """Several bodies' primitives as one set for one ray-casting pass.

    The kernel numbers capsules first, then ellipsoids, so the merged set holds every body's
    capsules, then every body's ellipsoids; each body's materials follow the previous bodies'
    (its primitives' material indices are offset accordingly). Returns the merged primitives,
    the person (1..N) of each merged primitive index, and the merged materials' tiles, scales
    and infrared dropouts. One body comes back as it is.
    """
    if len(prims) == 1:
        m = bodies[0].materials
        return (prims[0], np.ones(len(prims[0].mat), np.int64), m.tiles, m.scale,
                m.ir_dropout)
    offsets = np.cumsum([0] + [len(b.materials) for b in bodies])
    n_caps = [len(p.cap_r) for p in prims]
    cap_mat = [p.mat[:n] + o for p, n, o in zip(prims, n_caps, offsets, strict=False)]
    ell_mat = [p.mat[n:] + o for p, n, o in zip(prims, n_caps, offsets, strict=False)]
    merged = Primitives(
        cap_a=np.concatenate([p.cap_a for p in prims]),
        cap_b=np.concatenate([p.cap_b for p in prims]),
        cap_r=np.concatenate([p.cap_r for p in prims]),
        cap_e1=np.concatenate([p.cap_e1 for p in prims]),
        ell_c=np.concatenate([p.ell_c for p in prims]),
        ell_rot=np.concatenate([p.ell_rot for p in prims]),
        ell_r=np.concatenate([p.ell_r for p in prims]),
        mat=np.concatenate(cap_mat + ell_mat).astype(np.int64))
    owner = np.concatenate([np.full(n, k + 1) for k, n in enumerate(n_caps)]
                           + [np.full(len(p.ell_r), k + 1) for k, p in enumerate(prims)])
    return (merged, owner.astype(np.int64),
            np.concatenate([b.materials.tiles for b in bodies]),
            np.concatenate([b.materials.scale for b in bodies]),
            np.concatenate([b.materials.ir_dropout for b in bodies]))


def _contact_shadows(joints: NDArray[np.float64], body: Body, scene: Scene
                     ) -> NDArray[np.float64]:
    """Soft dark blobs on the floor under the feet and the body: (B, 5) centre (optical,
    metres), radius, strength (the ambient occlusion a person casts, without shadow rays)."""
    up = scene.up_optical
    h = scene.cam_height_m

    def on_floor(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return p - (p @ up + h) * up

    blobs = []
    for an, ft in ((LAN, LFT), (RAN, RFT)):
        p = 0.5 * (joints[an] + joints[ft])
        lift = float(p @ up + h)
        if lift < 0.4:
            blobs.append((*on_floor(p), 0.09 + 0.3 * lift, 0.5 - lift))
    lift = float(joints[HC] @ up + h)
    blobs.append((*on_floor(joints[HC]), max(0.25, 0.45 * lift), 0.3))
    return np.array(blobs, dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Ground truth in CAD-60's terms
# --------------------------------------------------------------------------------------------

def cad60_ground_truth(joints: NDArray[np.floating]
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """CAD-60 joints and orientations of a Kinect v1 pose.

    Parameters
    ----------
    joints : (20, 3) float metres, optical frame, `UTKINECT_JOINTS` order.

    Returns
    -------
    joints_mm : (15, 3) float64 millimetres, OpenNI world frame (x right, y up, z away),
        `skeleton.CAD60_JOINTS` order (anatomical sides); hand := wrist, foot := ankle.
    orientations : (11, 3, 3) float64 rotation matrices of joints 1-11, world frame: columns
        are the joint's x, y, z axes. A person facing the camera with arms stretched sideways
        (T-pose) gives the identity everywhere: x = towards the person's left, y = up, z away
        from the camera; the arm bones lie along x, the trunk and leg bones along y.
    """
    j = np.asarray(joints, dtype=np.float64)
    world = j * np.array([1.0, -1.0, 1.0])  # metres, y up
    joints_mm = world[list(CAD60_FROM_KINECT)] * 1000.0

    def frame(x_axis: NDArray | None, y_axis: NDArray | None) -> NDArray[np.float64]:
        if x_axis is not None:
            x = x_axis
            y = unit(t_y - (t_y @ x) * x, np.cross(t_z, x))
        else:
            y = y_axis
            x = unit(t_x - (t_x @ y) * y, np.cross(y, t_z))
        return np.column_stack([x, y, np.cross(x, y)])

    t_y = unit(world[SC] - world[HC], np.array([0.0, 1.0, 0.0]))
    t_x = world[LSH] - world[RSH]
    t_x = unit(t_x - (t_x @ t_y) * t_y, np.array([1.0, 0.0, 0.0]))
    t_z = np.cross(t_x, t_y)

    def d(a: int, b: int, fallback: NDArray) -> NDArray[np.float64]:
        return unit(world[b] - world[a], fallback)

    rots = [
        frame(None, d(SC, HEAD, t_y)),            # head
        frame(None, d(SC, HEAD, t_y)),            # neck
        np.column_stack([t_x, t_y, t_z]),         # torso
        frame(d(LSH, LEL, t_x), None),            # left shoulder
        frame(d(LEL, LWR, t_x), None),            # left elbow
        frame(d(REL, RSH, t_x), None),            # right shoulder
        frame(d(RWR, REL, t_x), None),            # right elbow
        frame(None, d(LKN, LHIP, t_y)),           # left hip
        frame(None, d(LAN, LKN, t_y)),            # left knee
        frame(None, d(RKN, RHIP, t_y)),           # right hip
        frame(None, d(RAN, RKN, t_y)),            # right knee
    ]
    return joints_mm, np.array(rots)
