"""Reader and writer of the Cornell Activity Dataset CAD-60 on-disk layout (Kinect v1, OpenNI).

Layout (see docs DATA.md), per person directory `dataN/`:

- `activityLabel.txt`: one line per video, `id,activity name,` (id: 10 digits).
- `<id>.txt`: the skeleton, one line per frame, 171 comma-separated numbers and a trailing
  comma, then a last line `END`. Fields: frame number; for joints 1-11 a 3x3 orientation
  matrix row by row, its confidence, X, Y, Z and the position confidence (14 values); for
  joints 12-15 X, Y, Z and confidence (4 values).
- `<id>/RGB_<k>.png` (8-bit, 3 channels) and `<id>/Depth_<k>.png` (single-channel 16-bit,
  millimetres, 0 = no reading, registered to the RGB grid), k = frame number of the skeleton
  line. The synthetic sets written by `pose4d synth` add `<id>/Mask_<k>.png` (8-bit, 255 =
  person), which `read_frames` reads into `Frame.mask` when present (`load_mask`).

Several people (the synthetic sets of `pose4d synth --people N`, N = 2-3; an extension of the
layout, which real CAD-60 never has). Person 1 of a video stays in `<id>.txt`, exactly as in a
single-person set; persons k = 2..N are in `<id>_p<k>.txt` beside it (k consecutive from 2), in
the same line format, with the same frame numbers, one line per frame. In a several-person video
every person's confidences (person 1's too) (position and orientation, all 15 joints) are 0 in a
frame where that person is not seen (out of the picture, or hidden behind another person or
furniture: `pose4d synth` counts fewer than 40 visible pixels at 320x240 as not seen) and 1
otherwise; the positions are written all the same (the rendered skeleton). `<id>/Mask_<k>.png`
holds every person's pixels, and `<id>/People_<k>.png` (8-bit, single channel) says whose they
are: k where person k is the visible surface, 0 elsewhere (`load_people`). `read_frames` gives
every person's ground truth in `Frame.people` (person k with `track_id` k), `Frame.truth` =
person 1's, and `Frame.mask` = every person's pixels: the foreground stage is to find all
people, so its ground truth holds all of them (person 1's alone would score the others' pixels
as false positives). A single-person video (no `_p<k>` files) reads exactly as before, with
`Frame.people` empty.

Frames. Joint positions in the files are millimetres in the OpenNI world frame: x to the image
right, y up, z away from the camera. The OpenNI perspective model at 320x240 (the dataset's
README) is `u = 160 + 285.171 x / z`, `v = 120 - 285.117 y / z`, which is the pinhole model of
`core.camera.cad60_intrinsics()` applied to the optical frame (x right, y down, z forward,
metres) that `world_to_optical` returns: `(x, -y, z) / 1000`. The README's affine fit
(`project_affine`) is kept for comparison only; it is right near 2.4-2.9 m.

Left and right. OpenNI labels in CAD-60 are mirrored: the file's "left" joints of a person
facing the camera are the person's anatomical right (they sit at smaller u, the image left).
The project's convention is anatomical sides everywhere, so `read_skeleton` swaps the left and
right slots (`_MIRROR`, the one place this happens), and `write_skeleton` swaps them back, so
files written here read exactly like the real ones. Orientation matrices move with their joint
(the slots are swapped; the matrices themselves are not reflected).

Every file written here goes to a temporary name in the same directory first and is renamed
when complete, so an interrupted run never leaves a half-written file behind.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics, depth_to_metres, project
from pose4d_ros.core.files import write_atomic
from pose4d_ros.core.joints import DETECTED, MISSING, JointSet
from pose4d_ros.core.skeleton import CAD60_JOINTS, mirror_index
from pose4d_ros.datasets.frame import Frame

N_JOINTS = 15
N_ORIENTED = 11  # joints 1-11 carry an orientation matrix
N_FIELDS = 1 + 14 * N_ORIENTED + 4 * (N_JOINTS - N_ORIENTED)  # 171 numbers per line

# The README's affine fit at 320x240: (u, v) = A @ (x, y, z) + b, x, y, z in mm (world frame).
AFFINE_U = (156.858, 0.0977, -0.00064, 0.00157)
AFFINE_V = (125.536, 0.000215, -0.11849, -0.00221)

_ID = re.compile(r'^\d{10}$')

# The frames' clock (`read_frames`, and the stamps of `pose4d cad60-to-bag`): 30 fps from T0_S,
# a one-second gap between videos.
T0_S = 1_700_000_000.0
FRAME_PERIOD_NS = 1_000_000_000 // 30 + 1  # 33.333... ms, rounded up so stamps never repeat
VIDEO_GAP_NS = 1_000_000_000


# OpenNI's mirrored labels: anatomical joint i is stored in file slot _MIRROR[i] (an involution,
# so the same map converts both ways). Joints 1-11 are mapped onto joints 1-11 only.
_MIRROR = tuple(mirror_index(CAD60_JOINTS))


@dataclass(frozen=True)
class Skeleton:
    """The skeleton track of one CAD-60 video, in anatomical left/right convention.

    Attributes
    ----------
    frames : (F,) int64, frame numbers k (from 1), strictly increasing; `RGB_<k>.png` etc.
    joints_mm : (F, 15, 3) float64, millimetres, OpenNI world frame (x right, y up, z away),
        `skeleton.CAD60_JOINTS` order.
    joint_conf : (F, 15) float64, position confidence (0, 0.5 or 1 in OpenNI files).
    orientations : (F, 11, 3, 3) float64, orientation matrices of joints 1-11 (rows as in the
        file), world frame.
    orientation_conf : (F, 11) float64.
    """

    frames: NDArray[np.int64]
    joints_mm: NDArray[np.float64]
    joint_conf: NDArray[np.float64]
    orientations: NDArray[np.float64]
    orientation_conf: NDArray[np.float64]

    def __post_init__(self) -> None:
        f = len(self.frames)
        shapes = {
            'joints_mm': (self.joints_mm.shape, (f, N_JOINTS, 3)),
            'joint_conf': (self.joint_conf.shape, (f, N_JOINTS)),
            'orientations': (self.orientations.shape, (f, N_ORIENTED, 3, 3)),
            'orientation_conf': (self.orientation_conf.shape, (f, N_ORIENTED)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f'Skeleton.{name} has shape {got}, expected {want}')
        if f and (np.any(self.frames < 1) or np.any(np.diff(self.frames) <= 0)):
            raise ValueError('Skeleton.frames must be >= 1 and strictly increasing')

    def __len__(self) -> int:
        return len(self.frames)

    def joints_optical(self) -> NDArray[np.float64]:
        """(F, 15, 3) float64 metres, camera optical frame (x right, y down, z forward)."""
        return world_to_optical(self.joints_mm)

    def pixels(self, intrinsics: Intrinsics | None = None, *,
               model: str = 'perspective') -> NDArray[np.float64]:
        """(F, 15, 2) float64 pixel (u, v) of every joint; see `project_joints`."""
        return project_joints(self.joints_mm, intrinsics, model=model)


@dataclass(frozen=True)
class Video:
    """One CAD-60 video: `person_dir/<video_id>.txt` and the frames in `person_dir/<video_id>/`."""

    person_dir: Path
    video_id: str
    activity: str

    @property
    def skeleton_path(self) -> Path:
        return self.person_dir / f'{self.video_id}.txt'

    @property
    def frame_dir(self) -> Path:
        return self.person_dir / self.video_id

    @property
    def person(self) -> str:
        """The person directory's name, e.g. `data1`."""
        return self.person_dir.name

    def skeleton_paths(self) -> list[Path]:
        """Every person's skeleton file: `<id>.txt`, then `<id>_p2.txt`, `<id>_p3.txt`, ...
        of a several-person video (see the module docstring). Raises `ValueError` when the
        person numbers have a gap."""
        pattern = re.compile(rf'^{re.escape(self.video_id)}_p(\d+)\.txt$')
        extra = {int(m.group(1)): path for path in self.person_dir.glob(f'{self.video_id}_p*.txt')
                 if (m := pattern.match(path.name))}
        numbers = sorted(extra)
        if numbers != list(range(2, 2 + len(numbers))):
            raise ValueError(f'{self.person_dir}: video {self.video_id} has person skeleton '
                             f'files for persons {numbers}; expected 2..N without gaps')
        return [self.skeleton_path] + [extra[k] for k in numbers]


# --------------------------------------------------------------------------------------------
# Frames and projection
# --------------------------------------------------------------------------------------------

def world_to_optical(joints_mm: NDArray[np.floating]) -> NDArray[np.float64]:
    """OpenNI world millimetres (x right, y up, z away) -> optical-frame metres (y down).

    Parameters
    ----------
    joints_mm : (..., 3) float, millimetres, OpenNI world frame.

    Returns
    -------
    (..., 3) float64 metres, optical frame, consistent with `core.camera.cad60_intrinsics()`.
    """
    return np.asarray(joints_mm, dtype=np.float64) * np.array([1e-3, -1e-3, 1e-3])


def project_perspective(joints_mm: NDArray[np.floating],
                        intrinsics: Intrinsics | None = None) -> NDArray[np.float64]:
    """The OpenNI perspective model: `u = cx + fx x / z`, `v = cy - fy y / z`.

    Parameters
    ----------
    joints_mm : (..., 3) float, millimetres, OpenNI world frame.
    intrinsics : the camera; default `cad60_intrinsics()` (320x240).

    Returns
    -------
    (..., 2) float64 pixel (u, v); NaN where z <= 0 (OpenNI writes 0 for lost joints).
    """
    intrinsics = intrinsics or cad60_intrinsics()
    p = np.asarray(joints_mm, dtype=np.float64)
    uv = project(world_to_optical(p).reshape(-1, 3), intrinsics)
    return uv.reshape(*p.shape[:-1], 2)


def project_affine(joints_mm: NDArray[np.floating],
                   intrinsics: Intrinsics | None = None) -> NDArray[np.float64]:
    """The CAD-60 README's affine fit (valid near z = 2.4-2.9 m), for comparison only.

    The fit is for 320x240; for another image size the pixels are scaled. Rows with z <= 0
    give NaN, as in `project_perspective`.
    """
    intrinsics = intrinsics or cad60_intrinsics()
    p = np.asarray(joints_mm, dtype=np.float64)
    au, av = np.asarray(AFFINE_U), np.asarray(AFFINE_V)
    u = au[0] + p[..., 0] * au[1] + p[..., 1] * au[2] + p[..., 2] * au[3]
    v = av[0] + p[..., 0] * av[1] + p[..., 1] * av[2] + p[..., 2] * av[3]
    uv = np.stack([u * intrinsics.width / 320.0, v * intrinsics.height / 240.0], axis=-1)
    uv[~(p[..., 2] > 0)] = np.nan
    return uv


def project_joints(joints_mm: NDArray[np.floating], intrinsics: Intrinsics | None = None, *,
                   model: str = 'perspective') -> NDArray[np.float64]:
    """Project world-frame joints to pixels with `model` = 'perspective' (default) or 'affine'."""
    if model == 'perspective':
        return project_perspective(joints_mm, intrinsics)
    if model == 'affine':
        return project_affine(joints_mm, intrinsics)
    raise ValueError(f"projection model must be 'perspective' or 'affine', got {model!r}")


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------

def read_activity_labels(path: str | Path) -> dict[str, str]:
    """`activityLabel.txt` -> {video id: activity name}, in file order.

    Lines are `id,activity name,`; blank lines are skipped. Raises `ValueError` naming the
    file and line for a line without an id and a name, or a repeated id.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f'{path}: activity label file not found')
    out: dict[str, str] = {}
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        fields = [f.strip() for f in line.split(',')]
        if len(fields) < 2 or not fields[0] or not fields[1]:
            raise ValueError(f'{path}:{lineno}: expected "id,activity name,", got {line!r}')
        vid = fields[0]
        if vid in out:
            raise ValueError(f'{path}:{lineno}: video id {vid} listed twice')
        out[vid] = fields[1]
    return out


def read_skeleton(path: str | Path) -> Skeleton:
    """Read one CAD-60 skeleton file `<id>.txt`, converting OpenNI's mirrored labels.

    Returns
    -------
    Skeleton with anatomical left/right (see the module docstring).

    Raises
    ------
    ValueError naming the file and line for a wrong field count, a non-numeric field, a frame
    number that is not a positive integer or does not increase, data after `END`, or a
    missing `END` line.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f'{path}: skeleton file not found')
    rows: list[list[float]] = []
    ended = False
    with path.open() as f:
        for lineno, line in enumerate(f, start=1):
            line = line.strip()
            if not line:
                continue
            if ended:
                raise ValueError(f'{path}:{lineno}: data after the END line')
            if line == 'END':
                ended = True
                continue
            fields = line.split(',')
            if fields[-1].strip() == '':
                fields = fields[:-1]  # the trailing comma of every line
            if len(fields) != N_FIELDS:
                raise ValueError(
                    f'{path}:{lineno}: expected {N_FIELDS} comma-separated numbers, '
                    f'got {len(fields)}')
            try:
                values = [float(x) for x in fields]
            except ValueError:
                bad = next(x for x in fields if not _is_number(x))
                raise ValueError(f'{path}:{lineno}: non-numeric field {bad!r}') from None
            if not np.all(np.isfinite(values)):
                raise ValueError(f'{path}:{lineno}: non-finite number')
            k = values[0]
            if k != int(k) or k < 1:
                raise ValueError(f'{path}:{lineno}: frame number {fields[0]!r} is not a '
                                 'positive integer')
            if rows and k <= rows[-1][0]:
                raise ValueError(f'{path}:{lineno}: frame number {int(k)} does not increase '
                                 f'(previous {int(rows[-1][0])})')
            rows.append(values)
    if not ended:
        raise ValueError(f'{path}: missing the END line (truncated file?)')
    data = np.asarray(rows, dtype=np.float64).reshape(-1, N_FIELDS)
    return _skeleton_from_rows(data)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _skeleton_from_rows(data: NDArray[np.float64]) -> Skeleton:
    f = len(data)
    oriented = data[:, 1:1 + 14 * N_ORIENTED].reshape(f, N_ORIENTED, 14)
    rest = data[:, 1 + 14 * N_ORIENTED:].reshape(f, N_JOINTS - N_ORIENTED, 4)
    joints = np.concatenate([oriented[:, :, 10:13], rest[:, :, 0:3]], axis=1)
    conf = np.concatenate([oriented[:, :, 13], rest[:, :, 3]], axis=1)
    rot = oriented[:, :, 0:9].reshape(f, N_ORIENTED, 3, 3)
    rot_conf = oriented[:, :, 9]
    # File slot -> anatomical joint (the mirrored OpenNI labels; see the module docstring).
    perm = np.asarray(_MIRROR)
    return Skeleton(
        frames=data[:, 0].astype(np.int64),
        joints_mm=joints[:, perm],
        joint_conf=conf[:, perm],
        orientations=rot[:, perm[:N_ORIENTED]],
        orientation_conf=rot_conf[:, perm[:N_ORIENTED]],
    )


def list_videos(root: str | Path) -> list[Video]:
    """The videos under a CAD-60 directory.

    Parameters
    ----------
    root : a person directory (`dataN/`, holding `activityLabel.txt`) or a directory of them.

    Returns
    -------
    Videos sorted by person directory, then in `activityLabel.txt` order. Raises `ValueError`
    when no `activityLabel.txt` is found or a listed skeleton file is missing.
    """
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f'{root}: not a directory')
    if (root / 'activityLabel.txt').is_file():
        person_dirs = [root]
    else:
        person_dirs = sorted(p for p in root.iterdir()
                             if p.is_dir() and (p / 'activityLabel.txt').is_file())
    if not person_dirs:
        raise ValueError(f'{root}: no activityLabel.txt here or in its subdirectories '
                         '(expected the CAD-60 layout dataN/activityLabel.txt)')
    videos = []
    for person_dir in person_dirs:
        for vid, activity in read_activity_labels(person_dir / 'activityLabel.txt').items():
            video = Video(person_dir, vid, activity)
            if not video.skeleton_path.is_file():
                raise ValueError(f'{person_dir / "activityLabel.txt"}: video {vid} listed but '
                                 f'{video.skeleton_path} is missing')
            videos.append(video)
    return videos


def load_rgb(path: str | Path) -> NDArray[np.uint8]:
    """Read an RGB PNG -> (H, W, 3) uint8 in RGB channel order (an alpha channel is dropped)."""
    path = Path(path)
    img = _imread(path)
    if img.dtype != np.uint8:
        raise ValueError(f'{path}: RGB image must be 8-bit, got {img.dtype}')
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f'{path}: RGB image must have 3 channels, got shape {img.shape}')
    return np.ascontiguousarray(img[:, :, 2::-1])  # OpenCV gives BGR(A)


def load_depth(path: str | Path) -> NDArray[np.uint16]:
    """Read a depth PNG -> (H, W) uint16 millimetres, 0 = no reading.

    An 8-bit file is refused: 8-bit depth images are visualisations, not measurements.
    """
    path = Path(path)
    img = _imread(path)
    if img.dtype != np.uint16:
        raise ValueError(f'{path}: depth image must be 16-bit (millimetres), got {img.dtype}; '
                         '8-bit depth files are visualisations, not measurements')
    if img.ndim != 2:
        raise ValueError(f'{path}: depth image must be single-channel, got shape {img.shape}')
    return img


def load_people(path: str | Path) -> NDArray[np.uint8]:
    """Read a several-person set's `People_<k>.png` -> (H, W) uint8: k where person k is the
    visible surface, 0 elsewhere."""
    path = Path(path)
    img = _imread(path)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f'{path}: person labels must be a single-channel 8-bit image, got '
                         f'{img.dtype} {img.shape}')
    return img


def person_skeleton_path(person_dir: str | Path, video_id: str, person: int) -> Path:
    """The skeleton file of person 1, 2, ... of a video: `<id>.txt`, `<id>_p<k>.txt`."""
    if person < 1:
        raise ValueError(f'persons are numbered from 1, got {person}')
    name = f'{video_id}.txt' if person == 1 else f'{video_id}_p{person}.txt'
    return Path(person_dir) / name


def people_path(frame_dir: str | Path, k: int) -> Path:
    """The person-label PNG of frame k of a several-person video."""
    return Path(frame_dir) / f'People_{k}.png'


def load_mask(path: str | Path) -> NDArray[np.bool_]:
    """Read a synthetic set's `Mask_<k>.png` (8-bit, 255 = person) -> (H, W) bool."""
    path = Path(path)
    img = _imread(path)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f'{path}: mask must be a single-channel 8-bit image, got '
                         f'{img.dtype} {img.shape}')
    return img > 127


def _imread(path: Path) -> NDArray:
    if not path.is_file():
        raise ValueError(f'{path}: image file not found')
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f'{path}: not a readable image')
    return img


def frame_paths(frame_dir: str | Path, k: int) -> tuple[Path, Path, Path]:
    """(RGB, Depth, Mask) PNG paths of frame k in a video's frame directory."""
    d = Path(frame_dir)
    return d / f'RGB_{k}.png', d / f'Depth_{k}.png', d / f'Mask_{k}.png'


def load_frame(frame_dir: str | Path, k: int) -> tuple[NDArray[np.uint8], NDArray[np.uint16]]:
    """Load frame k: ((H, W, 3) uint8 RGB, (H, W) uint16 depth mm).

    Raises `ValueError` naming the file when a PNG is missing or of the wrong kind, or when
    the RGB and depth images differ in size.
    """
    rgb_path, depth_path, _ = frame_paths(frame_dir, k)
    rgb = load_rgb(rgb_path)
    depth = load_depth(depth_path)
    if rgb.shape[:2] != depth.shape:
        raise ValueError(f'{depth_path}: depth is {depth.shape[1]}x{depth.shape[0]} but '
                         f'{rgb_path.name} is {rgb.shape[1]}x{rgb.shape[0]} (they must be '
                         'registered on the same grid)')
    return rgb, depth


def read_frames(root: str | Path, *, stride: int = 1, videos: Sequence[str] | None = None,
                max_frames: int | None = None, projection: str = 'perspective',
                t0_s: float = T0_S) -> Iterator[Frame]:
    """The frames of a CAD-60 directory (real or synthetic), video after video.

    Each frame has its RGB, its depth in metres, the OpenNI perspective intrinsics at its size,
    the video's skeleton as ground truth (the 15 joints' pixels by `projection`, 'perspective' or
    the README's 'affine' fit; 3-D in the optical frame; the file's confidence, MISSING where it
    is 0) and, in the synthetic sets, the person mask (`Mask_<k>.png`). A several-person video
    (`<id>_p<k>.txt` files, see the module docstring) also gives every person's ground truth in
    `Frame.people` (`track_id` = person number; `truth` is person 1's). Stamps keep the videos'
    30 fps clock from `t0_s`, with a one-second gap between videos.

    Parameters
    ----------
    root : a person directory (`dataN/`) or a directory of them.
    stride : every n-th frame of each video.
    videos : only these video ids (all if None).
    max_frames : only the first `max_frames` frames of each video.
    """
    if stride < 1:
        raise ValueError(f'stride must be >= 1, got {stride}')
    if projection not in ('perspective', 'affine'):
        raise ValueError(f"projection must be 'perspective' or 'affine', got {projection!r}")
    selected = list_videos(root)
    if videos is not None:
        unknown = set(videos) - {v.video_id for v in selected}
        if unknown:
            raise ValueError(f'{root}: no video(s) {", ".join(sorted(unknown))}')
        selected = [v for v in selected if v.video_id in set(videos)]
    stamp_ns = int(round(t0_s * 1e9))
    for video in selected:
        paths = video.skeleton_paths()
        skeletons = [read_skeleton(path) for path in paths]
        skeleton = skeletons[0]
        for other, path in zip(skeletons[1:], paths[1:], strict=True):
            if not np.array_equal(other.frames, skeleton.frames):
                raise ValueError(f'{path}: its frame numbers differ from {paths[0].name}\'s')
        with_mask = len(skeleton) > 0 and \
            frame_paths(video.frame_dir, int(skeleton.frames[0]))[2].is_file()
        for i, k in enumerate(skeleton.frames[:max_frames]):
            if i:
                stamp_ns += FRAME_PERIOD_NS * int(k - skeleton.frames[i - 1])
            if i % stride:
                continue
            rgb_path, _, mask_path = frame_paths(video.frame_dir, int(k))
            rgb, depth = load_frame(video.frame_dir, int(k))
            mask = load_mask(mask_path) if with_mask else None
            if mask is not None and mask.shape != depth.shape:
                raise ValueError(f'{mask_path}: mask size {mask.shape} differs from the depth '
                                 f'image {depth.shape}')
            intrinsics = cad60_intrinsics(depth.shape[1], depth.shape[0])
            truths = tuple(_truth(s, i, intrinsics, projection, track_id=p + 1)
                           for p, s in enumerate(skeletons))
            yield Frame(stamp_ns, rgb, depth_to_metres(depth), intrinsics, truths[0], mask,
                        key=str(rgb_path), video=f'{video.person}/{video.video_id}',
                        people=truths if len(truths) > 1 else ())
        stamp_ns += VIDEO_GAP_NS


def _truth(skeleton: Skeleton, i: int, intrinsics: Intrinsics, projection: str, *,
           track_id: int) -> JointSet:
    """Frame i of a skeleton as ground truth: pixels by `projection`, 3-D in the optical frame,
    the file's confidence (MISSING where it is 0)."""
    conf = skeleton.joint_conf[i]
    uv = project_joints(skeleton.joints_mm[i], intrinsics, model=projection)
    return JointSet(CAD60_JOINTS, uv, world_to_optical(skeleton.joints_mm[i]), confidence=conf,
                    source=np.where(conf > 0, DETECTED, MISSING), score=1.0, track_id=track_id)


# --------------------------------------------------------------------------------------------
# Writing (used by the synthetic renderer; files are written atomically)
# --------------------------------------------------------------------------------------------

def format_skeleton(skeleton: Skeleton) -> str:
    """The text of a CAD-60 skeleton file for `skeleton` (anatomical sides -> file slots)."""
    perm = np.asarray(_MIRROR)  # an involution: anatomical joint i goes to slot _MIRROR[i]
    joints = skeleton.joints_mm[:, perm]
    conf = skeleton.joint_conf[:, perm]
    rot = skeleton.orientations[:, perm[:N_ORIENTED]]
    rot_conf = skeleton.orientation_conf[:, perm[:N_ORIENTED]]
    lines = []
    for i, k in enumerate(skeleton.frames):
        values: list[str] = [str(int(k))]
        for j in range(N_ORIENTED):
            values += [_fmt(x) for x in rot[i, j].reshape(9)]
            values.append(_fmt(rot_conf[i, j]))
            values += [_fmt(x) for x in joints[i, j]]
            values.append(_fmt(conf[i, j]))
        for j in range(N_ORIENTED, N_JOINTS):
            values += [_fmt(x) for x in joints[i, j]]
            values.append(_fmt(conf[i, j]))
        lines.append(','.join(values) + ',')
    lines.append('END')
    return '\n'.join(lines) + '\n'


def _fmt(x: float) -> str:
    text = f'{float(x):.6g}'
    return '0' if text == '-0' else text


def write_skeleton(path: str | Path, skeleton: Skeleton) -> None:
    """Write a CAD-60 skeleton file `<id>.txt` (mirrored OpenNI labels, trailing commas, END)."""
    write_atomic(Path(path), format_skeleton(skeleton).encode())


def write_activity_labels(path: str | Path, labels: dict[str, str]) -> None:
    """Write `activityLabel.txt` from {video id: activity name} (ids: 10 digits, no commas)."""
    lines = []
    for vid, name in labels.items():
        if not _ID.match(vid):
            raise ValueError(f'video id must be 10 digits, got {vid!r}')
        if ',' in name or '\n' in name or not name.strip():
            raise ValueError(f'activity name must be non-empty without commas, got {name!r}')
        lines.append(f'{vid},{name},')
    write_atomic(Path(path), ('\n'.join(lines) + '\n').encode())


def _encode_png(path: Path, img: NDArray, compression: int) -> None:
    ok, buf = cv2.imencode('.png', img, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise ValueError(f'{path}: PNG encoding failed')
    write_atomic(path, buf.tobytes())


def write_rgb(path: str | Path, rgb: NDArray[np.uint8], *, compression: int = 1) -> None:
    """Write an (H, W, 3) uint8 RGB image as an 8-bit PNG."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f'{path}: RGB image must be (H, W, 3) uint8, got {rgb.dtype} '
                         f'{rgb.shape}')
    _encode_png(Path(path), np.ascontiguousarray(rgb[:, :, ::-1]), compression)


def write_depth(path: str | Path, depth_mm: NDArray[np.uint16], *,
                compression: int = 1) -> None:
    """Write an (H, W) uint16 millimetre depth image as a single-channel 16-bit PNG."""
    depth_mm = np.asarray(depth_mm)
    if depth_mm.dtype != np.uint16 or depth_mm.ndim != 2:
        raise ValueError(f'{path}: depth must be (H, W) uint16 millimetres, got '
                         f'{depth_mm.dtype} {depth_mm.shape}')
    _encode_png(Path(path), depth_mm, compression)


def write_mask(path: str | Path, mask: NDArray[np.bool_], *, compression: int = 1) -> None:
    """Write an (H, W) bool person mask as an 8-bit PNG (255 = person)."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f'{path}: mask must be 2-D, got shape {mask.shape}')
    _encode_png(Path(path), np.where(mask, 255, 0).astype(np.uint8), compression)


def write_people(path: str | Path, labels: NDArray[np.uint8], *, compression: int = 1) -> None:
    """Write an (H, W) uint8 person-label image (k = person k, 0 = nobody) as an 8-bit PNG."""
    labels = np.asarray(labels)
    if labels.dtype != np.uint8 or labels.ndim != 2:
        raise ValueError(f'{path}: person labels must be (H, W) uint8, got {labels.dtype} '
                         f'{labels.shape}')
    _encode_png(Path(path), labels, compression)


def write_frame(frame_dir: str | Path, k: int, rgb: NDArray[np.uint8],
                depth_mm: NDArray[np.uint16], mask: NDArray[np.bool_] | None = None) -> None:
    """Write `RGB_<k>.png`, `Depth_<k>.png` (and `Mask_<k>.png`) into a video's frame dir."""
    rgb_path, depth_path, mask_path = frame_paths(frame_dir, k)
    if np.asarray(rgb).shape[:2] != np.asarray(depth_mm).shape:
        raise ValueError(f'frame {k}: RGB {np.asarray(rgb).shape} and depth '
                         f'{np.asarray(depth_mm).shape} sizes differ')
    write_rgb(rgb_path, rgb)
    write_depth(depth_path, depth_mm)
    if mask is not None:
        write_mask(mask_path, mask)
