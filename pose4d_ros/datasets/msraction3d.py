"""Reader for MSR Action3D skeleton files (real Kinect v1 motion, 20 actions).

`aAA_sSS_eEE_skeleton3D.txt`: action AA (1-20), subject SS, take EE. 20 lines per frame, each
``x y z confidence``, metres, in the Kinect skeleton space (the same as UTKinect's: y up, z from
the sensor towards the scene), 15 frames a second. Frames where tracking failed hold zeros; some
sequences are empty or a few frames long. Li, Zhang and Liu, "Action recognition based on a bag
of 3D points", CVPR workshops 2010.

The output follows `datasets.utkinect`: joints in `UTKINECT_JOINTS` order, in the Kinect
skeleton space (`utkinect.to_optical` converts to the optical frame), resampled to 30 fps by
linear interpolation (`resample`). Labels are the person's own sides, as UTKinect's (checked on
all 447 sequences of s01-s08: with x flipped into the optical frame, the left-to-right shoulder
vector crossed with the hips-to-neck vector points away from the camera in 98 % of the frames,
as it does in 99.8 % of UTKinect's s01_e01; the rest are bends, where that vector lies flat).
Frames with a joint at exactly (0, 0, 0), a non-finite value or z <= 0 are dropped; gaps are
bridged by the interpolation, and `pieces` splits a sequence at gaps too long to bridge.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS, Take, read_rows
from pose4d_ros.datasets.utkinect import resample as _resample

FPS = 15.0  # the recording's frame rate

# The dataset's joint order (its body model), 1-20 in the files.
MSR_JOINTS: tuple[str, ...] = (
    'left_shoulder', 'right_shoulder', 'shoulder_center', 'spine', 'left_hip', 'right_hip',
    'hip_center', 'left_elbow', 'right_elbow', 'left_wrist', 'right_wrist', 'left_hand',
    'right_hand', 'left_knee', 'right_knee', 'left_ankle', 'right_ankle', 'left_foot',
    'right_foot', 'head',
)

# Row of the MSR frame that holds each UTKinect joint: `msr[TO_UTKINECT]` is in UTKinect order.
TO_UTKINECT: NDArray[np.int64] = np.array([MSR_JOINTS.index(n) for n in UTKINECT_JOINTS])

# Actions 1-20, named like UTKinect's (camelCase).
ACTIONS: tuple[str, ...] = (
    'highArmWave', 'horizontalArmWave', 'hammer', 'handCatch', 'forwardPunch', 'highThrow',
    'drawX', 'drawTick', 'drawCircle', 'handClap', 'twoHandWave', 'sideBoxing', 'bend',
    'forwardKick', 'sideKick', 'jogging', 'tennisSwing', 'tennisServe', 'golfSwing',
    'pickUpThrow',
)

_NAME = re.compile(r'(a(\d{2})_s(\d{2})_e(\d{2}))_skeleton3D\.txt$')


@dataclass(frozen=True)
class Sequence:
    """One MSR Action3D sequence, bad frames dropped.

    Attributes
    ----------
    name : 'aAA_sSS_eEE'.
    frames : (F,) int64 indices of the kept frames in the 15 fps recording, increasing.
    joints : (F, 20, 3) float64 metres, Kinect skeleton space, `UTKINECT_JOINTS` order.
    confidence : (F, 20) float64, the file's per-joint confidence (0 = inferred by the SDK).
    """

    name: str
    frames: NDArray[np.int64]
    joints: NDArray[np.float64]
    confidence: NDArray[np.float64]

    @property
    def action(self) -> int:
        return int(self.name[1:3])

    @property
    def action_name(self) -> str:
        return ACTIONS[self.action - 1]

    @property
    def subject(self) -> int:
        return int(self.name[5:7])

    @property
    def take(self) -> int:
        return int(self.name[9:11])


def parse_name(path: str | Path) -> tuple[str, int, int, int]:
    """('aAA_sSS_eEE', action, subject, take) of a skeleton file's name; ValueError otherwise."""
    match = _NAME.search(Path(path).name)
    if not match or not 1 <= int(match.group(2)) <= len(ACTIONS):
        raise ValueError(f'{path}: not an MSR Action3D skeleton file name '
                         '(aAA_sSS_eEE_skeleton3D.txt, action 01-20)')
    return match.group(1), int(match.group(2)), int(match.group(3)), int(match.group(4))


def read_sequence(path: str | Path) -> Sequence:
    """Read one `aAA_sSS_eEE_skeleton3D.txt` file.

    An empty file gives a sequence of no frames (the dataset has some: callers skip them).
    Raises `ValueError` naming the file (and line) for a bad name, a line without 4 numbers,
    or a number of lines that is not a multiple of 20.
    """
    path = Path(path)
    name = parse_name(path)[0]
    rows = read_rows(path, 4, 'x y z confidence')
    if len(rows) % 20:
        raise ValueError(f'{path}: {len(rows)} joint lines, not a multiple of 20 (20 a frame)')
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 20, 4)[:, TO_UTKINECT]
    xyz = data[..., :3]
    good = (np.isfinite(data).all(axis=(1, 2)) & ~np.all(xyz == 0.0, axis=2).any(axis=1)
            & (xyz[..., 2] > 0).all(axis=1))
    frames = np.flatnonzero(good).astype(np.int64)
    return Sequence(name, frames, xyz[good].copy(), data[good, :, 3].copy())


def list_sequences(directory: str | Path) -> list[Path]:
    """The `aAA_sSS_eEE_skeleton3D.txt` files of a directory, sorted by name."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f'{directory}: not a directory')
    return sorted(p for p in directory.glob('a*_skeleton3D.txt') if _NAME.search(p.name))


def action_number(spec: str) -> int:
    """1-20 from an action's name (any case), 'aNN' or 'NN'; ValueError otherwise."""
    s = spec.strip()
    lower = [a.lower() for a in ACTIONS]
    if s.lower() in lower:
        return lower.index(s.lower()) + 1
    digits = s[1:] if s[:1] in ('a', 'A') else s
    if digits.isdigit() and 1 <= int(digits) <= len(ACTIONS):
        return int(digits)
    raise ValueError(f'{spec!r} is not an MSR Action3D action (a01-a20 or one of '
                     f'{", ".join(ACTIONS)})')


def as_take(seq: Sequence) -> Take:
    """The sequence as a `utkinect.Take`: frame numbers on a 30 fps clock (twice the 15 fps
    index), so that `utkinect.resample` and `evaluation.tracking.split_take` apply."""
    return Take(seq.name, 2 * seq.frames, seq.joints)


def resample(seq: Sequence, *, fps: float = 30.0
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Linearly interpolate a sequence to a regular rate (across dropped frames too).

    Returns
    -------
    times : (T,) float64 seconds from the first kept frame, step 1/fps.
    joints : (T, 20, 3) float64 metres, Kinect skeleton space, `UTKINECT_JOINTS` order.
    """
    if len(seq.frames) == 0:
        raise ValueError(f'{seq.name}: no frames to resample')
    return _resample(as_take(seq), fps=fps)


def pieces(seq: Sequence, *, max_gap_s: float = 0.5) -> list[Sequence]:
    """The sequence split where more than `max_gap_s` seconds of frames were dropped (no
    motion is invented across such a gap); pieces in recording order."""
    if len(seq.frames) == 0:
        return []
    gaps = np.flatnonzero(np.diff(seq.frames) / FPS > max_gap_s)
    bounds = np.concatenate([[0], gaps + 1, [len(seq.frames)]])
    return [Sequence(seq.name, seq.frames[a:b], seq.joints[a:b], seq.confidence[a:b])
            for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
