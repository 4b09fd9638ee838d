"""A folder of RGB-D frames with a ROS `camera_info.yaml`: what a real camera recorded, frame by
frame, without ROS (the layout of the project's real development frames).

Layouts (colour and depth paired by name; depth registered to the colour image, 16-bit PNG
millimetres or a .npy of float metres or uint16 millimetres):

- `color/NAME.(png|jpg)` and `depth/NAME.(png|npy)`: a sequence, in name order;
- `color.png` and `depth.png`: one frame;
- `color_NAME.png` and `depth_NAME.png`: separate frames, each its own video.

`camera_info.yaml` is the ROS camera calibration file (`camera_calibration` writes it, drivers
read it): `image_width`, `image_height`, `camera_matrix`, `distortion_model`,
`distortion_coefficients`. The images are taken as rectified (a non-zero distortion is refused:
no stage undistorts).

A sequence has no stamps on disk: frame k is stamped k / `fps` (default `DEFAULT_FPS`), or from
`frames.yaml` beside `camera_info.yaml` (`fps: 10`). Separate frames are one second apart and
each its own video, so that a tracker starts anew at every one.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, depth_to_metres
from pose4d_ros.datasets.frame import Frame

CAMERA_INFO = 'camera_info.yaml'
DEFAULT_FPS = 30.0
COLOR_SUFFIXES = ('.png', '.jpg', '.jpeg')
DEPTH_SUFFIXES = ('.png', '.npy')
# The first stamp: any fixed positive time (a tracker needs only differences)
T0_NS = 1_700_000_000 * 10**9


def is_frames_dir(path: str | Path) -> bool:
    """True for a folder with `camera_info.yaml` and colour frames in one of the layouts."""
    p = Path(path)
    return (p / CAMERA_INFO).is_file() and bool(_pairs(p, strict=False)[1])


def read_camera_info(path: str | Path) -> Intrinsics:
    """The intrinsics of a ROS camera calibration file (`camera_info.yaml`); ValueError naming
    the file and the field on a file that is not one, or on a distorted camera."""
    path = Path(path)
    try:
        info = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f'{path}: not a readable camera calibration file ({exc})') from exc
    if not isinstance(info, dict):
        raise ValueError(f'{path}: not a camera calibration file (a YAML mapping)')

    def matrix(key: str, n: int) -> NDArray[np.float64]:
        value = info.get(key)
        data = value.get('data') if isinstance(value, dict) else None
        try:
            a = np.asarray(data, np.float64).ravel()
        except (TypeError, ValueError):
            a = np.zeros(0)
        if a.size != n:
            raise ValueError(f'{path}: {key}.data must hold {n} numbers, got {data!r}')
        return a

    k = matrix('camera_matrix', 9)
    try:
        width, height = int(info['image_width']), int(info['image_height'])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f'{path}: image_width and image_height must be integers') from exc
    if 'distortion_coefficients' in info:
        d = matrix('distortion_coefficients', len(info['distortion_coefficients'].get('data')
                                                  or ()))
        if np.any(d != 0):
            raise ValueError(f'{path}: distortion_coefficients {d.tolist()}: the frames must '
                             'be rectified (no stage undistorts)')
    return Intrinsics(fx=float(k[0]), fy=float(k[4]), cx=float(k[2]), cy=float(k[5]),
                      width=width, height=height)


def _pairs(root: Path, *, strict: bool = True) -> tuple[bool, list[tuple[str, Path, Path]]]:
    """(is a sequence, [(name, colour file, depth file)]) in name order. With `strict`, a colour
    frame without its depth image is a ValueError naming both."""
    def first(stem: Path, suffixes: tuple[str, ...]) -> Path | None:
        return next((stem.with_suffix(s) for s in suffixes if stem.with_suffix(s).is_file()),
                    None)

    sequence = (root / 'color').is_dir()
    if sequence:
        colours = [p for p in (root / 'color').iterdir() if p.suffix.lower() in COLOR_SUFFIXES]
        depth_of = {p: root / 'depth' / p.stem for p in colours}
    elif (root / 'color.png').is_file():
        colours = [root / 'color.png']
        depth_of = {colours[0]: root / 'depth'}
    else:
        colours = [p for p in root.glob('color_*') if p.suffix.lower() in COLOR_SUFFIXES]
        depth_of = {p: root / ('depth_' + p.stem[len('color_'):]) for p in colours}
    out = []
    for c in sorted(colours):
        d = first(depth_of[c], DEPTH_SUFFIXES)
        if d is None:
            if strict:
                raise ValueError(f'{c}: no depth image beside it ({depth_of[c]}.png or .npy)')
            continue
        name = c.stem if sequence or c.stem == 'color' else c.stem[len('color_'):]
        out.append((name, c, d))
    return sequence, out


def read_depth(path: Path) -> NDArray[np.float32]:
    """A depth image in metres (NaN = no reading) from a 16-bit PNG of millimetres or a .npy
    of float metres or uint16 millimetres."""
    if path.suffix == '.npy':
        depth = np.load(path, allow_pickle=False)
    else:
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            raise ValueError(f'{path}: not a readable image')
        if depth.dtype != np.uint16:
            raise ValueError(f'{path}: depth must be a 16-bit PNG of millimetres, got '
                             f'{depth.dtype}')
    try:
        return depth_to_metres(depth)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from exc


def read_color(path: Path) -> NDArray[np.uint8]:
    """A colour image as RGB uint8."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f'{path}: not a readable image')
    return np.ascontiguousarray(bgr[:, :, ::-1])


def frames_fps(root: Path) -> float:
    """The sequence's frame rate: `frames.yaml`'s `fps`, else `DEFAULT_FPS`."""
    meta = root / 'frames.yaml'
    if not meta.is_file():
        return DEFAULT_FPS
    fps = (yaml.safe_load(meta.read_text()) or {}).get('fps')
    if not isinstance(fps, (int, float)) or not 0 < fps <= 1000:
        raise ValueError(f'{meta}: fps must be a number in (0, 1000], got {fps!r}')
    return float(fps)


def read_frames(root: str | Path, *, fps: float | None = None, hold: int = 1
                ) -> Iterator[Frame]:
    """The frames of a folder (see the module's layouts), with no ground truth; `Frame.key` is
    '<folder>/<name>' (the hand labels' key, `evaluation.real`). `hold`: separate frames are
    each held this many frames at `fps` (default 30), a still camera's stream of a still scene,
    each its own video (a tracker confirms people over frames; a single frame shows only what
    it trusts at once)."""
    root = Path(root)
    if hold < 1:
        raise ValueError(f'hold must be >= 1 frame, got {hold}')
    intrinsics = read_camera_info(root / CAMERA_INFO)
    sequence, pairs = _pairs(root)
    if not pairs:
        raise ValueError(f'{root}: no colour frames (color/NAME.png|jpg, color.png or '
                         'color_NAME.png)')
    step_ns = round(1e9 / (fps or frames_fps(root)))
    if sequence:
        hold = 1
    for k, (name, c, d) in enumerate(pairs):
        color, depth = read_color(c), read_depth(d)
        intrinsics.check_size(color.shape, f'colour image {c}')
        intrinsics.check_size(depth.shape, f'depth image {d}')
        start = T0_NS + k * (step_ns if sequence else hold * step_ns + 10**9)
        for i in range(hold):
            yield Frame(start + i * step_ns, color, depth, intrinsics, None,
                        key=f'{root.name}/{name}', video=root.name if sequence else name)
