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

The tracker that recorded the files swapped the legs' labels in some of them (`repair_legs`, on
by default in `read_sequence`): along the hips' left-to-right axis, s02's knees and feet lie on
the other side in 93 % of the frames of its actions 1-12 (the whole legs swapped), and s03's
ankles and feet are crossed by over half a hip width, knees apart, in 28 % of the frames of its
actions 1-12 (both kinds in 7 % each of its actions 13-20). A body posed on those joints has its
thighs or shins crossed in an X while punching or waving: a pose the recording's people did not
make, and the ground truth of a render that shows it. Each other subject and action group has
such frames in at most 3.8 % (s01's actions 13-20; s07 and s08: 0.1 % of actions 1-12, 0.8 and
1.4 % of 13-20). Counts per subject and action group:
`python -c "from pose4d_ros.datasets.msraction3d import leg_swap_table; leg_swap_table(DIR)"`.
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


def read_sequence(path: str | Path, *, repair: bool = True) -> Sequence:
    """Read one `aAA_sSS_eEE_skeleton3D.txt` file, its swapped legs put back (`repair_legs`;
    `repair=False`: the joints as recorded).

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
    joints, conf = xyz[good].copy(), data[good, :, 3].copy()
    if repair:
        joints, conf = repair_legs(joints, conf)[:2]
    return Sequence(name, frames, joints, conf)


# Left and right joints of a leg below the hip, and how far across (hip widths, along the hips'
# left-to-right axis) a pair must lie on the wrong side to be taken for swapped labels
LEG_PAIRS = (('left_knee', 'right_knee'), ('left_ankle', 'right_ankle'),
             ('left_foot', 'right_foot'))
SWAPPED_LEGS = 0.3    # knees and feet both crossed this far: the whole legs swapped
SWAPPED_SHINS = 0.5   # ankles crossed this far, knees not: the shins' ends swapped


def _across(joints: NDArray[np.float64], pair: tuple[str, str]) -> NDArray[np.float64]:
    """(F,) left minus right joint of `pair` along the hips' left-to-right axis, in hip widths
    (negative: crossed)."""
    lh, rh = (UTKINECT_JOINTS.index(n) for n in ('left_hip', 'right_hip'))
    axis = joints[:, lh] - joints[:, rh]
    width2 = np.maximum(np.einsum('ij,ij->i', axis, axis), 1e-12)
    left, right = (UTKINECT_JOINTS.index(n) for n in pair)
    return np.einsum('ij,ij->i', joints[:, left] - joints[:, right], axis) / width2


def _swap(joints: NDArray, frames: NDArray[np.bool_], pairs: tuple[tuple[str, str], ...]) -> None:
    for left, right in pairs:
        i, j = UTKINECT_JOINTS.index(left), UTKINECT_JOINTS.index(right)
        joints[frames, i], joints[frames, j] = joints[frames, j].copy(), joints[frames, i].copy()


def repair_legs(joints: NDArray[np.float64], confidence: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_],
                           NDArray[np.bool_]]:
    """Put back leg labels the recording's tracker swapped, frame by frame.

    A frame whose knees and feet both lie over `SWAPPED_LEGS` hip widths on the wrong side of
    each other (along the hips' left-to-right axis) has its knees, ankles and feet swapped;
    then a frame whose ankles are crossed by over `SWAPPED_SHINS` hip widths while its knees
    are not has its ankles and feet swapped. Their confidences follow.

    Returns
    -------
    joints, confidence : repaired copies.
    legs, shins : (F,) bool, the frames of each repair.
    """
    joints, confidence = joints.copy(), confidence.copy()
    legs = ((_across(joints, LEG_PAIRS[0]) < -SWAPPED_LEGS)
            & (_across(joints, LEG_PAIRS[2]) < -SWAPPED_LEGS))
    for a in (joints, confidence[..., None]):
        _swap(a, legs, LEG_PAIRS)
    shins = ((_across(joints, LEG_PAIRS[1]) < -SWAPPED_SHINS)
             & (_across(joints, LEG_PAIRS[0]) > 0))
    for a in (joints, confidence[..., None]):
        _swap(a, shins, LEG_PAIRS[1:])
    return joints, confidence, legs, shins


def leg_swap_table(directory: str | Path) -> dict[str, tuple[int, int, int]]:
    """Per subject and action group ('s02 a01-12'): frames, frames of swapped legs and of
    swapped shins (`repair_legs`) over a directory's files; printed as a table."""
    table: dict[str, list[int]] = {}
    for path in list_sequences(directory):
        seq = read_sequence(path, repair=False)
        _, legs, shins = repair_legs(seq.joints, seq.confidence)[1:]
        key = f's{seq.subject:02d} a{"01-12" if seq.action <= 12 else "13-20"}'
        row = table.setdefault(key, [0, 0, 0])
        row[0] += len(legs)
        row[1] += int(legs.sum())
        row[2] += int(shins.sum())
    for key, (n, legs, shins) in sorted(table.items()):
        print(f'{key}  {n:5d} frames  legs swapped {100 * legs / max(n, 1):5.1f} %  '
              f'shins swapped {100 * shins / max(n, 1):5.1f} %')
    return {k: tuple(v) for k, v in table.items()}


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
