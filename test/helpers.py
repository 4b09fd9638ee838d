"""Test data shared by several test modules: a body in front of the camera and its parts as a
message, synthetic Kinect motion and tiny UTKinect and MSR Action3D files made from it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import cad60_intrinsics, project
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.skeleton import PARTS_10
from pose4d_ros.datasets.msraction3d import MSR_JOINTS
from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS
from pose4d_ros.synth import render

INTR = cad60_intrinsics()

# A person 2.5 m away, optical frame (metres): 14 joints, elbows and knees bent.
BODY = {
    'head': (0.0, -0.75, 2.5), 'neck': (0.0, -0.5, 2.5),
    'left_shoulder': (0.18, -0.48, 2.5), 'right_shoulder': (-0.18, -0.48, 2.5),
    'left_elbow': (0.30, -0.30, 2.42), 'right_elbow': (-0.30, -0.30, 2.42),
    'left_wrist': (0.38, -0.12, 2.35), 'right_wrist': (-0.38, -0.12, 2.35),
    'left_hip': (0.1, 0.0, 2.5), 'right_hip': (-0.1, 0.0, 2.5),
    'left_knee': (0.12, 0.45, 2.42), 'right_knee': (-0.12, 0.45, 2.42),
    'left_ankle': (0.12, 0.9, 2.5), 'right_ankle': (-0.12, 0.9, 2.5),
}

# Index of each UTKinect joint by name.
J = {n: i for i, n in enumerate(UTKINECT_JOINTS)}


def standing_pose(z: float = 2.8, cam_height: float = 1.0, arm: float = 0.0) -> np.ndarray:
    """A person facing the camera (optical frame), feet on a floor `cam_height` below the
    camera; `arm` (radians) lifts both arms sideways."""
    d = render._REST_DIR.copy()
    for side, sign in (('left', 1.0), ('right', -1.0)):
        for joint in (f'{side}_elbow', f'{side}_wrist', f'{side}_hand'):
            d[J[joint]] = [sign * np.sin(arm), np.cos(arm), -0.1]
    d[1:] /= np.linalg.norm(d[1:], axis=1, keepdims=True)
    pose = np.zeros((20, 3))
    for i in range(1, 20):
        pose[i] = pose[render.PARENTS[i]] + d[i] * render.REF_BONES[i]
    pose += [0.0, cam_height - 0.04 - pose[[14, 15, 18, 19], 1].max(), z]
    return pose


def synthetic_take(frames: int = 90) -> np.ndarray:
    """(F, 20, 3) optical-frame motion: arms swinging, walking slowly sideways and away."""
    t = np.arange(frames) / 30.0
    out = np.array([standing_pose(z=2.5 + 0.4 * np.sin(1.5 * ti), cam_height=0.9,
                                  arm=0.3 + 0.8 * np.sin(2 * ti)) for ti in t])
    out[:, :, 0] += 0.3 * np.sin(2 * t)[:, None]
    return out


def write_utkinect(directory: Path, frames: int = 90) -> None:
    """A tiny UTKinect directory: s01_e01 and s02_e01 from `synthetic_take`."""
    directory.mkdir(parents=True, exist_ok=True)
    sdk = synthetic_take(frames) * [-1.0, -1.0, 1.0]  # optical -> Kinect SDK space
    for name in ('s01_e01', 's02_e01'):
        lines = [' '.join([str(2 * i + 10)] + [f'{v:.5f}' for v in sdk[i].ravel()])
                 for i in range(frames)]
        (directory / f'joints_{name}.txt').write_text('\n'.join(lines) + '\n')
    (directory / 'actionLabel.txt').write_text(
        's01_e01\nwaveHands: 10 100\nclapHands: NaN NaN\ns02_e01\nsitDown: 150 180\n')


def write_msr(directory: Path, name: str, frames: int = 30, *, zero: tuple[int, ...] = (),
              start: int = 0, joints: np.ndarray | None = None) -> np.ndarray:
    """An `aAA_sSS_eEE_skeleton3D.txt` of `synthetic_take` at 15 fps (every other 30 fps frame),
    or of `joints` ((frames, 20, 3) Kinect space, UTKinect order) when given; frames in `zero`
    hold zeros. Returns the (frames, 20, 3) Kinect-space joints, UTKinect order."""
    directory.mkdir(parents=True, exist_ok=True)
    sdk = synthetic_take(2 * (frames + start))[2 * start::2] * [-1.0, -1.0, 1.0] \
        if joints is None else np.asarray(joints, np.float64)
    frames = len(sdk)
    lines = []
    for f in range(frames):
        for name_j in MSR_JOINTS:
            x, y, z = (0.0, 0.0, 0.0) if f in zero else sdk[f, J[name_j]]
            lines.append(f'{x:.6f} {y:.6f} {z:.6f} 1.000000')
    (directory / f'{name}_skeleton3D.txt').write_text('\n'.join(lines) + '\n')
    return sdk


def header_at(k: int):
    """The header of frame k of a 30 fps camera (rclpy message)."""
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import ns_to_stamp

    return Header(stamp=ns_to_stamp(1_700_000_000_000_000_000 + k * 33_333_334),
                  frame_id='camera_color_optical_frame')


def parts_msg(k: int, header, *, missing=()):
    """The 10 parts of `BODY` moved 2 mm right per frame, as a JointArray (rclpy), `missing`
    ones MISSING."""
    from pose4d_ros.nodes.convert import joints_to_msg

    xyz = np.array([BODY[n] for n in PARTS_10.names]) + [0.002 * k, 0, 0]
    uv = project(xyz, INTR)
    src = np.full(10, cj.DETECTED, np.uint8)
    for name in missing:
        i = PARTS_10.index(name)
        uv[i], xyz[i], src[i] = np.nan, np.nan, cj.MISSING
    return joints_to_msg(JointSet(PARTS_10.names, uv, xyz, source=src,
                                  confidence=np.where(src == 0, 0.9, 0.0)), header)
