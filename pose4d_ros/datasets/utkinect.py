"""Reader for UTKinect-Action3D skeleton files (real Kinect v1 motion).

`joints_sNN_eMM.txt`: one line per frame, whitespace separated: the frame number, then 20 joints
x (x, y, z) in metres in the Kinect SDK v1 skeleton space (61 columns). Frame numbers come from a
30 fps stream but are sparse (steps of 2-4) and sometimes repeat.

Kinect SDK skeleton space is right-handed: y up, z from the sensor towards the scene, x to the
sensor's left. Labels are the person's own sides (checked on the data: with x flipped into the
optical frame, the left-shoulder-to-right-shoulder vector crossed with the up vector points at
the camera in 99.8 % of the frames of s01_e01, as it must for a person facing the sensor).
`to_optical` converts to the camera optical frame (x right, y down, z forward).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

# Kinect SDK v1 joint order, as in the files.
UTKINECT_JOINTS: tuple[str, ...] = (
    'hip_center', 'spine', 'shoulder_center', 'head',
    'left_shoulder', 'left_elbow', 'left_wrist', 'left_hand',
    'right_shoulder', 'right_elbow', 'right_wrist', 'right_hand',
    'left_hip', 'left_knee', 'left_ankle', 'left_foot',
    'right_hip', 'right_knee', 'right_ankle', 'right_foot',
)

_NAME = re.compile(r'joints_(s\d+_e\d+)\.txt$')
_SUBJECT = re.compile(r'(?:^|_)s(\d+)(?:_|$)')


@dataclass(frozen=True)
class Take:
    """One UTKinect sequence.

    Attributes
    ----------
    name : 'sNN_eMM' (or an MSR Action3D sequence's 'aAA_sSS_eEE', `msraction3d.as_take`).
    frames : (F,) int frame numbers of a 30 fps stream, strictly increasing.
    joints : (F, 20, 3) float64 metres, Kinect SDK skeleton space, `UTKINECT_JOINTS` order.
    """

    name: str
    frames: NDArray[np.int64]
    joints: NDArray[np.float64]

    @property
    def subject(self) -> int:
        """NN of the name's 'sNN'."""
        match = _SUBJECT.search(self.name)
        if match is None:
            raise ValueError(f'{self.name!r}: no subject (sNN) in the take name')
        return int(match.group(1))


def read_rows(path: Path, n_fields: int, names: str = '') -> list[list[float]]:
    """The numbers of a text file of whitespace-separated lines, `n_fields` a line (blank lines
    skipped); `ValueError` naming the file and line for a line of another length (`names`, if
    given, says what the fields are) or a field that is not a number."""
    rows: list[list[float]] = []
    with path.open() as f:
        for lineno, line in enumerate(f, start=1):
            fields = line.split()
            if not fields:
                continue
            if len(fields) != n_fields:
                raise ValueError(f'{path}:{lineno}: expected {n_fields} fields'
                                 f'{f" ({names})" if names else ""}, got {len(fields)}')
            try:
                rows.append([float(x) for x in fields])
            except ValueError as exc:
                raise ValueError(f'{path}:{lineno}: non-numeric field ({exc})') from None
    return rows


def read_take(path: str | Path) -> Take:
    """Read one `joints_sNN_eMM.txt` file, dropping repeated frame numbers (first one kept).

    Raises `ValueError` naming the file and line for malformed lines, and for frame numbers
    that go backwards.
    """
    path = Path(path)
    match = _NAME.search(path.name)
    if not match:
        raise ValueError(f'{path}: not a UTKinect skeleton file name (joints_sNN_eMM.txt)')
    rows = read_rows(path, 61)
    if not rows:
        raise ValueError(f'{path}: no frames')
    data = np.asarray(rows)
    frames = data[:, 0].astype(np.int64)
    if np.any(np.diff(frames) < 0):
        bad = int(np.argmax(np.diff(frames) < 0)) + 2
        raise ValueError(f'{path}: frame numbers go backwards near data line {bad}')
    keep = np.concatenate([[True], np.diff(frames) > 0])
    return Take(match.group(1), frames[keep], data[keep, 1:].reshape(-1, 20, 3))


def list_takes(directory: str | Path) -> list[Path]:
    """The `joints_*.txt` files of a directory, sorted by name."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f'{directory}: not a directory')
    return sorted(p for p in directory.glob('joints_*.txt') if _NAME.search(p.name))


def read_actions(path: str | Path) -> dict[str, dict[str, tuple[int, int]]]:
    """`actionLabel.txt`: {take: {action: (start_frame, end_frame)}}; NaN ranges are skipped."""
    path = Path(path)
    out: dict[str, dict[str, tuple[int, int]]] = {}
    current: dict[str, tuple[int, int]] | None = None
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        if ':' not in line:
            current = out.setdefault(line, {})
            continue
        if current is None:
            raise ValueError(f'{path}:{lineno}: action before any take name')
        action, _, span = line.partition(':')
        parts = span.split()
        if len(parts) != 2:
            raise ValueError(f'{path}:{lineno}: expected "action: start end"')
        if 'NaN' in parts:
            continue
        current[action.strip()] = (int(parts[0]), int(parts[1]))
    return out


def resample(take: Take, *, fps: float = 30.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Linearly interpolate a take to a regular rate.

    Returns
    -------
    times : (T,) float64 seconds from the take's first frame, step 1/fps.
    joints : (T, 20, 3) float64, same frame as `take.joints`.
    """
    if fps <= 0:
        raise ValueError(f'fps must be positive, got {fps}')
    t_src = (take.frames - take.frames[0]) / 30.0
    times = np.arange(0.0, t_src[-1] + 1e-9, 1.0 / fps)
    flat = take.joints.reshape(len(take.frames), -1)
    out = np.empty((len(times), flat.shape[1]))
    for k in range(flat.shape[1]):
        out[:, k] = np.interp(times, t_src, flat[:, k])
    return times, out.reshape(len(times), 20, 3)


def to_optical(joints: NDArray[np.floating]) -> NDArray[np.float64]:
    """Kinect SDK skeleton space -> camera optical frame (x right, y down, z forward)."""
    return np.asarray(joints, dtype=np.float64) * np.array([-1.0, -1.0, 1.0])
