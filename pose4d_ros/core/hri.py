"""A tracked person as ROS4HRI (REP 155) sees a body: its id, its 2-D skeleton, its region of
interest and its frames.

REP 155 ("Conventions, Topics, Interfaces for Perception in Human-Robot Interaction") gives
each tracked body a short, non-persistent string id, publishes the ids in view on
`/humans/bodies/tracked` and, per body, `/humans/bodies/<id>/skeleton2d` (hri_msgs/Skeleton2D:
18 keypoints in OpenPose's COCO order, coordinates normalised by the image's width and height,
(0, 0) the image's top-left corner, a confidence each), `/humans/bodies/<id>/roi` (hri_msgs/
NormalizedRegionOfInterest2D) and the body's frames on /tf: `body_<id>` at the middle of the
hips (x forward out of the chest, y to the person's left, z towards the head, REP 103), its
child links named after the REP's kinematic model of the human (`head`, `l_shoulder`,
`l_elbow`, `l_wrist`, `l_hip`, `l_knee`, `l_ankle` and the `r_` ones), each suffixed `_<id>`.

This module maps the 14 joints of `core.skeleton.SKELETON_14` onto those views; it is plain
numpy (the messages' bytes are written by `wire.hri`). What the 14 joints lack (the nose, the
eyes, the ears; the REP's waist, torso and the head's and shoulders' intermediate links) is
not made up: the keypoints get confidence 0, the links no frame.
"""

from __future__ import annotations

import math
import re

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.core.kinematics import body_frame

# hri_msgs/Skeleton2D's keypoint codes (OpenPose COCO-18): index = the message's constant
SKELETON2D_KEYPOINTS: tuple[str, ...] = (
    'nose', 'neck', 'right_shoulder', 'right_elbow', 'right_wrist', 'left_shoulder',
    'left_elbow', 'left_wrist', 'right_hip', 'right_knee', 'right_ankle', 'left_hip',
    'left_knee', 'left_ankle', 'left_eye', 'right_eye', 'left_ear', 'right_ear')
# our joints have the COCO keypoints' names (both sides the person's own); head is the head's
# centre, not the nose, and is not given as one
KEYPOINT_JOINTS: dict[int, str] = {k: name for k, name in enumerate(SKELETON2D_KEYPOINTS)
                                   if name not in ('nose', 'left_eye', 'right_eye', 'left_ear',
                                                   'right_ear')}

# REP 155's links of the kinematic model of the human, for the joints we locate
BODY_LINKS: dict[str, str] = {
    'head': 'head',
    'left_shoulder': 'l_shoulder', 'left_elbow': 'l_elbow', 'left_wrist': 'l_wrist',
    'right_shoulder': 'r_shoulder', 'right_elbow': 'r_elbow', 'right_wrist': 'r_wrist',
    'left_hip': 'l_hip', 'left_knee': 'l_knee', 'left_ankle': 'l_ankle',
    'right_hip': 'r_hip', 'right_knee': 'r_knee', 'right_ankle': 'r_ankle',
}

# The joints' box grown by this share of its height on every side: the head joint is the
# head's centre and the ankles are above the soles (about 6 % of a standing person's height)
ROI_MARGIN = 0.08

_ID_PREFIX = re.compile(r'[A-Za-z][A-Za-z0-9]*\Z')


def id_prefix_problem(prefix: str) -> str | None:
    """Why `prefix` cannot start body ids, or None: an id is a token of topic names
    (`/humans/bodies/<id>/...`, which may not start with a digit) and of TF frame names."""
    if not _ID_PREFIX.match(prefix):
        return (f'{prefix!r}: a body id prefix is a letter, then letters or digits (it starts '
                'a token of topic names, which may not start with a digit)')
    return None


def body_id(track_id: int, prefix: str = 'b') -> str:
    """A track's REP 155 body id: `<prefix><track_id>` (short, and unique in a run since track
    ids are never reused), e.g. `b1`."""
    return f'{prefix}{int(track_id)}'


def skeleton2d(joints: JointSet, width: int, height: int) -> NDArray[np.float32]:
    """A person's hri_msgs/Skeleton2D keypoints.

    Parameters
    ----------
    joints : the person's joints, named as `core.skeleton.SKELETON_14` (others are ignored).
    width, height : the colour image's size, pixels.

    Returns
    -------
    (18, 3) float32 rows (x, y, c) in `SKELETON2D_KEYPOINTS` order: x = (u + 0.5) / width and
    y = (v + 0.5) / height (pixel (0, 0) is the centre of the top-left pixel, the message's
    (0, 0) that pixel's corner), clipped to [0, 1]; c the joint's confidence, clipped to
    [0, 1]. A keypoint we have no joint for, or whose joint is MISSING or has no pixel, is
    (0, 0, 0).
    """
    if width <= 0 or height <= 0:
        raise ValueError(f'image size {width}x{height}: must be positive')
    out = np.zeros((len(SKELETON2D_KEYPOINTS), 3), np.float32)
    for k, name in KEYPOINT_JOINTS.items():
        i = joints.get(name)
        if i is None or joints.source[i] == MISSING:
            continue
        u, v = joints.uv[i]
        if not (math.isfinite(u) and math.isfinite(v)):
            continue
        out[k] = (min(max((u + 0.5) / width, 0.0), 1.0),
                  min(max((v + 0.5) / height, 0.0), 1.0),
                  min(max(float(joints.confidence[i]), 0.0), 1.0))
    return out


def body_roi(joints: JointSet, width: int, height: int, *, margin: float = ROI_MARGIN
             ) -> tuple[float, float, float, float, float] | None:
    """A person's region of interest, hri_msgs/NormalizedRegionOfInterest2D's fields.

    The box of the located joints' pixels (not MISSING, finite), grown by `margin` x its height
    on every side, normalised as `skeleton2d` normalises keypoints and clipped to the image;
    c is the mean confidence of those joints. Returns (xmin, ymin, xmax, ymax, c), or None
    when fewer than two joints are located.
    """
    if width <= 0 or height <= 0:
        raise ValueError(f'image size {width}x{height}: must be positive')
    located = (joints.source != MISSING) & np.isfinite(joints.uv).all(axis=1)
    if located.sum() < 2:
        return None
    uv = joints.uv[located] + 0.5
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    grow = margin * (hi[1] - lo[1])
    size = np.array([width, height], np.float64)
    lo = np.clip((lo - grow) / size, 0.0, 1.0)
    hi = np.clip((hi + grow) / size, 0.0, 1.0)
    c = float(np.clip(joints.confidence[located], 0.0, 1.0).mean())
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), c


def quaternion(rotation: NDArray[np.floating]) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a 3x3 rotation matrix, w >= 0 (Shepperd's method: the largest of the
    four squares is taken first, so no division by a small number)."""
    r = np.asarray(rotation, dtype=np.float64)
    t = float(np.trace(r))
    if t > max(r[0, 0], r[1, 1], r[2, 2]):
        s = 2.0 * math.sqrt(1.0 + t)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s,
             0.25 * s)
    elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = (0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s,
             (r[2, 1] - r[1, 2]) / s)
    elif r[1, 1] >= r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s,
             (r[0, 2] - r[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s,
             (r[1, 0] - r[0, 1]) / s)
    sign = -1.0 if q[3] < 0 else 1.0
    return tuple(float(sign * c) for c in q)  # type: ignore[return-value]


Transform = tuple[str, str, tuple[float, ...]]  # parent, child, (x, y, z, qx, qy, qz, qw)


def body_transforms(joints: JointSet, camera_frame: str, body: str) -> list[Transform]:
    """A person's REP 155 frames: `body_<body>` in `camera_frame`, and each located joint's
    link (`BODY_LINKS`) as `<link>_<body>` in `body_<body>`.

    `body_<body>` lies at the middle of the hips (both must be located, with finite 3-D
    positions; otherwise the person has no frames this time), x forward (the way the chest
    faces), y to the person's left, z from the hips towards the shoulders (REP 103; the axes of
    `kinematics.body_frame`). The links' frames are their joints' positions in it, their
    rotation the body's (the joints' own orientations are not estimated). Positions in metres
    from `joints.xyz` (the camera optical frame).
    """
    located = (joints.source != MISSING) & np.isfinite(joints.xyz).all(axis=1)
    idx = {name: i for i, name in enumerate(joints.names) if located[i]}
    if 'left_hip' not in idx or 'right_hip' not in idx:
        return []
    xyz = joints.xyz

    def at(name: str) -> NDArray[np.float64]:
        return xyz[idx[name]] if name in idx else np.full(3, np.nan)

    origin = 0.5 * (xyz[idx['left_hip']] + xyz[idx['right_hip']])
    left_up_forward = body_frame(at('left_shoulder'), at('right_shoulder'), at('left_hip'),
                                 at('right_hip'))
    rotation = left_up_forward[:, [2, 0, 1]]  # columns x forward, y left, z up
    root = f'body_{body}'
    out: list[Transform] = [(camera_frame, root, (*origin.tolist(), *quaternion(rotation)))]
    inside = (xyz - origin) @ rotation  # rows: each joint in the body's frame
    for name, link in BODY_LINKS.items():
        if name in idx:
            out.append((root, f'{link}_{body}', (*inside[idx[name]].tolist(),
                                                 0.0, 0.0, 0.0, 1.0)))
    return out
