"""Test data shared by several test modules: a body in front of the camera and its parts as a
message, synthetic Kinect motion and tiny UTKinect and MSR Action3D files made from it, small
part models and photograph networks of random weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import cad60_intrinsics, project
from pose4d_ros.core.convnet import ConvNet
from pose4d_ros.core.dpm import PartModel
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


def diagnostic_values(diagnostics: list, stage: str, key: str) -> list[int]:
    """The values of `key` in stage `stage`'s status (`pose4d: <stage>`) of every
    DiagnosticArray received, in order."""
    return [int(kv.value) for m in diagnostics for s in m.status for kv in s.values
            if s.name == f'pose4d: {stage}' and kv.key == key]


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


# ------------------------------------------------------------------- part models and networks

NAMES = ('right_ankle', 'right_knee', 'right_hip', 'left_hip', 'left_knee', 'left_ankle',
         'right_wrist', 'right_elbow', 'right_shoulder', 'left_shoulder', 'left_elbow',
         'left_wrist', 'neck', 'head')


MIRROR = (5, 4, 3, 2, 1, 0, 11, 10, 9, 8, 7, 6, 12, 13)


def random_net(width: int = 4, input_px: int = 64, seed: int = 0) -> ConvNet:
    """A network of the shipped shape with random weights."""
    rng = np.random.default_rng(seed)
    shapes = {'stem': (3, 3, width)}
    for stage, cin, cout, blocks in (('s2', width, 2 * width, 2), ('s3', 2 * width, 4 * width, 2),
                                     ('s4', 4 * width, 6 * width, 3)):
        for i in range(blocks):
            shapes[f'{stage}.{i}.c1'] = (3, cin if i == 0 else cout, cout)
            shapes[f'{stage}.{i}.c2'] = (3, cout, cout)
            if i == 0:
                shapes[f'{stage}.{i}.skip'] = (1, cin, cout)
    shapes.update({'l3': (1, 4 * width, 6 * width), 'u3.c1': (3, 6 * width, 4 * width),
                   'u3.c2': (3, 4 * width, 4 * width), 'u3.skip': (1, 6 * width, 4 * width),
                   'l2': (1, 2 * width, 4 * width), 'u2.c1': (3, 4 * width, 2 * width),
                   'u2.c2': (3, 2 * width, 2 * width), 'u2.skip': (1, 4 * width, 2 * width),
                   'head': (1, 2 * width, 14)})
    weights = {n: ((rng.normal(0, (2 / (k * k * i)) ** 0.5, (k, k, i, o))).astype(np.float32),
                   rng.normal(0, 0.1, o).astype(np.float32))
               for n, (k, i, o) in shapes.items()}
    return ConvNet(NAMES, MIRROR, input_px, weights, {'seed': seed})


def random_model(parents, k=2, fs=2, channels='rgb', seed=0) -> PartModel:
    rng = np.random.default_rng(seed)
    p = len(parents)
    c = 32 if channels == 'rgb' else 64
    springs = np.zeros((p, k, 4), np.float32)
    springs[1:] = rng.uniform(0.0, 0.3, (p - 1, k, 4))
    springs[1:, :, [1, 3]] += 0.05
    names = tuple(f'p{i}' for i in range(p))
    return PartModel(names, tuple(parents), channels, 4,
                     rng.normal(size=(p, k, fs, fs, c)).astype(np.float32),
                     springs, rng.integers(-2, 3, (p, k, 2)).astype(np.int32),
                     rng.normal(size=(p, k, k)).astype(np.float32), 32.0, 0.5, (20.0, 60.0),
                     'float' if channels == 'rgbd' else '')


def planted_image(rng: np.random.Generator) -> np.ndarray:
    """Grey noise with three distinct bright/dark blobs (the 'parts')."""
    im = rng.integers(90, 110, (96, 96)).astype(np.float32)
    yy, xx = np.mgrid[0:96, 0:96]
    for (cy, cx, r, v) in ((30, 40, 6, 250.0), (60, 30, 5, 0.0), (62, 66, 7, 200.0)):
        im[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = v
    return np.repeat(im[:, :, None], 3, axis=2).astype(np.uint8)


def tenpart_model(channels: str = 'rgbd') -> PartModel:
    rng = np.random.default_rng(1)
    k = 3
    base = random_model(PARTS_10.parents, k=k, fs=5, channels=channels, seed=1)
    return PartModel(PARTS_10.names, PARTS_10.parents, channels, 4, base.filters * 0.05,
                     base.springs, base.anchors, base.bias * 0.1, 32.0, 0.5, (30.0, 80.0),
                     base.depth_encoding, (0.5, 4.5),
                     rng.normal(size=(10, 3)).astype(np.float32), True,
                     {'data': 'unit test', 'seed': '1'})


def person_frame(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box 'person' at 2.5 m in front of a wall at 4 m."""
    col = rng.integers(0, 256, (240, 320, 3)).astype(np.uint8)
    depth = np.full((240, 320), 4.0, np.float32)
    mask = np.zeros((240, 320), bool)
    mask[40:220, 130:190] = True
    depth[mask] = 2.5
    return col, depth, mask
